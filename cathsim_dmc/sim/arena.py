"""The operating scene: physics options, lights and the two cameras.

``top`` looks along -z (patient posterior), the antero-posterior fluoroscopy view;
``side`` looks along -x (patient left to right), the lateral view. Both are orthographic,
as an X-ray projection nearly is, and are framed on an anatomy with `frame_cameras`,
which can also turn ``top`` into a left anterior oblique (LAO) view: the camera swung
about the patient's vertical axis towards the patient's left (`lao_camera_axes`).
"""

from __future__ import annotations

import mujoco
import numpy as np
from dm_control import composer

from cathsim_dmc.core import task_defaults
from cathsim_dmc.sim.physics import PhysicsSettings, physics_settings

PHYSICS_TIMESTEP_S = 0.005  # the guidewire's default; tasks take the wire's own
BLOOD_DENSITY_KG_M3 = 1055.0  # whole blood (Kenner 1989)
BLOOD_VISCOSITY_PA_S = 0.0035  # whole blood at high shear, 3.5-4 mPa s


class OperatingArena(composer.Arena):
    """Empty scene with lights, a top (AP) and a side (lateral) camera."""

    def _build(
        self,
        name: str = "operating_room",
        timestep_s: float = PHYSICS_TIMESTEP_S,
        blood_drag: bool = False,
        physics: str | PhysicsSettings = task_defaults.PHYSICS,
    ):
        """Builds the scene.

        Args:
          name: model name.
          timestep_s: physics timestep in seconds.
          physics: solver settings, a name in `physics.PHYSICS_SETTINGS` ("accurate",
            "fast") or a `PhysicsSettings`.
          blood_drag: apply MuJoCo's fluid forces for blood (density and viscosity
            above) to every moving body. At the wire's speeds (tens of mm/s) the drag
            is small against its stiffness and wall contact (the tip path after 30 full
            insertion steps moved by < 0.01 mm); off by default.
        """
        if not isinstance(blood_drag, (bool, np.bool_)):  # -1 or "yes" would read as on
            raise ValueError(f"blood_drag={blood_drag!r} must be True or False")
        super()._build(name=name)
        root = self._mjcf_root
        root.compiler.angle = "radian"
        # implicitfast: joint damping and servo damping integrated implicitly (stable
        # at stiff servos); elliptic cones: friction forces read out directly and
        # more accurate than pyramids.
        root.option.set_attributes(
            timestep=timestep_s,
            integrator="implicitfast",
            cone="elliptic",
            gravity=[0, 0, -9.81],
        )
        # One contact per wire-wall pair instead of ~1.4: the convex wall prisms are
        # thin and a capsule meets them at a point; 20% faster in wall contact with
        # the same penetration and no escapes (physics probe).
        root.option.flag.multiccd = "disable"
        # Solver, iterations, Jacobian, noslip and sleep: all explicit, none inherited
        # from dm_control's arena template (which sets noslip_iterations=5).
        physics_settings(physics).apply(root)
        if blood_drag:
            # implicitfast would differentiate the fluid forces every step (measured 9x
            # slower); Euler keeps joint damping implicit and costs the same as before.
            root.option.set_attributes(density=BLOOD_DENSITY_KG_M3, viscosity=BLOOD_VISCOSITY_PA_S, integrator="Euler")
        # Room for hundreds of wall contacts (the default 24 MB overflows in a jammed wire).
        root.size.memory = "128M"
        root.visual.quality.shadowsize = 0  # no shadow maps: they double software-GL cost
        root.visual.map.znear = 0.001
        root.visual.headlight.set_attributes(ambient=[0.5, 0.5, 0.5], diffuse=[0.5, 0.5, 0.5], specular=[0, 0, 0])
        root.visual.rgba.haze = [0, 0, 0, 0]
        root.worldbody.add(
            "light",
            name="front",
            pos=[0, 0, 1],
            dir=[0, 0, -1],
            directional=True,
            castshadow=False,
            diffuse=[0.4, 0.4, 0.4],
        )
        self._top = root.worldbody.add(
            "camera", name="top", pos=[0, 0, 1], quat=[1, 0, 0, 0], projection="orthographic", fovy=0.3
        )
        # Looking along -x: camera -z axis = world -x, camera up (+y) = world +y.
        self._side = root.worldbody.add(
            "camera", name="side", pos=[1, 0, 0], xyaxes=[0, 0, -1, 0, 1, 0], projection="orthographic", fovy=0.3
        )

    @property
    def top_camera(self):
        return self._top

    @property
    def side_camera(self):
        return self._side

    def frame_cameras(self, bounds_m, margin: float = 1.1, lao_deg: float = 0.0, cranial_deg: float = 0.0):
        """Centres both cameras on an axis-aligned box [[min xyz], [max xyz]] in metres.

        `lao_deg` turns the top camera about world +y (the patient's long axis) by that
        angle towards the patient's left, looking at the patient from the front left: a
        left anterior oblique view (negative: right anterior oblique); 0 is the AP view.
        `cranial_deg` then tilts it towards the patient's head (negative: caudal). The
        turned camera is framed on the box's corners seen along its own axes
        (`top_camera_frame`).
        """
        lo, hi = np.asarray(bounds_m, dtype=float)
        centre = (lo + hi) / 2
        extent = hi - lo
        self._top.pos, self._top.quat, self._top.fovy = top_camera_frame(bounds_m, lao_deg, cranial_deg, margin)
        self._side.pos = [hi[0] + 0.5, centre[1], centre[2]]
        self._side.fovy = float(max(extent[2], extent[1]) * margin)
        self._mjcf_root.visual.map.zfar = 5.0
        self._mjcf_root.statistic.center = centre
        self._mjcf_root.statistic.extent = float(np.max(extent))


def top_camera_frame(bounds_m, lao_deg: float = 0.0, cranial_deg: float = 0.0, margin: float = 1.1):
    """(position, MuJoCo quaternion, fovy) of the top camera framed on an axis-aligned box
    [[min xyz], [max xyz]] (metres) in the C-arm view (`carm_camera_axes`): centred on it,
    in front of all of it, and showing all of it (fovy, the visible height of an
    orthographic camera, in metres; images are square)."""
    lo, hi = np.asarray(bounds_m, dtype=float)
    centre = (lo + hi) / 2
    extent = hi - lo
    if lao_deg == 0 and cranial_deg == 0:
        return [centre[0], centre[1], hi[2] + 0.5], [1, 0, 0, 0], float(max(extent[0], extent[1]) * margin)
    right, up, towards = carm_camera_axes(lao_deg, cranial_deg)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    pos = centre + (float(np.max((corners - centre) @ towards)) + 0.5) * towards
    if cranial_deg == 0:  # the LAO view: up is the patient's long axis
        return pos, lao_camera_quat(lao_deg), float(max(np.ptp((corners - centre) @ right), extent[1]) * margin)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.stack([right, up, towards], axis=1).ravel())
    fovy = float(max(np.ptp(corners @ right), np.ptp(corners @ up)) * margin)
    return pos, quat, fovy


def lao_camera_axes(lao_deg: float):
    """World directions of the LAO top camera's image right, image up and view axis
    (towards the camera): world +x, +y, +z turned by `lao_deg` about +y, so that the
    camera sits at (sin, 0, cos) of the angle, anterior and to the patient's left."""
    a = np.radians(float(lao_deg))
    return (np.array([np.cos(a), 0.0, -np.sin(a)]), np.array([0.0, 1.0, 0.0]), np.array([np.sin(a), 0.0, np.cos(a)]))


def carm_camera_axes(lao_deg: float, cranial_deg: float = 0.0):
    """World directions of the C-arm view's image right, image up and view axis (towards
    the camera): the LAO view (`lao_camera_axes`) tilted `cranial_deg` about its image
    right towards the patient's head (+y; negative: caudal), as a C-arm's second angle
    turns it. The image right stays in the patient's transverse plane."""
    right, _, towards = lao_camera_axes(lao_deg)
    b = np.radians(float(cranial_deg))
    towards = np.cos(b) * towards + np.sin(b) * np.array([0.0, 1.0, 0.0])
    return right, np.cross(towards, right), towards


def lao_camera_quat(lao_deg: float) -> np.ndarray:
    """MuJoCo quaternion (w, x, y, z) of the turn by `lao_deg` about +y."""
    half = np.radians(float(lao_deg)) / 2
    return np.array([np.cos(half), 0.0, np.sin(half), 0.0])


def top_camera_matrix(physics, camera_name: str = "top", size: int = 80) -> np.ndarray:
    """3x4 matrix mapping world points (homogeneous, metres) to pixel coordinates."""
    camera = physics.model.name2id(camera_name, "camera")
    pos = physics.data.cam_xpos[camera]
    rot = physics.data.cam_xmat[camera].reshape(3, 3)
    fovy = physics.model.cam_fovy[camera]
    scale = size / fovy
    # Camera frame: x right, y up, looking along -z. Pixel u to the right, v down.
    world_to_cam = np.concatenate([rot.T, (-rot.T @ pos)[:, None]], axis=1)
    project = np.array([[scale, 0, 0, size / 2], [0, -scale, 0, size / 2], [0, 0, 0, 1]])
    return project @ np.vstack([world_to_cam, [0, 0, 0, 1]])
