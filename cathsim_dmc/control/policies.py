"""Policies for evaluation and data collection: functions from (observation, env) to an action.

`env` is a `cathsim_dmc.suite.gym.CathSimEnv`; built-in policies may use it (the expert reads
privileged state through it). Trained agents (checkpoints) are policies of the same
shape, loaded by `cathsim_dmc.agents.trained`; this module imports neither SB3 nor torch.
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

import numpy as np


class Policy(Protocol):
    """What evaluation, data collection and training call: the action for `observation`
    (a dict of arrays, as the environment returns it) in `env`, a `CathSimEnv`."""

    def __call__(self, observation, env) -> np.ndarray: ...


class ForwardPolicy:
    """Insert at full speed, never rotate."""

    def __call__(self, observation, env) -> np.ndarray:
        return with_catheter_parked(np.array([1.0, 0.0], dtype=np.float32), env)


class RandomPolicy:
    """Uniform random actions, seeded."""

    def __init__(self, seed: int = 0):
        self._rng = np.random.default_rng(seed)

    def __call__(self, observation, env) -> np.ndarray:
        return self._rng.uniform(-1.0, 1.0, size=_action_size(env)).astype(np.float32)


class AdversarialPolicy:
    """Stress actions for containment and force checks, seeded: bursts of 5-40 control
    steps, each of one mode drawn at random from `MODES`:

    * ``random``: uniform in [-1, 1]^2;
    * ``bang_bang``: each axis -1 or +1, held for 1-5 steps;
    * ``insert_rotate``: full insertion with full rotation one way (drives the wire to the
      end of its stroke and buckles it);
    * ``reversals``: insertion flips sign every step, rotation full one way.

    `mode` names the current burst's mode (for reports).
    """

    MODES = ("random", "bang_bang", "insert_rotate", "reversals")

    def __init__(self, seed: int = 0):
        self._rng = np.random.default_rng(seed)
        self._burst: list = []
        self.mode = None

    def _next_burst(self) -> None:
        rng = self._rng
        self.mode = self.MODES[rng.integers(len(self.MODES))]
        length = int(rng.integers(5, 41))
        if self.mode == "random":
            burst = list(rng.uniform(-1, 1, (length, 2)))
        elif self.mode == "bang_bang":
            burst = []
            while len(burst) < length:
                burst.extend([rng.choice([-1.0, 1.0], size=2)] * int(rng.integers(1, 6)))
            burst = burst[:length]
        elif self.mode == "insert_rotate":
            burst = [np.array([1.0, rng.choice([-1.0, 1.0])])] * length
        else:
            turn = rng.choice([-1.0, 1.0])
            burst = [np.array([1.0 if k % 2 == 0 else -1.0, turn]) for k in range(length)]
        self._burst = burst[::-1]  # popped from the end

    def __call__(self, observation=None, env=None) -> np.ndarray:
        if not self._burst:
            self._next_burst()
        return with_catheter_parked(np.asarray(self._burst.pop(), dtype=np.float32), env)


def _action_size(env) -> int:
    """Entries of `env`'s actions: 2, or 3 with a catheter (`Navigate.action_size`)."""
    return getattr(getattr(env, "task", None), "action_size", 2)


def with_catheter_parked(action: np.ndarray, env) -> np.ndarray:
    """A wire-only [insertion, rotation] `action`, with the catheter's carriage at rest
    (its entry 0) when `env` has a catheter."""
    missing = _action_size(env) - len(action)
    return np.concatenate([action, np.zeros(missing, dtype=action.dtype)]) if missing > 0 else action


def _expert(seed: int = 0, **options):
    from cathsim_dmc.control.expert import CenterlineExpert

    return CenterlineExpert(**options)


# The scripted experts: the policies that can demonstrate, take over and label in training.
EXPERT_POLICIES = {
    "expert": _expert,
    # the expert without turns on straight stretches: data for image-only students
    "expert_steady": lambda seed=0: _expert(seed, hold_rotation_on_straight=True),
}
BUILTIN_POLICIES = {
    "forward": lambda seed=0: ForwardPolicy(),
    "random": RandomPolicy,
    "adversarial": AdversarialPolicy,
    **EXPERT_POLICIES,
}


def make_policy(name: str, seed: int = 0):
    """A built-in policy by name (`BUILTIN_POLICIES`); a trained agent is loaded by
    `cathsim_dmc.agents.trained.make_policy`, which also takes these names."""
    if name in BUILTIN_POLICIES:
        return BUILTIN_POLICIES[name](seed=seed)
    if Path(name).exists():
        raise ValueError(
            f"policy={name!r} is a checkpoint path: cathsim_dmc.agents.trained.make_policy loads trained agents "
            f"(cathsim_dmc.control.policies holds the built-in ones, {sorted(BUILTIN_POLICIES)})"
        )
    raise ValueError(f"policy={name!r} is not a built-in policy {sorted(BUILTIN_POLICIES)}")
