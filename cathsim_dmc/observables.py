"""Observation presets and the image observables (top view, guidewire mask).

Renders draw only what an observation needs: the merged visual mesh of the vessel
(group 1), the wire (group 2) and the robot's guide channel; never the collision pieces
(group 3, thousands of meshes) nor markers (group 4).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from dm_control import composer
from dm_control.composer.observation import observable
from dm_control.mujoco.wrapper.core import MjvOption

from cathsim_dmc import _gl, geom_groups

TOP_CAMERA = "top"
IMAGE_SIZE = 80  # the paper's 80x80 observation
IMAGE_STYLES = ("camera",)


@dataclass(frozen=True)
class ObservationSettings:
    """Which observations an environment returns, and how images are made."""

    enabled: frozenset = field(default_factory=frozenset)
    image_size: int = IMAGE_SIZE
    style: str = "camera"


OBSERVATION_PRESETS = {
    "internal": ObservationSettings(frozenset({"joint_pos", "joint_vel"})),
    "pixels": ObservationSettings(frozenset({"pixels"})),
    "pixels_mask": ObservationSettings(frozenset({"pixels", "guidewire_mask"})),
    "internal_pixels": ObservationSettings(frozenset({"pixels", "joint_pos", "joint_vel"})),
    "enn": ObservationSettings(frozenset({"pixels", "guidewire_mask", "joint_pos", "joint_vel"})),
}


class JointObservables(composer.Observables):
    """Positions and velocities of an entity's `joints` (the proprioception group)."""

    @composer.observable
    def joint_pos(self):
        return observable.MJCFFeature("qpos", self._entity.joints)

    @composer.observable
    def joint_vel(self):
        return observable.MJCFFeature("qvel", self._entity.joints)

    @property
    def proprioception(self):
        return [self.joint_pos, self.joint_vel]


def observation_settings(preset: str, **overrides) -> ObservationSettings:
    if preset not in OBSERVATION_PRESETS:
        raise ValueError(f"obs={preset!r} is not a preset; choose one of {sorted(OBSERVATION_PRESETS)}")
    settings = OBSERVATION_PRESETS[preset]
    if overrides:
        settings = ObservationSettings(**{**settings.__dict__, **overrides})
    if settings.style not in IMAGE_STYLES:
        raise ValueError(f"image style={settings.style!r}; choose one of {IMAGE_STYLES}")
    return settings


def _scene_option(groups) -> MjvOption:
    option = MjvOption()
    option.geomgroup[:] = 0
    for g in groups:
        option.geomgroup[g] = 1
    option.sitegroup[:] = 0
    return option


_IMAGE_OPTION = _scene_option([0, geom_groups.VISUAL, geom_groups.WIRE])
_MASK_OPTION = _scene_option([geom_groups.WIRE])


class CameraCache:
    """dm_control Cameras built once per compiled model and reused.

    Building a Camera allocates a scene sized for the whole model (~0.2 s with
    thousands of wall pieces); rendering with a built one takes milliseconds.
    """

    def __init__(self):
        self._cameras = {}
        self._model = None

    def render(self, physics, camera: str, pixels: int, **render_kwargs) -> np.ndarray:
        if self._model is not physics.model.ptr:  # a recompiled model invalidates cameras
            self._cameras.clear()
            self._model = physics.model.ptr
        key = (camera, pixels)
        if key not in self._cameras:
            from dm_control.mujoco.engine import Camera

            try:
                self._cameras[key] = Camera(physics, pixels, pixels, camera)
            except Exception as error:  # without a GL backend dm_control fails deep in GL set-up
                raise RuntimeError(f"{_gl.missing_backend_message()} ({error})") from error
        # A Camera renders into one buffer it reuses: copy, or every frame is the last.
        return self._cameras[key].render(**render_kwargs).copy()


class TopView:
    """The top (AP) camera image and guidewire mask of one environment."""

    # At 80 px over a ~0.2 m field one pixel spans ~3 mm, more than three wire diameters:
    # drawn at that size the wire breaks into dashes. Both images are drawn larger and
    # reduced; software GL pays mostly per drawn geom, little per pixel.
    IMAGE_SUPERSAMPLING = 2
    MASK_SUPERSAMPLING = 4

    def __init__(self, size: int = IMAGE_SIZE, camera: str = TOP_CAMERA):
        self.size = int(size)
        self.camera = camera
        self._cache = CameraCache()

    def image(self, physics, style: str = "camera") -> np.ndarray:
        """Grayscale view, uint8 (size, size, 1), anti-aliased."""
        pixels = self.size * self.IMAGE_SUPERSAMPLING
        rgb = self._cache.render(physics, self.camera, pixels, scene_option=_IMAGE_OPTION)
        gray = _blocks(rgb.astype(np.float32) @ _LUMA, self.size).mean(axis=2)
        return gray.round().clip(0, 255).astype(np.uint8)[..., None]

    def mask(self, physics) -> np.ndarray:
        """Binary mask (0 or 255) of the wire, uint8 (size, size, 1): a pixel is set if
        the wire covers any part of it."""
        pixels = self.size * self.MASK_SUPERSAMPLING
        seg = self._cache.render(physics, self.camera, pixels, segmentation=True, scene_option=_MASK_OPTION)
        covered = _blocks(seg[..., 0] >= 0, self.size).any(axis=2)
        return np.where(covered, 255, 0).astype(np.uint8)[..., None]


_LUMA = np.array([0.299, 0.587, 0.114], dtype=np.float32)


def _blocks(image: np.ndarray, size: int) -> np.ndarray:
    """(size*k, size*k, ...) -> (size, size, k*k, ...) pixel blocks."""
    k = image.shape[0] // size
    blocks = image.reshape(size, k, size, k, *image.shape[2:]).swapaxes(1, 2)
    return blocks.reshape(size, size, k * k, *image.shape[2:])


_VIDEO_OPTION = _scene_option([0, geom_groups.VISUAL, geom_groups.WIRE, geom_groups.MARKER])


def video_frame(physics, size: int = 480, camera: str = TOP_CAMERA, cache: CameraCache | None = None) -> np.ndarray:
    """RGB frame for videos and viewers: vessel, wire, robot and the target marker.

    Pass the same `cache` for every frame of a video.
    """
    return (cache or CameraCache()).render(physics, camera, size, scene_option=_VIDEO_OPTION)
