"""The typed schema of cathsim-train's config: one dataclass per config group, registered
in Hydra's ConfigStore, and the one place where option defaults and ranges live.

The YAML files in conf/ stay the options a user picks (`algo=sac_tuned`, `demos=expert`);
each starts from its group's schema (`defaults: [schema, _self_]`) and sets only what
differs from it. Composition then refuses an unknown key (`trainer.total_timestep=5`) and
a value of the wrong type (`trainer.total_timesteps=abc`); `config_tools.validate` checks
the ranges (positive, within [0, 1], one of a few names) before any work.

Registering (`config_tools.register_schemas`) must precede composing conf/: the tools do it
in cathsim_dmc.app.cli._common. Importing this module needs neither dm_control, MuJoCo nor
torch: the simulation reads its defaults from here.

The other tools (cathsim-eval, -collect, -bc, -force, -bench, -export) have a schema each
too, in cathsim_dmc/app/tool_schemas.py, which also registers and checks them all.

Run folders written before an option was removed or moved still resume: `upgrade_saved_config`
translates their config.yaml (see there).
"""

import logging
from dataclasses import MISSING as NO_DEFAULT
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, List, Mapping, Optional

log = logging.getLogger(__name__)
MISSING = "???"  # OmegaConf's marker of a value a config group fills in

DEVICES = ("auto", "cpu", "cuda")  # or cuda:<index>
FINAL_POLICIES = ("best", "last")
# tasks.load(extra_observations=...)'s names (tasks/observations.py reads them from here)
EXTRA_OBSERVATIONS = ("wire_slack", "drive_force", "tip_position", "contact_force")
# the scripted experts that can demonstrate (cathsim_dmc.control.policies.BUILTIN_POLICIES' names)
DEMONSTRATORS = ("expert", "expert_steady")


def _number(default, minimum=None, maximum=None, above=None, whole=False, choices=None, below=None):
    """A dataclass field with its range: >= `minimum`, > `above`, <= `maximum`, < `below`,
    an int if `whole`, or one of `choices` (strings). None as a default means the option may be off."""
    check = {"minimum": minimum, "maximum": maximum, "above": above, "whole": whole, "choices": choices, "below": below}
    if isinstance(default, list):
        return field(default_factory=lambda: list(default), metadata=check)
    return field(default=default, metadata=check)


def _count(default, minimum=0):
    return _number(default, minimum=minimum, whole=True)


@dataclass
class TaskConfig:
    """`task`: the navigation task every tool runs (conf/task/<target>.yaml). These are also
    the defaults of the Python API (`tasks.load`, `Navigate`), which reads them from here;
    the ranges are checked by tasks.check_options, which both share."""

    target: str = MISSING  # bca | lcca
    delta_m: float = 0.004  # success radius (the paper's 4 mm)
    success_reward: float = 10.0
    dense: bool = True  # the dense reward (false: only the success reward)
    max_steps: int = 300  # the paper's episode limit
    physics: str = "fast"  # fast (PGS, prism wall) | fast_field | accurate (Newton); docs/model.md#physics
    catheter: Optional[str] = None  # a shaped catheter over the wire (angled_5f); docs/model.md#catheter
    # The start pose: the robot's rotation drawn from start_rotation_rad +- start_rotation_jitter_rad
    # (pi: the tip's bend in the view's plane), its insertion from [0, start_insertion_jitter_m].
    start_rotation_rad: float = 3.141592653589793
    start_rotation_jitter_rad: float = 0.3
    start_insertion_jitter_m: float = 0.002


# Arguments of tasks.load / Navigate that were removed (their measurements showed no gain):
# name -> the one line a caller, or a checkpoint trained with one, gets instead.
REMOVED_TASK_ARGUMENTS = {
    "aim_weight": "removed on 2026-11-27: the aim shaping measured no better than progress_weight",
    "insertion_limit_margin_m": "removed on 2026-11-27: the carriage travel limit measured no gain",
}


@dataclass
class AlgoConfig:
    """`algo`: SAC. The defaults are the paper's settings (CathSim's table of SAC settings);
    conf/algo/sac_tuned.yaml and sac_cpu.yaml change a few."""

    name: str = "sac"
    learning_rate: float = _number(3.0e-4, above=0.0)
    buffer_size: int = _count(1_000_000, minimum=1)  # transitions; refused up front if it would not fit in memory
    batch_size: int = _count(256, minimum=1)
    tau: float = _number(0.005, minimum=0.0, maximum=1.0)
    gamma: float = _number(0.99, minimum=0.0, maximum=1.0)
    train_freq: int = _count(1, minimum=1)
    gradient_steps: int = 1  # SB3's: -1 means as many as environment steps
    target_update_interval: int = _count(1, minimum=1)
    target_entropy: float = -2.0  # = -dim(action)
    # The paper lists the entropy coefficient as 1 next to a target entropy. A target only
    # matters when the coefficient is learned, so "1" is read as its initial value: SB3's
    # "auto_1.0" (learned, starting at 1.0). A number fixes it.
    ent_coef: str = "auto_1.0"
    learning_starts: int = _count(1000)  # random actions before the first update
    net_arch: List[int] = _number([256, 256], minimum=1, whole=True)  # actor and critic heads on the features
    share_features_extractor: bool = False  # true: one ENN for actor and critic (faster on a CPU)
    critic_layer_norm: bool = False  # true: LayerNorm after each hidden layer of the critics (RLPD)
    # > 0: evaluate (and keep as best.zip) an exponential average of the actor's weights
    actor_average_tau: float = _number(0.0, minimum=0.0, maximum=1.0)


@dataclass
class DemosConfig:
    """`demos`: demonstrations mixed into training. The defaults are plain SAC (none);
    conf/demos/expert.yaml is the recipe's."""

    episodes: int = _count(0)  # expert episodes recorded before training (0: none)
    share: float = _number(0.5, minimum=0.0, maximum=1.0)  # of every batch (RLPD's symmetric sampling)
    capacity: int = _count(20_000, minimum=1)  # most demonstration transitions kept (100 expert episodes: ~6-16k)
    pretrain_actor_steps: int = _count(0)  # behavioural-cloning steps of the actor before SAC starts
    critic_warmup_steps: int = _count(0)  # critic-only updates on the demonstrations after that
    # behavioural-cloning term in the actor's loss, x mean|Q|, counted on every
    # demonstration state of the batch (TD3+BC's form; 0: plain SAC)
    bc_weight: float = _number(0.0, minimum=0.0)
    # rounds of takeover demonstrations after pre-training (0: none): the actor drives, the
    # expert takes over at a random step, its part joins the demonstrations and the actor
    # is re-trained on them (half of pretrain_actor_steps)
    takeover_rounds: int = _count(0)
    takeover_episodes: int = _count(20, minimum=1)  # episodes per round
    takeover_max_student_steps: int = _count(200)  # the expert takes over at a step drawn from 0..this
    # rounds of expert labels after pre-training (DAgger; 0: none): the actor drives
    # dagger_episodes episodes, the expert labels every state it reaches with its own
    # action, and the actor is re-trained (pretrain_actor_steps) on the demonstrations and
    # all labels so far; the cloning term (bc_weight) then covers the labels' states too
    dagger_rounds: int = _count(0)
    dagger_episodes: int = _count(50, minimum=1)
    dagger_capacity: int = _count(200_000, minimum=1)  # most expert labels kept
    path: Optional[str] = None  # a cathsim-collect folder to take them from instead of recording the expert
    # the scripted expert that records the demonstrations, takes over and labels: expert, or
    # expert_steady (no turns where the path runs straight ahead of the tip)
    expert: str = _number("expert", choices=DEMONSTRATORS)


@dataclass
class TrainerConfig:
    """`trainer`: the training run around the algorithm."""

    # with demos=expert every default-recipe run so far chose its best.zip within its
    # first 7k steps (docs/training.md); demos=none needs ~100k, the paper 600000
    total_timesteps: int = _count(8000, minimum=1)
    n_envs: int = _count(1, minimum=1)  # > 1: one subprocess per environment
    # steps between deterministic evaluations (TensorBoard, evaluations.jsonl, best.zip; 0: none)
    eval_every: int = _count(1000)
    eval_episodes: int = _count(10, minimum=1)  # of each periodic evaluation (and the final one, if not below)
    # also evaluate the pre-trained policy before the first step, so that it competes for best.zip
    eval_at_start: bool = False
    final_eval_episodes: Optional[int] = _count(20, minimum=1)  # of the final report (null: eval_episodes)
    # when several periodic evaluations share the best success rate, more episodes for each
    # of them (at most 3) decide best.zip (0: the earlier of a tie is kept)
    tie_break_episodes: int = _count(20)
    # steps between checkpoints; null: with every periodic evaluation (eval_every; 1000 steps
    # without one), so a killed run resumes from its last evaluation; 0: only at the end
    checkpoint_every: Optional[int] = _count(None)
    save_replay_buffer: bool = False  # also checkpoint the replay buffer (large with images)
    device: str = _number("auto", choices=DEVICES)  # or cuda:<index>
    # 1 thread: 71 ms per SAC update against 478 ms with 2 on a busy 2-core machine; 0: torch's default
    torch_threads: int = _count(1)
    progress_bar: bool = True
    video: bool = True  # video of the first evaluation episode
    # which policy the final report evaluates (best: best.zip of the periodic evaluations, when eval_every > 0)
    final_policy: str = _number("best", choices=FINAL_POLICIES)


@dataclass
class ExperimentalConfig:
    """`experimental`: options that work and are tested but are not part of the recipe; no
    training result of the recipe used them. Each line says what was measured."""

    # running mean/std of the vector observations, saved beside each checkpoint: no training result measured with it
    normalize_observations: bool = False
    # extra observables, always in `info`: no training result measured with them
    extra_observations: List[str] = _number([], choices=EXTRA_OBSERVATIONS)


@dataclass
class ScenarioConfig:
    """The groups every tool that runs the environment composes: the task, the aorta and
    the observations."""

    task: TaskConfig = MISSING
    aorta: Any = MISSING
    obs: Any = MISSING


@dataclass
class TrainConfig(ScenarioConfig):
    """cathsim-train's whole config (conf/train.yaml): the groups, then the run's own keys."""

    algo: AlgoConfig = MISSING
    reward: Any = MISSING
    demos: DemosConfig = MISSING
    seed: int = _count(0)
    resume: Optional[str] = None  # a run folder to continue from its last checkpoint
    trainer: TrainerConfig = field(default_factory=TrainerConfig)
    experimental: ExperimentalConfig = field(default_factory=ExperimentalConfig)


# --- ranges ---------------------------------------------------------------------------

TRAIN_SECTIONS = {
    "trainer": TrainerConfig,
    "algo": AlgoConfig,
    "demos": DemosConfig,
    "experimental": ExperimentalConfig,
}


def check_section(name: str, schema, values: Mapping) -> None:
    """ValueError naming `name.key=value` for the first value of `values` (a dict or a
    DictConfig) outside its range in `schema` (`name` "": the top level). Keys `values`
    lacks are not checked: a Python caller may pass only the options it sets."""
    from collections.abc import Sequence

    from cathsim_dmc.core.checks import check_number

    for spec in fields(schema):
        if not spec.metadata or spec.name not in values:
            continue
        value, check = values[spec.name], spec.metadata
        key = f"{name}.{spec.name}" if name else spec.name
        if check.get("folder"):  # an output folder: an existing file there would fail late
            if value is not None and Path(str(value)).exists() and not Path(str(value)).is_dir():
                raise ValueError(f"{key}={str(value)!r} is a file; give a folder (new or existing)")
            continue
        if value is None and type(None) in getattr(spec.type, "__args__", ()):
            continue  # an Optional option, off
        # a list option checks each item
        items = list(value) if isinstance(value, Sequence) and not isinstance(value, str) else [value]
        if check["choices"] is not None:
            for item in items:
                if str(item) not in check["choices"] and not (
                    key == "trainer.device" and str(item).startswith("cuda:")
                ):
                    raise ValueError(f"{key}={value!r}; choose one of {list(check['choices'])}")
            continue
        for item in items:
            if check["above"] is not None:
                check_number(key, item, check["above"], whole=check["whole"], inclusive=False)
            number = check_number(key, item, check["minimum"], whole=check["whole"])
            if check["maximum"] is not None and not number <= check["maximum"]:
                raise ValueError(f"{key}={item!r} must lie in [{check['minimum']:g}, {check['maximum']:g}]")
            if check.get("below") is not None and not number < check["below"]:
                low = check["minimum"] if check["minimum"] is not None else check["above"]
                raise ValueError(
                    f"{key}={item!r} must lie in {'[' if check['minimum'] is not None else '('}"
                    f"{low:g}, {check['below']:g})"
                )


def with_defaults(schema, values: Mapping | None) -> dict:
    """`values` (a Python caller's dict may hold only the options it sets) over `schema`'s
    defaults: the trainer reads every option, and each default lives here once."""
    defaults = {
        spec.name: spec.default_factory() if spec.default is NO_DEFAULT else spec.default
        for spec in fields(schema)
        if spec.default is not NO_DEFAULT or spec.default_factory is not NO_DEFAULT
    }
    return {**defaults, **dict(values or {})}


# --- run folders written by older versions ----------------------------------------------

# Options that moved: old key -> new key.
MOVED = {
    "trainer.normalize_observations": "experimental.normalize_observations",
    "obs.extra": "experimental.extra_observations",
}
# Options that were removed (their measurements showed no gain) -> the value with which
# the old code did what the current code does.
REMOVED = {
    "demos.warm_start_steps": 0,
    "algo.actor_learning_rate_scale": 1.0,
    "trainer.confirm_episodes": 0,
    "demos.bc_filter": "none",
    "task.insertion_limit_margin_m": None,
    "reward.aim_weight": 0.0,
    "experimental.expert_end_game": "strokes",
}


def upgrade_saved_config(saved) -> Any:
    """A run folder's config.yaml (a DictConfig), as the current schema reads it.

    Moved keys are translated. A removed key is dropped, with one warning naming it, when
    its value was the one that did what the code now always does: the run continues
    exactly as it was trained. Otherwise it fails with one line (ValueError) naming the
    removed option: continuing would silently train something other than the run's
    first part, which a resumed run must never do.
    """
    from omegaconf import OmegaConf

    config = OmegaConf.to_container(saved, resolve=True)
    if (config.get("reward") or {}).get("name") == "aim":
        raise ValueError(
            "this run was trained with reward=aim, since removed (it measured no better than "
            "reward=progress; docs/training.md): it cannot continue as trained; start a new run"
        )
    dropped = []
    for old, new in MOVED.items():
        value = _pop(config, old)
        if value is not NO_DEFAULT:
            _put(config, new, value)
    demos = config.get("demos") or {}
    inert_filter = not demos.get("bc_weight") or not demos.get("episodes")  # no cloning term: no filter
    for old, inert in REMOVED.items():
        value = _pop(config, old)
        if value is NO_DEFAULT:
            continue
        if value != inert and not (value is None and inert == 0) and not (old == "demos.bc_filter" and inert_filter):
            raise ValueError(
                f"this run was trained with {old}={value!r}, an option since removed "
                f"(it measured no gain; docs/training.md): it cannot continue as trained; "
                f"start a new run"
            )
        dropped.append(old)
    if dropped:
        log.warning("resume: dropped options since removed, at the values that change nothing: %s", ", ".join(dropped))
    return OmegaConf.merge(OmegaConf.structured(TrainConfig), config)


def _pop(config: dict, dotted: str):
    section, _, key = dotted.partition(".")
    node = config.get(section)
    return node.pop(key, NO_DEFAULT) if isinstance(node, dict) else NO_DEFAULT


def _put(config: dict, dotted: str, value) -> None:
    section, _, key = dotted.partition(".")
    config.setdefault(section, {})[key] = value
