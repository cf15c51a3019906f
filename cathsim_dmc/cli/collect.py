"""cathsim-collect: record demonstrations from the scripted expert or a trained agent.

    cathsim-collect task=bca aorta=type1 policy=expert episodes=200
    cathsim-collect policy=outputs/train/bca-type1/enn/<run> episodes=100   # Z recorded too
    cathsim-collect out=outputs/collect/bca-type1/<run> episodes=400       # resume or grow

Writes a dataset folder (manifest.json + shard_<n>.npz; layout in
cathsim_dmc/rl/collect.py) that cathsim-bc and cathsim-force read.
"""

from __future__ import annotations

import logging
from pathlib import Path

log = logging.getLogger("cathsim-collect")


def task_options(cfg) -> dict:
    from omegaconf import OmegaConf

    options = dict(delta_m=cfg.task.delta_m, success_reward=cfg.task.success_reward, dense=cfg.task.dense,
                   max_steps=cfg.task.max_steps)
    params = cfg.aorta.get("params")
    if params is not None:
        options["aorta_params"] = OmegaConf.to_container(params, resolve=True)
    return options


def run(cfg) -> dict:
    from hydra.core.hydra_config import HydraConfig

    from cathsim_dmc.cli.eval import image_options
    from cathsim_dmc.rl.collect import collect

    out = Path(str(cfg.out)) if cfg.get("out") else Path(HydraConfig.get().runtime.output_dir)
    manifest = collect(out, cfg.task.target, cfg.aorta.name, str(cfg.policy), int(cfg.episodes),
                       int(cfg.episodes_per_shard), int(cfg.seed), task_options(cfg), image_options(cfg.obs),
                       show_progress=cfg.progress_bar, action_noise_std=float(cfg.action_noise_std))
    print(f"{manifest['episodes']} episodes, {manifest['samples']} samples, "
          f"{manifest['successes']} reached the target; dataset in {out}")
    return manifest


def main():
    from cathsim_dmc.cli._common import run_hydra
    from cathsim_dmc.observables import OBSERVATION_PRESETS
    from cathsim_dmc.policies import BUILTIN_POLICIES
    from cathsim_dmc.tasks import TARGETS, aorta_choices

    run_hydra(run, "collect", {
        "task": lambda: TARGETS, "aorta": aorta_choices,
        "policy": lambda: sorted(BUILTIN_POLICIES), "obs": lambda: sorted(OBSERVATION_PRESETS),
    }, paths_allowed=("policy",))


if __name__ == "__main__":
    main()
