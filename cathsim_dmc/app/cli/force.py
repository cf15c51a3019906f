"""cathsim-force: a CNN predicts the total contact force (N) from the top image.

    cathsim-force data=outputs/collect/bca-type1/<run>
    cathsim-force data=[<dataset a>,<dataset b>] force.sizes=[1000,10000,100000]

Trains one network per training-set size (nested subsets of the training episodes) and
writes force.json and force.md (test MSE in N^2 and RMSE in N on held-out episodes,
against the training-mean predictor and the network before fine-tuning), plus the
trained networks (force_model_<n>.pt) into the run folder.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

log = logging.getLogger("cathsim-force")


def run(cfg) -> dict:
    import torch
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import OmegaConf
    from tqdm import tqdm

    from cathsim_dmc.app.cli.bc import dataset_paths
    from cathsim_dmc.learning.datasets import has_keys, load_arrays
    from cathsim_dmc.learning.supervised.force import ForceConfig, markdown, train_force_sizes

    # image_key, label and every force.* value were checked before Hydra started (cathsim_dmc/app/tool_schemas.py)
    options = OmegaConf.to_container(cfg.force, resolve=True)
    options["sizes"] = tuple(int(s) for s in options["sizes"])
    force_cfg = ForceConfig(**options, seed=int(cfg.seed))
    if not force_cfg.sizes:
        raise ValueError("force.sizes=[] names no training size; e.g. force.sizes=[1000,10000]")
    paths = dataset_paths(cfg.data)
    image = f"obs_{cfg.image_key}"
    use_z = force_cfg.z_coef > 0 and has_keys(paths, ("feature_z",))
    if not has_keys(paths, (cfg.label,)):
        raise ValueError(
            f"label={cfg.label} is not in the data {paths} (collected before it was recorded); "
            f"collect again or choose label=contact_force_n"
        )
    arrays = load_arrays(paths, [image, cfg.label] + (["feature_z"] if use_z else []))
    log.info(
        "%d samples from %d episodes; Z %s",
        len(arrays["episode"]),
        len(set(arrays["episode"])),
        "regressed too" if use_z else "not in the data",
    )
    if cfg.torch_threads:
        torch.set_num_threads(int(cfg.torch_threads))
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))

    bars = {}

    def progress(size, epoch, epochs, best):
        bar = bars.get(size)
        if bar is None:
            bar = bars[size] = tqdm(total=epochs, unit="epoch", desc=f"{size:,} samples", disable=not cfg.progress_bar)
        bar.update(1)
        bar.set_postfix(val_mse=f"{best:.4f}")
        if epoch == epochs:
            bar.close()

    report = train_force_sizes(
        arrays[image], arrays[cfg.label], arrays["episode"], force_cfg, arrays.get("feature_z"), run_dir, progress
    )
    report = {"data": paths, "image_key": cfg.image_key, "label": cfg.label, "config": options, **report}
    (run_dir / "force.json").write_text(json.dumps(report, indent=2))
    table = markdown(report)
    (run_dir / "force.md").write_text(table)
    for r in report["sizes"]:
        if r["train_samples"] < r["size_requested"]:
            log.warning(
                "force.sizes asked for %d samples; the training episodes hold %d, all used",
                r["size_requested"],
                r["train_samples"],
            )
        log.info(
            "%d samples: %d updates in %.0f s (%.1f s per epoch per 10K samples)",
            r["train_samples"],
            r["updates"],
            r["seconds"],
            r["seconds"] / r["epochs"] * 10_000 / max(r["fit_samples"], 1),
        )
    print(table, end="")
    print(f"run folder: {run_dir}")
    return report


def main():
    from cathsim_dmc.app.cli._common import run_hydra

    run_hydra(run, "force")


if __name__ == "__main__":
    main()
