"""Shared by the Hydra entry points: validate choices before Hydra starts.

Hydra reports an unknown config-group option as a multi-line error with exit status 1.
Our tools promise one line naming the valid choices and exit status 2, so the
command-line overrides for the axes we know are checked first.
"""

from __future__ import annotations

import sys
from typing import Callable, Mapping, Sequence

USAGE_ERROR = 2
INTERRUPTED = 130  # 128 + SIGINT, as a shell reports a process Ctrl-C stopped
ASSET_FOLDER_OPTION = "folder"  # conf/aorta/folder.yaml: an asset folder given as aorta=DIR


def fail(message: str) -> "NoReturn":  # noqa: F821
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(USAGE_ERROR)


def interrupted(error: KeyboardInterrupt) -> "NoReturn":  # noqa: F821
    """Ctrl-C: one line (what was kept, how to continue; `run_files.Interrupted` says it) and
    exit status 130, no traceback."""
    from tqdm import tqdm

    for bar in list(getattr(tqdm, "_instances", ())):  # an open bar would share the line
        bar.close()
    print(f"interrupted: {error or 'stopped before it finished'}", file=sys.stderr)
    raise SystemExit(INTERRUPTED)


def check_overrides(
    argv: Sequence[str], choices: Mapping[str, Callable[[], Sequence[str]]], paths_allowed: Sequence[str] = ()
) -> None:
    """Exit with status 2 if `key=value` (or `key=a,b` in a sweep) names an unknown choice.

    For keys in `paths_allowed` an existing file or folder is accepted too (a checkpoint).
    """
    from pathlib import Path

    for arg in argv:
        if arg.startswith("-") or "=" not in arg:
            continue
        key, _, value = arg.lstrip("+~").partition("=")
        if key not in choices:
            continue
        valid = list(choices[key]())
        for item in value.split(","):
            if item in valid or (key, item) == ("aorta", ASSET_FOLDER_OPTION):  # from expand_aorta_folder
                continue
            if key in paths_allowed:
                if not Path(item).exists():
                    fail(f"{key}={item!r} is neither one of {valid} nor an existing checkpoint path")
            else:
                fail(f"{key}={item!r} is not valid; choose one of {valid}")


def expand_aorta_folder(argv: Sequence[str], choices: Sequence[str]) -> list:
    """`aorta=DIR` (an asset folder: meta.json inside) -> `aorta=folder aorta.name=<DIR,
    absolute> aorta.label=<DIR's name>`, which Hydra can compose: the run folder and the
    tables then carry the folder's name. Other arguments pass unchanged; a value that is
    neither a known aorta nor an asset folder exits with one line.
    """
    from pathlib import Path

    out = []
    for arg in argv:
        key, sep, value = arg.partition("=")
        if key != "aorta" or not sep or value in choices or "," in value:
            out.append(arg)
            continue
        folder = Path(value).expanduser()
        if not (folder / "meta.json").is_file():
            what = "a folder without meta.json" if folder.is_dir() else "not a folder"
            fail(
                f"aorta={value!r} is neither one of {list(choices)} nor an asset folder ({what}; "
                "make one with cathsim-aorta)"
            )
        folder = folder.resolve()
        out += [f"aorta={ASSET_FOLDER_OPTION}", f"aorta.name={folder}", f"aorta.label={folder.name}"]
    return out


def check_composes(config_name: str, argv: Sequence[str]) -> None:
    """Compose the tool's config with the command line's overrides, as Hydra is about to,
    and exit with status 2 and one line if that fails: an unknown key, a value of the
    wrong type or out of range (the schemas of cathsim_dmc.app.train_schema), a task value the task
    cannot use (`env_kwargs`), a malformed override, a missing config option. Hydra itself
    would print several lines and exit 1, after making the run folder.

    A sweep (-m) or a Hydra flag (--cfg, --help, ...) is left to Hydra.
    """
    if any(arg.startswith("-") for arg in argv):
        return
    from hydra import compose, initialize_config_dir
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    from cathsim_dmc.app.tool_schemas import check_known_keys, register_schemas, tool_schemas, validate
    from cathsim_dmc.core.shipped import conf_root

    register_schemas()
    try:
        with initialize_config_dir(config_dir=str(conf_root()), version_base="1.3", job_name=config_name):
            cfg = compose(config_name, overrides=list(argv))
        if config_name in tool_schemas():  # its keys and ranges, before Hydra makes the run folder
            validate(cfg, config_name)
        else:
            check_known_keys(cfg, None)
        if "task" in cfg and "aorta" in cfg:  # the task's own ranges and names (tasks.check_options)
            env_kwargs(cfg, training=config_name == "train")
    except (HydraException, OmegaConfBaseException) as error:
        fail(composition_error(error))
    except ValueError as error:
        fail(str(error))


def composition_error(error: Exception) -> str:
    """One line for a failed composition. A value the schema refuses names its key and
    value; otherwise Hydra's problem and hint are kept (its message spans lines: the
    problem, a hint, the key again, a link)."""
    from omegaconf.errors import OmegaConfBaseException

    cause = error
    while cause is not None and not (isinstance(cause, OmegaConfBaseException) and getattr(cause, "full_key", None)):
        cause = cause.__cause__
    if cause is not None and "not in" in str(cause).splitlines()[0]:  # an unknown key
        return f"unknown option {cause.full_key}: {str(cause).splitlines()[0]}"
    if cause is not None and getattr(cause, "value", None) is not None:  # a value of the wrong type
        problem = str(cause).splitlines()[0].rstrip(".")
        if isinstance(cause.value, float) and cause.value.is_integer() and "Integer" in problem:  # 1e12
            return (
                f"{cause.full_key}={cause.value:g} is written as a decimal number; an integer is needed: "
                f"write {int(cause.value)}"
            )
        return f"{cause.full_key}={cause.value!r}: {problem}"
    lines = [line.strip().rstrip(".:") for line in str(error).splitlines()]
    keep = [
        line
        for line in lines
        if line and not line.startswith(("full_key", "object_type", "See https", "Set the environment"))
    ]
    message = "; ".join(keep[:4]) if keep else type(error).__name__
    override = getattr(error, "override", None)  # a malformed key=value names itself
    return f"cannot parse {override!r}: {message}" if override else message


def register_resolvers() -> None:
    """`${pid:}` in conf/: default run folders carry the process id after the time (to the
    microsecond), so runs started at once never share one (conf/hydra/output)."""
    import os

    from omegaconf import OmegaConf

    OmegaConf.register_new_resolver("pid", os.getpid, replace=True)


def run_hydra(
    task_function,
    config_name: str,
    argv_choices: Mapping[str, Callable[[], Sequence[str]]],
    paths_allowed: Sequence[str] = (),
):
    """Validate argv, then run `task_function` as a Hydra app on the shipped conf/; Ctrl-C
    at any point ends with one line and exit status 130."""
    try:
        return _run_hydra(task_function, config_name, argv_choices, paths_allowed)
    except KeyboardInterrupt as error:  # Hydra passes it on from the task, as from composing
        interrupted(error)


def _run_hydra(
    task_function,
    config_name: str,
    argv_choices: Mapping[str, Callable[[], Sequence[str]]],
    paths_allowed: Sequence[str] = (),
):
    import hydra

    from cathsim_dmc.app.tool_schemas import register_schemas
    from cathsim_dmc.core.shipped import conf_root

    register_schemas()  # conf/ composes on them
    register_resolvers()
    if "aorta" in argv_choices:
        sys.argv[1:] = expand_aorta_folder(sys.argv[1:], list(argv_choices["aorta"]()))
    check_overrides(sys.argv[1:], argv_choices, paths_allowed)
    check_composes(config_name, sys.argv[1:])

    def guarded(cfg):
        # Hydra prints a traceback for exceptions from the task; a bad value in the
        # config is the user's input, so it gets our one-line error (SystemExit passes),
        # as does a machine without the C compiler that physics=fast needs once, and a run
        # folder another run holds. Imported here: a refused command line never loads
        # MuJoCo, SciPy or torch.
        from cathsim_dmc.core.run_files import FolderInUse
        from cathsim_dmc.sim.wall_field import NativeBuildError

        try:
            return task_function(cfg)
        except (ValueError, FileNotFoundError, MemoryError, NativeBuildError, FolderInUse) as error:
            fail(str(error))

    guarded.__name__ = getattr(task_function, "__name__", "app")
    guarded.__module__ = getattr(task_function, "__module__", __name__)
    app = hydra.main(version_base="1.3", config_path=str(conf_root()), config_name=config_name)(guarded)
    return app()


def explicit_override(key: str) -> bool:
    """Whether the command line set `key` (not only the config's default)."""
    from hydra.core.hydra_config import HydraConfig

    return any(o.lstrip("+~").split("=", 1)[0] == key for o in HydraConfig.get().overrides.task)


# Options that change what an agent sees or drives. A checkpoint records them (policy.json)
# and is evaluated, and replayed for datasets, with them whatever the command line says
# (cathsim-eval lets an explicit task.physics= win: a transfer test between settings).
IMAGE_OPTIONS = ("renderer", "style", "lao_deg", "tracking_noise_m", "registration_error_m")
AGENT_OPTIONS = ("extra_observations", "physics", "catheter")


def pick(options: Mapping, keys: Sequence[str]) -> dict:
    return {key: options[key] for key in keys if key in options}


def env_kwargs(cfg, training: bool = False, policy=None) -> dict:
    """`CathSimEnv(**...)` / `tasks.load(**...)` arguments from a tool's Hydra config.

    Reads the `task` group (target, success radius and reward, time limit, physics
    settings, catheter), `aorta` (name, generator parameters), `obs` (preset, renderer, style,
    LAO angle), `experimental.extra_observations` and, with `training`, the training reward (`reward` group): evaluation
    always scores the paper's task. With `policy` a CheckpointPolicy, its observation
    preset and the options it was trained with win. The task's values are checked here,
    so that a bad one fails before any work (`tasks.check_options`).
    """
    from omegaconf import OmegaConf

    from cathsim_dmc import tasks
    from cathsim_dmc.agents.trained import CheckpointPolicy
    from cathsim_dmc.app.train_schema import TaskConfig

    task = cfg.task
    kwargs = dict(
        task=task.target,
        aorta=cfg.aorta.name,
        delta_m=task.delta_m,
        success_reward=task.success_reward,
        dense=task.dense,
        max_steps=task.max_steps,
    )
    for key in ("start_rotation_rad", "start_rotation_jitter_rad", "start_insertion_jitter_m"):
        # Only a changed start: a dataset's task options (compared when it is continued) stay as before.
        if task.get(key) is not None and task[key] != getattr(TaskConfig, key):
            kwargs[key] = task[key]
    if task.get("physics") is not None:
        kwargs["physics"] = task.physics
    if task.get("catheter") is not None:
        kwargs["catheter"] = task.catheter
    params = cfg.aorta.get("params")
    if params is not None:
        kwargs["aorta_params"] = OmegaConf.to_container(params, resolve=True)
    obs = cfg.get("obs")
    if obs is not None:
        if "extra" in obs:  # an untyped group: say where the option went rather than ignore it
            raise ValueError("obs.extra is now experimental.extra_observations (cathsim-train)")
        kwargs["obs"] = obs.name
        kwargs.update({key: obs[key] for key in IMAGE_OPTIONS if obs.get(key) is not None})
        for key in ("lao_deg", "tracking_noise_m", "registration_error_m"):
            if not kwargs.get(key):  # the AP view, no noise: recorded as before the options existed
                kwargs.pop(key, None)
    experimental = cfg.get("experimental")
    if experimental is not None and experimental.get("extra_observations"):
        kwargs["extra_observations"] = tuple(experimental.extra_observations)
    if training and cfg.get("reward") is not None:
        kwargs.update(reward=cfg.reward.kind, progress_weight=cfg.reward.progress_weight)
    if isinstance(policy, CheckpointPolicy):  # a trained agent sees and drives what it was trained with
        kwargs.update(obs=policy.obs_preset, **policy.image_options, **policy.env_options)
    tasks.check_options(**{k: v for k, v in kwargs.items() if k not in ("task", "aorta", "obs")})
    return kwargs
