"""The typed schema of cathsim-train's config: one dataclass per config group, registered
in Hydra's ConfigStore.

The YAML files in conf/ stay the options a user picks (`algo=sac_tuned`, `demos=expert`);
each starts from its group's schema (`defaults: [schema, _self_]`) and sets only what
differs from it. Composition then refuses an unknown key (`trainer.total_timestep=5`) and
a value of the wrong type (`trainer.total_timesteps=abc`); `config_tools.validate` checks
the ranges (positive, within [0, 1], one of a few names) before any work.

Each default and range is defined once, where the code that uses it lives: the task's in
cathsim_dmc.core.task_defaults (the Python API's too), the algorithm's, the demonstrations'
and the trainer's in cathsim_dmc.learning.rl.settings (AlgoConfig, DemosConfig,
TrainerConfig, the groups of the same names). This module assembles them with the run's
own keys.

Registering (`config_tools.register_schemas`) must precede composing conf/: the tools do it
in cathsim_dmc.app.cli._common. Importing this module needs neither dm_control, MuJoCo nor
torch, so a command line is checked before anything heavy loads.

The other tools (cathsim-eval, -collect, -bc, -force, -bench, -export) have a schema each
too, in cathsim_dmc/app/tool_schemas.py, which also registers and checks them all.

A run folder is resumed only in the run format this version writes
(`cathsim_dmc.core.run_files.check_run_format`): `resumed_config` reads its config.yaml.
"""

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, List, Optional

from cathsim_dmc.core import task_defaults
from cathsim_dmc.core.registry import EXTRA_OBSERVATIONS
from cathsim_dmc.core.settings import count, setting
from cathsim_dmc.learning.rl.settings import AlgoConfig, DemosConfig, TrainerConfig

MISSING = "???"  # OmegaConf's marker of a value a config group fills in
RUN_CONFIG = "config.yaml"  # in a cathsim-train run folder: its whole config, resolved


@dataclass
class TaskConfig:
    """`task`: the navigation task every tool runs (conf/task/<target>.yaml). The defaults
    are the Python API's (`tasks.load`, `Navigate`: cathsim_dmc.core.task_defaults); the
    ranges are checked by tasks.check_options, which both share."""

    target: str = MISSING  # bca | lcca
    delta_m: float = task_defaults.SUCCESS_RADIUS_M  # success radius (the paper's 4 mm)
    success_reward: float = task_defaults.SUCCESS_REWARD
    dense: bool = task_defaults.DENSE_REWARD  # the dense reward (false: only the success reward)
    max_steps: int = task_defaults.MAX_STEPS  # the paper's episode limit
    # fast (PGS, prism wall) | fast_field | accurate (Newton); docs/model.md#physics
    physics: str = task_defaults.PHYSICS
    catheter: Optional[str] = None  # a shaped catheter over the wire (angled_5f); docs/model.md#catheter
    # The start pose: the robot's rotation drawn from start_rotation_rad +- start_rotation_jitter_rad
    # (pi: the tip's bend in the view's plane), its insertion from [0, start_insertion_jitter_m].
    start_rotation_rad: float = task_defaults.START_ROTATION_RAD
    start_rotation_jitter_rad: float = task_defaults.START_ROTATION_JITTER_RAD
    start_insertion_jitter_m: float = task_defaults.START_INSERTION_JITTER_M
    # Safe success (every evaluation report's Safe Success column): the target reached without
    # any control step's wall force (the step's mean) above this, newtons.
    safe_force_n: float = task_defaults.SAFE_FORCE_N


@dataclass
class ExperimentalConfig:
    """`experimental`: options that work and are tested but are not part of the recipe; no
    training result of the recipe used them. Each line says what was measured."""

    # running mean/std of the vector observations, saved beside each checkpoint: no training result measured with it
    normalize_observations: bool = False
    # extra observables, always in `info`: no training result measured with them
    extra_observations: List[str] = setting([], choices=EXTRA_OBSERVATIONS)


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
    seed: int = count(0)
    resume: Optional[str] = None  # a run folder to continue from its last checkpoint
    trainer: TrainerConfig = field(default_factory=TrainerConfig)
    experimental: ExperimentalConfig = field(default_factory=ExperimentalConfig)


TRAIN_SECTIONS = {
    "trainer": TrainerConfig,
    "algo": AlgoConfig,
    "demos": DemosConfig,
    "experimental": ExperimentalConfig,
}


def resumed_config(run_dir):
    """The config.yaml of the cathsim-train run folder `run_dir`, typed by TrainConfig, once
    its run format is this version's (`check_run_format`: one line, ValueError, otherwise)."""
    from omegaconf import OmegaConf

    from cathsim_dmc.core.run_files import check_run_format

    check_run_format(run_dir)
    return OmegaConf.merge(OmegaConf.structured(TrainConfig), OmegaConf.load(Path(run_dir) / RUN_CONFIG))
