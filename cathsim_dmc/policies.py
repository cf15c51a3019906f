"""Built-in baseline policies: functions from (observation, environment) to an action."""

from __future__ import annotations

import numpy as np


class ForwardPolicy:
    """Insert at full speed, never rotate."""

    def __call__(self, observation, env) -> np.ndarray:
        return np.array([1.0, 0.0], dtype=np.float32)


class RandomPolicy:
    """Uniform random actions, seeded."""

    def __init__(self, seed: int = 0):
        self._rng = np.random.default_rng(seed)

    def __call__(self, observation, env) -> np.ndarray:
        return self._rng.uniform(-1.0, 1.0, size=2).astype(np.float32)


BUILTIN_POLICIES = {"forward": ForwardPolicy, "random": RandomPolicy}


def make_policy(name: str, seed: int = 0):
    if name == "random":
        return RandomPolicy(seed)
    if name in BUILTIN_POLICIES:
        return BUILTIN_POLICIES[name]()
    raise ValueError(f"policy={name!r} is not a built-in policy; choose one of {sorted(BUILTIN_POLICIES)}")
