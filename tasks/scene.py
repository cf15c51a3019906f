"""The navigation scene: the arena with the aorta, the robot at its access, the wire on
the robot and the target marker, and where the wire is allowed to be.

Access: the robot's introducer sheath goes in through the aorta's open lower end
(`Aorta.access_position_m`), its seal plate closing that end, and its tip (the robot's
outlet) lies `robot.sheath_depth_m` inside the lumen (see `FollowerRobot`). The wire may
be in the lumen or in the robot's guide channel and sheath (`NavigationScene.containment`);
anywhere else it has escaped.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cathsim_dmc.anatomy.containment import Channel, Containment, lumen_field
from cathsim_dmc.core import task_defaults
from cathsim_dmc.entities import Aorta, FollowerRobot, Guidewire, TargetMarker
from cathsim_dmc.sim import physics as cs_physics
from cathsim_dmc.sim.arena import OperatingArena

WALL_COMPLIANCE_M = 0.5e-3  # how far a wire centre may sit past a wall beyond its own radius (soft contact)


@dataclass
class NavigationScene:
    """The built scene; `arena` is the root entity a task returns."""

    arena: OperatingArena
    aorta: Aorta
    guidewire: Guidewire
    robot: FollowerRobot
    target: TargetMarker
    # Where the wire may be: the lumen (with the wire's radius plus `WALL_COMPLIANCE_M` of
    # tolerance) and the robot's guide channel and sheath, up to the sheath's tip.
    containment: Containment


def build_scene(
    aorta: Aorta,
    guidewire: Guidewire,
    robot: FollowerRobot,
    target_position_m,
    target_radius_m: float,
    lao_deg: float = 0.0,
    blood_drag: bool = False,
    physics: str | cs_physics.PhysicsSettings = task_defaults.PHYSICS,
) -> NavigationScene:
    """Assembles the scene around the entities (which it attaches).

    The arena takes the wire's physics timestep, `blood_drag` and the solver settings
    `physics` (`OperatingArena`); its cameras frame the aorta, the top one turned `lao_deg`
    degrees (left anterior oblique; 0: AP). The target marker is a sphere of
    `target_radius_m` (the success radius) at `target_position_m`. ValueError if the
    robot's sheath cannot seal this aorta's access or the wire's shaped tip would start
    inside the sheath (`check_introducer`).
    """
    arena = OperatingArena(timestep_s=guidewire.physics_timestep_s, blood_drag=blood_drag, physics=physics)
    arena.attach(aorta)
    arena.frame_cameras(aorta.bounds_m, lao_deg=lao_deg)
    robot_frame = arena.attach(robot)
    # The robot's introducer sheath seals the access (the vessel's open end) and
    # reaches sheath_depth_m into the lumen: its tip, the robot's outlet, lies there.
    check_introducer(aorta, guidewire, robot)
    direction = aorta.entry_direction / np.linalg.norm(aorta.entry_direction)
    outlet = aorta.access_position_m + robot.sheath_depth_m * direction
    robot_frame.pos = outlet
    robot_frame.quat = quat_z_to(direction)
    robot.attach(guidewire, robot.wire_attachment_site)
    target = TargetMarker(radius_m=target_radius_m, name="target")
    target_frame = arena.attach(target)
    target_frame.pos = target_position_m
    # The wire belongs in the lumen or in the guide channel and sheath, which end at
    # the outlet inside the lumen: no path outside the two is left. Anywhere else the
    # wire has escaped. The channel's capsule reaches its bore's corners plus the
    # tolerance, and past the outlet only into the lumen.
    tolerance_m = guidewire.radius_m + WALL_COMPLIANCE_M
    introducer = Channel(
        start_m=outlet - robot.channel_length_m * direction,
        end_m=outlet,
        radius_m=robot.channel_half_width_m * np.sqrt(2.0) + tolerance_m,
    )
    containment = Containment(lumen_field(aorta.asset), tolerance_m, [introducer])
    return NavigationScene(arena, aorta, guidewire, robot, target, containment)


def check_introducer(aorta: Aorta, guidewire: Guidewire, robot: FollowerRobot) -> None:
    """ValueError unless the robot's sheath can seal this aorta's access and the wire's tip can start outside it."""
    if robot.seal_half_width_m is None:
        raise ValueError(
            "robot has no seal plate (seal_half_width_m=None): the access would stay open beside "
            "the sheath and a buckled wire could leave the vessel there"
        )
    # The wall's pieces lie contact_margin_m behind the lumen surface (see `Aorta`).
    needed_m = aorta.access_radius_m + aorta.contact_margin_m + aorta.wall_thickness_m
    if robot.seal_half_width_m < needed_m:
        raise ValueError(
            f"robot seal_half_width_m={robot.seal_half_width_m} m does not cover the open end of "
            f"aorta {aorta.name!r} (radius plus wall: {needed_m:.4g} m)"
        )
    shaped = bool(np.any(guidewire.rest_qpos))
    if shaped and robot.initial_insertion_m <= guidewire.tip_length_m:
        raise ValueError(
            f"robot initial_insertion_m={robot.initial_insertion_m} m must exceed the wire's "
            f"tip_length_m={guidewire.tip_length_m} m: the shaped tip must start outside the sheath"
        )


def quat_z_to(direction) -> np.ndarray:
    """Unit quaternion (w, x, y, z) rotating +z onto `direction`."""
    d = np.asarray(direction, dtype=float)
    d = d / np.linalg.norm(d)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, d)
    s = np.linalg.norm(axis)
    c = float(np.dot(z, d))
    if s < 1e-12:
        return np.array([1.0, 0, 0, 0]) if c > 0 else np.array([0.0, 1, 0, 0])
    angle = np.arctan2(s, c)
    axis /= s
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis])
