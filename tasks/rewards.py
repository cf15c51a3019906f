"""Navigate's rewards: each term a small function, looked up by name (`get_reward`).

A step's reward (`NavigationReward.reward`) is

* `success_reward` when the tip reached the target (which ends the episode); otherwise
* minus the tip's distance to the target in metres (dense) or 0 (sparse), the distance
  measured by "euclidean" (the paper's straight line) or "geodesic" (along the vessel);
* plus "progress" shaping: `progress_weight` times the step's progress towards the
  target, in units of one full-speed insertion step;
* plus "aim" shaping: the change of a potential that grows as the tip's bend turns
  towards where the target's centerline goes next (the potential is paid for the step the
  aim happens, rather than only when the tip later moves).

`Navigate(reward=..., progress_weight=..., aim_weight=...)` picks the distance and the
shaping weights; the training configs conf/reward/*.yaml name them (`kind`,
`progress_weight`, `aim_weight`). Success, the time limit and the metrics do not depend
on any of them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

SUCCESS_REWARD = 10.0
# Aim shaping looks this many lumen radii ahead along the target's centerline (as the expert).
AIM_LOOKAHEAD_RADII = 1.5
# The aim counts fully once the next stretch is this far off the shaft's axis (the share of
# the look-ahead across the shaft); straight ahead, the bend's direction does not matter.
AIM_FULL_OFF_AXIS = 0.5


# -- the dense reward's distances, tip to target, in metres --------------------------------
def euclidean(tip_position_m, target_position_m, along_vessel_m: Callable[[], float] | None = None) -> float:
    """The straight line from tip to target (the paper's)."""
    return float(np.linalg.norm(tip_position_m - target_position_m))


def geodesic(tip_position_m, target_position_m, along_vessel_m: Callable[[], float]) -> float:
    """The larger of the distance along the vessel (`along_vessel_m()`) and the straight line.

    Along the vessel, a tip deep in a wrong branch is 2-3x farther than one at the right
    ostium (the straight line ranks it closer); the straight line still counts near the
    target, where a tip riding the branch wall is level with the target but off its axis.
    `along_vessel_m` is called only here, so a task locates its tip on the centerline tree
    only for this distance.
    """
    straight = euclidean(tip_position_m, target_position_m)
    return max(along_vessel_m(), straight)


# -- shaping -------------------------------------------------------------------------------
def progress(previous_distance_m: float, distance_m: float, step_m: float, weight: float) -> float:
    """`weight` x the step's progress towards the target (the distance it removed) over
    `step_m`, one full-speed insertion step: +weight for a full step towards the target."""
    return weight * (previous_distance_m - distance_m) / step_m


def aim(angle_rad: float, off_axis: float, weight: float) -> float:
    """The aim's potential: -weight x (angle from the tip's bend to the aim / pi), faded out
    where the path runs straight ahead (`off_axis`: the aim's share across the shaft, see
    `CenterlinePath.aim_error`). The reward pays its change from step to step."""
    return -weight * abs(angle_rad) / np.pi * min(1.0, off_axis / AIM_FULL_OFF_AXIS)


_REWARDS = {"euclidean": euclidean, "geodesic": geodesic, "progress": progress, "aim": aim}
DISTANCES = ("euclidean", "geodesic")  # what `Navigate(reward=...)` accepts
SHAPING = ("progress", "aim")


def get_reward(name: str) -> Callable[..., float]:
    """The reward term called `name`: a distance (`DISTANCES`) or a shaping term (`SHAPING`)."""
    if name not in _REWARDS:
        raise ValueError(f"reward {name!r} is not a reward term; choose one of {list(_REWARDS)}")
    return _REWARDS[name]


@dataclass(frozen=True)
class NavigationReward:
    """One task's reward: which distance it penalises, whether dense, the success reward
    and the shaping weights (0: no shaping)."""

    kind: str = "euclidean"
    dense: bool = True
    success_reward: float = SUCCESS_REWARD
    progress_weight: float = 0.0
    aim_weight: float = 0.0

    def __post_init__(self):
        if self.kind not in DISTANCES:
            raise ValueError(f"reward={self.kind!r}; choose one of {list(DISTANCES)}")

    def distance_m(self, tip_position_m, target_position_m, along_vessel_m: Callable[[], float]) -> float:
        """The distance this reward penalises, in metres (`along_vessel_m()`: the geodesic part)."""
        return get_reward(self.kind)(tip_position_m, target_position_m, along_vessel_m)

    def aim_potential(self, angle_rad: float, off_axis: float) -> float:
        return aim(angle_rad, off_axis, self.aim_weight)

    def step_reward(self, previous_distance_m: float, distance_m: float, success: bool, step_m: float) -> float:
        """The reward of a step that took the tip from `previous_distance_m` to `distance_m`
        and did or did not reach the target, without the aim shaping (`step_m`: one
        full-speed insertion step, the progress shaping's unit)."""
        if success:
            return self.success_reward
        reward = -distance_m if self.dense else 0.0
        if self.progress_weight:
            reward += progress(previous_distance_m, distance_m, step_m, self.progress_weight)
        return reward

    def reward(self, previous_distance_m: float, distance_m: float, success: bool, step_m: float,
               previous_aim_potential: float, aim_potential: float) -> float:
        """`step_reward` plus the aim potential's change (none on success: the episode ends there)."""
        reward = self.step_reward(previous_distance_m, distance_m, success, step_m)
        if not success:
            reward += aim_potential - previous_aim_potential
        return reward
