"""Shared by the Hydra entry points: bad input gets one line and exit status 2, before any work.

Hydra composes a tool's config once. Its own errors (an unknown config-group option or key,
a value of the wrong type, a malformed override) would print several lines and exit with
status 1; they reach `run_hydra` instead (HYDRA_FULL_ERROR) and become one line
(`composition_error`). What Hydra cannot check (the schemas' ranges, the task's own values,
the policy, the output folders) `check_config` checks before Hydra makes the run folder
(the CheckConfig callback of conf/hydra/output/), or as a sweep's job starts.

Two arguments are read before Hydra, as it cannot compose them: `aorta=DIR` (an asset
folder) and `policy=RUN` (a trained agent, whose task and aorta it takes).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Mapping, Sequence

from cathsim_dmc.core.registry import IMAGE_OPTIONS

USAGE_ERROR = 2
INTERRUPTED = 130  # 128 + SIGINT, as a shell reports a process Ctrl-C stopped
ASSET_FOLDER_OPTION = "folder"  # conf/aorta/folder.yaml: an asset folder given as aorta=DIR
SCHEMA_OPTION = "schema"  # each typed group's schema, an option Hydra lists but no one chooses
# Files of a finished evaluation (cathsim_dmc.evaluation.rollouts): a run folder holding them
# is refused unless overwrite=true.
EVALUATION_RESULTS = ("metrics.json", "trajectories.npz")

# Whether CheckConfig checked this run before Hydra made its folder ("checked"), and whether
# the tool's own function has started ("started": an error past it is not the command line's).
_state = {"checked": False, "started": False}


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


def _given(argv: Sequence[str]) -> dict:
    """key -> value of the command line's `key=value` overrides (the last one wins)."""
    return {
        arg.lstrip("+~").split("=", 1)[0]: arg.split("=", 1)[1]
        for arg in argv
        if "=" in arg and not arg.startswith("-")
    }


def expand_aorta_folder(argv: Sequence[str], choices: Sequence[str]) -> list:
    """`aorta=DIR` (an asset folder: meta.json inside) -> `aorta=folder aorta.name=<DIR,
    absolute> aorta.label=<DIR's name>`, which Hydra can compose: the run folder and the
    tables then carry the folder's name. Other arguments pass unchanged (`aorta=folder
    aorta.name=DIR` too, the form a sweep over folders takes); a value that is neither a
    known aorta nor an asset folder exits with one line.
    """
    out = []
    for arg in argv:
        key, sep, value = arg.partition("=")
        if key != "aorta" or not sep or value in (*choices, ASSET_FOLDER_OPTION) or "," in value:
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


def policy_scenario(argv: Sequence[str], verb: str) -> list:
    """`policy=<run folder or checkpoint>`: the task and aorta its policy.json names, as
    `task=` and `aorta=` overrides, unless the command line gives them; printed (`verb`:
    "evaluating"), so a run is never scored on another task without a word. A folder
    without the run's checkpoint, or without policy.json, exits with one line here."""
    given = _given(argv)
    policy = given.get("policy")
    if not policy or "," in policy or not Path(policy).exists():  # a built-in name, a sweep, or refused later
        return list(argv)
    from cathsim_dmc.agents.trained import policy_info

    try:
        _, info = policy_info(policy)
    except (FileNotFoundError, ValueError) as error:
        fail(str(error))
    taken = [
        f"{group}={info[group]}"
        for group, field in (("task", "task.target"), ("aorta", "aorta.name"))
        if info.get(group) is not None and group not in given and field not in given
    ]
    if taken:
        print(f"{verb} on {' '.join(taken)} from the run's policy.json (task= and aorta= choose others)")
    return [*argv, *taken]


def check_policy(value: str) -> None:
    """ValueError unless `policy=` is a built-in policy, the shipped navigator or an existing path."""
    from cathsim_dmc.agents.trained import PRETRAINED_KINDS
    from cathsim_dmc.control.policies import BUILTIN_POLICIES

    valid = sorted([*BUILTIN_POLICIES, *PRETRAINED_KINDS])
    if value not in valid and not Path(value).exists():
        raise ValueError(f"policy={value!r} is neither one of {valid} nor an existing checkpoint path")


def check_config(cfg, tool: str, run_dir) -> None:
    """ValueError naming the first value of `tool`'s composed config that Hydra did not check:
    a key past the schema (`+key=`), a value out of its range (cathsim_dmc/app/train_schema.py,
    tool_schemas.py), a task value the task cannot use (`env_kwargs`), an unknown policy, an
    output folder that cannot be written (`run_dir`, Hydra's run folder, or an `out=`), and for
    cathsim-eval a run folder that holds a finished evaluation (without overwrite=true)."""
    from dataclasses import fields

    from cathsim_dmc.app.tool_schemas import check_known_keys, tool_schemas, validate
    from cathsim_dmc.core.run_files import check_writable_folder

    schema = tool_schemas().get(tool)
    if schema is not None:
        validate(cfg, tool)
    else:
        check_known_keys(cfg, None)
    if "policy" in cfg:
        check_policy(str(cfg.policy))
        catheter = cfg.task.get("catheter") if "task" in cfg else None
        if catheter:  # asked of an agent trained without one (its recorded options say so)
            from cathsim_dmc.agents.trained import check_catheter, recorded_env_options

            options = recorded_env_options(str(cfg.policy), cfg.task.target)
            if options is not None:
                check_catheter(str(cfg.policy), catheter, options)
    check_writable_folder("hydra.run.dir", run_dir)
    for spec in fields(schema) if schema is not None else ():
        if spec.metadata.get("folder") and cfg.get(spec.name):
            check_writable_folder(spec.name, cfg[spec.name])
    if tool == "eval" and not cfg.overwrite:
        found = [name for name in EVALUATION_RESULTS if (Path(str(run_dir)) / name).is_file()]
        if found:
            raise ValueError(
                f"hydra.run.dir={str(run_dir)!r} holds the results of an evaluation ({', '.join(found)}); "
                "pass overwrite=true to replace them, or choose another folder"
            )
    if "task" in cfg and "aorta" in cfg:  # the task's own ranges and names (tasks.check_options)
        env_kwargs(cfg, training=tool == "train")


def check_or_fail(cfg, tool: str, run_dir) -> None:
    """`check_config`, its error as one line with exit status 2."""
    import logging

    from omegaconf.errors import OmegaConfBaseException

    # The task's checks import the simulator, whose OpenGL backend logs at INFO into Hydra's
    # log handler: not this check's output, and no line beside a refusal's one.
    disabled = logging.root.manager.disable
    logging.disable(max(disabled, logging.INFO))
    try:
        check_config(cfg, tool, run_dir)
    except OmegaConfBaseException as error:  # e.g. a mandatory value left out (aorta=folder)
        fail(composition_error(error))
    except (ValueError, FileNotFoundError) as error:
        fail(str(error))
    finally:
        logging.disable(disabled)


def check_before_the_run(config) -> None:
    """A single run's config, as Hydra composed it (with its `hydra` node), before Hydra makes
    the run folder (conf/hydra/output's CheckConfig callback)."""
    check_or_fail(config, config.hydra.job.config_name, config.hydra.run.dir)
    _state["checked"] = True


def composition_error(error: Exception) -> str:
    """One line for a failed composition. An unknown config-group option names the valid
    ones; a value the schema refuses names its key and value; otherwise Hydra's problem and
    hint are kept (its message spans lines: the problem, a hint, the key again, a link)."""
    from hydra.errors import MissingConfigException
    from omegaconf.errors import OmegaConfBaseException

    if isinstance(error, MissingConfigException) and error.options and error.missing_cfg_file:
        group, _, value = error.missing_cfg_file.rpartition("/")
        hidden = (SCHEMA_OPTION, ASSET_FOLDER_OPTION) if group == "aorta" else (SCHEMA_OPTION,)
        return f"{group}={value!r} is not valid; choose one of {[o for o in error.options if o not in hidden]}"
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


def run_hydra(task_function, config_name: str, policy_verb: str | None = None):
    """Run `task_function` as a Hydra app on the shipped conf/: bad input ends with one line
    and exit status 2, Ctrl-C at any point with one line and exit status 130. `policy_verb`
    ("evaluating"): the tool takes `policy=`, whose run names the task and aorta
    (`policy_scenario`)."""
    try:
        return _run_hydra(task_function, config_name, policy_verb)
    except KeyboardInterrupt as error:  # Hydra passes it on from the task, as from composing
        interrupted(error)


def _run_hydra(task_function, config_name: str, policy_verb: str | None):
    import os

    import hydra
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    from cathsim_dmc.app.tool_schemas import register_schemas
    from cathsim_dmc.core.registry import aorta_choices
    from cathsim_dmc.core.shipped import conf_root

    register_schemas()  # conf/ composes on them
    register_resolvers()
    _state.update(checked=False, started=False)
    argv = sys.argv[1:]
    if policy_verb:
        argv = policy_scenario(argv, policy_verb)
    sys.argv[1:] = expand_aorta_folder(argv, aorta_choices())

    def guarded(cfg):
        # Hydra prints a traceback for exceptions from the task; a bad value in the
        # config is the user's input, so it gets our one-line error (SystemExit passes),
        # as does a machine without the C compiler that physics=fast needs once, and a run
        # folder another run holds. Imported here: a refused command line never loads
        # MuJoCo, SciPy or torch.
        from hydra.core.hydra_config import HydraConfig

        from cathsim_dmc.core.run_files import FolderInUse
        from cathsim_dmc.sim.wall_field import NativeBuildError

        if not _state["checked"]:  # a sweep's job: checked as it starts
            check_or_fail(cfg, HydraConfig.get().job.config_name, HydraConfig.get().runtime.output_dir)
        _state["started"] = True
        try:
            return task_function(cfg)
        except (ValueError, FileNotFoundError, MemoryError, NativeBuildError, FolderInUse) as error:
            fail(str(error))

    guarded.__name__ = getattr(task_function, "__name__", "app")
    guarded.__module__ = getattr(task_function, "__module__", __name__)
    app = hydra.main(version_base="1.3", config_path=str(conf_root()), config_name=config_name)(guarded)
    before = os.environ.get("HYDRA_FULL_ERROR")
    os.environ["HYDRA_FULL_ERROR"] = "1"  # Hydra's errors come here rather than as its own report
    try:
        return app()
    except (HydraException, OmegaConfBaseException) as error:
        if _state["started"]:  # the tool's own code: a bug, with its traceback
            raise
        fail(composition_error(error))
    finally:
        if before is None:
            os.environ.pop("HYDRA_FULL_ERROR", None)
        else:
            os.environ["HYDRA_FULL_ERROR"] = before


def explicit_override(key: str) -> bool:
    """Whether the command line set `key` (not only the config's default)."""
    from hydra.core.hydra_config import HydraConfig

    return any(o.lstrip("+~").split("=", 1)[0] == key for o in HydraConfig.get().overrides.task)


# Options that change what an agent sees or drives. A checkpoint records them (policy.json)
# and is evaluated, and replayed for datasets, with them whatever the command line says
# (cathsim-eval lets an explicit task.physics= win: a transfer test between settings).
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
    from cathsim_dmc.agents.trained import CheckpointPolicy, check_catheter
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
    for key in ("start_rotation_rad", "start_rotation_jitter_rad", "start_insertion_jitter_m", "safe_force_n"):
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
        for key in ("view_deg_range", "cranial_deg_range"):
            if key in kwargs:  # a list in policy.json, as every option a checkpoint records
                kwargs[key] = list(
                    OmegaConf.to_container(kwargs[key]) if OmegaConf.is_config(kwargs[key]) else kwargs[key]
                )
        for key in ("lao_deg", "tracking_noise_m", "registration_error_m"):
            if not kwargs.get(key):  # the AP view, no noise: recorded as before the options existed
                kwargs.pop(key, None)
        if kwargs.get("tracking_source") == "projection":  # the default, as before the option existed
            kwargs.pop("tracking_source")
    experimental = cfg.get("experimental")
    if experimental is not None and experimental.get("extra_observations"):
        kwargs["extra_observations"] = tuple(experimental.extra_observations)
    if training and cfg.get("reward") is not None:
        kwargs.update(reward=cfg.reward.kind, progress_weight=cfg.reward.progress_weight)
    if isinstance(policy, CheckpointPolicy):  # a trained agent sees and drives what it was trained with
        check_catheter(str(cfg.get("policy") or policy.path), kwargs.get("catheter"), policy.env_options)
        kwargs.update(obs=policy.obs_preset, **policy.image_options, **policy.env_options)
    tasks.check_options(**{k: v for k, v in kwargs.items() if k not in ("task", "aorta", "obs")})
    return kwargs
