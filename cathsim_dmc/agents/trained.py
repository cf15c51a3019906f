"""Trained agents as policies: a checkpoint of cathsim-train (SAC) or cathsim-bc loaded
into a function (observation, env) -> action, like the built-in ones of
`cathsim_dmc.control.policies`.

    policy = make_policy("outputs/train/bca-type1/internal/<run>")  # or "expert", "random" ...

This module sits above the learning packages (rl/, supervised/) and the policies, which
import none of it: loading a checkpoint needs SB3 and torch, a scripted policy does not.
"""

from __future__ import annotations

import json
import pickle
import zipfile
from pathlib import Path

import numpy as np

from cathsim_dmc.control.policies import BUILTIN_POLICIES
from cathsim_dmc.control.policies import make_policy as make_builtin_policy
from cathsim_dmc.core.run_files import POLICY_FILE, load_normalizer, normalizer_path, read_policy_file
from cathsim_dmc.core.shipped import assets_root


class CheckpointPolicy:
    """A trained agent loaded from a checkpoint; acts deterministically on observations.

    :param model: an object with SB3's ``predict(observation, deterministic)`` (a SAC model
        or a loaded cathsim-bc student)
    :param obs_preset: the observation preset it was trained with
    :param image_options: the renderer and style it was trained with
    :param env_options: environment options it was trained with that change what it sees
        or drives (e.g. extra observations, the physics settings)
    :param normalizer: SB3's VecNormalize with the training's observation statistics, or None
    :param path: the file it was loaded from (None: a model in memory)
    """

    def __init__(
        self,
        model,
        obs_preset: str,
        image_options: dict | None = None,
        env_options: dict | None = None,
        normalizer=None,
        path=None,
    ):
        self.model = model
        self.obs_preset = obs_preset
        self.image_options = dict(image_options or {})
        self.env_options = dict(env_options or {})
        self.normalizer = normalizer
        self.path = None if path is None else Path(path)

    def __call__(self, observation, env) -> np.ndarray:
        # A model with memory (a frame-stacking student) starts afresh with each episode.
        if hasattr(self.model, "reset") and getattr(getattr(env, "task", None), "step_count", None) == 0:
            self.model.reset()
        if self.normalizer is not None:
            observation = self.normalizer.normalize_obs(observation)
        action, _ = self.model.predict(observation, deterministic=True)
        return np.asarray(action, dtype=np.float32)


def find_checkpoint(path) -> Path:
    """The model file for `path`: a checkpoint file itself, or in a run folder the one its
    own final report evaluated: checkpoints/best.zip when the run kept one (and its
    config.yaml does not say trainer.final_policy=final), else the final model, else the
    last checkpoint of a run that did not finish. A folder with none of these is refused
    (FileNotFoundError): another .zip in it is not the run's agent."""
    path = Path(path)
    if path.is_file():
        return path
    if path.is_dir():
        best = path / "checkpoints" / "best.zip"
        candidates = [path / "final_model.zip", path / "checkpoints" / "last.zip", path / "bc_policy.pt"]
        candidates.insert(0 if _final_policy(path) == "best" else len(candidates), best)
        for candidate in candidates:
            if candidate.is_file():
                return candidate
        raise FileNotFoundError(
            f"{path} holds none of checkpoints/best.zip, final_model.zip, checkpoints/last.zip (a cathsim-train "
            "run) or bc_policy.pt (a cathsim-bc run); for another checkpoint give its file"
        )
    raise FileNotFoundError(f"no checkpoint at {path}")


def _final_policy(run_dir: Path) -> str:
    """trainer.final_policy of a cathsim-train run folder ("best" when it does not say)."""
    saved = run_dir / "config.yaml"
    if not saved.is_file():
        return "best"
    from omegaconf import OmegaConf

    return str(OmegaConf.select(OmegaConf.load(saved), "trainer.final_policy", default="best"))


def policy_info(path) -> tuple[Path, dict]:
    """(model file, its policy.json) of a checkpoint file or run folder: the observation preset,
    image and environment options, task and aorta it was trained with. The policy.json is the
    one beside the model, or in the run folder above it."""
    model_path = find_checkpoint(path)
    for folder in (model_path.parent, model_path.parent.parent):
        info_file = folder / POLICY_FILE
        if info_file.is_file():
            try:
                return model_path, read_policy_file(info_file, what=model_path)
            except json.JSONDecodeError as error:
                raise ValueError(f"{info_file} is not readable JSON ({error})") from None
    raise FileNotFoundError(f"{model_path} has no {POLICY_FILE} beside it; was it written by cathsim-train?")


def recorded_env_options(name: str, task: str | None = None) -> dict | None:
    """The environment options a trained agent records (its policy.json, or the shipped
    navigator's metadata for `task`), read without loading it; None for a built-in policy."""
    if name in BUILTIN_POLICIES:
        return None
    if name in PRETRAINED_KINDS and not Path(name).exists():
        meta = policy_files(task, kind=name)[1] if task else None
        if meta is None or not meta.is_file():
            return None  # no navigator for the task: load_pretrained says so
        return json.loads(meta.read_text()).get("env_options") or {}
    return policy_info(name)[1].get("env_options") or {}


def check_catheter(policy_name: str, catheter, env_options: dict) -> None:
    """ValueError when a catheter is asked of an agent trained without one: it sees and drives
    the guidewire alone, and the catheter's joints would not fit its observations."""
    if catheter and not env_options.get("catheter"):
        raise ValueError(
            f"task.catheter={catheter!r}, but policy={policy_name} was trained without a catheter (it drives the "
            f"guidewire alone; its options: {dict(env_options)}); leave task.catheter out"
        )


def load_checkpoint_policy(path) -> CheckpointPolicy:
    """Load a checkpoint written by cathsim-train (or cathsim-bc).

    Its `policy.json` (next to it, or in the run folder above) names the algorithm and
    the observation preset the agent was trained with. A checkpoint of another version's
    run format fails in one line (ValueError, `run_files.read_policy_file`).
    """
    model_path, info = policy_info(path)
    algo = info.get("algo", "sac")
    try:
        if algo == "sac":
            from cathsim_dmc.learning.rl.checkpoints import load_policy_model

            # the recipe's deterministic policy: SACfD's averaged actor, as evaluated in training
            model = load_policy_model(model_path)
        elif algo == "bc":
            from cathsim_dmc.learning.supervised.bc import load_bc_policy

            model = load_bc_policy(model_path)
        else:
            raise ValueError(f"{model_path}: unknown algorithm {algo!r} in {POLICY_FILE}")
    except (OSError, KeyError, RuntimeError, EOFError, ValueError, zipfile.BadZipFile, pickle.UnpicklingError) as error:
        raise ValueError(f"{model_path} is not a readable checkpoint ({type(error).__name__}: {error})") from error
    normalizer = None
    if info.get("normalize_observations"):
        stats = normalizer_path(model_path)
        if not stats.is_file():
            raise FileNotFoundError(
                f"{model_path} was trained with normalised observations but {stats.name} is missing beside it"
            )
        try:
            normalizer = load_normalizer(stats)
        except (OSError, EOFError, AttributeError, pickle.UnpicklingError) as error:
            raise ValueError(f"{stats} is not a readable normaliser ({type(error).__name__}: {error})") from error
    return CheckpointPolicy(
        model, info["obs"], info.get("image_options"), info.get("env_options"), normalizer, path=model_path
    )


# -- the shipped navigators (cathsim_dmc.agents.pretrained writes them) ----------------------
PRETRAINED = "pretrained"  # the policy name the tools accept (policy=pretrained)
PRETRAINED_FLUORO = "pretrained_fluoro"  # the navigator that reads only what a C-arm shows
# policy= name -> the stem of its files in assets/policies/: <stem>_<target>.pt, .json, .md
PRETRAINED_KINDS = {PRETRAINED: "navigator", PRETRAINED_FLUORO: "navigator_fluoro"}
POLICY_FOLDER = "policies"


def policy_files(target: str, folder: Path | None = None, kind: str = PRETRAINED) -> tuple[Path, Path, Path]:
    """(weights .pt, metadata .json, model card .md) of the shipped navigator of `kind` (a
    key of PRETRAINED_KINDS) for `target`."""
    folder = Path(folder) if folder is not None else assets_root() / POLICY_FOLDER
    stem = folder / f"{PRETRAINED_KINDS[kind]}_{target}"
    return stem.with_suffix(".pt"), stem.with_suffix(".json"), stem.with_suffix(".md")


def shipped_targets(folder: Path | None = None, kind: str = PRETRAINED) -> tuple:
    """The targets with a shipped navigator of `kind`."""
    folder = Path(folder) if folder is not None else assets_root() / POLICY_FOLDER
    prefix = f"{PRETRAINED_KINDS[kind]}_"
    # navigator_fluoro_lcca.pt also starts with "navigator_": a target is one word
    names = (p.stem.removeprefix(prefix) for p in folder.glob(f"{prefix}*.pt"))
    return tuple(sorted(name for name in names if "_" not in name))


def _spaces(meta: dict):
    from gymnasium import spaces

    observation = spaces.Dict(
        {
            key: spaces.Box(-np.inf, np.inf, shape=tuple(shape), dtype=np.float32)
            for key, shape in meta["observation_shapes"].items()
        }
    )
    action = spaces.Box(-1.0, 1.0, shape=(int(meta["action_size"]),), dtype=np.float32)
    return observation, action


def _policy(meta: dict):
    """SB3's SAC policy with the shipped network's shape (its actor is what is loaded)."""
    from stable_baselines3.sac.policies import MultiInputPolicy

    from cathsim_dmc.learning.networks import ENNExtractor

    observation, action = _spaces(meta)
    return MultiInputPolicy(
        observation,
        action,
        lr_schedule=lambda _: 0.0,
        net_arch=list(meta["net_arch"]),
        features_extractor_class=ENNExtractor,
        share_features_extractor=False,
    )


class PretrainedActor:
    """The shipped actor as a model with SB3's `predict(observation, deterministic)`."""

    def __init__(self, weights: Path, meta: dict):
        import torch

        self.meta = meta
        self.policy = _policy(meta)
        state = torch.load(weights, map_location="cpu", weights_only=True)
        self.policy.actor.load_state_dict(state)
        self.policy.set_training_mode(False)

    def predict(self, observation, deterministic: bool = True):
        return self.policy.predict(observation, deterministic=deterministic)


def load_pretrained(target: str, folder: Path | None = None, kind: str = PRETRAINED):
    """The shipped navigator of `kind` (policy=pretrained, the 3-D tracked roadmap's, or
    policy=pretrained_fluoro, the C-arm's) for `target` as a `CheckpointPolicy` (ValueError
    naming the targets that have one)."""
    weights, meta_path, _ = policy_files(target, folder, kind)
    if not weights.is_file():
        shipped = list(shipped_targets(folder, kind))
        raise ValueError(f"no {kind} navigator for task={target!r}; shipped: {shipped}")
    meta = json.loads(meta_path.read_text())
    return CheckpointPolicy(
        PretrainedActor(weights, meta), meta["obs"], meta.get("image_options"), meta.get("env_options"), path=weights
    )


def make_policy(name: str, seed: int = 0, task: str | None = None):
    """A built-in policy by name (`cathsim_dmc.control.policies.BUILTIN_POLICIES`), the shipped
    navigator for `task` ("pretrained", `cathsim_dmc.agents.pretrained`), or a trained agent by
    the path of its checkpoint or run folder."""
    if name in BUILTIN_POLICIES:
        return make_builtin_policy(name, seed=seed)
    if name in PRETRAINED_KINDS and not Path(name).exists():
        if task is None:
            raise ValueError(f"policy={name} needs the task (bca or lcca) it navigates to")
        return load_pretrained(task, kind=name)
    if Path(name).exists():
        return load_checkpoint_policy(name)
    raise ValueError(
        f"policy={name!r} is neither a built-in policy {sorted(BUILTIN_POLICIES)}, one of "
        f"{sorted(PRETRAINED_KINDS)}, nor a checkpoint path"
    )
