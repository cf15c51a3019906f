"""Navigate: steer the guidewire tip from the descending aorta into a target branch."""

from __future__ import annotations

from dataclasses import dataclass

import dm_env.specs
import mujoco
import numpy as np
from dm_control import composer

from cathsim_dmc.anatomy.containment import Containment
from cathsim_dmc.anatomy.paths import CenterlineTree
from cathsim_dmc.core import task_defaults
from cathsim_dmc.core.checks import check_number
from cathsim_dmc.entities import Aorta, FollowerRobot, Guidewire
from cathsim_dmc.entities.catheter import Catheter, CatheterDrive, catheter_named
from cathsim_dmc.sim import physics as cs_physics
from cathsim_dmc.sim.arena import top_camera_frame
from cathsim_dmc.sim.render import ObservationSettings
from cathsim_dmc.tasks.measurements import StepInfo, WireMeasurements
from cathsim_dmc.tasks.observations import check_extra_observations, task_observables
from cathsim_dmc.tasks.presets import OBSERVATION_PRESETS
from cathsim_dmc.tasks.rewards import NavigationReward
from cathsim_dmc.tasks.roadmap import TargetClocks
from cathsim_dmc.tasks.scene import NavigationScene, build_scene

CONTROL_TIMESTEP_S = 0.1  # one step moves the wire up to 4 mm at 40 mm/s
# The task's defaults (success radius, rewards, time limit, start pose, physics) are
# cathsim_dmc.core.task_defaults', which the command-line tools' schemas read too.
# The largest success radius `check_options` accepts. Every shipped target lies 17.5-18.5 cm
# (straight line) from the wire tip's start, and the supra-aortic branches leave the arch a
# few centimetres apart: a sphere wider than 5 cm around a target reaches into the arch
# and the neighbouring branch, and 18 cm counts the start itself as a success.
MAX_SUCCESS_RADIUS_M = 0.05
# The largest start insertion jitter: the shipped routes run 20-24 cm along the centerline to
# targets 17.5-18.5 cm above the start, so a start up to 5 cm deeper is still far below the arch.
MAX_START_INSERTION_JITTER_M = 0.05


def check_options(
    delta_m=None,
    max_steps=None,
    success_reward=None,
    progress_weight=None,
    physics=None,
    catheter=None,
    start_rotation_rad=None,
    start_rotation_jitter_rad=None,
    start_insertion_jitter_m=None,
    safe_force_n=None,
    **others,
) -> None:
    """ValueError naming the parameter for a task setting the task cannot use.

    `Navigate` checks its own arguments with it; `build_task` and the command-line tools
    call it before building anything. A zero success radius would make MuJoCo fail on a
    zero-size marker, and `max_steps=0` would end every episode after one step. Other
    names are left to `Navigate`.
    """
    if delta_m is not None and check_number("delta_m", delta_m, 0.0, inclusive=False) > MAX_SUCCESS_RADIUS_M:
        raise ValueError(
            f"delta_m={delta_m!r} m is larger than any meaningful success radius; choose one in "
            f"(0, {MAX_SUCCESS_RADIUS_M}] m (the paper's: {task_defaults.SUCCESS_RADIUS_M})"
        )
    if max_steps is not None:
        check_number("max_steps", max_steps, 1, whole=True)
    if success_reward is not None:
        check_number("success_reward", success_reward)
    if progress_weight is not None:
        check_number("progress_weight", progress_weight, 0.0)
    if physics is not None:  # a name in cs_physics.PHYSICS_SETTINGS ("accurate", "fast")
        cs_physics.physics_settings(physics)
    if catheter is not None:  # a name in CATHETERS ("angled_5f") or a Catheter
        catheter_named(catheter)
    if start_rotation_rad is not None:
        check_number("start_rotation_rad", start_rotation_rad)
    if (
        start_rotation_jitter_rad is not None
        and check_number("start_rotation_jitter_rad", start_rotation_jitter_rad, 0.0) > np.pi
    ):
        raise ValueError(
            f"start_rotation_jitter_rad={start_rotation_jitter_rad!r} rad is more than a half turn; "
            f"choose one in [0, pi]"
        )
    if (
        start_insertion_jitter_m is not None
        and check_number("start_insertion_jitter_m", start_insertion_jitter_m, 0.0) > MAX_START_INSERTION_JITTER_M
    ):
        raise ValueError(
            f"start_insertion_jitter_m={start_insertion_jitter_m!r} m is deeper than a start below the "
            f"arch allows; choose one in [0, {MAX_START_INSERTION_JITTER_M}] m"
        )
    if safe_force_n is not None:
        check_number("safe_force_n", safe_force_n, 0.0, inclusive=False)


@dataclass(frozen=True)
class StartPose:
    """The robot's pose at the start of an episode: insertion drawn from [0,
    `insertion_jitter_m`] metres, rotation `rotation_rad` +- `rotation_jitter_rad`."""

    insertion_jitter_m: float = task_defaults.START_INSERTION_JITTER_M
    rotation_rad: float = task_defaults.START_ROTATION_RAD
    rotation_jitter_rad: float = task_defaults.START_ROTATION_JITTER_RAD

    def draw(self, random_state) -> tuple[float, float]:
        """(insertion in metres, rotation in radians) for one episode."""
        insertion = random_state.uniform(0.0, self.insertion_jitter_m)
        rotation = self.rotation_rad + random_state.uniform(-self.rotation_jitter_rad, self.rotation_jitter_rad)
        return insertion, rotation


class Navigate(composer.Task):
    """Reach `target` (a site of the aorta) with the guidewire tip.

    Reward: `success_reward` when the tip is within `delta_m` of the target (which ends
    the episode), otherwise minus the distance in metres (dense) or 0 (sparse). After
    `max_steps` control steps the episode is truncated (discount 1). A diverged
    simulation also truncates, with `diverged` set in `step_info`.

    Training options (success, the time limit and the metrics do not depend on them; the
    terms are in `cathsim_dmc.tasks.rewards`): `reward="geodesic"` measures the distance
    along the vessel instead of the straight line; `progress_weight` adds that weight
    times the step's progress towards the target in units of one full-speed insertion
    step (potential-style shaping). The defaults are `cathsim_dmc.core.task_defaults`'.

    Physics: `physics="fast"` (the default: PGS capped at 10 iterations, dense Jacobian,
    noslip off, sleep on; about twice the speed of `accurate` in wall contact) or `"accurate"`
    (Newton), the solver settings of `cathsim_dmc.sim.physics.PHYSICS_SETTINGS`.

    Access (`cathsim_dmc.tasks.scene`): the robot's introducer sheath seals the aorta's
    open lower end and its tip lies `robot.sheath_depth_m` (3 mm) inside the lumen. The
    wire's shaped tip starts just past the sheath: with the default robot and wire its end
    lies 7-9 mm (with the start's 0-2 mm insertion jitter, `start_insertion_jitter_m`)
    past the `entry` site, which is 10 mm above the open end in every shipped aorta: the
    15 mm angled tip spans 12.3 mm along the axis, so it cannot start at the entry without
    starting in the straight sheath. The robot starts rotated `start_rotation_rad` +-
    `start_rotation_jitter_rad`. The wire may be in the lumen or in the guide channel and
    sheath (`containment`); anywhere else it has escaped, which truncates the episode like
    a divergence (`escaped`).

    Safe success (the evaluation's `safe_success_pct`, not the reward): the target reached
    without any control step's wall force (`mean_wall_force_n`, the step's mean) above
    `safe_force_n` newtons.

    C-arm view: with the observation settings' `view_deg_range` (and `cranial_deg_range`),
    every episode draws its own view of the top camera (images, image-plane tracking,
    videos): LAO and cranial angles uniform in those ranges, from the episode's random state,
    after the start pose. Without them the view is the fixed `lao_deg` (AP by default) and
    no draw is made. `carm_view_deg` is the episode's (LAO, cranial) angles.

    Catheter: `catheter="angled_5f"` (or a `Catheter`) puts a shaped catheter over the wire
    (`CatheterDrive`, docs/model.md#catheter). Actions then have a third entry, the
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
        delta_m: float = task_defaults.SUCCESS_RADIUS_M,
        success_reward: float = task_defaults.SUCCESS_REWARD,
        dense: bool = task_defaults.DENSE_REWARD,
        max_steps: int = task_defaults.MAX_STEPS,
        observations: ObservationSettings = OBSERVATION_PRESETS["internal"],
        control_timestep_s: float = CONTROL_TIMESTEP_S,
        start_insertion_jitter_m: float = StartPose.insertion_jitter_m,
        start_rotation_rad: float = StartPose.rotation_rad,
        start_rotation_jitter_rad: float = StartPose.rotation_jitter_rad,
        blood_drag: bool = False,
        reward: str = "euclidean",
        progress_weight: float = 0.0,
        extra_observations: tuple = (),
        physics: str = task_defaults.PHYSICS,
        catheter: Catheter | str | None = None,
        safe_force_n: float = task_defaults.SAFE_FORCE_N,
    ):
        if target not in aorta.targets:
            raise ValueError(
                f"target={target!r} is not a site of aorta {aorta.name!r}; choose one of {sorted(aorta.targets)}"
            )
        check_options(
            delta_m=delta_m,
            max_steps=max_steps,
            success_reward=success_reward,
            progress_weight=progress_weight,
            physics=physics,
            catheter=catheter,
            start_rotation_rad=start_rotation_rad,
            start_rotation_jitter_rad=start_rotation_jitter_rad,
            start_insertion_jitter_m=start_insertion_jitter_m,
            safe_force_n=safe_force_n,
        )
        self._aorta, self._guidewire, self._robot = aorta, guidewire, robot
        self._target_name = target
        self._physics_setting = physics
        self._catheter_drive = None if catheter is None else CatheterDrive(catheter_named(catheter), guidewire, robot)
        self._delta_m = float(delta_m)
        self._safe_force_n = float(safe_force_n)
        self._max_steps = int(max_steps)
        self._start = StartPose(
            float(start_insertion_jitter_m), float(start_rotation_rad), float(start_rotation_jitter_rad)
        )
        self._settings = observations
        self._reward = NavigationReward(
            kind=reward, dense=bool(dense), success_reward=float(success_reward), progress_weight=float(progress_weight)
        )
        self._extra_observations = check_extra_observations(extra_observations)
        self._paths = CenterlineTree.from_asset(aorta.asset)
        self._measurements = WireMeasurements(aorta, guidewire, robot, self._paths, target)

        self._scene = build_scene(
            aorta,
            guidewire,
            robot,
            aorta.targets[target],
            self._delta_m,
            lao_deg=observations.lao_deg,
            blood_drag=blood_drag,
            physics=physics,
        )
        self._containment = self._scene.containment
        depth_m = float(self._containment.field.signed_distance_m(self.target_position_m)[0])
        if not depth_m > 0:  # no episode could succeed: it would evaluate at 0% without a word
            raise ValueError(
                f"target {target!r} of aorta {aorta.name!r} lies outside its lumen "
                f"({-depth_m * 1e3:.1f} mm or more); `cathsim-aorta validate {aorta.asset.path}` "
                f"lists the asset's problems"
            )
        self.set_timesteps(control_timestep=control_timestep_s, physics_timestep=guidewire.physics_timestep_s)
        self._task_observables, self._top_view, self._roadmap, self._image_tracker = task_observables(
            self, observations, self._extra_observations
        )
        self._carm_view_deg = (float(observations.lao_deg), 0.0)

        self._step_count = 0
        # The depth clock and the catheter's call, from the 3-D tracker and from the image tracker.
        self._clocks = TargetClocks(with_catheter=catheter is not None)
        self._clocks_2d = TargetClocks(with_catheter=catheter is not None)
        self._success = False
        self._diverged = False
        self._escaped = False
        self._step_force = cs_physics.ControlStepForce()
        self._reward_distance_m = self._previous_reward_distance_m = 0.0

    # -- structure -------------------------------------------------------------
    @property
    def root_entity(self):
        return self._scene.arena

    @property
    def scene(self) -> NavigationScene:
        """The assembled scene (`cathsim_dmc.tasks.scene`)."""
        return self._scene

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
    def success_radius_m(self) -> float:
        """The tip within this distance of the target succeeds (`delta_m`), metres."""
        return self._delta_m

    @property
    def safe_force_n(self) -> float:
        """A success is safe when no control step's wall force exceeded this, newtons."""
        return self._safe_force_n

    @property
    def registration_offset_m(self) -> np.ndarray:
        """The episode's registration error of the roadmap (`roadmap`, `roadmap_2d`, the
        overlay): a world vector, metres."""
        return self._roadmap.registration_offset_m

    @property
    def carm_view_deg(self) -> tuple:
        """The episode's C-arm view: (LAO, cranial) angles in degrees (negative: RAO, caudal)."""
        return self._carm_view_deg

    @property
    def start_pose(self) -> StartPose:
        return self._start

    @property
    def reward_settings(self) -> NavigationReward:
        """The reward's distance, density, success reward and shaping weights."""
        return self._reward

    @property
    def paths(self) -> CenterlineTree:
        """The aorta's centerline tree (distances along the vessel)."""
        return self._paths

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

    # -- episode ---------------------------------------------------------------
    def initialize_episode(self, physics, random_state):
        # The wire takes its rest shape in its own initialize_episode hook.
        insertion, rotation = self._start.draw(random_state)
        self._robot.set_pose(physics, insertion, rotation)
        self._draw_view(physics, random_state)
        if self._catheter_drive is not None:
            self._catheter_drive.initialize_episode(physics)
        self._step_count = 0
        self._success = False
        self._diverged = False
        self._escaped = False
        self._measurements.start_episode(physics)
        # composer runs the entities' hooks after this one; the start distances need the
        # wire in its rest shape (its hook is idempotent) and positions computed from it.
        self._guidewire.initialize_episode(physics, random_state)
        physics.forward()
        # No physics step yet: the reset's force is the start state's total (just forwarded).
        # NavigationEnvironment's physics then reports every physics step's total; in
        # another composer.Environment the step's force falls back to its end state's.
        measurements = self._measurements
        self._step_force.start(
            physics, measurements.wire_mask, measurements.vessel_mask, measurements.start_force_n(physics)
        )
        measurements.forget()
        measurements.set_start(physics, insertion)
        self._reward_distance_m = self._previous_reward_distance_m = self.reward_distance_m(physics)
        self._roadmap.remembers_wrong_branches = self._task_observables["wrong_branch_heading"].enabled
        self._roadmap.start(random_state)
        self._clocks.start()
        self._clocks_2d.start()
        if self._observes_roadmap():
            # The tip is first located on the whole roadmap (this fix starts the depth clock),
            # then tracked from there: the `roadmap` features of the reset are the second fix,
            # each with its own noise (as the tracker's readings at a reset always were).
            self._track_roadmap(physics)
            if self._task_observables["roadmap"].enabled:
                self._roadmap.measure(physics)
        if self._observes_image_plane():
            self._image_tracker.remembers_wrong_branches = self._task_observables["wrong_branch_heading_2d"].enabled
            self._image_tracker.start(random_state, self._roadmap.registration_offset_m)
            self._track_image(physics)

    def _draw_view(self, physics, random_state) -> None:
        """The episode's C-arm view, drawn when the settings give a range (the camera is
        left as built otherwise: nothing is drawn, nothing changes)."""
        settings = self._settings
        if settings.view_deg_range is None and settings.cranial_deg_range is None:
            return
        lao = random_state.uniform(*settings.view_deg_range) if settings.view_deg_range else settings.lao_deg
        cranial = random_state.uniform(*settings.cranial_deg_range) if settings.cranial_deg_range else 0.0
        self._carm_view_deg = (float(lao), float(cranial))
        camera = physics.bind(self._scene.arena.top_camera)
        camera.pos, camera.quat, camera.fovy = top_camera_frame(self._aorta.bounds_m, lao, cranial)
        # Its world frame too: with sleeping enabled (the fast physics), MuJoCo computes the
        # frames of what hangs from the world body only when data is reset, which happened
        # before this hook; the next reset recomputes the same frame from the model.
        body = int(physics.model.cam_bodyid[camera.element_id])
        rotation = np.zeros(9)
        mujoco.mju_quat2Mat(rotation, np.asarray(camera.quat, dtype=float))
        parent = physics.data.xmat[body].reshape(3, 3)
        camera.xpos = physics.data.xpos[body] + parent @ camera.pos
        camera.xmat = (parent @ rotation.reshape(3, 3)).ravel()

    def _observes_image_plane(self) -> bool:
        observables = self._task_observables
        watched = (
            "tracking_2d",
            "roadmap_2d",
            "tracking_2d_history",
            "target_depth_time_2d",
            "wrong_branch_heading_2d",
            "catheter_called_2d",
        )
        return any(observables[name].enabled for name in watched)

    def _track_image(self, physics) -> None:
        """One image-tracker measurement of the step's end state, and its clocks."""
        tracker = self._image_tracker
        tracker.measure(physics)
        self._clocks_2d.update(tracker.remaining_m, tracker.target_distance_m, self._progress_step_m())

    def before_step(self, physics, action, random_state):
        self._robot.apply_action(physics, action[:2])
        if self._catheter_drive is not None:
            self._catheter_drive.set_command(action[2])
        self._measurements.forget()
        self._step_force.begin_step()

    def after_step(self, physics, random_state):
        if self._catheter_drive is not None:
            self._catheter_drive.move(physics, self.control_timestep)
        self._measurements.end_step(physics)
        self._step_count += 1
        self._diverged = cs_physics.is_diverged(physics)
        self._escaped = not self._diverged and not self._containment.contains(self.wire_points_m(physics)).all()
        self._step_force.end_step(lambda: self.contact_forces(physics).total_n)
        if not (self._diverged or self._escaped):
            self._success = self.target_distance_m(physics) <= self._delta_m
            self._previous_reward_distance_m = self._reward_distance_m
            self._reward_distance_m = self.reward_distance_m(physics)
        if self._observes_roadmap():
            self._track_roadmap(physics)
        if self._observes_image_plane():
            self._track_image(physics)

    def _observes_roadmap(self) -> bool:
        observables = self._task_observables
        watched = ("roadmap", "target_depth_time", "wrong_branch_heading", "catheter_called")
        return any(observables[name].enabled for name in watched)

    def _track_roadmap(self, physics) -> None:
        """One roadmap measurement of the step's end state; counts a step at the target's
        depth (the tracked tip within one full-speed insertion step of it along the roadmap)
        and a step stalled near the target, and calls the catheter by the expert's rule."""
        self._roadmap.measure(physics)
        self._clocks.update(self._roadmap.remaining_m, self._roadmap.target_distance_m, self._progress_step_m())

    def action_spec(self, physics):
        return dm_env.specs.BoundedArray(
            shape=(self.action_size,), dtype=np.float32, minimum=-1.0, maximum=1.0, name=",".join(self.action_names)
        )

    @property
    def action_names(self) -> tuple:
        """What each action entry drives: the wire's insertion and rotation, then the catheter's carriage."""
        return ("insertion", "rotation") + (() if self._catheter_drive is None else ("catheter",))

    @property
    def action_size(self) -> int:
        return len(self.action_names)

    @property
    def catheter(self) -> Catheter | None:
        """The catheter over the wire, or None (then actions are [insertion, rotation])."""
        return None if self._catheter_drive is None else self._catheter_drive.catheter

    @property
    def catheter_offset_m(self) -> float:
        """How far the catheter's tip lies behind the wire's tip, along the wire, in metres (0: flush)."""
        return 0.0 if self._catheter_drive is None else self._catheter_drive.offset_m

    @property
    def mean_wall_force_n(self) -> float:
        """The last control step's wall force, averaged over its physics steps (after a
        reset: the start state's), newtons (`cathsim_dmc.sim.physics.ControlStepForce`)."""
        return self._step_force.mean_n

    def get_reward(self, physics):
        if self._diverged or self._escaped:  # cut short: the step says nothing about the task
            return 0.0
        return self.reward_for(self._previous_reward_distance_m, self._reward_distance_m, self._success)

    def reward_for(self, previous_distance_m: float, distance_m: float, success: bool) -> float:
        """The reward of a step that took the tip from `previous_distance_m` to `distance_m`
        (as `reward_distance_m` measures them) and did or did not reach the target
        (`NavigationReward.step_reward`)."""
        return self._reward.step_reward(previous_distance_m, distance_m, success, self._progress_step_m())

    def _progress_step_m(self) -> float:
        """One full-speed insertion step in metres: the progress shaping's unit."""
        return self._robot.max_insertion_speed_m_s * self.control_timestep

    def should_terminate_episode(self, physics):
        return self._success or self._diverged or self._escaped or self._step_count >= self._max_steps

    def get_discount(self, physics):
        # Success is a true terminal state; the time limit and divergence truncate.
        return 0.0 if self._success else 1.0

    # -- measurements (`WireMeasurements`) -------------------------------------
    @property
    def measurements(self) -> WireMeasurements:
        return self._measurements

    def tip_position_m(self, physics) -> np.ndarray:
        return self._measurements.tip_position_m(physics)

    def wire_points_m(self, physics) -> np.ndarray:
        """(N, 3) points along the wire: segment ends, segment centres and the tip."""
        return self._measurements.wire_points_m(physics)

    def target_distance_m(self, physics) -> float:
        return float(np.linalg.norm(self.tip_position_m(physics) - self.target_position_m))

    def path_distance_m(self, physics) -> float:
        """Tip to target along the vessel (`CenterlineTree.geodesic_distance_m`), metres."""
        return self._measurements.path_distance_m(physics)

    def slack_m(self, physics) -> float:
        """Carriage advance minus tip advance along the vessel since the start, metres."""
        return self._measurements.slack_m(physics)

    def contact_forces(self, physics) -> cs_physics.ContactForces:
        """Wire-vessel contact forces for the current state (computed once per step)."""
        return self._measurements.contact_forces(physics)

    @property
    def containment(self) -> Containment:
        """Where the wire may be: the lumen (with the wire's radius plus `scene.WALL_COMPLIANCE_M`
        of tolerance) and the robot's guide channel and sheath, up to the sheath's tip."""
        return self._containment

    def reward_distance_m(self, physics) -> float:
        """The distance the dense reward penalises for the current tip (`distance_for_reward_m`)."""
        return self._reward.distance_m(
            self.tip_position_m(physics), self.target_position_m, lambda: self.path_distance_m(physics)
        )

    def distance_for_reward_m(self, tip_position_m, location: tuple | None = None) -> float:
        """The distance the dense reward penalises for a tip at `tip_position_m`, in metres
        (`location`: the tip already located on the centerline tree, if it has been):
        `rewards.euclidean` or `rewards.geodesic`, as `reward=` chose."""
        tip = np.asarray(tip_position_m, dtype=float)

        def along_vessel_m() -> float:
            return self._paths.geodesic_from_location(
                location or self._paths.locate(tip, prefer=self._target_name), self._target_name
            )

        return self._reward.distance_m(tip, self.target_position_m, along_vessel_m)

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

    @property
    def steps_at_target_depth(self) -> int:
        """How many control steps in a row the tracked tip has been at the target's depth
        (`target_depth_time`'s count; counted while `roadmap` or `target_depth_time` is observed)."""
        return self._clocks.steps_at_depth

    @property
    def catheter_rate(self) -> float:
        """The catheter carriage's speed over the last control step, over its maximum (its
        encoder; 0 without a catheter)."""
        return 0.0 if self._catheter_drive is None else self._catheter_drive.rate

    @property
    def catheter_called(self) -> bool:
        """Whether the expert's rule for bringing the catheter up has fired on the tracked tip
        this episode (`catheter_called`; with a catheter, while a roadmap observable is on)."""
        return self._clocks.called

    @property
    def steps_at_target_depth_2d(self) -> int:
        """`steps_at_target_depth` counted from the image tracker's readings
        (`target_depth_time_2d`; while an image-plane observable is on)."""
        return self._clocks_2d.steps_at_depth

    @property
    def catheter_called_2d(self) -> bool:
        """`catheter_called` kept from the image tracker's readings (`catheter_called_2d`;
        while an image-plane observable is on)."""
        return self._clocks_2d.called

    def step_info(self, physics) -> StepInfo:
        contacts = self.contact_forces(physics)
        return StepInfo(
            tip_position_m=self.tip_position_m(physics),
            target_distance_m=self.target_distance_m(physics),
            contact_force_n=contacts.total_n,
            max_contact_force_n=contacts.max_n,
            mean_contact_force_n=self._step_force.mean_n,
            peak_contact_force_n=self._step_force.peak_n,
            success=self._success,
            diverged=self._diverged,
            path_distance_m=self.path_distance_m(physics),
            insertion_m=self._robot.insertion_m(physics),
            slack_m=self.slack_m(physics),
            drive_force_n=self._robot.drive_force_n(physics),
            escaped=self._escaped,
        )
