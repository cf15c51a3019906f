"""What the navigation task measures of the wire in a physics: the tip, points along the
wire, the tip on the centerline tree, the slack, and the wire-wall contacts.

Measurements a control step reads several times (the tip's place on the centerline
tree, the contact forces) are computed once per step: the task calls `start_episode`,
`forget` and `end_step` from its hooks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cathsim_dmc.anatomy.paths import CenterlineTree
from cathsim_dmc.entities import Aorta, FollowerRobot, Guidewire
from cathsim_dmc.sim import physics as cs_physics


@dataclass
class StepInfo:
    """What a step reports besides reward and observation (SI units)."""

    tip_position_m: np.ndarray
    target_distance_m: float
    contact_force_n: float  # total at the end of the control step (one physics step of twenty)
    max_contact_force_n: float  # largest single contact at the end of the control step
    # Total, averaged over the control step's physics steps: the step's wall force, which
    # the metrics, the `contact_force` observation and the training logs use.
    mean_contact_force_n: float
    # The largest of those physics-step totals: the step's peak (an impact lasts one physics step).
    peak_contact_force_n: float
    success: bool
    diverged: bool
    path_distance_m: float  # tip to target along the vessel (geodesic), metres
    insertion_m: float  # carriage travel from the start of the stroke, metres
    slack_m: float  # carriage advance minus tip advance along the vessel, metres
    drive_force_n: float  # insertion drive force, newtons
    escaped: bool  # a wire point left the lumen and the introducer (the episode is truncated)


class WireMeasurements:
    """The wire's measurements for a task whose target is `target_name` on `paths`."""

    def __init__(
        self, aorta: Aorta, guidewire: Guidewire, robot: FollowerRobot, paths: CenterlineTree, target_name: str
    ):
        self._aorta, self._guidewire, self._robot = aorta, guidewire, robot
        self._paths, self._target_name = paths, target_name
        self.wire_mask = self.vessel_mask = None  # geom masks of the wire and the wall (set per episode)
        self._contacts = None  # cached per control step
        self._stepped_state = None  # (qpos, qvel) as the last control step left them
        self._stepped_state_complete = False  # its acceleration stage computed in end_step
        self._wire_point_rows = None  # (body, geom, site) rows of the wire's points (set per episode)
        self._tip_location = None  # the tip on the centerline tree, cached per control step
        self._start_progress_m = 0.0  # tip progress at the start minus the carriage's (set per episode)

    # -- the task's hooks ------------------------------------------------------------------
    def start_episode(self, physics) -> None:
        """Reads the geom masks and the wire's rows of `physics`; forgets the last episode."""
        self._contacts = None
        self.wire_mask = np.zeros(physics.model.ngeom, dtype=bool)
        self.wire_mask[physics.bind(self._guidewire.geoms).element_id] = True
        self.vessel_mask = np.zeros(physics.model.ngeom, dtype=bool)
        self.vessel_mask[self._aorta.wall_geom_ids(physics)] = True
        # Rows of data.xpos / data.site_xpos for `wire_points_m`, read every control step:
        # indexing the arrays directly costs a fraction of a dm_control binding.
        self._wire_point_rows = (
            physics.bind(self._guidewire.segments).element_id,
            physics.bind(self._guidewire.geoms).element_id,
            physics.bind(self._guidewire.tip_site).element_id,
        )
        self._stepped_state = None

    def set_start(self, physics, insertion_m: float) -> None:
        """The start of the slack: the tip's place now, with the carriage at `insertion_m`."""
        self._start_progress_m = self.locate_tip(physics)[1] - insertion_m

    def forget(self) -> None:
        """The state is about to change (a control step, or a reset's start state)."""
        self._contacts = None
        self._stepped_state = None
        self._tip_location = None

    def end_step(self, physics) -> None:
        """After a control step: what of the new state its last physics step left current."""
        # Accelerations and constraint forces of the new state, once (the step info's
        # contact forces need them; see ConstraintSensingPhysics.complete_stepped_state).
        self._stepped_state_complete = (
            isinstance(physics, cs_physics.ConstraintSensingPhysics) and physics.complete_stepped_state()
        )
        # dm_control's legacy step (composer's default) ends with mj_step1: the position
        # and velocity stages of this state are current, so `contact_forces` needs only
        # the rest of mj_forward, as long as the state is still this one.
        if getattr(physics, "legacy_step", False):
            self._stepped_state = (physics.data.qpos.copy(), physics.data.qvel.copy())

    # -- measurements ----------------------------------------------------------------------
    def tip_position_m(self, physics) -> np.ndarray:
        return physics.bind(self._guidewire.tip_site).xpos.copy()

    def wire_points_m(self, physics) -> np.ndarray:
        """(N, 3) points along the wire: segment ends, segment centres and the tip."""
        rows = self._wire_point_rows
        if rows is None or physics.is_dirty:  # no episode yet, or a write not yet forwarded: bind forwards it
            return np.vstack(
                [
                    physics.bind(self._guidewire.segments).xpos,
                    physics.bind(self._guidewire.geoms).xpos,
                    physics.bind(self._guidewire.tip_site).xpos,
                ]
            )
        bodies, geoms, tip = rows
        data = physics.data
        return np.vstack([data.xpos[bodies], data.geom_xpos[geoms], data.site_xpos[tip]])

    def locate_tip(self, physics) -> tuple[str, float, float]:
        """The tip on the centerline tree (line, arc length, depth), located once per step:
        the reward, the path distance and the slack all read it."""
        if self._tip_location is None:
            self._tip_location = self._paths.locate(self.tip_position_m(physics), prefer=self._target_name)
        return self._tip_location

    def path_distance_m(self, physics) -> float:
        """Tip to target along the vessel (`CenterlineTree.geodesic_distance_m`), metres."""
        return self._paths.geodesic_from_location(self.locate_tip(physics), self._target_name)

    def slack_m(self, physics) -> float:
        """Carriage advance minus tip advance along the vessel since the start, metres.

        Near zero (a few mm: the wire takes the outer curve) while the wire follows the
        drive; it grows when the tip stalls and the shaft buckles behind it. A follower
        robot sees the same condition as a rising drive force (`drive_force_n`).
        """
        progress = self.locate_tip(physics)[1] - self._start_progress_m
        return self._robot.insertion_m(physics) - progress

    def contact_forces(self, physics) -> cs_physics.ContactForces:
        """Wire-vessel contact forces for the current state (computed once per step).

        Contacts with the robot's guide channel are not forces on tissue and are left out.
        In the state a control step left (positions and velocities as `end_step` saw
        them) only the acceleration and constraint stages are computed
        (`physics.forward_from_velocity_stage`: the same forces for 0.35-0.45 of an
        ``mj_forward``'s time); in any other state, a full ``mj_forward``.
        """
        if self._contacts is None:
            stepped = self._stepped_state
            in_stepped_state = (
                stepped is not None
                and np.array_equal(stepped[0], physics.data.qpos)
                and np.array_equal(stepped[1], physics.data.qvel)
            )
            if in_stepped_state and not self._stepped_state_complete:
                cs_physics.forward_from_velocity_stage(physics)
            self._contacts = cs_physics.wire_contacts(
                physics, self.wire_mask, recompute=not in_stepped_state, is_vessel_geom=self.vessel_mask
            )
        return self._contacts

    def start_force_n(self, physics) -> float:
        """The wall force of a state just forwarded (a reset's start state), newtons."""
        return cs_physics.wire_contacts(
            physics, self.wire_mask, recompute=False, is_vessel_geom=self.vessel_mask
        ).total_n
