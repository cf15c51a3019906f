"""A privileged scripted expert: steers the angled tip along the centerline into the target.

It reads simulator state an agent does not see (tip and tip-base positions, the shaft
direction, the asset's centerline to the target and its lumen radius) and does what an
interventionalist does with an angled wire:

* **aim**: the bend of the tip, seen from the base of the tip curve, is turned (by
  rotating the wire at the robot; a torsionally stiff wire turns its tip 1:1) towards
  a look-ahead point on the centerline. Aiming from the tip point would be wrong: the
  tip's offset from the shaft is its own bend.
* **advance only when aimed**: insertion is gated on the angle between the bend and the
  look-ahead direction; on straight stretches any orientation will do.
* **back off when lost**: if the tip leaves the centerline's lumen (a wrong branch) or
  progress along the centerline stalls, retract a few millimetres and aim again; after
  several back-offs without progress, measure progress afresh from where the tip is.
  A wrong branch the tip has been in is remembered: while the tip passes its ostium again,
  the aim is turned away from that branch's heading.
* **end game**: at the target's depth but outside the 4 mm zone, the tip rests on the
  branch wall (its bend reaches across most of the lumen). Turn the bend towards the
  branch axis while stroking the wire past the target and back, one, two, then three
  lumen radii (each deeper stroke leaves the wire in another posture) in quarter-radius
  steps; then retreat out of the branch and enter again.

With a catheter over the wire (`Navigate(catheter=...)`; actions then have a third entry,
the catheter's carriage) the wire goes first, alone, past the other ostia (a stiff curved
tip would hook the first of them), the catheter parked at the sheath. The catheter comes up
where the wire alone cannot finish: when the wire's tip, within `catheter_bring_up_m` of the
target, has not come `min_progress_m` closer for `catheter_stall_steps` control steps (a
branch that leaves its parent at a reverse angle, as the LCCA does from a bovine trunk: the
wire's shaft lies along the parent and takes the push), or when the end game's strokes end
without reaching the target (a wide branch: the wire's tip rests on the wall). Then it does
what an interventionalist does with a shaped catheter:

* **lead with the catheter**: the catheter's tip comes up to the wire's (the wire held);
  then it steers the pair (the catheter's curve, over the wire's soft tip, is the bend the
  aim turns) with the catheter following the wire;
* **hold it and advance the wire**: once the tip is within `catheter_hold_m` of the target
  and points at it (within `catheter_aim_rad`), hold the catheter and push the wire out
  of it at half speed without turning: the catheter's curve, backed by its stiffness,
  sends the wire up the branch;
* **try again**: if the tip ends up `catheter_give_up_m` further from the target than
  where the catheter was held, pull the wire back into the catheter and steer again; if
  the pair leaves the path's lumen (another branch) for `catheter_lost_steps` steps, draw
  the catheter back `catheter_stand_back_m` behind the wire's tip and let the wire lead
  again. The catheter comes up only while the wire's tip is in the path's lumen.

Past the other ostia the look-ahead follows the arch's inner curve, which keeps the bend
away from the branches on the outer curve; at the target ostium the centerline turns
into the branch and the bend follows it. Every length is relative to the asset's lumen
radius or the wire, so no per-aorta constant is tuned.
"""

from __future__ import annotations

import numpy as np

from cathsim_dmc.anatomy.paths import (
    CenterlinePath,
    CenterlineTree,
    WrongBranchMemory,
    component_across,
    signed_angle_rad,
)


class CenterlineExpert:
    """Scripted expert policy: `action = expert(observation, env)`.

    `env` is a `cathsim_dmc.suite.gym.CathSimEnv` (or anything with `.task` and `.physics`).

    Args:
      lookahead_radii: look-ahead distance along the centerline, in lumen radii.
      aligned_rad: insertion is allowed when the bend is within this angle of the aim.
      stall_steps: steps without progress (`min_progress_m`) before backing off.
      retract_steps: control steps of full retraction when backing off.
      lost_margin_m: the tip counts as lost (in a wrong branch) this far outside the
        lumen of the path to the target.
      hold_rotation_on_straight: no rotation where the path runs straight ahead of the tip
        (the look-ahead within about 14 degrees of the shaft: `aim_error`'s off-axis share
        below 0.25, where insertion needs no aim). There the aim is nearly along the shaft,
        and the turn it asks for flips sign with small changes of the start rotation; held,
        the first turn comes in the arch and varies smoothly with the start: labels an
        image-only student can learn (`policy=expert_steady`, docs/paper.md#imitation).
    """

    def __init__(
        self,
        lookahead_radii: float = 1.5,
        aligned_rad: float = np.deg2rad(35),
        stall_steps: int = 6,
        min_progress_m: float = 1e-3,
        retract_steps: int = 2,
        lost_margin_m: float = 2e-3,
        hold_rotation_on_straight: bool = False,
    ):
        self.lookahead_radii = lookahead_radii
        self.aligned_rad = aligned_rad
        self.stall_steps = stall_steps
        self.min_progress_m = min_progress_m
        self.retract_steps = retract_steps
        self.lost_margin_m = lost_margin_m
        self.hold_rotation_on_straight = hold_rotation_on_straight
        self.settle_steps = 3
        self.axis_gain = 0.5  # of the full correction per step: a gentle turn the tip can follow
        self.strokes_per_retreat = 3
        self.retreat_radii = 2.0
        # End-game strokes: the k-th goes k * stroke_radii lumen radii past the target and
        # back, at most stroke_step_radii lumen radii per control step.
        self.stroke_radii = 1.0
        self.stroke_step_radii = 0.25
        self.backoffs_before_reset = 8
        # Wrong branches: once the tip has been in another branch, the bend is turned away
        # from that branch (this share of the aim) while the tip passes its ostium.
        self.avoid_gain = 1.0
        # With a catheter (see the module docstring).
        self.catheter_bring_up_m = 0.030
        self.catheter_stall_steps = 60  # the wire this long near the target, no closer: the catheter comes up
        self.catheter_lost_steps = 3  # the pair this long out of the path's lumen: the wire leads again
        self.catheter_stand_back_m = 0.040
        self.catheter_hold_m = 0.014
        self.catheter_aim_rad = np.deg2rad(40)
        self.catheter_give_up_m = 0.005
        self.catheter_push = 0.5
        self._episode_key = None

    def reset(self, env):
        task = env.task
        self._line = CenterlinePath(*task.aorta.asset.centerlines[task.target_name])
        self._tree = CenterlineTree.from_asset(task.aorta.asset)
        self._avoid = WrongBranchMemory(self._tree, task.target_name)  # the wrong branches entered
        self._s = self._line.locate(task.tip_position_m(env.physics))[0]
        self._best_s = self._s
        self._since_progress = 0
        self._retracting = 0
        self._at_depth = 0
        self._backoffs = 0
        self._retreat_to = None
        # The end game's geometry: the target, the branch axis arriving at it, its radius.
        line = self._line
        self._target = line.at(line.length_m)
        self._target_radius = line.radius_at(line.length_m)
        axis = self._target - line.at(line.length_m - self._target_radius)
        self._target_axis = axis / np.linalg.norm(axis)
        self._max_rotation_step = task.robot.max_rotation_speed_rad_s * task.control_timestep
        self._max_insertion_step = task.robot.max_insertion_speed_m_s * task.control_timestep
        self._schedule = self._stroke_schedule()
        self._has_catheter = getattr(task, "catheter", None) is not None
        self.uses_catheter = False  # until the wire alone stalls (module docstring)
        self._catheter_phase = "wire"
        self._held_distance_m = None
        self._lost_steps = 0
        self._closest_m = np.inf  # the wire tip's closest approach to the target
        self._steps_no_closer = 0  # control steps within catheter_bring_up_m since then

    def __call__(self, observation, env) -> np.ndarray:
        action = self._wire_action(env)
        if not self._has_catheter:
            return action
        if not self.uses_catheter:  # the catheter stays parked at the sheath
            return np.append(action, 0.0).astype(np.float32)
        return self._catheter_action(action, env)

    def _catheter_action(self, wire_action, env) -> np.ndarray:
        """[insertion, rotation, catheter] for the catheter-led approach (module docstring)."""
        task, physics = env.task, env.physics
        offset = task.catheter_offset_m
        distance = task.target_distance_m(physics)
        if self._catheter_phase == "lead" and self._lost_steps >= self.catheter_lost_steps:
            self._catheter_phase = "stand_back"  # the pair is in another branch
        if self._catheter_phase == "stand_back":
            if offset < self.catheter_stand_back_m:
                return np.array([0.0, wire_action[1], -1.0], dtype=np.float32)
            self._catheter_phase = "wire"
        if self._catheter_phase == "wire":
            if distance > self.catheter_bring_up_m or self._lost_steps:
                return np.append(wire_action, 0.0).astype(np.float32)
            self._catheter_phase = "lead"
        if self._catheter_phase == "hold":
            if distance > self._held_distance_m + self.catheter_give_up_m:
                self._catheter_phase = "retract"
            else:
                return np.array([self.catheter_push, 0.0, 0.0], dtype=np.float32)
        if self._catheter_phase == "retract":
            if offset > 0.0:
                return np.array([-1.0, 0.0, 0.0], dtype=np.float32)
            self._catheter_phase = "lead"
        if offset > 0.0:  # bring the catheter's tip up to the wire's, the wire held
            return np.array([0.0, wire_action[1], 1.0], dtype=np.float32)
        tip = task.tip_position_m(physics)
        to_target = self._target - tip
        tip_axis = physics.bind(task.guidewire.segments[-1]).xmat.reshape(3, 3)[:, 2]
        aimed = np.dot(tip_axis, to_target) > np.cos(self.catheter_aim_rad) * np.linalg.norm(to_target)
        if distance < self.catheter_hold_m and aimed:
            self._catheter_phase, self._held_distance_m = "hold", distance
            return np.array([self.catheter_push, 0.0, 0.0], dtype=np.float32)
        # Steer the pair: the catheter moves with the wire.
        return np.array([wire_action[0], wire_action[1], wire_action[0]], dtype=np.float32)

    def _wire_action(self, env) -> np.ndarray:
        task, physics = env.task, env.physics
        key = (id(task), id(physics.model.ptr))
        if task.step_count == 0 or key != self._episode_key:
            self._episode_key = key
            self.reset(env)
        line = self._line
        tip = task.tip_position_m(physics)
        base_site = physics.bind(task.guidewire.tip_base_site)
        base = base_site.xpos.copy()
        shaft = base_site.xmat.reshape(3, 3)[:, 2].copy()  # the wire's axis where the curve begins

        # Progress: closest centerline point to the tip, searched near the last one so the
        # estimate cannot jump to a parallel stretch of vessel.
        s, outside = line.locate(tip, self._s - 0.01, self._s + 0.03)
        self._s = s
        radius = line.radius_at(s)
        remaining = line.length_m - s
        if s > self._best_s + self.min_progress_m:
            self._best_s, self._since_progress, self._backoffs = s, 0, 0
        else:
            self._since_progress += 1
        if self._has_catheter and not self.uses_catheter:
            distance = task.target_distance_m(physics)
            if distance < self._closest_m - self.min_progress_m:
                self._closest_m, self._steps_no_closer = distance, 0
            elif distance < self.catheter_bring_up_m:
                self._steps_no_closer += 1
            if self._steps_no_closer >= self.catheter_stall_steps:
                self.uses_catheter = True  # the wire alone stalls short of the target
        lost = outside > self.lost_margin_m
        self._lost_steps = self._lost_steps + 1 if lost else 0
        if lost:
            self._avoid.note(tip)
        if remaining < self.min_progress_m:
            self._since_progress = 0  # at the target's depth: only the aim is left to fix
        if self._retracting == 0 and (lost or self._since_progress >= self.stall_steps):
            self._retracting = self.retract_steps
            self._since_progress = 0
            self._backoffs += 1
            if self._backoffs >= self.backoffs_before_reset:
                # The best depth so far was reached along a path that no longer leads on
                # (say, pressed into the wrong ostium); measure progress from here.
                self._best_s, self._backoffs = s, 0

        # Aim: the bend (tip relative to the tip base, across the shaft) towards the
        # look-ahead point (relative to the tip base, across the shaft).
        # Near the target, aim at the target itself: the last look-ahead would overshoot.
        angle, off_axis = line.aim_error(tip, base, shaft, s, self.lookahead_radii * radius)
        away = self._avoid.heading_near(s, radius)
        if away is not None:
            aim_point = line.at(min(s + self.lookahead_radii * radius, line.length_m))
            aim = component_across(aim_point - base, shaft)
            aim = aim - self.avoid_gain * np.linalg.norm(aim) * component_across(away, shaft)
            angle = signed_angle_rad(component_across(tip - base, shaft), aim, shaft)
        straight_ahead = off_axis < 0.25
        bend = component_across(tip - base, shaft)
        rotation = np.clip(angle / self._max_rotation_step, -1.0, 1.0)
        if self.hold_rotation_on_straight and straight_ahead:
            rotation = 0.0

        if self._retreat_to is not None:
            # Out of the branch and back in: a fresh entry rests the tip on another wall.
            if s > self._retreat_to:
                return np.array([-1.0, rotation], dtype=np.float32)
            self._retreat_to = None
            # Progress counts afresh from here: the best depth so far was a stroke past the
            # target, which re-entering the branch cannot beat, so the stall rule would back
            # the wire out of the branch (and often out into the arch).
            self._best_s, self._since_progress, self._backoffs = s, 0, 0
        if remaining < self._max_insertion_step:
            self._at_depth += 1
        else:
            self._at_depth = 0
        if self._at_depth > self.settle_steps:
            return self._end_game(tip, shaft, bend, remaining)
        if self._retracting > 0:
            self._retracting -= 1
            insertion = -1.0
        elif straight_ahead or abs(angle) < self.aligned_rad:
            # Full speed, but no further than the target along the centerline.
            insertion = float(np.clip(remaining / self._max_insertion_step, -1.0, 1.0))
        else:
            insertion = 0.0
        return np.array([insertion, rotation], dtype=np.float32)

    def _end_game(self, tip, shaft, bend, remaining):
        """At the target's depth but not within reach: the tip rests on the branch wall.

        The tip's own bend holds it off the axis, so turn the bend towards the axis (at
        part gain, which the tip can follow) while stroking the wire past the target and
        back (`_stroke_schedule`), so the tip slides across the target's cross-section.
        After the strokes without success, retreat out of the branch and enter again.
        """
        to_axis = -component_across(tip - self._target, self._target_axis)
        angle = signed_angle_rad(bend, component_across(to_axis, shaft), shaft)
        rotation = float(np.clip(self.axis_gain * angle / self._max_rotation_step, -1.0, 1.0))

        schedule = self._schedule
        phase = self._at_depth - self.settle_steps - 1
        if phase >= len(schedule):
            self._retreat_to = self._line.length_m - self.retreat_radii * self._target_radius
            self._at_depth = 0
            if self._has_catheter:
                self.uses_catheter = True  # the strokes did not reach the target: bring up the catheter
            return np.array([-1.0, rotation], dtype=np.float32)
        past = schedule[phase]
        insertion = float(np.clip((remaining + past) / self._max_insertion_step, -1.0, 1.0))
        return np.array([insertion, rotation], dtype=np.float32)

    def _stroke_schedule(self):
        """How far past the target the end game pushes the wire at each of its steps (built at reset).

        Stroke k (1, 2, ...) goes k lumen radii past the target and back: each deeper
        stroke puts more of the wire into the branch, so the tip comes back through the
        target's depth in another posture (a shaft lying further along the branch, which
        changes how far the bend holds the tip off the axis). The steps are a quarter
        radius (about 1.4 mm in a BCA) rather than the full 4 mm a control step allows:
        success is checked once per control step, and a tip that passes the target d mm
        off the axis (d just under 4) is inside the 4 mm zone only along a chord of
        2 * sqrt(16 - d^2) mm (2.8 mm at 3.75 mm off), which a full-speed stroke can step over.
        """
        step = min(self._max_insertion_step, self.stroke_step_radii * self._target_radius)
        schedule = []
        for k in range(1, self.strokes_per_retreat + 1):
            amplitude = k * self.stroke_radii * self._target_radius
            half = max(2, int(np.ceil(amplitude / step)))
            schedule += [amplitude * j / half for j in range(half + 1)]
            schedule += [amplitude * (half - j) / half for j in range(1, half)]
        return schedule
