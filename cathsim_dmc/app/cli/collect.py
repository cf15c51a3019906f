"""cathsim-collect: record demonstrations from the scripted expert or a trained agent.

    cathsim-collect task=bca aorta=type1 policy=expert episodes=200
    cathsim-collect policy=outputs/train/bca-type1/enn/<run> episodes=100   # Z recorded too
    cathsim-collect out=outputs/collect/bca-type1/<run> episodes=400       # resume or grow

Writes a dataset folder (manifest.json + shard_<n>.npz; layout in
cathsim_dmc/agents/collect.py) that cathsim-bc and cathsim-force read.
"""

from __future__ import annotations

import logging
from pathlib import Path

log = logging.getLogger("cathsim-collect")


def run(cfg) -> dict:
    from hydra.core.hydra_config import HydraConfig

    from cathsim_dmc.agents.collect import collect
    from cathsim_dmc.app.cli._common import IMAGE_OPTIONS, env_kwargs, pick
    from cathsim_dmc.core.checks import check_number
    from cathsim_dmc.core.run_files import Interrupted, lock_folder
    from cathsim_dmc.learning.datasets import MANIFEST, read_manifest

    kwargs = env_kwargs(cfg)
    # The dataset always records every modality (supervised/collect.py); the obs group gives the
    # image options, and a trained policy's own options win inside `collect`.
    images = pick(kwargs, IMAGE_OPTIONS)
    options = {k: v for k, v in kwargs.items() if k not in ("task", "aorta", "obs", *IMAGE_OPTIONS)}
    out = Path(str(cfg.out)) if cfg.get("out") else Path(HydraConfig.get().runtime.output_dir)
    episodes = check_number("episodes", cfg.episodes, 1, whole=True)
    if cfg.get("out") and not (out.exists() and not out.is_dir()):  # (a file: `collect` says so)
        lock_folder(out)  # outside the Hydra run folder, which its own lock holds
    try:
        manifest = collect(
            out,
            cfg.task.target,
            cfg.aorta.name,
            str(cfg.policy),
            episodes,
            check_number("episodes_per_shard", cfg.episodes_per_shard, 1, whole=True),
            check_number("seed", cfg.seed, 0, whole=True),
            options,
            images,
            show_progress=cfg.progress_bar,
            action_noise_std=check_number("action_noise_std", cfg.action_noise_std, 0.0),
        )
    except KeyboardInterrupt:
        # Every finished shard is in the manifest (written atomically after each shard).
        kept = read_manifest(out / MANIFEST)["episodes"] if (out / MANIFEST).is_file() else 0
        raise Interrupted(
            f"collection stopped; {kept} finished episodes kept in {out}; continue with: "
            f"cathsim-collect out={out} episodes={episodes}"
        ) from None
    print(
        f"{manifest['episodes']} episodes, {manifest['samples']} samples, "
        f"{manifest['successes']} reached the target; dataset in {out}"
    )
    return manifest


def main():
    from cathsim_dmc.app.cli._common import run_hydra

    run_hydra(run, "collect", policy_verb="collecting")


if __name__ == "__main__":
    main()
