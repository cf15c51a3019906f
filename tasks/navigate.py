"""Navigate: steer the guidewire tip from the descending aorta into a target branch."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import dm_env.specs
from dm_control import composer
from dm_control.mujoco import wrapper
from dm_control.composer.observation import observable

from cathsim_dmc import model_cache
from cathsim_dmc.checks import check_number
from cathsim_dmc.anatomy.paths import CenterlineTree
from cathsim_dmc import physics as cs_physics
from cathsim_dmc.anatomy.containment import Channel, Containment, lumen_field
from cathsim_dmc.arena import OperatingArena
from cathsim_dmc.entities import Aorta, FollowerRobot, Guidewire, TargetMarker
from cathsim_dmc.entities.catheter import Catheter, CatheterOverWire, catheter_named
from cathsim_dmc.observables import OBSERVATION_PRESETS, ObservationSettings, TopView, image_noise

CONTROL_TIMESTEP_S = 0.1  # one step moves the wire up to 4 mm at 40 mm/s
MAX_STEPS = 300  # the paper's episode limit
SUCCESS_RADIUS_M = 0.004  # the paper's delta
SUCCESS_REWARD = 10.0
# The distance a dense reward penalises: "euclidean" (the paper's: straight line from the
# tip to the target) or "geodesic" (along the vessel, so a wrong branch scores worse than
# the right ostium; see `Navigate.reward_distance_m`).
REWARDS = ("euclidean", "geodesic")
EXTRA_OBSERVATIONS = ("wire_slack", "drive_force", "tip_position", "contact_force")
# Aim shaping looks this many lumen radii ahead along the target's centerline (as the expert).
AIM_LOOKAHEAD_RADII = 1.5
# The aim counts fully once the next stretch is this far off the shaft's axis (the share of
# the look-ahead across the shaft); straight ahead, the bend's direction does not matter.
AIM_FULL_OFF_AXIS = 0.5
WALL_COMPLIANCE_M = 0.5e-3  # how far a wire centre may sit past a wall beyond its own radius (soft contact)
def expected_action(names=("insertion", "rotation")) -> str:
    """What an action with entries `names` must be (the error messages' "expected ...")."""
    return f"shape ({len(names)},), finite, [{', '.join(names)}] in [-1, 1] (values outside are clipped)"


def check_options(delta_m=None, max_steps=None, success_reward=None, insertion_limit_margin_m=None,
                  progress_weight=None, aim_weight=None, physics=None, catheter=None, **_others) -> None:
    """ValueError naming the parameter for a task setting the task cannot use.

    `Navigate` checks its own arguments with it; `build_task` and the command-line tools
    call it before building anything. A zero success radius would make MuJoCo fail on a
    zero-size marker, and `max_steps=0` would end every episode after one step.
    """
    if delta_m is not None:
        check_number("delta_m", delta_m, 0.0, inclusive=False)
    if max_steps is not None:
        check_number("max_steps", max_steps, 1, whole=True)
    if success_reward is not None:
        check_number("success_reward", success_reward)
    if insertion_limit_margin_m is not None:  # metres past the target's centerline length
        check_number("insertion_limit_margin_m", insertion_limit_margin_m, 0.0)
    if progress_weight is not None:
        check_number("progress_weight", progress_weight, 0.0)
    if aim_weight is not None:
        check_number("aim_weight", aim_weight, 0.0)
    if physics is not None:  # a name in cs_physics.PHYSICS_SETTINGS ("accurate", "fast")
        cs_physics.physics_settings(physics)
    if catheter is not None:  # a name in CATHETERS ("angled_5f") or a Catheter
        catheter_named(catheter)


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


class Navigate(composer.Task):
    """Reach `target` (a site of the aorta) with the guidewire tip.

    Reward: `success_reward` when the tip is within `delta_m` of the target (which ends
    the episode), otherwise minus the distance in metres (dense) or 0 (sparse). After
    `max_steps` control steps the episode is truncated (discount 1). A diverged
    simulation also truncates, with `diverged` set in `step_info`.

    Training options (success, the time limit and the metrics do not depend on them):
    `reward="geodesic"` measures the distance along the vessel instead of the straight
    line; `progress_weight` adds that weight times the step's progress towards the target
    in units of one full-speed insertion step (potential-style shaping); and
    `insertion_limit_margin_m` stops the carriage at the centerline length from the entry
    to the target plus this margin (None: the full stroke). `aim_weight` adds potential
    shaping for turning the tip's bend towards where the target's centerline goes next
    (the privileged expert's aim): the potential is -aim_weight x (angle from bend to
    aim / pi), faded out where the path runs straight ahead, so aiming is paid for the
    step it happens rather than only when the tip later moves.

    Physics: `physics="fast"` (the default: PGS capped at 10 iterations, dense Jacobian,
    noslip off, sleep on; about twice the speed of `accurate` in wall contact) or `"accurate"`
    (Newton), the solver settings of `cathsim_dmc.physics.PHYSICS_SETTINGS`.

    Access: the robot's introducer sheath goes in through the aorta's open lower end
    (`Aorta.access_position_m`), its seal plate closing that end, and its tip (the
    robot's outlet) lies `robot.sheath_depth_m` (3 mm) inside the lumen; see
    `FollowerRobot`. The wire's shaped tip starts just past the sheath: with the default
    robot and wire its end lies 7-9 mm (with the start's 0-2 mm insertion jitter) past
    the `entry` site, which is 10 mm above the open end in every shipped aorta: the 15 mm
    angled tip spans 12.3 mm along the axis, so it cannot start at the entry without
    starting in the straight sheath. The wire may be in the lumen or in the
    guide channel and sheath (`containment`); anywhere else it has escaped, which
    truncates the episode like a divergence (`escaped`).

    Catheter: `catheter="angled_5f"` (or a `Catheter`) puts a shaped catheter over the wire
    (`CatheterOverWire`, docs/model.md#catheter). Actions then have a third entry, the
    catheter carriage's speed; the catheter starts parked with its tip at the sheath's,
    cannot pass the wire's tip nor go back into the sheath, and `joint_pos` gains its
    tip's offset behind the wire's tip over the robot's stroke (`catheter_offset_m`).
    """

    def __init__(
        self,
        aorta: Aorta,
        guidewire: Guidewire,
        robot: FollowerRobot,
        target: str = "bca",
        delta_m: float = SUCCESS_RADIUS_M,
        success_reward: float = SUCCESS_REWARD,
        dense: bool = True,
        max_steps: int = MAX_STEPS,
        observations: ObservationSettings = OBSERVATION_PRESETS["internal"],
        control_timestep_s: float = CONTROL_TIMESTEP_S,
        start_insertion_jitter_m: float = 0.002,
        start_rotation_rad: float = np.pi,
        start_rotation_jitter_rad: float = 0.3,
        blood_drag: bool = False,
        reward: str = "euclidean",
        progress_weight: float = 0.0,
        aim_weight: float = 0.0,
        insertion_limit_margin_m: float | None = None,
        extra_observations: tuple = (),
        physics: str = cs_physics.DEFAULT_PHYSICS,
        catheter: Catheter | str | None = None,
    ):
        if target not in aorta.targets:
            raise ValueError(f"target={target!r} is not a site of aorta {aorta.name!r}; choose one of {sorted(aorta.targets)}")
        self._aorta = aorta
        self._guidewire = guidewire
        self._robot = robot
        self._target_name = target
        check_options(delta_m=delta_m, max_steps=max_steps, success_reward=success_reward,
                      insertion_limit_margin_m=insertion_limit_margin_m, progress_weight=progress_weight,
                      aim_weight=aim_weight, physics=physics, catheter=catheter)
        self._physics_setting = physics
        self._catheter = None if catheter is None else catheter_named(catheter)
        self._catheter_on_wire = None if catheter is None else CatheterOverWire(self._catheter, guidewire)
        self._catheter_model_key = None  # the model the catheter last read the wire's joints from
        self._catheter_out_m = 0.0  # the catheter's tip past the sheath's tip, along the wire (per episode)
        self._catheter_offset_m = 0.0  # the catheter's tip behind the wire's tip
        self._catheter_command = 0.0
        self._delta_m = float(delta_m)
        self._success_reward = float(success_reward)
        self._dense = bool(dense)
        self._max_steps = int(max_steps)
        self._insertion_jitter_m = float(start_insertion_jitter_m)
        self._start_rotation_rad = float(start_rotation_rad)
        self._rotation_jitter_rad = float(start_rotation_jitter_rad)
        self._settings = observations
        if reward not in REWARDS:
            raise ValueError(f"reward={reward!r}; choose one of {list(REWARDS)}")
        unknown = sorted(set(extra_observations) - set(EXTRA_OBSERVATIONS))
        if unknown:
            raise ValueError(f"extra_observations {unknown} unknown; choose from {list(EXTRA_OBSERVATIONS)}")
        self._reward_kind = reward
        self._progress_weight = float(progress_weight)
        self._aim_weight = float(aim_weight)
        self._extra_observations = tuple(extra_observations)
        self._paths = CenterlineTree.from_asset(aorta.asset)
        self._insertion_limit_m = (None if insertion_limit_margin_m is None
                                   else self._paths.lines[target].length_m + float(insertion_limit_margin_m))

        self._arena = OperatingArena(timestep_s=guidewire.physics_timestep_s, blood_drag=blood_drag, physics=physics)
        self._arena.attach(aorta)
        self._arena.frame_cameras(aorta.bounds_m, lao_deg=observations.lao_deg)
        robot_frame = self._arena.attach(robot)
        # The robot's introducer sheath seals the access (the vessel's open end) and
        # reaches sheath_depth_m into the lumen: its tip, the robot's outlet, lies there.
        _check_introducer(aorta, guidewire, robot)
        direction = aorta.entry_direction / np.linalg.norm(aorta.entry_direction)
        outlet = aorta.access_position_m + robot.sheath_depth_m * direction
        robot_frame.pos = outlet
        robot_frame.quat = _quat_z_to(direction)
        robot.attach(guidewire, robot.wire_attachment_site)
        self._target = TargetMarker(radius_m=self._delta_m, name="target")
        target_frame = self._arena.attach(self._target)
        target_frame.pos = aorta.targets[target]

        self.set_timesteps(control_timestep=control_timestep_s, physics_timestep=guidewire.physics_timestep_s)
        self._task_observables = self._build_task_observables(observations)

        self._step_count = 0
        self._success = False
        self._diverged = False
        self._contacts = None  # cached per control step
        self._stepped_state = None  # (qpos, qvel) as the last control step left them
        self._stepped_state_complete = False  # its acceleration stage computed in after_step
        self._wall_force = None  # cs_physics.WallForceTotal for this physics (set per episode)
        self._wire_point_rows = None  # (body, geom, site) rows of the wire's points (set per episode)
        self._tip_location = None  # the tip on the centerline tree, cached per control step
        # Sum, count and largest of the physics-step totals of one control step.
        self._force_sum_n, self._force_samples, self._force_peak_n = 0.0, 0, 0.0
        self._mean_force_n = self._peak_force_n = 0.0
        self._reward_distance_m = self._previous_reward_distance_m = 0.0
        self._aim_potential = self._previous_aim_potential = 0.0
        self._start_progress_m = 0.0  # tip progress at the start minus the carriage's (set per episode)
        # The wire belongs in the lumen or in the guide channel and sheath, which end at
        # the outlet inside the lumen: no path outside the two is left. Anywhere else the
        # wire has escaped. The channel's capsule reaches its bore's corners plus the
        # tolerance, and past the outlet only into the lumen.
        tolerance_m = guidewire.radius_m + WALL_COMPLIANCE_M
        introducer = Channel(start_m=outlet - robot.channel_length_m * direction, end_m=outlet,
                             radius_m=robot.channel_half_width_m * np.sqrt(2.0) + tolerance_m)
        self._containment = Containment(lumen_field(aorta.asset), tolerance_m, [introducer])
        self._escaped = False

    # -- structure -------------------------------------------------------------
    @property
    def root_entity(self):
        return self._arena

    @property
    def aorta(self):
        return self._aorta

    @property
    def guidewire(self):
        return self._guidewire

    @property
    def robot(self):
        return self._robot

    @property
    def target_name(self) -> str:
        return self._target_name

    @property
    def target_position_m(self) -> np.ndarray:
        return np.asarray(self._aorta.targets[self._target_name], dtype=float)

    @property
    def physics_setting(self):
        """The solver settings this task was built with: a name ("accurate", "fast") or a
        `PhysicsSettings`."""
        return self._physics_setting

    @property
    def max_steps(self) -> int:
        return self._max_steps

    @property
    def paths(self) -> CenterlineTree:
        """The aorta's centerline tree (distances along the vessel)."""
        return self._paths

    @property
    def insertion_limit_m(self) -> float | None:
        """The carriage's travel limit in metres (None: the robot's full stroke)."""
        return self._insertion_limit_m

    @property
    def top_view(self):
        """The `TopView` drawing this task's `pixels` and `guidewire_mask`."""
        return self._top_view

    @property
    def observation_settings(self) -> ObservationSettings:
        return self._settings

    @property
    def task_observables(self):
        return self._task_observables

    def _build_task_observables(self, settings: ObservationSettings):
        robot, wire_joints = self._robot, self._guidewire.joints
        self._top_view = TopView(settings.image_size, renderer=settings.renderer, wire=self._guidewire,
                                 vessel_geom_id=self._aorta.visual_geom_id)
        obs = {
            # The robot's pose as bounded features (insertion / stroke, sin and cos of the
            # rotation, which is never wrapped otherwise), then the wire's bending angles (rad).
            "joint_pos": observable.Generic(lambda physics: np.concatenate(
                [robot.pose_features(physics), physics.bind(wire_joints).qpos, self._catheter_features()])),
            # Robot rates as fractions of the drive's maximum speeds, then the wire's (rad/s).
            "joint_vel": observable.Generic(lambda physics: np.concatenate(
                [robot.rate_features(physics), physics.bind(wire_joints).qvel])),
            "wire_slack": observable.Generic(lambda physics: np.array([self.slack_m(physics)])),
            "drive_force": observable.Generic(lambda physics: np.array([robot.drive_force_n(physics)])),
            "pixels": observable.Generic(lambda physics: self._top_view.image(physics, settings.style)),
            "guidewire_mask": observable.Generic(self._top_view.mask),
            "tip_position": observable.MJCFFeature("xpos", self._guidewire.tip_site),
            # The step's wall force: the total averaged over its physics steps (at reset,
            # the total of the start state).
            "contact_force": observable.Generic(lambda physics: np.array([self._mean_force_n], dtype=np.float64)),
        }
        for name, obs_item in obs.items():
            obs_item.enabled = name in settings.enabled or name in self._extra_observations
        if settings.noise_std > 0:
            obs["pixels"].corruptor = image_noise(settings.noise_std)
        return obs

    def _catheter_features(self) -> np.ndarray:
        """With a catheter: its tip's offset behind the wire's tip over the robot's stroke."""
        if self._catheter is None:
            return np.zeros(0)
        return np.array([self._catheter_offset_m / self._robot.stroke_m])

    # -- episode ---------------------------------------------------------------
    def initialize_episode(self, physics, random_state):
        # The wire takes its rest shape in its own initialize_episode hook.
        insertion = random_state.uniform(0.0, self._insertion_jitter_m)
        rotation = self._start_rotation_rad + random_state.uniform(
            -self._rotation_jitter_rad, self._rotation_jitter_rad)
        self._robot.set_pose(physics, insertion, rotation)
        self._robot.set_insertion_limit(physics, self._insertion_limit_m)
        if self._catheter_on_wire is not None:
            if self._catheter_model_key != id(physics.model.ptr):  # a new compiled model: read the wire's own joints
                self._catheter_on_wire.initialize(physics)
                self._catheter_model_key = id(physics.model.ptr)
            # The catheter starts parked: its tip at the sheath's, the wire's shaped tip out of it.
            self._catheter_out_m = 0.0
            self._catheter_command = 0.0
            self._apply_catheter(physics)
        self._step_count = 0
        self._success = False
        self._diverged = False
        self._escaped = False
        self._contacts = None
        self._wire_mask = np.zeros(physics.model.ngeom, dtype=bool)
        self._wire_mask[physics.bind(self._guidewire.geoms).element_id] = True
        self._vessel_mask = np.zeros(physics.model.ngeom, dtype=bool)
        self._vessel_mask[self._aorta.wall_geom_ids(physics)] = True
        self._wall_force = cs_physics.WallForceTotal(self._wire_mask, self._vessel_mask)
        # Rows of data.xpos / data.site_xpos for `wire_points_m`, read every control step:
        # indexing the arrays directly costs a fraction of a dm_control binding.
        self._wire_point_rows = (physics.bind(self._guidewire.segments).element_id,
                                 physics.bind(self._guidewire.geoms).element_id,
                                 physics.bind(self._guidewire.tip_site).element_id)
        self._stepped_state = None
        # composer runs the entities' hooks after this one; the start distances need the
        # wire in its rest shape (its hook is idempotent) and positions computed from it.
        self._guidewire.initialize_episode(physics, random_state)
        physics.forward()
        # No physics step yet: the reset's force is the start state's total (just forwarded).
        self._mean_force_n = cs_physics.wire_contacts(
            physics, self._wire_mask, recompute=False, is_vessel_geom=self._vessel_mask).total_n
        self._peak_force_n = self._mean_force_n
        self._contacts = None
        self._tip_location = None
        self._start_progress_m = self._locate_tip(physics)[1] - insertion
        self._reward_distance_m = self.reward_distance_m(physics)
        self._previous_reward_distance_m = self._reward_distance_m
        self._aim_potential = self._previous_aim_potential = self.aim_potential(physics)
        if isinstance(physics, cs_physics.ConstraintSensingPhysics):
            # NavigationEnvironment builds one; in another composer.Environment the
            # mean falls back to the end-of-step force.
            physics.after_constraint_solve = self._add_physics_step_force

    def _add_physics_step_force(self, physics):
        total = self._wall_force.total_n(physics.data.ptr)
        self._force_sum_n += total
        self._force_samples += 1
        if total > self._force_peak_n:
            self._force_peak_n = total

    def before_step(self, physics, action, random_state):
        self._robot.apply_action(physics, action[:2])
        if self._catheter is not None:
            self._catheter_command = float(np.clip(action[2], -1.0, 1.0))
        self._contacts = None
        self._stepped_state = None
        self._tip_location = None
        self._force_sum_n, self._force_samples, self._force_peak_n = 0.0, 0, 0.0

    def after_step(self, physics, random_state):
        if self._catheter is not None:
            self._move_catheter(physics)
        # Accelerations and constraint forces of the new state, once (the step info's
        # contact forces need them; see ConstraintSensingPhysics.complete_stepped_state).
        self._stepped_state_complete = (isinstance(physics, cs_physics.ConstraintSensingPhysics)
                                        and physics.complete_stepped_state())
        # dm_control's legacy step (composer's default) ends with mj_step1: the position
        # and velocity stages of this state are current, so `contact_forces` needs only
        # the rest of mj_forward, as long as the state is still this one.
        if getattr(physics, "legacy_step", False):
            self._stepped_state = (physics.data.qpos.copy(), physics.data.qvel.copy())
        self._step_count += 1
        self._diverged = cs_physics.is_diverged(physics)
        self._escaped = not self._diverged and not self._containment.contains(self.wire_points_m(physics)).all()
        if self._force_samples:
            self._mean_force_n, self._peak_force_n = self._force_sum_n / self._force_samples, self._force_peak_n
        else:
            self._mean_force_n = self._peak_force_n = self.contact_forces(physics).total_n
        if not (self._diverged or self._escaped):
            self._success = self.target_distance_m(physics) <= self._delta_m
            self._previous_reward_distance_m = self._reward_distance_m
            self._reward_distance_m = self.reward_distance_m(physics)
            self._previous_aim_potential = self._aim_potential
            self._aim_potential = self.aim_potential(physics)

    def action_spec(self, physics):
        return dm_env.specs.BoundedArray(
            shape=(self.action_size,), dtype=np.float32, minimum=-1.0, maximum=1.0, name=",".join(self.action_names))

    @property
    def action_names(self) -> tuple:
        """What each action entry drives: the wire's insertion and rotation, then the catheter's carriage."""
        return ("insertion", "rotation") + (() if self._catheter is None else ("catheter",))

    @property
    def action_size(self) -> int:
        return len(self.action_names)

    # -- catheter ----------------------------------------------------------------
    @property
    def catheter(self) -> Catheter | None:
        """The catheter over the wire, or None (then actions are [insertion, rotation])."""
        return self._catheter

    @property
    def catheter_offset_m(self) -> float:
        """How far the catheter's tip lies behind the wire's tip, along the wire, in metres (0: flush)."""
        return self._catheter_offset_m

    def _wire_out_of_sheath_m(self, physics) -> float:
        """How far the wire's tip lies past the sheath's tip (the robot's outlet), along the
        wire: its start length plus the carriage's travel."""
        return self._robot.initial_insertion_m + self._robot.insertion_m(physics)

    def _move_catheter(self, physics) -> None:
        """The catheter carriage's move of this control step: the catheter keeps its place while
        the wire moves, and moves by its own command (action +1: `max_speed_m_s` forwards). It
        cannot pass the wire's tip nor go back into the sheath."""
        moved_m = self._catheter_command * self._catheter.max_speed_m_s * self.control_timestep
        wire_out_m = self._wire_out_of_sheath_m(physics)
        self._catheter_out_m = float(np.clip(self._catheter_out_m + moved_m, 0.0, wire_out_m))
        self._apply_catheter(physics)

    def _apply_catheter(self, physics) -> None:
        wire_out_m = self._wire_out_of_sheath_m(physics)
        self._catheter_offset_m = max(0.0, wire_out_m - self._catheter_out_m)
        self._catheter_on_wire.apply(physics, self._catheter_offset_m, sheath_from_m=wire_out_m)

    def get_reward(self, physics):
        if self._diverged or self._escaped:  # cut short: the step says nothing about the task
            return 0.0
        reward = self.reward_for(self._previous_reward_distance_m, self._reward_distance_m, self._success)
        if not self._success:
            reward += self._aim_potential - self._previous_aim_potential
        return reward

    def reward_for(self, previous_distance_m: float, distance_m: float, success: bool) -> float:
        """The reward of a step that took the tip from `previous_distance_m` to `distance_m`
        (as `reward_distance_m` measures them) and did or did not reach the target."""
        if success:
            return self._success_reward
        reward = -distance_m if self._dense else 0.0
        if self._progress_weight:
            step_m = self._robot.max_insertion_speed_m_s * self.control_timestep
            reward += self._progress_weight * (previous_distance_m - distance_m) / step_m
        return reward

    def should_terminate_episode(self, physics):
        return self._success or self._diverged or self._escaped or self._step_count >= self._max_steps

    def get_discount(self, physics):
        # Success is a true terminal state; the time limit and divergence truncate.
        return 0.0 if self._success else 1.0

    # -- measurements ----------------------------------------------------------
    def tip_position_m(self, physics) -> np.ndarray:
        return physics.bind(self._guidewire.tip_site).xpos.copy()

    def wire_points_m(self, physics) -> np.ndarray:
        """(N, 3) points along the wire: segment ends, segment centres and the tip."""
        rows = self._wire_point_rows
        if rows is None or physics.is_dirty:  # no episode yet, or a write not yet forwarded: bind forwards it
            return np.vstack([physics.bind(self._guidewire.segments).xpos, physics.bind(self._guidewire.geoms).xpos,
                              physics.bind(self._guidewire.tip_site).xpos])
        bodies, geoms, tip = rows
        data = physics.data
        return np.vstack([data.xpos[bodies], data.geom_xpos[geoms], data.site_xpos[tip]])

    @property
    def containment(self) -> Containment:
        """Where the wire may be: the lumen (with the wire's radius plus `WALL_COMPLIANCE_M`
        of tolerance) and the robot's guide channel and sheath, up to the sheath's tip."""
        return self._containment

    def target_distance_m(self, physics) -> float:
        return float(np.linalg.norm(self.tip_position_m(physics) - self.target_position_m))

    def _locate_tip(self, physics) -> tuple[str, float, float]:
        """The tip on the centerline tree (line, arc length, depth), located once per step:
        the reward, the path distance and the slack all read it."""
        if self._tip_location is None:
            self._tip_location = self._paths.locate(self.tip_position_m(physics), prefer=self._target_name)
        return self._tip_location

    def path_distance_m(self, physics) -> float:
        """Tip to target along the vessel (`CenterlineTree.geodesic_distance_m`), metres."""
        return self._paths.geodesic_from_location(self._locate_tip(physics), self._target_name)

    def reward_distance_m(self, physics) -> float:
        """The distance the dense reward penalises for the current tip (`distance_for_reward_m`)."""
        location = self._locate_tip(physics) if self._reward_kind == "geodesic" else None
        return self.distance_for_reward_m(self.tip_position_m(physics), location)

    def distance_for_reward_m(self, tip_position_m, location: tuple | None = None) -> float:
        """The distance the dense reward penalises for a tip at `tip_position_m`, in metres
        (`location`: the tip already located on the centerline tree, if it has been).

        "euclidean": the straight line from tip to target (the paper's). "geodesic": the
        larger of the distance along the vessel and the straight line. Along the vessel, a
        tip deep in a wrong branch is 2-3x farther than one at the right ostium (the
        straight line ranks it closer); the straight line still counts near the target,
        where a tip riding the branch wall is level with the target but off its axis.
        """
        tip = np.asarray(tip_position_m, dtype=float)
        euclidean = float(np.linalg.norm(tip - self.target_position_m))
        if self._reward_kind == "euclidean":
            return euclidean
        location = location or self._paths.locate(tip, prefer=self._target_name)
        return max(self._paths.geodesic_from_location(location, self._target_name), euclidean)

    def aim_error(self, physics) -> tuple[float, float]:
        """(angle from the tip's bend to the aim in radians, off-axis share of the aim):
        `CenterlinePath.aim_error` on the target's centerline, looking
        `AIM_LOOKAHEAD_RADII` lumen radii past the tip."""
        line = self._paths.lines[self._target_name]
        tip = self.tip_position_m(physics)
        base = physics.bind(self._guidewire.tip_base_site)
        # The step's tree location already holds the arc length when the tip is on the
        # target's line; only a tip in another branch needs locating on that line.
        name, s_m, _ = self._locate_tip(physics)
        if name != self._target_name:
            s_m = line.locate(tip)[0]
        return line.aim_error(tip, base.xpos, base.xmat.reshape(3, 3)[:, 2], s_m,
                              AIM_LOOKAHEAD_RADII * line.radius_at(s_m))

    @property
    def aim_potential_weight(self) -> float:
        """`aim_weight`: the aim shaping's weight (0: none)."""
        return self._aim_weight

    def aim_potential(self, physics) -> float:
        """The aim shaping's potential (0 with `aim_weight` 0): see the class docstring."""
        if not self._aim_weight:
            return 0.0
        angle, off_axis = self.aim_error(physics)
        return -self._aim_weight * abs(angle) / np.pi * min(1.0, off_axis / AIM_FULL_OFF_AXIS)

    def slack_m(self, physics) -> float:
        """Carriage advance minus tip advance along the vessel since the start, metres.

        Near zero (a few mm: the wire takes the outer curve) while the wire follows the
        drive; it grows when the tip stalls and the shaft buckles behind it. A follower
        robot sees the same condition as a rising drive force (`drive_force_n`).
        """
        progress = self._locate_tip(physics)[1] - self._start_progress_m
        return self._robot.insertion_m(physics) - progress

    def contact_forces(self, physics) -> cs_physics.ContactForces:
        """Wire-vessel contact forces for the current state (computed once per step).

        Contacts with the robot's guide channel are not forces on tissue and are left out.
        In the state a control step left (positions and velocities as `after_step` saw
        them) only the acceleration and constraint stages are computed
        (`physics.forward_from_velocity_stage`: the same forces for 0.35-0.45 of an
        ``mj_forward``'s time); in any other state, a full ``mj_forward``.
        """
        if self._contacts is None:
            stepped = self._stepped_state
            in_stepped_state = (stepped is not None and np.array_equal(stepped[0], physics.data.qpos)
                                and np.array_equal(stepped[1], physics.data.qvel))
            if in_stepped_state and not self._stepped_state_complete:
                cs_physics.forward_from_velocity_stage(physics)
            self._contacts = cs_physics.wire_contacts(physics, self._wire_mask, recompute=not in_stepped_state,
                                                      is_vessel_geom=self._vessel_mask)
        return self._contacts

    @property
    def diverged(self) -> bool:
        return self._diverged

    @property
    def escaped(self) -> bool:
        """A wire point was outside `containment` at the end of the last step."""
        return self._escaped

    @property
    def success(self) -> bool:
        return self._success

    @property
    def step_count(self) -> int:
        return self._step_count

    def step_info(self, physics) -> StepInfo:
        contacts = self.contact_forces(physics)
        return StepInfo(
            tip_position_m=self.tip_position_m(physics),
            target_distance_m=self.target_distance_m(physics),
            contact_force_n=contacts.total_n,
            max_contact_force_n=contacts.max_n,
            mean_contact_force_n=self._mean_force_n,
            peak_contact_force_n=self._peak_force_n,
            success=self._success,
            diverged=self._diverged,
            path_distance_m=self.path_distance_m(physics),
            insertion_m=self._robot.insertion_m(physics),
            slack_m=self.slack_m(physics),
            drive_force_n=self._robot.drive_force_n(physics),
            escaped=self._escaped,
        )


class NavigationEnvironment(composer.Environment):
    """composer.Environment that turns a physics divergence into a truncation.

    composer ends a diverged episode with discount 0 (as if terminal); a diverged
    simulation says nothing about the task, so the episode is cut with discount 1.

    Building is fast: an aorta built with ``hulls_in_mjcf=False`` gets its wall added
    to a `mujoco.MjSpec` of the compiled scene (see `Aorta.add_geoms`), the compiled
    model is cached as MJB (keyed by the scene, the wall and the MuJoCo version), and
    the model compiled here is kept for the first reset (composer compiles a second
    time otherwise; no entity changes its MJCF per episode).

    The physics is a `ConstraintSensingPhysics`, so that the task can average the wall
    force over each control step's physics steps (`StepInfo.mean_contact_force_n`).
    """

    def __init__(self, task: Navigate, cache_models: bool = True, **kwargs):
        kwargs.setdefault("raise_exception_on_physics_error", False)
        kwargs.setdefault("strip_singleton_obs_buffer_dim", True)
        kwargs.setdefault("recompile_mjcf_every_episode", False)
        self._cache_models = bool(cache_models)
        super().__init__(task, **kwargs)
        if not self._recompile_mjcf_every_episode:
            self._mjcf_never_compiled = False

    def _recompile_physics(self):
        aorta = self._task.aorta
        physics = getattr(self, "_physics", None)
        if physics:
            physics.free()
        root = self._task.root_entity.mjcf_model
        if aorta.hulls_in_mjcf:
            self._physics = cs_physics.ConstraintSensingPhysics.from_mjcf_model(root)
            self._physics.legacy_step = self._legacy_step
            return
        model = model_cache.compile_model(root, aorta.add_geoms, aorta.geoms_key, cache=self._cache_models)
        self._physics = cs_physics.ConstraintSensingPhysics.from_model(wrapper.MjModel(model))
        self._physics.legacy_step = self._legacy_step

    def step(self, action):
        """Steps with `action` = [insertion, rotation] (then the catheter's carriage, with a
        catheter), each in [-1, 1]; values outside are clipped.

        An action of another shape or with a NaN or infinite value raises ValueError before
        any physics runs, and the environment stays usable. A diverged simulation or an
        escaped wire ends the episode as a truncation (reward 0, discount 1).
        """
        timestep = super().step(validated_action(action, self.task.action_names))
        if (self.task.diverged or self.task.escaped) and timestep.last():
            timestep = timestep._replace(reward=0.0, discount=1.0)
        return timestep


def validated_action(action, names=("insertion", "rotation")) -> np.ndarray:
    """`action` as a float64 array of shape (len(names),); ValueError naming the bad value otherwise."""
    expected = expected_action(names)
    try:
        raw = np.asarray(action)
        if raw.dtype.kind not in "iufO":
            raise TypeError
        array = raw.astype(np.float64)
    except (TypeError, ValueError):  # strings, ragged lists, objects that are not numbers
        raise ValueError(f"action={_one_line(action)} is not numeric; expected {expected}") from None
    if array.shape != (len(names),):
        raise ValueError(f"action={_one_line(action)} has shape {array.shape}; expected {expected}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"action={_one_line(action)} is not finite; expected {expected}")
    return array


def _one_line(value) -> str:
    if isinstance(value, np.ndarray):
        text = np.array2string(value, separator=", ", threshold=6, max_line_width=10**6)
    else:
        text = repr(value)
    text = " ".join(text.split())
    return text if len(text) <= 80 else text[:77] + "..."


def _check_introducer(aorta: Aorta, guidewire: Guidewire, robot: FollowerRobot) -> None:
    """ValueError unless the robot's sheath can seal this aorta's access and the wire's tip can start outside it."""
    if robot.seal_half_width_m is None:
        raise ValueError("robot has no seal plate (seal_half_width_m=None): the access would stay open beside "
                         "the sheath and a buckled wire could leave the vessel there")
    # The wall's pieces lie contact_margin_m behind the lumen surface (see `Aorta`).
    needed_m = aorta.access_radius_m + aorta.contact_margin_m + aorta.wall_thickness_m
    if robot.seal_half_width_m < needed_m:
        raise ValueError(f"robot seal_half_width_m={robot.seal_half_width_m} m does not cover the open end of "
                         f"aorta {aorta.name!r} (radius plus wall: {needed_m:.4g} m)")
    shaped = bool(np.any(guidewire.rest_qpos))
    if shaped and robot.initial_insertion_m <= guidewire.tip_length_m:
        raise ValueError(f"robot initial_insertion_m={robot.initial_insertion_m} m must exceed the wire's "
                         f"tip_length_m={guidewire.tip_length_m} m: the shaped tip must start outside the sheath")


def _quat_z_to(direction) -> np.ndarray:
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
