"""Observation presets: named settings that turn the task's observables on and off.

Each preset is one file of conf/obs/, read by the command-line tools (Hydra's `obs=`
group) and by the Python API (`tasks.load(obs=...)`) alike.
"""

from __future__ import annotations

from pathlib import Path

from cathsim_dmc.core.checks import check_number
from cathsim_dmc.core.registry import IMAGE_OPTIONS
from cathsim_dmc.core.shipped import conf_root
from cathsim_dmc.sim.render import IMAGE_STYLES, MAX_RENDER_PX, RENDERERS, ObservationSettings, TopView

# What a preset can enable (the task has a few more, enabled one by one as extra observations).
PRESET_OBSERVABLES = (
    "pixels",
    "guidewire_mask",
    "joint_pos",
    "joint_vel",
    "roadmap",
    "robot_state",
    "target_depth_time",
    "wrong_branch_heading",
    "catheter_called",
    "catheter_rate",
    "roadmap_overlay",
    "tracking_2d",
    "roadmap_2d",
    "tracking_2d_history",
    "wrong_branch_heading_2d",
    "catheter_called_2d",
    "target_depth_time_2d",
    "carm_view",
)
# Options a preset file may set (besides name and observables).
PRESET_OPTIONS = ("image_size", *IMAGE_OPTIONS)
TRACKING_SOURCES = ("projection", "fluoro_image")  # ObservationSettings.tracking_source
# The observables of the image tracker (tasks/tracking2d.py), which tracking_source feeds.
IMAGE_PLANE_OBSERVABLES = frozenset(
    (
        "tracking_2d",
        "tracking_2d_history",
        "roadmap_2d",
        "wrong_branch_heading_2d",
        "catheter_called_2d",
        "target_depth_time_2d",
    )
)
# What a single-plane C-arm suite measures: the image and what is found or drawn in it, the
# C-arm's reported angles and the robot's encoders (policy=pretrained_fluoro reads only these).
C_ARM_OBSERVABLES = IMAGE_PLANE_OBSERVABLES | {"pixels", "roadmap_overlay", "carm_view", "robot_state", "catheter_rate"}
MAX_VIEW_DEG = 45.0  # the largest LAO/RAO and cranial/caudal angle a per-episode view may draw


def load_presets(folder) -> dict:
    """name -> ObservationSettings of every preset file in `folder` (conf/obs/*.yaml).

    A preset file is the one definition of its preset, for the command-line tools (Hydra's
    `obs=` group) and the Python API (`tasks.load(obs=...)`) alike: `name`, the
    `observables` it enables, and optionally the options of `PRESET_OPTIONS`.
    """
    import yaml

    presets = {}
    for path in sorted(Path(folder).glob("*.yaml")):
        spec = yaml.safe_load(path.read_text()) or {}
        unknown = sorted(set(spec.get("observables") or ()) - set(PRESET_OBSERVABLES))
        if spec.get("name") != path.stem or not spec.get("observables") or unknown:
            raise ValueError(
                f"{path}: a preset needs name: {path.stem} and observables from "
                f"{list(PRESET_OBSERVABLES)} (unknown: {unknown})"
            )
        options = {key: spec[key] for key in PRESET_OPTIONS if spec.get(key) is not None}
        for key in ("view_deg_range", "cranial_deg_range"):
            if key in options:
                options[key] = tuple(options[key])
        presets[path.stem] = ObservationSettings(frozenset(spec["observables"]), **options)
    return presets


OBSERVATION_PRESETS = load_presets(conf_root() / "obs")


def observation_settings(preset: str, **overrides) -> ObservationSettings:
    if preset not in OBSERVATION_PRESETS:
        raise ValueError(f"obs={preset!r} is not a preset; choose one of {sorted(OBSERVATION_PRESETS)}")
    settings = OBSERVATION_PRESETS[preset]
    if overrides:
        for key in ("view_deg_range", "cranial_deg_range"):
            if overrides.get(key) is not None:
                overrides[key] = check_view_range(key, overrides[key])
        settings = ObservationSettings(**{**settings.__dict__, **overrides})
    check_number("image_size", settings.image_size, 1, whole=True)  # 0 divides by zero in the renderer
    if settings.style not in IMAGE_STYLES:
        raise ValueError(f"image style={settings.style!r}; choose one of {IMAGE_STYLES}")
    if settings.renderer not in RENDERERS:
        raise ValueError(f"renderer={settings.renderer!r}; choose one of {RENDERERS}")
    largest = TopView.largest_image_size(settings)
    if largest is not None and settings.image_size > largest:
        raise ValueError(
            f"image_size={settings.image_size!r} is too large for the {settings.renderer} renderer "
            f"and the {settings.style} style (its GL renders are supersampled within the "
            f"{MAX_RENDER_PX} px offscreen framebuffer); choose 1 to {largest}"
        )
    if not settings.noise_std >= 0:
        raise ValueError(f"noise_std={settings.noise_std!r} must be >= 0 (grey levels)")
    for key in ("tracking_noise_m", "registration_error_m"):
        check_number(key, getattr(settings, key), 0)  # a standard deviation in metres
    if not -90 <= check_number("lao_deg", settings.lao_deg) <= 90:
        raise ValueError(f"lao_deg={settings.lao_deg!r} must be between -90 and 90 (degrees; 0 = AP)")
    # The tracking presets' frame (tracking_source="fluoro_image") is a fluoro frame whatever `style` says.
    reads_frames = settings.style == "fluoro" or bool(settings.enabled & IMAGE_PLANE_OBSERVABLES)
    for key in ("detector_dose_ngy", "blur_mm"):
        if check_number(key, getattr(settings, key), 0) > 0 and not reads_frames:
            raise ValueError(
                f"{key}={getattr(settings, key)!r} is the fluoroscopic detector's; it needs style='fluoro' "
                f"(or an image-plane preset, whose tracker may read fluoro frames)"
            )
    for key in ("view_deg_range", "cranial_deg_range"):
        if getattr(settings, key) is not None:
            check_view_range(key, getattr(settings, key))
    if settings.tracking_source not in TRACKING_SOURCES:
        raise ValueError(f"tracking_source={settings.tracking_source!r}; choose one of {list(TRACKING_SOURCES)}")
    if settings.view_deg_range is not None and settings.lao_deg != 0:
        raise ValueError(
            f"lao_deg={settings.lao_deg!r} and view_deg_range={list(settings.view_deg_range)}: give one, "
            f"a fixed view or a range to draw one from per episode"
        )
    return settings


def check_view_range(key: str, value) -> tuple:
    """`value` as a (low, high) pair of angles in degrees within +-MAX_VIEW_DEG; ValueError
    naming `key` otherwise."""
    try:
        low, high = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{key}={value!r} must be [low, high] in degrees, e.g. [-45, 45]") from None
    if not -MAX_VIEW_DEG <= low <= high <= MAX_VIEW_DEG:
        raise ValueError(
            f"{key}={[low, high]} must be [low, high] with -{MAX_VIEW_DEG:g} <= low <= high <= {MAX_VIEW_DEG:g} degrees"
        )
    return (low, high)
