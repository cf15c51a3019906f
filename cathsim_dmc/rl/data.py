"""Datasets from trajectory files, for behavioural cloning and force prediction.

    from cathsim_dmc.rl.data import TrajectoryDataset
    data = TrajectoryDataset(["run/trajectories.npz"], inputs=("obs_pixels",), targets=("action",))
    image, action = data[0]          # float32 tensors: image in [0, 1], (1, 80, 80)

Episodes stay whole: `split_by_episode` holds out complete episodes, so that test
samples never come from an episode the model was trained on.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cathsim_dmc.trajectory import load_trajectories


def load_arrays(paths, keys) -> dict:
    """Concatenate `keys` (and a global episode id) over several trajectory files."""
    parts = {key: [] for key in keys}
    episodes, offset = [], 0
    for path in paths:
        arrays = load_trajectories(path)
        missing = [k for k in keys if k not in arrays]
        if missing:
            hint = " (record observations with save_observations=true)" if any(k.startswith("obs_") for k in missing) else ""
            raise ValueError(f"{path} has no {missing}{hint}; it has {sorted(arrays)}")
        for key in keys:
            parts[key].append(arrays[key])
        episodes.append(arrays["episode"] + offset)
        offset += int(arrays["episode"].max()) + 1 if len(arrays["episode"]) else 0
    out = {key: np.concatenate(values) for key, values in parts.items()}
    out["episode"] = np.concatenate(episodes)
    return out


def split_by_episode(episode_ids, test_fraction: float, seed: int = 0):
    """(train rows, test rows): whole episodes, `test_fraction` of them held out."""
    ids = np.unique(episode_ids)
    rng = np.random.default_rng(seed)
    test = rng.choice(ids, size=max(1, int(round(test_fraction * len(ids)))), replace=False) if len(ids) > 1 else []
    is_test = np.isin(episode_ids, test)
    return np.flatnonzero(~is_test), np.flatnonzero(is_test)


class TrajectoryDataset:
    """A torch-style dataset of (inputs..., targets...) rows from trajectory files.

    uint8 inputs (images) are scaled to float32 in [0, 1]; everything else is float32.
    """

    def __init__(self, paths, inputs=("obs_pixels",), targets=("action",), rows=None):
        if isinstance(paths, (str, Path)):
            paths = [paths]
        self.inputs, self.targets = tuple(inputs), tuple(targets)
        self.arrays = load_arrays(paths, self.inputs + self.targets)
        self.episode = self.arrays["episode"]
        self.rows = np.arange(len(self.episode)) if rows is None else np.asarray(rows)

    def subset(self, rows) -> "TrajectoryDataset":
        other = object.__new__(TrajectoryDataset)
        other.__dict__.update(self.__dict__)
        other.rows = self.rows[np.asarray(rows)]
        return other

    def __len__(self) -> int:
        return len(self.rows)

    def __getitem__(self, index):
        import torch

        row = self.rows[index]
        out = []
        for key in self.inputs + self.targets:
            value = self.arrays[key][row]
            value = value.astype(np.float32) / 255.0 if value.dtype == np.uint8 else np.asarray(value, np.float32)
            out.append(torch.from_numpy(np.atleast_1d(value)))
        return tuple(out)
