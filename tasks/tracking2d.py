"""The `tracking_2d` and `roadmap_2d` observations: the wire tracked in the fluoroscopic
image and the registered roadmap projected into it, in millimetres in the image plane.

What they assume a real system has (docs/observations.md#fluoro):

* a single-plane fluoroscope (the `top` camera, in the episode's C-arm view), and an image
  tracker that finds the wire in each frame: its tip and the points at `TRACKED_MM`
  behind it, measured along the wire *in the image* (a single plane cannot see depth, so
  a wire running towards the detector looks shorter), each with independent Gaussian
  noise of `tracking_noise_m` per image axis and step;
* the roadmap of the `roadmap` observation (the centerline from the access to the target
  with its lumen radius, from the pre-operative CTA, registered with one offset of
  `registration_error_m` per axis and episode), projected through the same view.

Coordinates: image right (x) and image up (y, towards the patient's head in AP), in
millimetres at the vessel, from the image centre. `tracking_2d` (2 per point, tip first)
holds the tracked points; `roadmap_2d` holds, relative to the tracked tip, the roadmap's
points `AHEAD_MM` past the point nearest the tip (measured along the 3-D roadmap, as
`roadmap`'s), the target (2 each), then the lumen radius at the nearest point and at the
target, the length left along the roadmap to the target and how far the tip lies outside
the projected tube (negative inside), all in millimetres (1 each).

The nearest point is the one where the tracked tip lies deepest inside the projected tube,
tracked from step to step within `TRACK_BACK_M` behind and `TRACK_AHEAD_M` ahead (as the
`roadmap` tracker does), so that it cannot jump to a stretch of vessel that crosses the
one the tip is in, in the projection.

`tracking_2d_history` (preset `tracking_2d_memory`) is a frame stack of the tracking: the
tracked points of the `HISTORY_STEPS` measurements before this one, newest first, each
relative to this measurement's tracked tip (2 per point; before the episode's first
measurement, its first). How the image responds to the robot's moves over a few frames is
what shows the depth and roll one view hides.

Neither holds anything a single-plane image and the pre-operative roadmap do not give:
no depth along the view axis, no 3-D tip, no wire angles, no forces.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from cathsim_dmc.anatomy.paths import CenterlinePath, CenterlineTree, WrongBranchMemory, deepest_on_polyline
from cathsim_dmc.sim.wire_finder import wire_mask, wire_path_px
from cathsim_dmc.tasks.roadmap import AHEAD_MM, LOST_MARGIN_M, TRACK_AHEAD_M, TRACK_BACK_M

TRACKED_MM = (0, 3, 6, 9, 12, 15, 20, 30)
TRACKING_2D_SIZE = 2 * len(TRACKED_MM)
HISTORY_STEPS = 4  # tracking_2d_history: the control steps it remembers (at 10 frames/s, 0.4 s)
TRACKING_2D_HISTORY_SIZE = HISTORY_STEPS * TRACKING_2D_SIZE
ROADMAP_2D_SIZE = 2 * len(AHEAD_MM) + 2 + 2 + 1 + 1
WRONG_BRANCH_HEADING_2D_SIZE = 3
MM = 1e-3


def image_plane(physics, camera: str = "top"):
    """(origin, 2x3 matrix) taking a world point p (metres) to image-plane millimetres:
    matrix @ (p - origin); x along the image right, y along the image up, from the image
    centre (where the camera's axis meets the image)."""
    cam = physics.model.name2id(camera, "camera")
    axes = physics.data.cam_xmat[cam].reshape(3, 3)
    return physics.data.cam_xpos[cam].copy(), axes[:, :2].T / MM


def resample_back(points_2d: np.ndarray, distances: np.ndarray) -> np.ndarray:
    """Points `distances` behind the last of the polyline `points_2d` (proximal to
    distal), measured along it; beyond its start, the start."""
    back = points_2d[::-1]
    steps = np.linalg.norm(np.diff(back, axis=0), axis=1)
    along = np.concatenate([[0.0], np.cumsum(steps)])
    return np.stack([np.interp(distances, along, back[:, k]) for k in range(2)], axis=1)


class ImageTracker:
    """The image-plane tracking and roadmap of one task, over an episode: `start` at a
    reset (after the episode's view is set), `measure` once per control step."""

    def __init__(self, task, tracking_noise_m: float = 0.0, frame=None):
        points, radius = task.aorta.asset.centerlines[task.target_name]
        # With `frame` ((physics, random_state) -> the fluoroscopic frame, uint8), the wire is
        # found in that image (tracking_source="fluoro_image"); else it is projected.
        self._frame = frame
        self._line = CenterlinePath(points, radius)
        self._task = task
        self.tracking_noise_m = float(tracking_noise_m)
        self._random_state = np.random.RandomState(0)
        self._offset = np.zeros(3)
        self._s = None
        # The episode's last HISTORY_STEPS + 1 measurements' tracked points, oldest first (the
        # first measurement fills it); the newest is `tracking_2d`.
        self._frames = deque([np.zeros((len(TRACKED_MM), 2))] * (HISTORY_STEPS + 1), maxlen=HISTORY_STEPS + 1)
        self._roadmap = np.zeros(ROADMAP_2D_SIZE)
        self._tree = None  # the registered vessel tree, built when first needed
        self._wrong_branches = None
        # Kept only while `wrong_branch_heading_2d` is observed (the task sets this at a reset).
        self.remembers_wrong_branches = False
        self._wrong_branch_heading = np.zeros(WRONG_BRANCH_HEADING_2D_SIZE)
        self.remaining_m = self.target_distance_m = np.inf

    def start(self, random_state, registration_offset_m) -> None:
        """A new episode with the roadmap registered `registration_offset_m` (a world
        vector, metres) off; the nearest point is searched afresh by the next `measure`."""
        self._random_state = random_state
        self._offset = np.asarray(registration_offset_m, dtype=float).copy()
        self._s = None
        self._frames.clear()
        self._wrong_branches = None  # forgotten: a new episode
        self._wrong_branch_heading = np.zeros(WRONG_BRANCH_HEADING_2D_SIZE)
        self.remaining_m = self.target_distance_m = np.inf

    def tracked(self, physics=None) -> np.ndarray:
        """The last measurement's tracked wire points (the `tracking_2d` observable)."""
        return self._frames[-1].ravel().copy()

    def history(self, physics=None) -> np.ndarray:
        """The tracked points of the `HISTORY_STEPS` measurements before the last, newest
        first, relative to the last one's tip (the `tracking_2d_history` observable)."""
        *earlier, last = self._frames
        return (np.stack(earlier[::-1]) - last[0]).ravel()

    def roadmap(self, physics=None) -> np.ndarray:
        """The last measurement's projected roadmap (the `roadmap_2d` observable)."""
        return self._roadmap.copy()

    def wrong_branch_heading(self, physics=None) -> np.ndarray:
        """The last measurement's `wrong_branch_heading_2d` (module docstring)."""
        return self._wrong_branch_heading.copy()

    def measure(self, physics) -> None:
        task, line = self._task, self._line
        origin, to_image = image_plane(physics)
        if self._frame is None:
            wire = task.guidewire
            joints = np.concatenate([physics.bind(wire.segments).xpos, [task.tip_position_m(physics)]])
            wire_2d = (joints - origin) @ to_image.T
        else:
            wire_2d = self._wire_in_frame(physics, origin, to_image)
        if wire_2d is None:  # nothing found in the frame: the tracker holds its last fix
            tracked = self._frames[-1] if self._frames else np.zeros((len(TRACKED_MM), 2))
        else:
            tracked = resample_back(wire_2d, np.asarray(TRACKED_MM, dtype=float))
        if self.tracking_noise_m > 0:
            tracked = tracked + self._random_state.normal(0.0, self.tracking_noise_m / MM, tracked.shape)
        tip = tracked[0]

        # The registered roadmap, projected: its polyline (with the extension past the
        # target) and each point's arc length along the 3-D line.
        road = (line.points + self._offset - origin) @ to_image.T
        lo, hi = (-np.inf, np.inf) if self._s is None else (self._s - TRACK_BACK_M, self._s + TRACK_AHEAD_M)
        s, outside_mm = deepest_on_polyline(road, line.arclength, line.radius / MM, tip, lo, hi)
        self._s = s
        end = line.length_m
        self.remaining_m = end - s
        self._wrong_branch_heading = self._remember_wrong_branches(tip, s, outside_mm, origin, to_image)

        def projected(s_m):
            return (line.at(s_m) + self._offset - origin) @ to_image.T

        ahead = np.array([projected(s + d * MM) for d in AHEAD_MM]) - tip
        self.target_distance_m = float(np.linalg.norm(projected(end) - tip)) * MM
        self._frames.extend([tracked] * (1 if self._frames else self._frames.maxlen))
        self._roadmap = np.concatenate(
            [
                ahead.ravel(),
                projected(end) - tip,
                [line.radius_at(s) / MM, line.radius_at(end) / MM],
                [(end - s) / MM],
                [outside_mm],
            ]
        )

    def _wire_in_frame(self, physics, origin, to_image) -> np.ndarray | None:
        """The wire found in this step's fluoroscopic frame, in image-plane mm, from the
        sheath to the tip (None if not found). The frame is orthographic: a pixel spans
        fovy / size of the image plane."""
        frame = self._frame(physics, self._random_state)
        size = frame.shape[0]
        mm_per_px = physics.model.cam_fovy[physics.model.name2id("top", "camera")] / size / MM
        entry_mm = (self._line.points[0] + self._offset - origin) @ to_image.T  # the sheath, on the roadmap
        entry_px = (entry_mm[0] / mm_per_px + size / 2, size / 2 - entry_mm[1] / mm_per_px)
        path = wire_path_px(wire_mask(frame), entry_px)
        if path is None:
            return None
        path_mm = np.stack([(path[:, 0] - size / 2) * mm_per_px, (size / 2 - path[:, 1]) * mm_per_px], axis=1)
        return path_mm[::-1]

    def _remember_wrong_branches(self, tip, s, outside_mm, origin, to_image) -> np.ndarray:
        """Note the branch of the projected vessel tree the tracked tip is lost in; the image
        heading of a remembered one whose ostium the tip is passing, flagged."""
        if not self.remembers_wrong_branches:
            return np.zeros(WRONG_BRANCH_HEADING_2D_SIZE)
        if self._wrong_branches is None:
            if self._tree is None:
                self._tree = CenterlineTree.from_asset(self._task.aorta.asset)
            self._wrong_branches = WrongBranchMemory(self._tree, self._task.target_name)
        if outside_mm > LOST_MARGIN_M / MM:
            # The branch whose projected tube the tip lies deepest in, if it is inside one.
            depths = {}
            for name, other in self._tree.lines.items():
                road = (other.points + self._offset - origin) @ to_image.T
                depths[name] = deepest_on_polyline(road, other.arclength, other.radius / MM, tip)[1]
            name = min(depths, key=depths.get)
            if depths[name] <= 0:
                self._wrong_branches.note_branch(name)
        heading = self._wrong_branches.heading_near(s, self._line.radius_at(s))
        if heading is None:
            return np.zeros(WRONG_BRANCH_HEADING_2D_SIZE)
        heading_2d = to_image @ heading
        norm = np.linalg.norm(heading_2d)
        # A branch heading straight along the view axis has no image direction: flagged only.
        return np.concatenate([[1.0], heading_2d / norm if norm > 1e-9 else np.zeros(2)])
