"""cathsim-eval: run a policy on a (task, aorta) pair and report the paper's metrics.

    cathsim-eval task=bca aorta=type2 policy=expert episodes=20 seed=0
    cathsim-eval policy=outputs/train/bca-type1/<run>      # a trained agent
    cathsim-eval -m task=bca,lcca aorta=type1,type2 policy=expert   # one combined table

Writes into the run folder: metrics.json, metrics.md, trajectories.npz, path.png
(tip paths over the AP view), forces.png, and a video of the first episode.
"""

from __future__ import annotations

from pathlib import Path

# What a checkpoint records of how it saw its episodes but an explicit obs.<key>= may change at
# evaluation: the C-arm's view, the detector's noise and blur, the tracking and registration
# errors. They leave the observations' shapes as they were.
VIEW_AND_NOISE_OPTIONS = (
    "tracking_noise_m",
    "registration_error_m",
    "lao_deg",
    "view_deg_range",
    "cranial_deg_range",
    "detector_dose_ngy",
    "blur_mm",
    "tracking_source",
)


def evaluate(cfg) -> dict:
    from hydra.core.hydra_config import HydraConfig

    from cathsim_dmc.agents.trained import CheckpointPolicy, make_policy
    from cathsim_dmc.app.cli._common import env_kwargs, explicit_override
    from cathsim_dmc.core.checks import check_number
    from cathsim_dmc.evaluation.rollouts import METRICS_MD, check_report_options, evaluate_policy
    from cathsim_dmc.suite.gym import CathSimEnv

    check_report_options(cfg.episodes, cfg.video_format, cfg.video_size)
    seed = check_number("seed", cfg.seed, 0, whole=True)
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    policy = make_policy(str(cfg.policy), seed=seed, task=cfg.task.target)
    checkpoint = isinstance(policy, CheckpointPolicy)
    if checkpoint:
        print(f"evaluating {policy.path}")
    if checkpoint and explicit_override("obs") and cfg.obs.name != policy.obs_preset:
        # A checkpoint is evaluated on the observations it was trained on; a silent switch
        # would report numbers for a configuration nobody asked for.
        raise ValueError(
            f"obs={cfg.obs.name!r}, but {cfg.policy} was trained with obs={policy.obs_preset!r} and is "
            f"evaluated with it; leave obs= out"
        )
    kwargs = env_kwargs(cfg, policy=policy)
    if checkpoint and explicit_override("task.physics"):
        # A deliberate transfer test: the agent under other solver settings than it was
        # trained with (it records its own in policy.json, and those win otherwise).
        kwargs["physics"] = cfg.task.physics
    for key in VIEW_AND_NOISE_OPTIONS:
        # A robustness test: the roadmap's noise, another C-arm view or detector than in training.
        if checkpoint and explicit_override(f"obs.{key}"):
            value = cfg.obs.get(key)
            if value is None:
                kwargs.pop(key, None)
            else:
                kwargs[key] = list(value) if key.endswith("_range") else value
    env = CathSimEnv(**kwargs)
    name = Path(str(cfg.policy)).name if checkpoint else str(cfg.policy)
    try:
        report = evaluate_policy(
            env,
            policy,
            name,
            cfg.episodes,
            seed,
            out_dir,
            cfg.video,
            cfg.video_size,
            cfg.video_format,
            cfg.save_observations,
        )
    finally:
        env.close()
    print((out_dir / METRICS_MD).read_text(), end="")
    print(f"results in {out_dir}")
    return report


def main():
    from cathsim_dmc.app.cli._common import run_hydra

    run_hydra(evaluate, "eval", policy_verb="evaluating")


if __name__ == "__main__":
    main()
