"""Behavioural cloning: an image-only student imitates demonstrations (cathsim-bc).

The student is the paper's network on the 1 x 80 x 80 top image:

    Conv2d(32, 8, s4) -> Conv2d(64, 4, s2) -> Conv2d(64, 3, s1), ReLU each, flatten (2,304)
    -> Linear(512) + ReLU -> Linear(2): the mean of a Gaussian over [insertion, rotation],
    whose log-std is a learned parameter that does not depend on the image.

Loss = -mean log N(a_expert | mean, std) - beta * entropy + lambda * sum(w^2) over the
weight matrices and kernels (not biases, not the log-std); optionally + c * MSE(Z_hat, Z)
from an extra Linear(512 -> |Z|) head: distilling the ENN's features into the student.
The student acts with the mean, clipped to [-1, 1].
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn

from cathsim_dmc.learning.networks import image_encoder

BC_CHECKPOINT = "bc_policy.pt"
HIDDEN = 512
ACTION_DIM = 2
# The obs preset that gives the student its image, for evaluation.
PRESET_FOR_IMAGE = {"pixels": "pixels", "guidewire_mask": "pixels_mask"}


class BCNetwork(nn.Module):
    """The paper's image CNN with a Gaussian action head (and an optional Z head)."""

    def __init__(self, image_shape=(1, 80, 80), z_dim: int = 0, init_log_std: float = 0.0):
        super().__init__()
        self.image_shape, self.z_dim = tuple(int(s) for s in image_shape), int(z_dim)
        self.encoder = image_encoder(*self.image_shape, features=HIDDEN)
        self.mean = nn.Linear(HIDDEN, ACTION_DIM)
        self.log_std = nn.Parameter(torch.full((ACTION_DIM,), float(init_log_std)))
        self.z_head = nn.Linear(HIDDEN, self.z_dim) if self.z_dim else None

    def forward(self, images):
        """(mean, log_std, z_hat or None) for a batch of images (uint8 or float in [0, 1])."""
        x = images.float() / 255.0 if images.dtype == torch.uint8 else images
        hidden = self.encoder(x)
        z = self.z_head(hidden) if self.z_head is not None else None
        return self.mean(hidden), self.log_std.expand(len(x), -1), z


def weight_l2(net: nn.Module) -> torch.Tensor:
    return sum((p**2).sum() for name, p in net.named_parameters() if name.endswith("weight"))


def bc_loss(net: BCNetwork, images, actions, entropy_coef: float, l2_coef: float, z=None, z_coef: float = 0.0):
    """(loss, terms): NLL of the expert actions - beta * entropy + lambda * L2 (+ c * Z MSE)."""
    mean, log_std, z_hat = net(images)
    dist = torch.distributions.Normal(mean, log_std.exp())
    nll = -dist.log_prob(actions).sum(-1).mean()
    entropy = dist.entropy().sum(-1).mean()
    l2 = weight_l2(net)
    loss = nll - entropy_coef * entropy + l2_coef * l2
    terms = {
        "nll": nll.item(),
        "entropy": entropy.item(),
        "l2": l2.item(),
        "action_mse": ((mean - actions) ** 2).mean().item(),
    }
    if z is not None and z_coef > 0:
        z_mse = ((z_hat - z) ** 2).mean()
        loss = loss + z_coef * z_mse
        terms["z_mse"] = z_mse.item()
    terms["loss"] = loss.item()
    return loss, terms


@dataclass
class BCConfig:
    epochs: int = 50
    batch_size: int = 32
    learning_rate: float = 1e-3
    entropy_coef: float = 1e-3
    l2_coef: float = 1e-5
    distill_coef: float = 0.0  # > 0 and Z in the data: regress Z from the image too
    val_fraction: float = 0.1
    frames: int = 1  # the latest image and the frames - 1 before it, stacked as channels
    seed: int = 0


@dataclass
class BCResult:
    net: BCNetwork
    history: list = field(default_factory=list)
    seconds: float = 0.0
    train_rows: np.ndarray | None = None
    val_rows: np.ndarray | None = None


def _evaluate(net, images, actions, rows, cfg, z=None, batch: int = 256) -> dict:
    totals, count = {}, 0
    net.eval()
    with torch.no_grad():
        for start in range(0, len(rows), batch):
            idx = rows[start : start + batch]
            zb = torch.from_numpy(z[idx]) if z is not None else None
            _, terms = bc_loss(
                net,
                torch.from_numpy(images[idx]),
                torch.from_numpy(actions[idx]),
                cfg.entropy_coef,
                cfg.l2_coef,
                zb,
                cfg.distill_coef,
            )
            for key, value in terms.items():
                totals[key] = totals.get(key, 0.0) + value * len(idx)
            count += len(idx)
    net.train()
    return {key: value / max(count, 1) for key, value in totals.items()}


def train_bc(
    images: np.ndarray,
    actions: np.ndarray,
    episodes: np.ndarray,
    cfg: BCConfig,
    z: np.ndarray | None = None,
    progress=None,
    log=None,
) -> BCResult:
    """Fit a student to (image, action) pairs; whole episodes held out for validation.

    `images` (N, C, H, W) uint8, `actions` (N, 2) float32, `episodes` (N,) ids, `z` (N, F).
    `progress(epoch, train_terms, val_terms)` is called after each epoch.
    """
    from cathsim_dmc.learning.datasets import split_by_episode

    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    actions = np.asarray(actions, dtype=np.float32)
    z = np.asarray(z, dtype=np.float32) if z is not None and cfg.distill_coef > 0 else None
    if cfg.val_fraction > 0 and len(np.unique(episodes)) > 1:
        train_rows, val_rows = split_by_episode(episodes, cfg.val_fraction, cfg.seed)
    else:
        train_rows, val_rows = np.arange(len(actions)), np.arange(0)
    net = BCNetwork(images.shape[1:], z.shape[1] if z is not None else 0)
    optimizer = torch.optim.Adam(net.parameters(), lr=cfg.learning_rate)
    history, t0 = [], time.perf_counter()
    for epoch in range(1, cfg.epochs + 1):
        order = rng.permutation(train_rows)
        sums, n = {}, 0
        for start in range(0, len(order), cfg.batch_size):
            idx = np.sort(order[start : start + cfg.batch_size])  # sorted: faster gathers
            zb = torch.from_numpy(z[idx]) if z is not None else None
            loss, terms = bc_loss(
                net,
                torch.from_numpy(images[idx]),
                torch.from_numpy(actions[idx]),
                cfg.entropy_coef,
                cfg.l2_coef,
                zb,
                cfg.distill_coef,
            )
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            for key, value in terms.items():
                sums[key] = sums.get(key, 0.0) + value * len(idx)
            n += len(idx)
        train_terms = {key: value / n for key, value in sums.items()}
        val_terms = _evaluate(net, images, actions, val_rows, cfg, z) if len(val_rows) else {}
        history.append(
            {
                "epoch": epoch,
                "seconds": time.perf_counter() - t0,
                **{f"train_{k}": v for k, v in train_terms.items()},
                **{f"val_{k}": v for k, v in val_terms.items()},
            }
        )
        if progress is not None:
            progress(epoch, train_terms, val_terms)
    return BCResult(net, history, time.perf_counter() - t0, train_rows, val_rows)


# -- checkpoints ------------------------------------------------------------------
def save_bc(
    net: BCNetwork,
    run_dir,
    image_key: str,
    image_options: dict | None = None,
    extra: dict | None = None,
    frames: int = 1,
) -> Path:
    """bc_policy.pt (weights + shape) and policy.json (how to evaluate it); atomic writes."""
    from cathsim_dmc.core.run_files import write_atomic, write_policy_file

    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    path = run_dir / BC_CHECKPOINT
    state = {
        "state_dict": net.state_dict(),
        "image_shape": list(net.image_shape),
        "z_dim": net.z_dim,
        "image_key": image_key,
        "frames": int(frames),
    }
    write_atomic(path, lambda tmp: torch.save(state, tmp))
    info = {
        "algo": "bc",
        "obs": PRESET_FOR_IMAGE[image_key],
        "image_key": image_key,
        "image_options": dict(image_options or {}),
        **(extra or {}),
    }
    write_policy_file(run_dir, info, indent=2)
    return path


class BCPolicyModel:
    """A loaded student with SB3's `predict` signature, so CheckpointPolicy can drive it.

    A student trained on `frames` > 1 stacked images keeps the latest ones; `reset()`
    empties the buffer at an episode's start, and the first image then fills it.
    """

    def __init__(self, net: BCNetwork, image_key: str, frames: int = 1):
        self.net, self.image_key, self.frames = net.eval(), image_key, int(frames)
        self._recent = deque(maxlen=self.frames)

    def reset(self) -> None:
        self._recent.clear()

    def predict(self, observation, deterministic: bool = True):
        image = np.asarray(observation[self.image_key])
        if self.frames > 1:
            self._recent.extend([image] * (self.frames if not self._recent else 1))
            image = np.concatenate(self._recent, axis=0)
        with torch.no_grad():
            mean, log_std, _ = self.net(torch.from_numpy(image[None]))
            action = mean if deterministic else torch.distributions.Normal(mean, log_std.exp()).sample()
        return np.clip(action[0].numpy(), -1.0, 1.0).astype(np.float32), None


def load_bc_policy(path) -> BCPolicyModel:
    checkpoint = torch.load(Path(path), map_location="cpu", weights_only=True)
    net = BCNetwork(checkpoint["image_shape"], checkpoint["z_dim"])
    net.load_state_dict(checkpoint["state_dict"])
    return BCPolicyModel(net, checkpoint["image_key"], checkpoint.get("frames", 1))


def epoch_seconds_per_10k(history: list, samples: int) -> float:
    """Mean wall time of one epoch scaled to 10,000 training samples."""
    if not history or samples == 0:
        return math.nan
    return history[-1]["seconds"] / len(history) * 10_000 / samples
