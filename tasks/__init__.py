"""The navigation suite: every (target, aorta) pair, loaded like a dm_control suite task.

from cathsim_dmc import tasks
env = tasks.load("bca", "type1", obs="enn", seed=0)
tasks.ALL_TASKS  # (("bca", "type1"), ("lcca", "type1"), ...)
"""

from __future__ import annotations

from pathlib import Path

from cathsim_dmc.core import task_defaults
from cathsim_dmc.core.registry import CUSTOM_AORTA, RANDOM_AORTA, TARGETS, all_tasks, aorta_choices
from cathsim_dmc.entities import Aorta, FollowerRobot, Guidewire
from cathsim_dmc.sim.physics import physics_settings
from cathsim_dmc.tasks.environment import NavigationEnvironment
from cathsim_dmc.tasks.navigate import Navigate, check_options
from cathsim_dmc.tasks.presets import OBSERVATION_PRESETS, observation_settings
from cathsim_dmc.tasks.randomized import RandomAnatomyEnvironment, random_anatomy_environment

OBSERVATIONS = tuple(OBSERVATION_PRESETS)
# Straight shaft between the sheath's tip and the wire's shaped tip at the start, metres:
# with the 3 mm sheath depth and the 15 mm angled tip, the tip starts 7-9 mm past the `entry`
# site (see `Navigate`).
TIP_START_PAST_SHEATH_M = 0.002
ALL_TASKS = all_tasks()


def validate(task: str, aorta: str, obs: str = "internal") -> None:
    """Raise ValueError naming the valid choices if any name is unknown.

    `aorta` may also be the path of an asset folder (for example an imported mesh).
    """
    if task not in TARGETS:
        raise ValueError(f"task={task!r} is not a navigation target; choose one of {list(TARGETS)}")
    if aorta not in aorta_choices() and not (Path(aorta) / "meta.json").is_file():
        raise ValueError(
            f"aorta={aorta!r} is not a shipped aorta or an asset folder; choose one of {list(aorta_choices())}"
        )
    if obs not in OBSERVATION_PRESETS:
        raise ValueError(f"obs={obs!r} is not an observation preset; choose one of {list(OBSERVATIONS)}")


def check_keywords(what: str, given, accepts, supplied=()) -> None:
    """ValueError listing the valid names if `given` (keyword arguments) holds one that
    the callables `accepts` do not take (or that the caller `supplied` itself)."""
    import inspect

    valid = sorted(
        {
            name
            for function in accepts
            for name, p in inspect.signature(function).parameters.items()
            if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)
        }
        - {"self", *supplied}
    )
    unknown = sorted(set(given or ()) - set(valid))
    if unknown:
        raise ValueError(
            f"{what}: unknown keyword argument{'s' if len(unknown) > 1 else ''} "
            f"{', '.join(map(repr, unknown))}; valid: {', '.join(valid)}"
        )


# What build_task passes to Navigate and the entities itself.
_SUPPLIED = {
    Navigate.__init__: ("aorta", "guidewire", "robot", "target", "observations"),
    FollowerRobot._build: ("name",),
    Guidewire._build: ("name",),
    Aorta._build: ("asset", "name"),
}


def build_task(
    task: str = "bca",
    aorta: str = "type1",
    obs: str = "internal",
    guidewire: dict | None = None,
    robot: dict | None = None,
    aorta_options: dict | None = None,
    aorta_params: dict | None = None,
    image_size: int | None = None,
    renderer: str | None = None,
    style: str | None = None,
    noise_std: float | None = None,
    lao_deg: float | None = None,
    tracking_noise_m: float | None = None,
    registration_error_m: float | None = None,
    detector_dose_ngy: float | None = None,
    blur_mm: float | None = None,
    view_deg_range=None,
    cranial_deg_range=None,
    tracking_source: str | None = None,
    **task_kwargs,
) -> Navigate:
    """The Navigate task for a (target, aorta) pair with entity parameters overridden.

    `aorta="custom"` generates an aorta from `aorta_params` (generator fields of
    `cathsim_dmc.anatomy.ArchParams`, optionally `preset`), cached after its first build.
    `image_size`, `renderer` ("raster" or "gl"), `style` ("camera" or "fluoro") and
    `noise_std` (grey levels) override the observation preset's image settings; `lao_deg`
    turns the top camera (images and videos) into a left anterior oblique view of that
    many degrees (negative: right anterior oblique; 0, the presets' default: AP).
    `tracking_noise_m` and `registration_error_m` (standard deviations, metres) override
    the `roadmap` observation's noise (`cathsim_dmc.tasks.roadmap`) and of the image-plane
    tracking (`cathsim_dmc.tasks.tracking2d`). `detector_dose_ngy` and `blur_mm` set the
    fluoroscopic detector of the `fluoro` style (`cathsim_dmc.sim.detector`);
    `view_deg_range` and `cranial_deg_range` ([low, high] degrees) draw a C-arm view per
    episode (`Navigate`). `tracking_source="fluoro_image"` finds the wire of the image-plane
    observations in the fluoroscopic frame (`cathsim_dmc.sim.wire_finder`). `safe_force_n`
    sets the wall force a safe success stays under.
    `physics="fast"` (default), `"fast_field"` or `"accurate"` picks the physics settings (`Navigate`).
    """
    validate(task, aorta, obs)
    check_options(**task_kwargs)
    check_keywords("tasks.load", task_kwargs, [build_task, Navigate.__init__], _SUPPLIED[Navigate.__init__])
    for what, given, entity in (
        ("guidewire", guidewire, Guidewire),
        ("robot", robot, FollowerRobot),
        ("aorta_options", aorta_options, Aorta),
    ):
        check_keywords(what, given, [entity._build], _SUPPLIED[entity._build])
    if aorta == RANDOM_AORTA:
        raise ValueError(f"aorta='{RANDOM_AORTA}' is a pool of anatomies, not one task: use tasks.load")
    if aorta == CUSTOM_AORTA:
        from cathsim_dmc.anatomy import generated_asset

        aorta = generated_asset(dict(aorta_params or {}))
    elif aorta_params:
        raise ValueError(f"aorta_params is only used with aorta='{CUSTOM_AORTA}', not aorta={aorta!r}")
    image_options = dict(
        image_size=image_size,
        renderer=renderer,
        style=style,
        noise_std=noise_std,
        lao_deg=lao_deg,
        tracking_noise_m=tracking_noise_m,
        registration_error_m=registration_error_m,
        detector_dose_ngy=detector_dose_ngy,
        blur_mm=blur_mm,
        view_deg_range=view_deg_range,
        cranial_deg_range=cranial_deg_range,
        tracking_source=tracking_source,
    )
    settings = observation_settings(obs, **{k: v for k, v in image_options.items() if v is not None})
    wire = Guidewire(**(guidewire or {}))
    # Every wall the wire touches carries the wire's contact parameters (MuJoCo mixes them).
    contact = dict(channel_solref=wire.contact_solref, channel_solimp=wire.contact_solimp)
    # The shaped tip starts just outside the introducer sheath, whatever its length.
    start = dict(initial_insertion_m=wire.tip_length_m + TIP_START_PAST_SHEATH_M)
    follower = FollowerRobot(
        wire_length_m=wire.length_m, wire_radius_m=wire.radius_m, **{**contact, **start, **(robot or {})}
    )
    # The wall goes into the compiled model directly (NavigationEnvironment; fast build).
    wall = dict(
        solref=wire.contact_solref,
        solimp=wire.contact_solimp,
        hulls_in_mjcf=False,
        wall=physics_settings(task_kwargs.get("physics") or task_defaults.PHYSICS).wall,
    )
    vessel = Aorta(asset=aorta, **{**wall, **(aorta_options or {})})
    return Navigate(vessel, wire, follower, target=task, observations=settings, **task_kwargs)


def load(
    task: str = "bca",
    aorta: str = "type1",
    obs: str = "internal",
    seed=None,
    environment_kwargs: dict | None = None,
    **kwargs,
) -> NavigationEnvironment:
    """A ready composer environment for (task, aorta); kwargs go to `build_task`.

    `aorta="random"` returns a `RandomAnatomyEnvironment`: the anatomy is redrawn every
    `resample_every` episodes from a pool, set by `aorta_params` (`pool_size`, `pool_seed`,
    `resample_every`, `order` ("random" or "cycle"), `prebuild`, `assets`, and `sample_arch_params`'s distribution:
    `distribution` ("morphometry" or "fixed_branches"), `base`, `arch_types`, `type_weights`, `size_scale`,
    `diameter_scale`, `obliquity_deg`, `obliquity_range_deg`). `pool_seed` may be a name of
    `randomized.POOL_SEEDS` ("training", "tuning", "heldout").
    """
    if aorta == RANDOM_AORTA:
        params = kwargs.pop("aorta_params", None)
        validate(task, aorta, obs)
        check_options(**kwargs)
        check_keywords("tasks.load", kwargs, [build_task, Navigate.__init__], _SUPPLIED[Navigate.__init__])

        def build(asset, random_state):
            return NavigationEnvironment(
                build_task(task, str(asset), obs, **kwargs), random_state=random_state, **(environment_kwargs or {})
            )

        return random_anatomy_environment(params, build, seed=seed)
    navigate = build_task(task, aorta, obs, **kwargs)
    return NavigationEnvironment(navigate, random_state=seed, **(environment_kwargs or {}))


__all__ = [
    "ALL_TASKS",
    "CUSTOM_AORTA",
    "RANDOM_AORTA",
    "RandomAnatomyEnvironment",
    "TARGETS",
    "aorta_choices",
    "OBSERVATIONS",
    "Navigate",
    "NavigationEnvironment",
    "build_task",
    "check_options",
    "load",
    "validate",
]
