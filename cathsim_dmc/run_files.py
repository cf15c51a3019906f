"""Files beside a checkpoint, shared by their writers (rl/train.py, rl/bc.py) and their
reader (policies.py), so that neither side imports the other."""

from __future__ import annotations

import pickle
from pathlib import Path

POLICY_FILE = "policy.json"  # next to a checkpoint: what it needs to be evaluated
NORMALIZER_SUFFIX = ".vecnormalize.pkl"  # <checkpoint>.vecnormalize.pkl: its observation normaliser


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
