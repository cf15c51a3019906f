"""The trajectory file every tool writes and reads (``trajectories.npz``).

Schema (version 2): one row per control step, all episodes concatenated.

  schema_version     ()        int, 1
  task, aorta        ()        str
  episode            (N,)      int, episode index
  step               (N,)      int, step within the episode (1 = after the first action)
  action             (N, A)    float32, [insertion, rotation] in [-1, 1] (A = 2), then the
                               catheter's carriage with a catheter (A = 3)
  reward             (N,)      float32
  tip_position_m     (N, 3)    float32, tip after the step, metres
  contact_force_n    (N,)      float32, total wire-vessel contact force in the state after the
                               step, newtons (one instant: zero in most steps, see
                               `mean_contact_force_n`)
  target_distance_m  (N,)      float32
  success            (N,)      bool, tip within the success radius after the step
  terminated         (N,)      bool, episode ended at the target
  truncated          (N,)      bool, episode cut by the time limit or divergence
  obs_<key>          (N, ...)  observation after the step, when recorded (e.g. obs_pixels
                               (N, 1, 80, 80) uint8, obs_joint_pos (N, J) float32)
  start_tip_position_m (E, 3)  float32, tip at reset, per episode
  optimal_path_length_m (E,)   float32, centerline length from the start to the target
  target_position_m  (3,)      float32
  policy             ()        str, what produced the actions

Optional keys (absent from files that did not record them; readers check):

  start_obs_<key>    (E, ...)  observation at reset, per episode, stored with obs_<key>:
                               the action of a row was chosen from the previous row's
                               observation, or from this one for step 1
  feature_z          (N, F)    float32, the feature vector Z of the ENN policy that acted,
                               computed from that row's observation (cathsim-collect)
  start_feature_z    (E, F)    float32, Z of the reset observation
  episode_aorta      (E,)      str, the anatomy of each episode (aorta=random); the file's
                               `aorta` is then "random"
  episode_target_position_m (E, 3) float32, each episode's target (aorta=random)
  mean_contact_force_n (N,)    float32, total wire-vessel contact force averaged over the
                               physics steps of the control step, newtons (what a force
                               sensor's low-pass sees). The force the metrics use
                               (`wall_forces_n`); every tool records it, files written
                               before it existed fall back to `contact_force_n`.
  expert_action      (N, A)    float32, the policy's own action when `action` (executed)
                               had exploration noise added (cathsim-collect action_noise_std)
  first_episode      ()        int, global index of this file's episode 0 (a shard of a
                               cathsim-collect dataset; episode e was reset with seed + e)
  safe_force_n       ()        float32, the task's safe-success threshold (newtons): a success
                               is safe if no step's `mean_contact_force_n` is above it

Version 2 added `optimal_path_length_m` (for SPL), `policy` and `obs_<key>`.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

SCHEMA_VERSION = 2
FORCE_KEY = "mean_contact_force_n"  # the wall force of a step, as the metrics read it
_PER_STEP = {
    "episode": np.int32,
    "step": np.int32,
    "action": np.float32,
    "reward": np.float32,
    "tip_position_m": np.float32,
    "contact_force_n": np.float32,
    "target_distance_m": np.float32,
    "success": bool,
    "terminated": bool,
    "truncated": bool,
}


@dataclass
class TrajectoryRecorder:
    """Collects steps from any policy, writes the versioned npz."""

    task: str
    aorta: str
    target_position_m: np.ndarray
    policy: str = ""
    record_observations: bool = False
    safe_force_n: float | None = None  # the task's (Navigate.safe_force_n); None: not recorded
    rows: dict = field(default_factory=lambda: {k: [] for k in _PER_STEP})
    observations: dict = field(default_factory=dict)
    starts: list = field(default_factory=list)
    optimal_paths: list = field(default_factory=list)
    start_observations: dict = field(default_factory=dict)
    mean_forces: list = field(default_factory=list)
    episode_aortas: list = field(default_factory=list)
    episode_targets: list = field(default_factory=list)

    def start_episode(
        self,
        tip_position_m,
        optimal_path_length_m: float,
        observation=None,
        aorta: str | None = None,
        target_position_m=None,
    ) -> None:
        """Begin an episode; `aorta` and `target_position_m` name its anatomy and target
        when they change between episodes (aorta=random)."""
        self.starts.append(np.asarray(tip_position_m, dtype=np.float32))
        self.optimal_paths.append(float(optimal_path_length_m))
        if aorta is not None:
            self.episode_aortas.append(str(aorta))
            self.episode_targets.append(np.asarray(target_position_m, dtype=np.float32))
        if self.record_observations and observation is not None:
            # Behavioural cloning pairs an action with the observation it was chosen
            # from; for an episode's first action that is the reset observation.
            for key, value in observation.items():
                self.start_observations.setdefault(key, []).append(_stored(value))

    def record(self, action, reward, info, terminated, truncated, observation=None) -> None:
        if self.record_observations and observation is not None:
            for key, value in observation.items():
                self.observations.setdefault(key, []).append(_stored(value))
        values = {
            "episode": len(self.starts) - 1,
            "step": info["step"],
            "action": action,
            "reward": reward,
            "tip_position_m": info["tip_position_m"],
            "contact_force_n": info["contact_force_n"],
            "target_distance_m": info["target_distance_m"],
            "success": info["success"],
            "terminated": terminated,
            "truncated": truncated,
        }
        for key, value in values.items():
            self.rows[key].append(value)
        if "mean_contact_force_n" in info:
            self.mean_forces.append(info["mean_contact_force_n"])

    def keep_episodes(self, count: int) -> None:
        """Forget every episode after the first `count` (an unfinished one, after Ctrl-C)."""
        rows = sum(1 for episode in self.rows["episode"] if episode < count)
        for values in (*self.rows.values(), *self.observations.values()):
            del values[rows:]
        del self.mean_forces[rows:]
        for values in (
            self.starts,
            self.optimal_paths,
            self.episode_aortas,
            self.episode_targets,
            *self.start_observations.values(),
        ):
            del values[count:]

    def arrays(self) -> dict:
        out = {key: np.asarray(self.rows[key], dtype=dtype) for key, dtype in _PER_STEP.items()}
        out["action"] = action_rows(out["action"], width=2)
        out["tip_position_m"] = out["tip_position_m"].reshape(-1, 3)
        if self.mean_forces and len(self.mean_forces) == len(out["episode"]):
            out["mean_contact_force_n"] = np.asarray(self.mean_forces, dtype=np.float32)
        out.update({f"obs_{key}": np.stack(values) for key, values in self.observations.items()})
        out.update({f"start_obs_{key}": np.stack(values) for key, values in self.start_observations.items()})
        if self.episode_aortas and len(self.episode_aortas) == len(self.starts):
            out["episode_aorta"] = np.asarray(self.episode_aortas, dtype=np.str_)
            out["episode_target_position_m"] = np.stack(self.episode_targets).reshape(-1, 3)
        out.update(
            schema_version=np.int32(SCHEMA_VERSION),
            task=np.str_(self.task),
            aorta=np.str_(self.aorta),
            policy=np.str_(self.policy),
            start_tip_position_m=np.asarray(self.starts, dtype=np.float32).reshape(-1, 3),
            optimal_path_length_m=np.asarray(self.optimal_paths, dtype=np.float32),
            target_position_m=np.asarray(self.target_position_m, dtype=np.float32),
        )
        if self.safe_force_n is not None:
            out["safe_force_n"] = np.float32(self.safe_force_n)
        return out

    def save(self, path, compress: bool = True, **extra) -> Path:
        """Write the npz atomically; `extra` arrays are added as they are."""
        return save_npz(path, {**self.arrays(), **extra}, compress)


def wall_forces_n(arrays: dict) -> np.ndarray:
    """The wall force of each row (N,), in newtons: the step mean (`mean_contact_force_n`).

    The end-of-step total (`contact_force_n`) samples one physics step of twenty: it is
    zero in most steps and a single physics step can read an impact. Files written before
    the step mean was recorded fall back to it.
    """
    key = FORCE_KEY if FORCE_KEY in arrays else "contact_force_n"
    return np.asarray(arrays[key], dtype=float)


def save_npz(path, arrays: dict, compress: bool = True) -> Path:
    path = Path(path)
    from cathsim_dmc.core.run_files import write_atomic

    # Atomic, under a name no reader's pattern matches: a reader never sees half a file.
    return write_atomic(path, lambda tmp: (np.savez_compressed if compress else np.savez)(tmp, **arrays))


def _stored(value) -> np.ndarray:
    value = np.asarray(value)
    return value if value.dtype == np.uint8 else value.astype(np.float32)


def load_trajectories(path) -> dict:
    """Read a trajectory file; one clear error if it is missing or of another schema."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no trajectory file at {path}")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {key: data[key] for key in data.files}
    # a CSV or a pickle (ValueError), a truncated file, one .npy array (no context manager)
    except (OSError, ValueError, EOFError, TypeError, AttributeError, zipfile.BadZipFile):
        raise ValueError(f"{path} is not a trajectory file (the trajectories.npz cathsim-eval writes)") from None
    version = int(arrays.get("schema_version", -1))
    if version != SCHEMA_VERSION:
        raise ValueError(f"{path} has trajectory schema {version}; this version reads schema {SCHEMA_VERSION}")
    return arrays


def action_rows(values: np.ndarray, width: int) -> np.ndarray:
    """`values` (a stack of per-step vectors) as (N, its width); (0, `width`) when empty."""
    return values.reshape(0, width) if values.size == 0 else values.reshape(len(values), -1)
