"""Navigate's rewards: each term a small function, looked up by name (`get_reward`).

A step's reward (`NavigationReward.reward`) is

* `success_reward` when the tip reached the target (which ends the episode); otherwise
* minus the tip's distance to the target in metres (dense) or 0 (sparse), the distance
  measured by "euclidean" (the paper's straight line) or "geodesic" (along the vessel);
* plus "progress" shaping: `progress_weight` times the step's progress towards the
  target, in units of one full-speed insertion step.

`Navigate(reward=..., progress_weight=...)` picks the distance and the shaping weight;
the training configs conf/reward/*.yaml name them (`kind`, `progress_weight`). Success,
the time limit and the metrics do not depend on either.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from cathsim_dmc.core import task_defaults


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


_REWARDS = {"euclidean": euclidean, "geodesic": geodesic, "progress": progress}
DISTANCES = ("euclidean", "geodesic")  # what `Navigate(reward=...)` accepts
SHAPING = ("progress",)


def get_reward(name: str) -> Callable[..., float]:
    """The reward term called `name`: a distance (`DISTANCES`) or a shaping term (`SHAPING`)."""
    if name not in _REWARDS:
        raise ValueError(f"reward {name!r} is not a reward term; choose one of {list(_REWARDS)}")
    return _REWARDS[name]


@dataclass(frozen=True)
class NavigationReward:
    """One task's reward: which distance it penalises, whether dense, the success reward
    and the progress shaping's weight (0: no shaping)."""

    kind: str = "euclidean"
    dense: bool = task_defaults.DENSE_REWARD
    success_reward: float = task_defaults.SUCCESS_REWARD
    progress_weight: float = 0.0

    def __post_init__(self):
        if self.kind not in DISTANCES:
            raise ValueError(f"reward={self.kind!r}; choose one of {list(DISTANCES)}")

    def distance_m(self, tip_position_m, target_position_m, along_vessel_m: Callable[[], float]) -> float:
        """The distance this reward penalises, in metres (`along_vessel_m()`: the geodesic part)."""
        return get_reward(self.kind)(tip_position_m, target_position_m, along_vessel_m)

    def step_reward(self, previous_distance_m: float, distance_m: float, success: bool, step_m: float) -> float:
        """The reward of a step that took the tip from `previous_distance_m` to `distance_m`
        and did or did not reach the target (`step_m`: one full-speed insertion step, the
        progress shaping's unit)."""
        if success:
            return self.success_reward
        reward = -distance_m if self.dense else 0.0
        if self.progress_weight:
            reward += progress(previous_distance_m, distance_m, step_m, self.progress_weight)
        return reward
