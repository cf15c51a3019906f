"""Policies for evaluation and data collection: functions from (observation, env) to an action.

`env` is a `cathsim_dmc.gym.CathSimEnv`; built-in policies may use it (the expert reads
privileged state through it), learned ones only look at the observation.
"""

from __future__ import annotations

import json
import pickle
import zipfile
from pathlib import Path

import numpy as np

from cathsim_dmc.run_files import POLICY_FILE, is_temporary, load_normalizer, normalizer_path  # noqa: F401  (public here too)


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


def _expert(seed: int = 0):
    from cathsim_dmc.experts import CenterlineExpert

    return CenterlineExpert()


BUILTIN_POLICIES = {"forward": lambda seed=0: ForwardPolicy(), "random": RandomPolicy, "adversarial": AdversarialPolicy,
                    "expert": _expert}


class CheckpointPolicy:
    """A trained agent loaded from a checkpoint; acts deterministically on observations."""

    def __init__(self, model, obs_preset: str, image_options: dict | None = None, env_options: dict | None = None,
                 normalizer=None):
        self.model = model
        self.obs_preset = obs_preset
        self.image_options = dict(image_options or {})  # renderer, style it was trained with
        self.env_options = dict(env_options or {})  # e.g. the insertion limit it was trained with
        self.normalizer = normalizer  # SB3 VecNormalize with the training's observation statistics

    def __call__(self, observation, env) -> np.ndarray:
        # A model with memory (a frame-stacking student) starts afresh with each episode.
        if hasattr(self.model, "reset") and getattr(getattr(env, "task", None), "step_count", None) == 0:
            self.model.reset()
        if self.normalizer is not None:
            observation = self.normalizer.normalize_obs(observation)
        action, _ = self.model.predict(observation, deterministic=True)
        return np.asarray(action, dtype=np.float32)


def find_checkpoint(path) -> Path:
    """The model file for `path`: a checkpoint file itself, or the newest one in a run folder."""
    path = Path(path)
    if path.is_file():
        return path
    if path.is_dir():
        for candidate in (path / "final_model.zip", path / "checkpoints" / "last.zip", path / "bc_policy.pt"):
            if candidate.is_file():
                return candidate
        zips = sorted((p for p in path.glob("**/*.zip") if not is_temporary(p)), key=lambda p: p.stat().st_mtime)
        if zips:
            return zips[-1]
        raise FileNotFoundError(f"no checkpoint (.zip, or bc_policy.pt from cathsim-bc) in {path}")
    raise FileNotFoundError(f"no checkpoint at {path}")


def load_checkpoint_policy(path) -> CheckpointPolicy:
    """Load a checkpoint written by cathsim-train (or cathsim-bc).

    Its `policy.json` (next to it, or in the run folder above) names the algorithm and
    the observation preset the agent was trained with.
    """
    model_path = find_checkpoint(path)
    info = None
    for folder in (model_path.parent, model_path.parent.parent):
        if (folder / POLICY_FILE).is_file():
            info = json.loads((folder / POLICY_FILE).read_text())
            break
    if info is None:
        raise FileNotFoundError(f"{model_path} has no {POLICY_FILE} beside it; was it written by cathsim-train?")
    algo = info.get("algo", "sac")
    try:
        if algo == "sac":
            from stable_baselines3 import SAC

            model = SAC.load(model_path, device="cpu")
        elif algo == "bc":
            from cathsim_dmc.supervised.bc import load_bc_policy

            model = load_bc_policy(model_path)
        else:
            raise ValueError(f"{model_path}: unknown algorithm {algo!r} in {POLICY_FILE}")
    except (OSError, KeyError, RuntimeError, EOFError, ValueError, zipfile.BadZipFile, pickle.UnpicklingError) as error:
        raise ValueError(f"{model_path} is not a readable checkpoint ({type(error).__name__}: {error})") from error
    normalizer = None
    if info.get("normalize_observations"):
        stats = normalizer_path(model_path)
        if not stats.is_file():
            raise FileNotFoundError(f"{model_path} was trained with normalised observations but {stats.name} "
                                    f"is missing beside it")
        try:
            normalizer = load_normalizer(stats)
        except (OSError, EOFError, AttributeError, pickle.UnpicklingError) as error:
            raise ValueError(f"{stats} is not a readable normaliser ({type(error).__name__}: {error})") from error
    return CheckpointPolicy(model, info["obs"], info.get("image_options"), info.get("env_options"), normalizer)


def make_policy(name: str, seed: int = 0):
    """A built-in policy by name, or a checkpoint by path."""
    if name in BUILTIN_POLICIES:
        return BUILTIN_POLICIES[name](seed=seed)
    if Path(name).exists():
        return load_checkpoint_policy(name)
    raise ValueError(f"policy={name!r} is neither a built-in policy {sorted(BUILTIN_POLICIES)} nor a checkpoint path")
