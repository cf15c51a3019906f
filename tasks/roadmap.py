"""The `roadmap` observation: the vessel roadmap around the tracked tip, in the tip's frame.

What it assumes a real system has (docs/observations.md#roadmap):

* a **roadmap**: the centerline from the access to the target, with its lumen radius,
  segmented from the pre-operative CTA and registered to the patient (2-D/3-D
  registration errs by `registration_error_m`: one offset of the whole roadmap per
  episode);
* the **tracked tip**: the wire's tip and the base of its curve in 3-D (an EM sensor in
  the tip, or the wire reconstructed from biplane fluoroscopy), each with independent
  Gaussian noise of `tracking_noise_m` per axis and step;
* the robot's encoders (`robot_state`).

The features are expressed in the tip's own frame, so that they read the same in every
anatomy (Scarponi et al. 2024 call this shape invariance): z along the wire's shaft at the
base of the tip curve, x towards the tip's bend (the side the angled tip points to), y
completing the right-handed frame. Lengths are in centimetres. In order:

* the roadmap's points at `AHEAD_MM` past the point nearest the tip, relative to the tip
  (3 each; past the target the roadmap runs on along the branch's axis for 30 mm);
* the target relative to the tip (3);
* the tip relative to the base of its curve (3: its bend and how straight it is);
* the lumen radius at the nearest point and at the target (2);
* the remaining length along the roadmap to the target, in decimetres (1; negative past it);
* how far the tip lies outside the roadmap's tube (1; negative inside: positive means a
  wrong branch or the ascending aorta).

The nearest point is tracked from step to step within a window along the line (as a
navigation system would), so it cannot jump to a parallel stretch of vessel.

The tracker measures once per control step, when the task tells it to (`Navigate`'s
`after_step`; at a reset, `start`): the observables read that step's measurement.

`target_depth_time` (preset `roadmap_timed`) is a clock the same system can
keep: how many control steps the tracked tip has stayed at the target's depth (within one
full-speed insertion step of it along the roadmap), over `DEPTH_CLOCK_STEPS`, at most 1.
The task keeps the count (`Navigate.steps_at_target_depth`). With it, the scripted
expert's end game (strokes past the target and back, timed by its own count of the same
steps) becomes a function of what the policy observes.

`wrong_branch_heading` (presets `roadmap_memory*`) is the other memory the expert
acts on: the wrong branches the tracked tip has entered (it lay more than `LOST_MARGIN_M`
outside the roadmap's tube, inside another vessel of the registered segmentation). While the
tip passes the ostium of one of them (within two lumen radii along the roadmap), it is
[1, that branch's heading from its ostium in the tip's frame (3, a unit vector)]; otherwise
zeros. The expert turns its aim away from the same heading there
(`cathsim_dmc.anatomy.paths.WrongBranchMemory`).

`catheter_called` (with a catheter; preset `roadmap_memory_carriage`) is 1 from
the step the expert's rule for bringing the catheter up has fired on the tracked tip, for the
rest of the episode, else 0: the tip has stayed within `STALL_NEAR_M` of the target for
`CATHETER_STALL_STEPS` steps without coming `STALL_PROGRESS_M` closer than its closest
approach, or the depth clock has run through the expert's end game (`END_GAME_STEPS`: 3
settling steps, then strokes of 8, 16 and 24 quarter-radius steps). The expert keeps the
catheter up from then on; without the flag, whether it is up is hidden state.
"""

from __future__ import annotations

import numpy as np

from cathsim_dmc.anatomy.paths import CenterlinePath, CenterlineTree, WrongBranchMemory, component_across

AHEAD_MM = (0, 4, 8, 12, 16, 24, 32, 48)
ROADMAP_SIZE = 3 * len(AHEAD_MM) + 3 + 3 + 2 + 1 + 1
CM = 0.01
# The nearest point is searched this far behind and ahead of the last one, in metres.
TRACK_BACK_M, TRACK_AHEAD_M = 0.01, 0.03
# target_depth_time's unit: control steps (the expert's end game takes about 50 in a BCA).
DEPTH_CLOCK_STEPS = 100
# wrong_branch_heading: the tip counts as lost this far outside the roadmap's tube (the
# expert's lost_margin_m, cathsim_dmc/control/expert.py).
LOST_MARGIN_M = 2e-3
# catheter_called: the expert's catheter rule (cathsim_dmc/control/expert.py: catheter_bring_up_m,
# min_progress_m, catheter_stall_steps; the end game's settle_steps and stroke schedule).
STALL_NEAR_M, STALL_PROGRESS_M, CATHETER_STALL_STEPS = 0.030, 1e-3, 60
END_GAME_STEPS = 3 + 1 + 2 * (4 + 8 + 12)
WRONG_BRANCH_HEADING_SIZE = 4


class RoadmapTracker:
    """The roadmap features of one task, tracked over an episode: `start` at a reset,
    `measure` once per control step, `features` the last measurement."""

    def __init__(self, task, tracking_noise_m: float = 0.0, registration_error_m: float = 0.0):
        points, radius = task.aorta.asset.centerlines[task.target_name]
        self._line = CenterlinePath(points, radius)
        self._task = task
        self.tracking_noise_m = float(tracking_noise_m)
        self.registration_error_m = float(registration_error_m)
        self._random_state = np.random.RandomState(0)
        self._offset = np.zeros(3)
        self._s = None
        self._features = np.zeros(ROADMAP_SIZE)  # before the first episode: a placeholder of the right shape
        self._tree = None  # the registered vessel tree, built when first needed
        self._wrong_branches = None
        # Kept only while `wrong_branch_heading` is observed (the task sets this at a reset).
        self.remembers_wrong_branches = False
        self._wrong_branch_heading = np.zeros(WRONG_BRANCH_HEADING_SIZE)
        self._target_distance_m = np.inf

    def start(self, random_state) -> None:
        """A new episode: a new registration offset; the nearest point is searched afresh
        by the next `measure`."""
        self._random_state = random_state
        self._offset = (
            random_state.normal(0.0, self.registration_error_m, 3) if self.registration_error_m > 0 else np.zeros(3)
        )
        self._s = None
        self._wrong_branches = None  # forgotten: a new episode
        self._wrong_branch_heading = np.zeros(WRONG_BRANCH_HEADING_SIZE)
        self._target_distance_m = np.inf

    def measure(self, physics) -> None:
        """A new tracking measurement of the current state (its own noise), kept as `features`."""
        self._features = self._measure(physics)

    def features(self, physics=None) -> np.ndarray:
        """The last measurement's roadmap features (the `roadmap` observable)."""
        return self._features.copy()

    def wrong_branch_heading(self, physics=None) -> np.ndarray:
        """The last measurement's `wrong_branch_heading` (module docstring)."""
        return self._wrong_branch_heading.copy()

    @property
    def registration_offset_m(self) -> np.ndarray:
        """This episode's registration error: the roadmap lies this world vector off (metres)."""
        return self._offset.copy()

    @property
    def target_distance_m(self) -> float:
        """The last measurement's distance from the tracked tip to the roadmap's target (m)."""
        return self._target_distance_m

    @property
    def remaining_m(self) -> float:
        """The last measurement's length along the roadmap from the nearest point to the target (m)."""
        return self._line.length_m - self._s

    def _tracked(self, position) -> np.ndarray:
        if self.tracking_noise_m > 0:
            position = position + self._random_state.normal(0.0, self.tracking_noise_m, 3)
        # The roadmap is registered with an error: the tip as seen on it is off by the offset.
        return position - self._offset

    def _measure(self, physics) -> np.ndarray:
        task, line = self._task, self._line
        base_site = physics.bind(task.guidewire.tip_base_site)
        tip = self._tracked(task.tip_position_m(physics))
        base = self._tracked(base_site.xpos.copy())
        shaft = base_site.xmat.reshape(3, 3)[:, 2]
        bend = component_across(tip - base, shaft)
        if np.linalg.norm(bend) < 1e-6:  # a straight tip: its roll is the segment's own
            bend = base_site.xmat.reshape(3, 3)[:, 0]
        x = bend / np.linalg.norm(bend)
        frame = np.stack([x, np.cross(shaft, x), shaft])  # rows: the tip frame's axes in world coordinates

        if self._s is None:
            s, outside = line.locate(tip)
        else:
            s, outside = line.locate(tip, self._s - TRACK_BACK_M, self._s + TRACK_AHEAD_M)
        self._s = s
        self._wrong_branch_heading = self._remember_wrong_branches(tip, s, outside, frame)
        end = line.length_m
        self._target_distance_m = float(np.linalg.norm(line.at(end) - tip))
        # Past the target the roadmap runs on along the branch (the line's extension): near
        # the target the points still show the branch's axis, which the last turn needs.
        ahead = np.array([line.at(s + d * 1e-3) for d in AHEAD_MM]) - tip
        parts = [
            (ahead @ frame.T).ravel() / CM,
            frame @ (line.at(end) - tip) / CM,
            frame @ (tip - base) / CM,
            [line.radius_at(s) / CM, line.radius_at(end) / CM],
            [(end - s) / (10 * CM)],
            [outside / CM],
        ]
        return np.concatenate([np.asarray(p, dtype=float).ravel() for p in parts])

    def _remember_wrong_branches(self, tip, s, outside, frame) -> np.ndarray:
        """Note the branch the tracked tip is lost in; the heading of a remembered one whose
        ostium the tip is passing, in the tip's frame, flagged (`wrong_branch_heading`)."""
        if not self.remembers_wrong_branches:
            return np.zeros(WRONG_BRANCH_HEADING_SIZE)
        if self._wrong_branches is None:
            if self._tree is None:
                self._tree = CenterlineTree.from_asset(self._task.aorta.asset)
            self._wrong_branches = WrongBranchMemory(self._tree, self._task.target_name)
        if outside > LOST_MARGIN_M:
            self._wrong_branches.note(tip)
        heading = self._wrong_branches.heading_near(s, self._line.radius_at(s))
        if heading is None:
            return np.zeros(WRONG_BRANCH_HEADING_SIZE)
        return np.concatenate([[1.0], frame @ heading])


class TargetClocks:
    """The depth clock and the catheter's call, kept from one tracker's readings over an
    episode: `start` at a reset, `update` once per measurement.

    `steps_at_depth` counts the measurements in a row with the tip within one full-speed
    insertion step of the target's depth along the roadmap (`target_depth_time`); `called`
    turns on, with a catheter, when the expert's catheter rule fires on these readings
    (module docstring, `catheter_called`) and stays on until `start`.
    """

    def __init__(self, with_catheter: bool):
        self._with_catheter = bool(with_catheter)
        self.start()

    def start(self) -> None:
        self.steps_at_depth = 0
        self.called = False
        self._steps_stalled = 0
        self._closest_m = np.inf

    def update(self, remaining_m: float, target_distance_m: float, insertion_step_m: float) -> None:
        """One measurement: the length left along the roadmap to the target, the distance to
        it, and one full-speed insertion step (all metres)."""
        self.steps_at_depth = self.steps_at_depth + 1 if remaining_m < insertion_step_m else 0
        if target_distance_m < self._closest_m - STALL_PROGRESS_M:
            self._closest_m, self._steps_stalled = target_distance_m, 0
        elif target_distance_m < STALL_NEAR_M:
            self._steps_stalled += 1
        stalled = self._steps_stalled >= CATHETER_STALL_STEPS
        ended = self.steps_at_depth >= END_GAME_STEPS
        if self._with_catheter and (stalled or ended):
            self.called = True
