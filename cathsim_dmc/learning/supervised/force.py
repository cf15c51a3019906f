"""Contact-force prediction from the image (cathsim-force).

A CNN on the 1 x 80 x 80 top image (the paper's trunk, as in the BC student: three
convolutions, flatten, Linear(512) + ReLU) with an MLP head, Linear(256) + ReLU ->
Linear(1), predicting the total wire-vessel contact force f in newtons. When the
dataset carries the ENN's features Z, a Linear(512 -> |Z|) head regresses them as well:
loss = z_coef * L_Z + L_f, both mean squared errors.

`train_force_sizes` trains one network per training-set size on nested subsets of the
training episodes (each size's episodes include the smaller sizes') and scores all of
them on the same held-out episodes, next to two baselines:

* **train mean**: predict the training subset's mean force for every image;
* **before fine-tuning**: the same network with the weights it starts training from
  (its seeded random initialisation, or with `init_from` the encoder of a BC student
  and an untrained head), i.e. what training adds.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from cathsim_dmc.learning.networks import image_encoder

HIDDEN = 512


class ForceNetwork(nn.Module):
    def __init__(self, image_shape=(1, 80, 80), z_dim: int = 0):
        super().__init__()
        self.image_shape, self.z_dim = tuple(int(s) for s in image_shape), int(z_dim)
        self.encoder = image_encoder(*self.image_shape, features=HIDDEN)
        self.head = nn.Sequential(nn.Linear(HIDDEN, 256), nn.ReLU(), nn.Linear(256, 1))
        self.z_head = nn.Linear(HIDDEN, self.z_dim) if self.z_dim else None

    def forward(self, images):
        """(force in N (B,), z_hat or None) for a batch of images (uint8 or float in [0, 1])."""
        x = images.float() / 255.0 if images.dtype == torch.uint8 else images
        hidden = self.encoder(x)
        return self.head(hidden)[:, 0], (self.z_head(hidden) if self.z_head is not None else None)


@dataclass
class ForceConfig:
    sizes: tuple = (1_000, 10_000, 100_000)
    epochs: int = 20
    min_updates: int = 2_000  # small subsets still get this many gradient steps
    batch_size: int = 32
    learning_rate: float = 1e-3
    z_coef: float = 1.0  # weight of L_Z when Z is in the data
    test_fraction: float = 0.2  # episodes held out for the test MSE (same for every size)
    val_fraction: float = 0.1  # of each subset's episodes: picks the best epoch
    seed: int = 0
    init_from: str | None = None  # a cathsim-bc run folder or bc_policy.pt: start from its encoder
    # Also score without test samples above this force (N): a handful of single-physics-step
    # impulses (the mass-scaled wire striking the wall) can decide a test MSE alone.
    outlier_n: float | None = 10.0


def nested_subsets(episodes: np.ndarray, train_rows: np.ndarray, sizes, seed: int = 0) -> list:
    """[(size asked, rows)]: prefixes of the training rows taken episode by episode in a
    seeded random order, so every subset contains the smaller ones. A size beyond what
    exists gets all the training rows (and larger sizes are dropped)."""
    ids = np.unique(episodes[train_rows])
    order = np.random.default_rng(seed).permutation(ids)
    rows = np.concatenate([train_rows[episodes[train_rows] == e] for e in order]) if len(ids) else train_rows
    out = []
    for size in sorted(int(s) for s in sizes):
        out.append((size, rows[:size]))
        if size >= len(rows):
            break
    return out


def _predict(net, images, rows, batch: int = 512) -> np.ndarray:
    net.eval()
    out = []
    with torch.no_grad():
        for start in range(0, len(rows), batch):
            out.append(net(torch.from_numpy(images[rows[start : start + batch]]))[0].numpy())
    net.train()
    return np.concatenate(out) if out else np.zeros(0, np.float32)


def mse(prediction, target) -> float:
    return float(np.mean((np.asarray(prediction, np.float64) - np.asarray(target, np.float64)) ** 2))


def initial_network(image_shape, z_dim: int, cfg: ForceConfig) -> ForceNetwork:
    torch.manual_seed(cfg.seed)
    net = ForceNetwork(image_shape, z_dim)
    if cfg.init_from:
        from cathsim_dmc.learning.supervised.bc import BC_CHECKPOINT

        path = Path(cfg.init_from)
        path = path / BC_CHECKPOINT if path.is_dir() else path
        if not path.is_file():
            raise FileNotFoundError(f"force.init_from={cfg.init_from!r}: no {BC_CHECKPOINT} there")
        checkpoint = torch.load(path, map_location="cpu", weights_only=True)
        if tuple(checkpoint["image_shape"]) != net.image_shape:
            raise ValueError(
                f"force.init_from={cfg.init_from!r} takes images {checkpoint['image_shape']}, "
                f"the data has {list(net.image_shape)}"
            )
        encoder = {k[len("encoder.") :]: v for k, v in checkpoint["state_dict"].items() if k.startswith("encoder.")}
        net.encoder.load_state_dict(encoder)
    return net


def train_force(
    images, force, rows, cfg: ForceConfig, z=None, net: ForceNetwork | None = None, episodes=None, progress=None
) -> tuple:
    """Fit `net` on `rows`; the best of `val_fraction` held-out episodes is kept.

    Returns (net, info) with the number of updates, seconds and the validation MSE.
    """
    from cathsim_dmc.learning.datasets import split_by_episode

    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    if episodes is not None and cfg.val_fraction > 0 and len(np.unique(episodes[rows])) > 2:
        fit, val = split_by_episode(episodes[rows], cfg.val_fraction, cfg.seed)
        fit, val = rows[fit], rows[val]
    else:
        fit, val = rows, rows[:0]
    batches = max(1, math.ceil(len(fit) / cfg.batch_size))
    epochs = max(cfg.epochs, math.ceil(cfg.min_updates / batches))
    optimizer = torch.optim.Adam(net.parameters(), lr=cfg.learning_rate)
    use_z = z is not None and net.z_head is not None and cfg.z_coef > 0
    best, best_state, t0, updates = math.inf, None, time.perf_counter(), 0
    for epoch in range(1, epochs + 1):
        order = rng.permutation(fit)
        for start in range(0, len(order), cfg.batch_size):
            idx = np.sort(order[start : start + cfg.batch_size])
            pred, z_hat = net(torch.from_numpy(images[idx]))
            loss = ((pred - torch.from_numpy(force[idx])) ** 2).mean()
            if use_z:
                loss = loss + cfg.z_coef * ((z_hat - torch.from_numpy(z[idx])) ** 2).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            updates += 1
        if len(val):
            val_mse = mse(_predict(net, images, val), force[val])
            if val_mse < best:
                best, best_state = val_mse, copy.deepcopy(net.state_dict())
        if progress is not None:
            progress(epoch, epochs, best)
    if best_state is not None:
        net.load_state_dict(best_state)
    return net, {
        "updates": updates,
        "epochs": epochs,
        "seconds": time.perf_counter() - t0,
        "fit_samples": int(len(fit)),
        "val_samples": int(len(val)),
        "val_mse": best,
    }


def score(prediction, target) -> dict:
    value = mse(prediction, target)
    return {"mse_n2": value, "rmse_n": math.sqrt(value)}


def train_force_sizes(images, force, episodes, cfg: ForceConfig, z=None, out_dir=None, progress=None) -> dict:
    """One network per size in cfg.sizes, all scored on the same held-out episodes."""
    from cathsim_dmc.learning.datasets import split_by_episode

    force = np.asarray(force, dtype=np.float32)
    z = np.asarray(z, dtype=np.float32) if z is not None and cfg.z_coef > 0 else None
    if len(np.unique(episodes)) < 2:
        raise ValueError("force prediction needs at least 2 episodes (training and held-out test episodes)")
    train_rows, test_rows = split_by_episode(episodes, cfg.test_fraction, cfg.seed)
    target = force[test_rows]
    inliers = target <= cfg.outlier_n if cfg.outlier_n is not None else np.ones(len(target), bool)
    results = []
    for size, rows in nested_subsets(episodes, train_rows, cfg.sizes, cfg.seed):
        net = initial_network(images.shape[1:], z.shape[1] if z is not None else 0, cfg)
        before_prediction = _predict(net, images, test_rows)
        net, info = train_force(
            images,
            force,
            rows,
            cfg,
            z,
            net,
            episodes,
            (lambda e, n, b, s=len(rows): progress(s, e, n, b)) if progress else None,
        )
        if out_dir is not None:
            torch.save(
                {"state_dict": net.state_dict(), "image_shape": list(net.image_shape), "z_dim": net.z_dim},
                Path(out_dir) / f"force_model_{len(rows)}.pt",
            )
        predictions = {
            "model": _predict(net, images, test_rows),
            "train_mean": np.full(len(target), force[rows].mean()),
            "before_fine_tuning": before_prediction,
        }
        results.append(
            {
                "size_requested": size,
                "train_samples": int(len(rows)),
                "train_episodes": int(len(np.unique(episodes[rows]))),
                **{key: score(p, target) for key, p in predictions.items()},
                **info,
            }
        )
        if 0 < inliers.sum() < len(inliers):  # only when some, not all, test samples are outliers
            results[-1]["without_outliers"] = {
                key: score(p[inliers], target[inliers]) for key, p in predictions.items()
            }
    return {
        "test_samples": int(len(test_rows)),
        "test_episodes": int(len(np.unique(episodes[test_rows]))),
        "train_samples_available": int(len(train_rows)),
        "test_force_mean_n": float(target.mean()),
        "test_force_std_n": float(target.std()),
        "uses_z": z is not None,
        "outlier_n": cfg.outlier_n,
        "test_outliers": int((~inliers).sum()),
        "test_force_max_n": float(target.max()),
        "test_force_std_without_outliers_n": float(target[inliers].std()) if inliers.any() else math.nan,
        "sizes": results,
    }


def markdown(report: dict) -> str:
    """force.md: test MSE (N^2) and RMSE (N) per training size, with both baselines."""
    header = [
        "| Training samples | Network MSE (N²) | Network RMSE (N) | Train-mean MSE (N²) | Train-mean RMSE (N) "
        "| Before fine-tuning MSE (N²) | Before fine-tuning RMSE (N) |",
        "|---|---|---|---|---|---|---|",
    ]

    def table(scores_of) -> list:
        rows = list(header)
        for r in report["sizes"]:
            label = f"{r['train_samples']:,}"
            if r["train_samples"] < r["size_requested"]:
                label += f" (all there is; {r['size_requested']:,} asked)"
            cells = [label]
            for key in ("model", "train_mean", "before_fine_tuning"):
                cells += [f"{scores_of(r)[key]['mse_n2']:.4f}", f"{scores_of(r)[key]['rmse_n']:.3f}"]
            rows.append("| " + " | ".join(cells) + " |")
        return rows

    lines = table(lambda r: r)
    lines.append("")
    lines.append(
        f"Test: {report['test_samples']:,} samples from {report['test_episodes']} held-out episodes "
        f"({report.get('label', 'force')} {report['test_force_mean_n']:.3f} ± {report['test_force_std_n']:.3f} N, "
        f"max {report.get('test_force_max_n', math.nan):.3g} N); "
        f"Z regression {'on' if report['uses_z'] else 'off'}."
    )
    if all("without_outliers" in r for r in report["sizes"]):
        lines += [
            "",
            f"Without the {report['test_outliers']} test sample(s) above {report['outlier_n']:g} N "
            f"(the rest: {report['test_force_std_without_outliers_n']:.3f} N std):",
            "",
        ]
        lines += table(lambda r: r["without_outliers"])
    return "\n".join(lines) + "\n"
