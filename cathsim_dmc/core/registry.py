"""The suite's names and Gymnasium ids, importable without dm_control or MuJoCo.

`import cathsim_dmc` registers every id from here: the ids point at
``cathsim_dmc.suite.gym:make_registered`` by name, so dm_control and MuJoCo load only when
``gymnasium.make`` builds an environment, and the anatomy layer stays pure geometry.
Besides every (target, shipped aorta) pair, ``{task}-random-v0`` draws a generated arch
each episode (``aorta="random"``).
"""

from __future__ import annotations

from cathsim_dmc.core.shipped import available_aortas, conf_root

TARGETS = ("bca", "lcca")
ENV_ID_FORMAT = "cathsim_dmc/{task}-{aorta}-v0"
ENTRY_POINT = "cathsim_dmc.suite.gym:make_registered"
RANDOM_AORTA = "random"  # tasks.load's randomised anatomy (cathsim_dmc.tasks.randomized)
CUSTOM_AORTA = "custom"  # generated from `aorta_params` (cached after the first build)
# tasks.load(extra_observations=...)'s names (cathsim_dmc.tasks.observations builds them)
EXTRA_OBSERVATIONS = ("wire_slack", "drive_force", "tip_position", "contact_force")


def env_id(task: str, aorta: str) -> str:
    return ENV_ID_FORMAT.format(task=task, aorta=aorta)


def all_tasks() -> tuple:
    """Every (target, shipped aorta) pair, as `cathsim_dmc.tasks.ALL_TASKS`."""
    return tuple((target, aorta) for aorta in available_aortas() for target in TARGETS)


def aorta_choices() -> tuple:
    """What `aorta=` accepts by name: every shipped aorta, `custom` and `random`."""
    return available_aortas() + (CUSTOM_AORTA, RANDOM_AORTA)


def config_choices(group: str) -> list:
    """The options of a config group of conf/ (its YAML files' names), sorted. For `obs`,
    these are the keys of `cathsim_dmc.tasks.presets.OBSERVATION_PRESETS`, which loads the
    same files; the command-line tools check their arguments against this list before
    anything heavier is imported."""
    return sorted(path.stem for path in (conf_root() / group).glob("*.yaml"))


def register_all() -> None:
    """Register an id for every pair in the suite (idempotent)."""
    import gymnasium

    pairs = (*all_tasks(), *((target, RANDOM_AORTA) for target in TARGETS))
    for task, aorta in pairs:
        name = env_id(task, aorta)
        if name not in gymnasium.registry:
            gymnasium.register(
                id=name, entry_point=ENTRY_POINT, kwargs={"task": task, "aorta": aorta, "registered_id": name}
            )


# Observation-preset options that change what an agent sees (a preset file may set them, plus
# `image_size`; a checkpoint records them): one list for tasks/presets.py and the tools.
IMAGE_OPTIONS = (
    "renderer",
    "style",
    "lao_deg",
    "tracking_noise_m",
    "registration_error_m",
    "detector_dose_ngy",
    "blur_mm",
    "view_deg_range",
    "cranial_deg_range",
    "tracking_source",
)
