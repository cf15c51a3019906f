"""Files beside a checkpoint, shared by their writers (rl/checkpoints.py, supervised/bc.py,
supervised/collect.py) and their readers (agents.py, supervised/data.py), so that neither
side imports the other.

Every file is written under a temporary name and renamed into place, so a reader never
sees half a file. A temporary name is hidden and carries `.tmp` (`.last.tmp.zip`), keeps
the real suffix (so SB3 and NumPy do not append another), never matches a reader's
pattern (`shard_*.npz`, `*.zip`), and is removed when a writer starts again."""

from __future__ import annotations

import os
import pickle
from pathlib import Path

POLICY_FILE = "policy.json"  # next to a checkpoint: what it needs to be evaluated
NORMALIZER_SUFFIX = ".vecnormalize.pkl"  # <checkpoint>.vecnormalize.pkl: its observation normaliser
TEMPORARY_MARK = ".tmp"


def temporary_path(path) -> Path:
    """Where `path` is written before it is renamed into place: `.<stem>.tmp<suffix>`."""
    path = Path(path)
    return path.with_name(f".{path.stem}{TEMPORARY_MARK}{path.suffix}")


def is_temporary(path) -> bool:
    """True for a half-written file (this module's temporary names, and the older
    `<name>.tmp...` ones), which readers skip."""
    return TEMPORARY_MARK in Path(path).name


def write_atomic(path, write) -> Path:
    """Call `write(temporary)` and rename the result to `path`: all of it or none of it."""
    path = Path(path)
    tmp = temporary_path(path)
    write(tmp)
    os.replace(tmp, path)
    return path


def remove_temporaries(folder) -> list:
    """Delete the half-written files a killed writer left in `folder` (not its subfolders)."""
    folder = Path(folder)
    stale = [p for p in folder.iterdir() if p.is_file() and is_temporary(p)] if folder.is_dir() else []
    for path in stale:
        path.unlink(missing_ok=True)
    return stale


def normalizer_path(checkpoint) -> Path:
    """Where the observation normaliser of `checkpoint` (a .zip) is kept: beside it."""
    checkpoint = Path(checkpoint)
    return checkpoint.with_name(checkpoint.stem + NORMALIZER_SUFFIX)


def load_normalizer(path):
    """A saved SB3 VecNormalize (observation statistics), frozen for evaluation."""
    with open(path, "rb") as f:
        normalizer = pickle.load(f)
    normalizer.training = False
    return normalizer
