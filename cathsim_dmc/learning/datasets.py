"""Datasets from trajectory files, for behavioural cloning and force prediction.

    from cathsim_dmc.learning.datasets import TrajectoryDataset, load_arrays
    data = TrajectoryDataset(["run/trajectories.npz"], inputs=("obs_pixels",), targets=("action",))
    image, action = data[0]          # float32 tensors: image in [0, 1], (1, 80, 80)
    arrays = load_arrays(["outputs/collect/bca-type1/<run>"], ("obs_pixels", "action"), before_action=True)

A path is a trajectory file or a folder: a `cathsim-collect` dataset (its
`shard_*.npz`, in order) or a run folder with a `trajectories.npz`. Only the keys asked
for are read from each file (an uncompressed shard reads one key without touching the
others), and episode ids are renumbered so they are unique across files.

Episodes stay whole: `split_by_episode` holds out complete episodes, so that test
samples never come from an episode the model was trained on.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np

from cathsim_dmc.core.run_files import is_temporary
from cathsim_dmc.evaluation.trajectory import SCHEMA_VERSION

MANIFEST = "manifest.json"  # a cathsim-collect dataset's description (supervised/collect.py)

SHARD_GLOB = "shard_*.npz"


def expand_paths(paths) -> list:
    """Trajectory files named by `paths` (files, dataset folders, run folders), in order."""
    if isinstance(paths, (str, Path)):
        paths = [paths]
    files = []
    for path in map(Path, paths):
        if path.is_file():
            files.append(path)
        elif path.is_dir():
            found = (
                _manifest_shards(path)
                or sorted(p for p in path.glob(SHARD_GLOB) if not is_temporary(p))
                or sorted(path.glob("trajectories.npz"))
            )
            if not found:
                raise FileNotFoundError(
                    f"{path} holds no dataset ({SHARD_GLOB} or trajectories.npz); collect one with cathsim-collect"
                )
            files.extend(found)
        else:
            raise FileNotFoundError(f"no dataset at {path}")
    if not files:
        raise FileNotFoundError("no dataset given")
    return files


def read_manifest(path) -> dict:
    """A dataset's manifest.json, or ValueError naming the file if it is not readable JSON."""
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ValueError(
            f"{path} is not a readable {MANIFEST} ({type(error).__name__}: {error}); "
            f"delete it and run cathsim-collect on the folder again (finished shards are kept)"
        ) from error


def _manifest_shards(folder: Path) -> list:
    """The shards a cathsim-collect manifest lists (a run asked for fewer episodes than an
    earlier one may leave more shard files than the dataset holds)."""
    manifest = folder / MANIFEST
    if not manifest.is_file():
        return []
    return [folder / shard["file"] for shard in read_manifest(manifest).get("shards", [])]


def read_keys(path, keys) -> dict:
    """`keys` of one trajectory file (and nothing else), with the schema checked."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            version = int(data["schema_version"]) if "schema_version" in data.files else -1
            if version != SCHEMA_VERSION:
                raise ValueError(f"{path} has trajectory schema {version}; this version reads schema {SCHEMA_VERSION}")
            missing = [k for k in keys if k not in data.files]
            if missing:
                hint = (
                    " (record observations with save_observations=true, or collect with cathsim-collect)"
                    if any(k.startswith(("obs_", "start_")) for k in missing)
                    else ""
                )
                raise ValueError(f"{path} has no {missing}{hint}; it has {sorted(data.files)}")
            return {key: data[key] for key in keys}
    except (OSError, EOFError, TypeError, AttributeError, zipfile.BadZipFile) as error:
        raise _unreadable(path, error) from error
    except ValueError as error:
        if str(path) in str(error):
            raise
        raise _unreadable(path, error) from error


def _unreadable(path, error) -> ValueError:
    # NumPy reads a file that is no .npz archive (a CSV, say) as a pickle, and refuses that
    reason = "not an .npz archive" if "pickle" in str(error) else f"{type(error).__name__}: {error}"
    return ValueError(
        f"{path} is not a readable trajectory file ({reason}); cathsim-eval and cathsim-collect write them"
    )


def has_keys(paths, keys) -> bool:
    """Whether every trajectory file of `paths` holds all of `keys` (nothing is read)."""
    for path in expand_paths(paths):
        try:
            with np.load(path, allow_pickle=False) as data:
                if not set(keys) <= set(data.files):
                    return False
        except (OSError, EOFError, ValueError, TypeError, AttributeError, zipfile.BadZipFile) as error:
            raise _unreadable(path, error) from error
    return True


def _is_observation(key: str) -> bool:
    return key.startswith("obs_") or key == "feature_z"


def _before_action(values, start, episode, step):
    """Row i's value as it was when row i's action was chosen: the previous row's
    observation, or the episode's reset observation for its first step."""
    out = np.empty_like(values)
    out[1:] = values[:-1]
    first = step == 1
    out[first] = start[episode[first]]
    return out


def load_arrays(paths, keys, before_action: bool = False) -> dict:
    """Concatenate `keys` (and a global `episode` id) over trajectory files and folders.

    Rows hold the observation *after* their action. With `before_action`, observation
    keys (`obs_<key>`, `feature_z`) are shifted to the observation the action was chosen
    from, which is what behavioural cloning pairs with the action; this needs the
    reset observations (`start_obs_<key>`) that cathsim-collect records.
    """
    keys = tuple(keys)
    parts = {key: [] for key in keys}
    episodes, offset = [], 0
    for path in expand_paths(paths):
        shifted = [k for k in keys if before_action and _is_observation(k)]
        extra = ["episode", "step"] + [f"start_{k}" for k in shifted]
        arrays = read_keys(path, tuple(dict.fromkeys(keys + tuple(extra))))
        for key in keys:
            value = arrays[key]
            if key in shifted:
                value = _before_action(value, arrays[f"start_{key}"], arrays["episode"], arrays["step"])
            parts[key].append(value)
        episodes.append(arrays["episode"] + offset)
        offset += int(arrays["episode"].max()) + 1 if len(arrays["episode"]) else 0
    out = {key: np.concatenate(values) for key, values in parts.items()}
    out["episode"] = np.concatenate(episodes)
    if len(out["episode"]) == 0:
        raise ValueError(
            f"the dataset {[str(p) for p in ([paths] if isinstance(paths, (str, Path)) else paths)]} has no samples"
        )
    return out


def stack_frames(images: np.ndarray, episode: np.ndarray, step: np.ndarray, frames: int) -> np.ndarray:
    """(N, frames * C, H, W): each row's image preceded by the `frames - 1` images before
    it in its episode, oldest first, stacked along the channels. Where an episode has no
    earlier image its first one repeats, as a policy's frame buffer starts after a reset.

    Rows of an episode must be contiguous and in step order (1, 2, ...), as `load_arrays`
    returns them.
    """
    frames = int(frames)
    if frames < 1:
        raise ValueError(f"frames={frames} must be at least 1")
    if frames == 1:
        return images
    rows = np.arange(len(images))
    first = rows - (np.asarray(step) - 1)
    if len(rows) and (first.min() < 0 or not np.array_equal(episode[first], episode)):
        raise ValueError("stack_frames needs each episode's rows contiguous and in step order")
    index = np.maximum(rows[:, None] - np.arange(frames - 1, -1, -1)[None, :], first[:, None])
    n, channels, height, width = images.shape
    return images[index].reshape(n, frames * channels, height, width)


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

    def __init__(self, paths, inputs=("obs_pixels",), targets=("action",), rows=None, before_action: bool = False):
        self.inputs, self.targets = tuple(inputs), tuple(targets)
        self.arrays = load_arrays(paths, self.inputs + self.targets, before_action=before_action)
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
