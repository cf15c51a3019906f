"""The images: the top (AP) view and the guidewire mask (GL or raster), videos, and the
settings that say which observations an environment makes and how its images look.

Renders draw only what an observation needs: the merged visual mesh of the vessel
(group 1), the wire (group 2) and the robot's guide channel; never the collision pieces
(group 3, thousands of meshes) nor markers (group 4).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from dm_control.mujoco.wrapper.core import MjvOption

from cathsim_dmc.core.checks import check_number
from cathsim_dmc.sim import geom_groups, raster
from cathsim_dmc.sim import gl_backend as _gl

TOP_CAMERA = "top"
IMAGE_SIZE = 80  # the paper's 80x80 observation
IMAGE_STYLES = ("camera", "fluoro")
RENDERERS = ("gl", "raster")
# The roadmap overlay's grey levels: the lumen's silhouette and the target (`TopView.roadmap_overlay`).
OVERLAY_LUMEN_LEVEL = 128.0
OVERLAY_TARGET_LEVEL = 255.0


@dataclass(frozen=True)
class ObservationSettings:
    """Which observations an environment returns, and how images are made."""

    enabled: frozenset = field(default_factory=frozenset)
    image_size: int = IMAGE_SIZE
    style: str = "camera"  # or "fluoro"
    renderer: str = "raster"  # or "gl"
    noise_std: float = 0.0  # Gaussian pixel noise (grey levels), seeded by the environment
    # The top camera turned this many degrees towards the patient's left about the
    # vertical axis (left anterior oblique; negative: right anterior oblique); 0 = AP.
    lao_deg: float = 0.0
    # The roadmap observation's noise (tasks/roadmap.py): the tracked tip's, per axis and
    # step, and the roadmap's registration error, one offset per episode; metres (std).
    tracking_noise_m: float = 0.0
    registration_error_m: float = 0.0
    # The fluoroscopic detector (`cathsim_dmc.sim.detector`; style "fluoro"): the air kerma
    # at the detector per frame, nanograys (0: no quantum noise), and the Gaussian blur at
    # the vessel, millimetres (std; 0: none).
    detector_dose_ngy: float = 0.0
    blur_mm: float = 0.0
    # A C-arm view drawn per episode (`Navigate`): the LAO angle (negative: RAO) and the
    # cranial angle (negative: caudal) uniform in these [low, high] ranges, degrees; None:
    # the fixed view of `lao_deg`.
    view_deg_range: tuple | None = None
    cranial_deg_range: tuple | None = None
    # Where the image-plane observations (`tracking_2d`, ...) find the wire: "projection"
    # (the simulator's wire projected into the view, plus `tracking_noise_m`) or
    # "fluoro_image" (found in the step's fluoroscopic frame of this image size and detector,
    # `cathsim_dmc.sim.wire_finder`).
    tracking_source: str = "projection"


def image_noise(std: float):
    """Observation corruptor: Gaussian noise of `std` grey levels on a uint8 image,
    drawn from the environment's random state (a seeded episode stays reproducible)."""

    def corrupt(value, random_state):
        noisy = value + random_state.normal(0.0, std, size=value.shape)
        return noisy.round().clip(0, 255).astype(np.uint8)

    return corrupt


def _scene_option(groups) -> MjvOption:
    option = MjvOption()
    option.geomgroup[:] = 0
    for g in groups:
        option.geomgroup[g] = 1
    option.sitegroup[:] = 0
    return option


_IMAGE_OPTION = _scene_option([0, geom_groups.VISUAL, geom_groups.WIRE])
_MASK_OPTION = _scene_option([geom_groups.WIRE])
_BACKGROUND_OPTION = _scene_option([0, geom_groups.VISUAL])


# The compiled models keep MuJoCo's default offscreen framebuffer (640 x 480 pixels), and
# every camera image here is square, so its side can be at most the framebuffer's height.
MAX_RENDER_PX = 480


def check_render_size(name: str, value) -> int:
    """`value` as a square image side MuJoCo can render (1 to MAX_RENDER_PX pixels), or a
    ValueError naming the parameter."""
    size = check_number(name, value, 1, whole=True)
    if size > MAX_RENDER_PX:
        raise ValueError(
            f"{name}={value!r} is larger than the offscreen framebuffer; choose 1 to {MAX_RENDER_PX} pixels"
        )
    return size


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
            # Checked against this model's own buffer: else dm_control's error surfaces as a GL failure.
            buffer = physics.model.vis.global_
            if pixels > min(buffer.offwidth, buffer.offheight):
                raise ValueError(
                    f"image size={pixels} is larger than the model's offscreen framebuffer "
                    f"({buffer.offwidth}x{buffer.offheight} px)"
                )
            from dm_control.mujoco.engine import Camera

            try:
                self._cameras[key] = Camera(physics, pixels, pixels, camera)
            except Exception as error:  # without a GL backend dm_control fails deep in GL set-up
                raise RuntimeError(f"{_gl.missing_backend_message()} ({error})") from error
        # A Camera renders into one buffer it reuses: copy, or every frame is the last.
        return self._cameras[key].render(**render_kwargs).copy()


class TopView:
    """The top (AP) camera image and guidewire mask of one environment.

    `renderer="gl"` renders every step with MuJoCo's OpenGL renderer. `renderer="raster"`
    projects the wire's joints through the (orthographic, fixed) top camera and draws the
    polyline with OpenCV onto a background made once per compiled model, so a step
    costs no GL at all. `style="fluoro"` is an X-ray-like roadmap (see
    `cathsim_dmc.sim.raster`); `style="camera"` is the shaded see-through vessel.

    The robot (rail, guide channel) appears in the camera-style background as GL draws
    it, but the raster wire is drawn over it: the rail hides only the wire's first
    centimetres outside the patient, and the rail is white like the wire. The fluoro
    style shows the patient only: the robot stays outside the X-ray field.
    """

    # At 80 px over a ~0.2 m field one pixel spans ~3 mm, more than three wire diameters:
    # drawn at that size the wire breaks into dashes. Both images are drawn larger and
    # reduced; software GL pays mostly per drawn geom, little per pixel.
    IMAGE_SUPERSAMPLING = 2
    MASK_SUPERSAMPLING = 4
    RASTER_SUPERSAMPLING = 4  # OpenCV canvas; also the roadmap's sampling
    # Camera style, raster: grey level of a pixel fully covered by the bright wire seen
    # through the see-through vessel (median 222 over such pixels of a 480 px GL render).
    CAMERA_WIRE_LEVEL = 222.0

    @classmethod
    def largest_image_size(cls, settings: ObservationSettings) -> int | None:
        """The largest `image_size` whose GL renders fit the offscreen framebuffer, for the
        images `settings` enable; None if they need no GL render (any size)."""
        factors = []
        if "pixels" in settings.enabled:
            if settings.style == "camera":  # gl: the image; raster: its background
                factors.append(cls.IMAGE_SUPERSAMPLING)
            elif settings.renderer == "gl":  # fluoro: the wire's coverage from a segmentation render
                factors.append(cls.MASK_SUPERSAMPLING)
        if "guidewire_mask" in settings.enabled and settings.renderer == "gl":
            factors.append(cls.MASK_SUPERSAMPLING)
        return MAX_RENDER_PX // max(factors) if factors else None

    def __init__(
        self, size: int = IMAGE_SIZE, camera: str = TOP_CAMERA, renderer: str = "gl", wire=None, vessel_geom_id=None
    ):
        if renderer not in RENDERERS:
            raise ValueError(f"renderer={renderer!r}; choose one of {RENDERERS}")
        self.size = int(size)
        self.camera = camera
        self.renderer = renderer
        self._wire = wire
        self._vessel_geom_id = vessel_geom_id  # physics -> geom id of the lumen mesh
        self._cache = CameraCache()
        self._drawer = raster.WireDrawer(self.size, self.RASTER_SUPERSAMPLING)
        self._scene = None  # per compiled model and view: projection, element ids, backgrounds
        self._model = None
        self._view = None

    def image(self, physics, style: str = "camera") -> np.ndarray:
        """Grayscale view, uint8 (size, size, 1), anti-aliased."""
        if style not in IMAGE_STYLES:
            raise ValueError(f"image style={style!r}; choose one of {IMAGE_STYLES}")
        if self.renderer == "gl" and style == "camera":
            pixels = self.size * self.IMAGE_SUPERSAMPLING
            rgb = self._cache.render(physics, self.camera, pixels, scene_option=_IMAGE_OPTION)
            gray = _blocks(rgb.astype(np.float32) @ _LUMA, self.size).mean(axis=2)
            return gray.round().clip(0, 255).astype(np.uint8)[..., None]
        scene = self._scene_for(physics)
        if self.renderer == "gl":  # fluoro: the wire's coverage from a segmentation render
            covered = self._segmentation(physics) >= 0
            cover = np.minimum(_blocks(covered, self.size).mean(axis=2) * scene["fluoro_gain"], 1.0)
        else:
            width = scene["wire_width_px"] * (scene["fluoro_gain"] if style == "fluoro" else 1.0)
            cover = self._drawer.coverage(self._wire_uv(physics, scene), width)
        if style == "fluoro":
            image = self._fluoro_background(physics, scene) * (1.0 - raster.WIRE_OPACITY * cover)
        else:
            background = self._camera_background(physics, scene)
            image = background + cover * (self.CAMERA_WIRE_LEVEL - background)
        return image.round().clip(0, 255).astype(np.uint8)[..., None]

    def mask(self, physics) -> np.ndarray:
        """Binary mask (0 or 255) of the wire, uint8 (size, size, 1): a pixel is set if
        the wire covers any part of it."""
        if self.renderer == "gl":
            covered = _blocks(self._segmentation(physics) >= 0, self.size).any(axis=2)
        else:
            scene = self._scene_for(physics)
            covered = self._drawer.mask(self._wire_uv(physics, scene), scene["wire_width_px"])
        return np.where(covered, 255, 0).astype(np.uint8)[..., None]

    # -- helpers ---------------------------------------------------------------
    def _segmentation(self, physics) -> np.ndarray:
        pixels = self.size * self.MASK_SUPERSAMPLING
        return self._cache.render(physics, self.camera, pixels, segmentation=True, scene_option=_MASK_OPTION)[..., 0]

    def _scene_for(self, physics) -> dict:
        # A recompiled model, or the camera moved to another view (`Navigate`'s per-episode
        # C-arm view), invalidates it all.
        if self._model is not physics.model.ptr or self._view != self._camera_pose(physics):
            if self._wire is None or self._vessel_geom_id is None:
                raise ValueError("the raster renderer and the fluoro style need the wire and the vessel geom")
            self._model = physics.model.ptr
            self._view = self._camera_pose(physics)
            matrix, towards_camera = raster.camera_axes(physics, self.camera)
            wire_width_px = self._wire.diameter_m * self.size * float(np.linalg.norm(matrix[0, :3]))
            self._scene = dict(
                matrix=matrix,
                towards_camera=towards_camera,
                bodies=physics.bind(self._wire.segments).element_id.copy(),
                tip=int(physics.bind(self._wire.tip_site).element_id),
                wire_width_px=wire_width_px,
                fluoro_gain=max(1.0, raster.FLUORO_WIRE_MIN_WIDTH_PX / wire_width_px),
                pixel_m=1.0 / (self.size * float(np.linalg.norm(matrix[0, :3]))),
            )
        return self._scene

    def _camera_pose(self, physics) -> bytes:
        cam = physics.model.name2id(self.camera, "camera")
        data = physics.data
        return data.cam_xpos[cam].tobytes() + data.cam_xmat[cam].tobytes() + physics.model.cam_fovy[cam].tobytes()

    def pixel_size_m(self, physics) -> float:
        """The side of one output pixel at the vessel (the camera's field over the image size), metres."""
        return self._scene_for(physics)["pixel_m"]

    @property
    def drawn_pixel_size_m(self) -> float:
        """`pixel_size_m` of the view of the last image drawn."""
        if self._scene is None:
            raise RuntimeError("no image drawn yet")
        return self._scene["pixel_m"]

    def roadmap_overlay(self, physics, offset_m, target_m, target_radius_m: float) -> np.ndarray:
        """The registered roadmap as a fluoroscope overlays it, uint8 (size, size, 1): the
        lumen's silhouette (`OVERLAY_LUMEN_LEVEL` where a pixel is all inside it; the
        pre-operative CTA's vessel tree projected through the camera) and the target, a
        disc of `target_radius_m` (at least one pixel wide) at `OVERLAY_TARGET_LEVEL`. The
        registration error `offset_m` (a world vector, metres) moves both, as a
        misregistered roadmap lies beside the live image. Made once per view and offset."""
        scene = self._scene_for(physics)
        offset = np.asarray(offset_m, dtype=float).reshape(3)
        key = (offset.tobytes(), np.asarray(target_m, dtype=float).tobytes(), float(target_radius_m))
        if scene.get("overlay_key") != key:
            k = self.RASTER_SUPERSAMPLING
            if "silhouette" not in scene:
                geom = int(self._vessel_geom_id(physics))
                vertices, faces = raster.mesh_in_world(physics, geom)
                _, crossings = raster.path_length_map(
                    vertices, faces, scene["matrix"], scene["towards_camera"], self.size * k
                )
                scene["silhouette"] = raster.reduce_area((crossings > 0).astype(np.float32), self.size)
            shift = (
                raster.project(offset[None], scene["matrix"], self.size)[0]
                - raster.project(np.zeros((1, 3)), scene["matrix"], self.size)[0]
            )
            lumen = cv2.warpAffine(
                scene["silhouette"],
                np.array([[1.0, 0.0, shift[0]], [0.0, 1.0, shift[1]]], dtype=np.float32),
                (self.size, self.size),
                flags=cv2.INTER_LINEAR,
                borderMode=cv2.BORDER_CONSTANT,
                borderValue=0.0,
            )
            centre = raster.project((np.asarray(target_m, dtype=float) + offset)[None], scene["matrix"], self.size)[0]
            radius_px = max(target_radius_m / scene["pixel_m"], 0.5)
            target = self._drawer.disc(centre, radius_px)
            overlay = np.maximum(lumen * OVERLAY_LUMEN_LEVEL, target * OVERLAY_TARGET_LEVEL)
            scene["overlay"] = overlay.round().clip(0, 255).astype(np.uint8)[..., None]
            scene["overlay_key"] = key
        return scene["overlay"].copy()

    def _wire_uv(self, physics, scene) -> np.ndarray:
        """The wire's centreline (segment joints, proximal to distal, then the tip) in
        output pixel coordinates."""
        points = np.concatenate([physics.data.xpos[scene["bodies"]], physics.data.site_xpos[scene["tip"]][None]])
        return raster.project(points, scene["matrix"], self.size)

    def _fluoro_background(self, physics, scene) -> np.ndarray:
        if "fluoro" not in scene:
            geom = int(self._vessel_geom_id(physics))
            vertices, faces = raster.mesh_in_world(physics, geom)
            k = self.RASTER_SUPERSAMPLING
            length, _ = raster.path_length_map(vertices, faces, scene["matrix"], scene["towards_camera"], self.size * k)
            # Transmission averaged over each output pixel, as a detector pixel integrates it.
            scene["fluoro"] = 255.0 * raster.reduce_area(raster.fluoro_roadmap(length), self.size)
        return scene["fluoro"]

    def _camera_background(self, physics, scene) -> np.ndarray:
        if "camera" not in scene:  # one GL render of everything but the wire
            pixels = self.size * self.IMAGE_SUPERSAMPLING
            rgb = self._cache.render(physics, self.camera, pixels, scene_option=_BACKGROUND_OPTION)
            scene["camera"] = _blocks(rgb.astype(np.float32) @ _LUMA, self.size).mean(axis=2)
        return scene["camera"]


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
