"""cathsim-train: SAC (with the scripted expert's demonstrations by default) on a navigation task.

    cathsim-train task=bca aorta=type2                      # the recipe: conf/train.yaml
    cathsim-train obs=enn trainer.total_timesteps=100000 seed=1
    cathsim-train -m seed=0,1,2,3,4                         # seed sweep
    cathsim-train resume=outputs/train/bca-type1/enn/<run>  # continue from the last checkpoint

Options, their defaults and ranges: cathsim_dmc/app/train_schema.py (checked before any work).

The run folder gets: config.yaml (resolved), policy.json, tensorboard/, checkpoints/
(step_<n>.zip, last.zip), final_model.zip and eval/ (metrics.md, metrics.json, path.png,
forces.png, trajectories.npz, video) from cathsim_dmc.evaluation.rollouts, as cathsim-eval writes them.
"""

from __future__ import annotations

import logging
from pathlib import Path

log = logging.getLogger("cathsim-train")


def run(cfg) -> dict:
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import OmegaConf

    from cathsim_dmc.agents.trained import load_checkpoint_policy
    from cathsim_dmc.app.cli._common import AGENT_OPTIONS, IMAGE_OPTIONS, env_kwargs, pick
    from cathsim_dmc.app.tool_schemas import validate
    from cathsim_dmc.app.train_schema import resumed_config
    from cathsim_dmc.core.run_files import Interrupted, lock_folder
    from cathsim_dmc.evaluation.rollouts import METRICS_MD, evaluate_policy
    from cathsim_dmc.learning.rl.checkpoints import BEST_MODEL, CHECKPOINT_DIR, FINAL_MODEL, best_record
    from cathsim_dmc.learning.rl.train import make_vec_env, train
    from cathsim_dmc.suite.gym import CathSimEnv

    resume = cfg.get("resume")
    if resume:
        run_dir = Path(str(resume))
        saved = run_dir / "config.yaml"
        if not saved.is_file():
            raise FileNotFoundError(f"resume={resume!r} is not a cathsim-train run folder (no config.yaml)")
        lock_folder(run_dir)  # one process at a time continues a run, whatever its hydra.run.dir
        # The run continues with its own settings (a run of another version is refused); only the
        # step budget may be raised.
        original = resumed_config(run_dir)
        if any(o.startswith("trainer.total_timesteps=") for o in HydraConfig.get().overrides.task):
            original.trainer.total_timesteps = cfg.trainer.total_timesteps
        check_resume_overrides(resume, original, cfg, HydraConfig.get().overrides.task)
        cfg = original

    # Every setting is checked before the run folder, an environment or a model exists.
    validate(cfg)
    seed = cfg.seed
    algo = OmegaConf.to_container(cfg.algo, resolve=True)
    # rl.train reads the experimental switch with the trainer's options
    trainer = dict(
        OmegaConf.to_container(cfg.trainer, resolve=True),
        normalize_observations=cfg.experimental.normalize_observations,
    )
    train_kwargs, eval_kwargs = env_kwargs(cfg, training=True), env_kwargs(cfg)
    agent_options = pick(eval_kwargs, AGENT_OPTIONS)
    image_options = pick(eval_kwargs, IMAGE_OPTIONS)
    demos = OmegaConf.to_container(cfg.demos, resolve=True)
    task, aorta, obs = cfg.task.target, cfg.aorta.name, cfg.obs.name
    if not resume:
        log.info(
            "recipe: %s: batch_size %d, %s",
            recipe(HydraConfig.get().runtime.choices),
            cfg.algo.batch_size,
            "one features extractor shared by actor and critics"
            if cfg.algo.share_features_extractor
            else "separate features extractors for actor and critics",
        )
        run_dir = Path(HydraConfig.get().runtime.output_dir)
        run_dir.mkdir(parents=True, exist_ok=True)
        (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))

    vec_kwargs = {k: v for k, v in train_kwargs.items() if k not in ("task", "aorta", "obs")}
    env = make_vec_env(task, aorta, obs, seed, cfg.trainer.n_envs, vec_kwargs)
    try:
        result = train(
            env,
            run_dir,
            algo,
            trainer,
            seed,
            obs,
            task,
            aorta,
            resume=bool(resume),
            make_eval_env=lambda: CathSimEnv(**eval_kwargs),
            image_options=image_options,
            demos=demos,
            make_demo_env=lambda: CathSimEnv(**train_kwargs),
            env_options=agent_options,
        )
    finally:
        env.close()
    log.info(
        "trained %d steps in %.0f s (%.1f env steps/s)",
        result.steps,
        result.seconds,
        result.steps / max(result.seconds, 1e-9),
    )

    best = best_record(run_dir)
    if cfg.trainer.final_policy == "best" and best is not None:
        # Loaded as cathsim-eval loads it: the model, its normaliser and its policy.json.
        policy = load_checkpoint_policy(run_dir / CHECKPOINT_DIR / BEST_MODEL)
        log.info(
            "evaluating best.zip (step %d: %.0f%% success over %s selection episodes)",
            best["step"],
            100 * best["success_rate"],
            best.get("episodes", cfg.trainer.eval_episodes),
        )
    else:  # the final model as cathsim-eval loads it (with the averaged actor of sac_tuned)
        policy = load_checkpoint_policy(run_dir / FINAL_MODEL)
    eval_env = CathSimEnv(**eval_kwargs)
    try:
        report = evaluate_policy(
            eval_env,
            policy,
            f"sac-{obs}",
            cfg.trainer.final_eval_episodes or cfg.trainer.eval_episodes,
            seed=10_000 + seed,
            out_dir=run_dir / "eval",
            video=cfg.trainer.video,
            label={"seed": seed},
        )
    except Interrupted as error:
        raise Interrupted(
            f"training finished ({run_dir / 'final_model.zip'}); {error}; evaluate it again "
            f"with: cathsim-eval policy={run_dir} seed={10_000 + seed}"
        ) from None
    finally:
        eval_env.close()
    print((run_dir / "eval" / METRICS_MD).read_text(), end="")
    print(f"run folder: {run_dir}")
    return report


# What a resumed run takes from the command line: a larger step budget (docs/cli.md).
RESUME_MAY_CHANGE = ("trainer.total_timesteps",)


def check_resume_overrides(resume, saved, cfg, overrides) -> None:
    """ValueError naming each `key=value` of the command line (`overrides`, Hydra's) that
    differs from the resumed run's saved config (`saved`; `cfg`: the command line's
    composition), but for RESUME_MAY_CHANGE: the run continues with its own settings, and
    an override it dropped would go unnoticed. A config group chosen (`task=bca`) is
    compared by the keys it sets (`_group_keys`)."""
    from omegaconf import OmegaConf

    def plain(node):
        return OmegaConf.to_container(node, resolve=True) if OmegaConf.is_config(node) else node

    differ = []
    for override in overrides:
        key, sep, _ = override.lstrip("+").partition("=")
        if not sep or override.startswith("~") or key in ("resume", *RESUME_MAY_CHANGE):
            continue
        for compared in _group_keys(cfg, key, override.split("=", 1)[1]) or [key]:
            theirs = plain(OmegaConf.select(saved, compared))
            if compared not in RESUME_MAY_CHANGE and plain(OmegaConf.select(cfg, compared)) != theirs:
                differ.append(f"{override} (the run has {compared}={theirs!r})")
                break
    if differ:
        raise ValueError(
            f"resume={resume} continues the run with its own config.yaml, which differs from the command line in "
            f"{', '.join(differ)}; leave them out (a resumed run takes only {', '.join(RESUME_MAY_CHANGE)}) or "
            "start a new run"
        )


def _group_keys(cfg, group: str, option: str) -> list:
    """The keys that choosing `group=option` (a conf/ group) sets, [] if `group` is none: the
    one naming the option (task.target, obs.name, or the whole section when none does), and
    for a group of the global package (+experiment=) every key its file sets."""
    import yaml

    from cathsim_dmc.core.shipped import conf_root

    path = conf_root() / group / f"{option}.yaml"
    if not (conf_root() / group).is_dir():
        return []
    text = path.read_text() if path.is_file() else ""
    if "@package _global_" not in text:
        section = cfg.get(group)
        named = [f"{group}.{name}" for name in ("target", "name") if section is not None and name in section]
        return named[:1] or [group]
    body = yaml.safe_load(text) or {}
    keys = []
    for entry in body.pop("defaults", []):  # `override /obs: roadmap`: the groups it picks
        for name, picked in entry.items() if isinstance(entry, dict) else ():
            keys += _group_keys(cfg, name.replace("override", "").strip().strip("/"), str(picked))

    def leaves(node, prefix):
        for name, value in node.items():
            if isinstance(value, dict):
                leaves(value, f"{prefix}{name}.")
            else:
                keys.append(f"{prefix}{name}")

    leaves(body, "")
    return keys


def resume_in_place(argv: list) -> list:
    """`resume=<run>` continues in the run's own folder: Hydra's log of the resumed part
    goes there too (appended), unless the command line names another hydra.run.dir. The
    run's config.yaml is its config; Hydra's copy of the resumed invocation is not kept. A
    multirun (`-m resume=a,b`) is left as it is: each job continues its own run folder, and
    Hydra keeps the jobs' logs in the sweep's folders (hydra.run.dir is no sweep option)."""
    if "-m" in argv or "--multirun" in argv:
        return list(argv)
    resume = [arg.split("=", 1)[1] for arg in argv if arg.startswith("resume=")]
    if resume and resume[-1] not in ("", "null") and not any(a.startswith("hydra.run.dir=") for a in argv):
        return [*argv, f"hydra.run.dir={resume[-1]}", "hydra.output_subdir=null"]
    return list(argv)


def explicit_algo(argv: list) -> list:
    """An `algo=` on the command line is taken as it is: the image presets' settings
    (conf/algo_for_obs, chosen by train.yaml with the default algo) are then left out."""
    if any(arg.split("=", 1)[0] == "algo" for arg in argv) and "~algo_for_obs" not in argv:
        return [*argv, "~algo_for_obs"]
    return list(argv)


def recipe(choices) -> str:
    """The log's line naming the algorithm settings a run composed (Hydra's group choices)."""
    from cathsim_dmc.core.shipped import conf_root

    extra = choices.get("algo_for_obs")
    if extra and (conf_root() / "algo_for_obs" / f"{extra}.yaml").is_file():
        return f"algo={choices.get('algo')} with the image preset's settings (conf/algo_for_obs/{extra}.yaml)"
    return f"algo={choices.get('algo')}"


def main():
    import sys

    from cathsim_dmc.app.cli._common import run_hydra

    sys.argv[1:] = explicit_algo(resume_in_place(sys.argv[1:]))
    run_hydra(run, "train")


if __name__ == "__main__":
    main()
