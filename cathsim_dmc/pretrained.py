"""Pretrained navigators shipped with the package: the actor's weights only, with a model card.

    from cathsim_dmc.pretrained import load_pretrained
    policy = load_pretrained("lcca")          # a CheckpointPolicy: action = policy(observation, env)

    cathsim-eval policy=pretrained task=lcca aorta=type3       # any shipped name or asset folder

Each target has three files in `assets/policies/`: `navigator_<target>.pt` (the actor's
state dict and the network's shape), `navigator_<target>.json` (the observation preset,
its options and how it was trained) and `navigator_<target>.md` (the model card: the
training command, the commit, the data, the results and the known limits). The actor is
SB3's SAC actor over this package's feature extractor, rebuilt from the saved shapes: no
critic, optimiser or replay buffer is shipped.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from cathsim_dmc.paths import assets_root

PRETRAINED = "pretrained"  # the policy name the tools accept (policy=pretrained)
POLICY_FOLDER = "policies"


def policy_files(target: str, folder: Path | None = None) -> tuple[Path, Path, Path]:
    """(weights .pt, metadata .json, model card .md) of the shipped navigator for `target`."""
    folder = Path(folder) if folder is not None else assets_root() / POLICY_FOLDER
    stem = folder / f"navigator_{target}"
    return stem.with_suffix(".pt"), stem.with_suffix(".json"), stem.with_suffix(".md")


def shipped_targets(folder: Path | None = None) -> tuple:
    folder = Path(folder) if folder is not None else assets_root() / POLICY_FOLDER
    return tuple(sorted(p.stem.removeprefix("navigator_") for p in folder.glob("navigator_*.pt")))


def _spaces(meta: dict):
    import gymnasium
    from gymnasium import spaces

    observation = spaces.Dict({key: spaces.Box(-np.inf, np.inf, shape=tuple(shape), dtype=np.float32)
                               for key, shape in meta["observation_shapes"].items()})
    action = spaces.Box(-1.0, 1.0, shape=(int(meta["action_size"]),), dtype=np.float32)
    assert isinstance(observation, gymnasium.spaces.Dict)
    return observation, action


def _policy(meta: dict):
    """SB3's SAC policy with the shipped network's shape (its actor is what is loaded)."""
    from stable_baselines3.sac.policies import MultiInputPolicy

    from cathsim_dmc.rl.features import ENNExtractor

    observation, action = _spaces(meta)
    return MultiInputPolicy(observation, action, lr_schedule=lambda _: 0.0, net_arch=list(meta["net_arch"]),
                            features_extractor_class=ENNExtractor, share_features_extractor=False)


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


def load_pretrained(target: str, folder: Path | None = None):
    """The shipped navigator for `target` as a `CheckpointPolicy` (ValueError naming the
    targets that have one)."""
    from cathsim_dmc.agents import CheckpointPolicy

    weights, meta_path, _ = policy_files(target, folder)
    if not weights.is_file():
        raise ValueError(f"no pretrained navigator for task={target!r}; shipped: {list(shipped_targets(folder))}")
    meta = json.loads(meta_path.read_text())
    return CheckpointPolicy(PretrainedActor(weights, meta), meta["obs"], meta.get("image_options"),
                            meta.get("env_options"), path=weights)


def export_actor(checkpoint, target: str, card: str, folder: Path | None = None, trained: dict | None = None) -> Path:
    """Write the actor of a cathsim-train `checkpoint` (a .zip or a run folder: the policy
    its report evaluated) as the shipped navigator for `target`, with the model card
    `card` (markdown) and `trained` (how it was trained) in its metadata. Returns the .pt."""
    import torch

    from cathsim_dmc.agents import load_checkpoint_policy

    policy = load_checkpoint_policy(checkpoint)
    if policy.normalizer is not None:
        raise ValueError(f"{checkpoint} was trained with normalised observations; a shipped actor has no normaliser")
    model = policy.model
    extractor_kwargs = model.policy_kwargs
    meta = {
        "target": target,
        "obs": policy.obs_preset,
        "image_options": policy.image_options,
        "env_options": policy.env_options,
        "observation_shapes": {k: list(s.shape) for k, s in model.observation_space.spaces.items()},
        "action_size": int(model.action_space.shape[0]),
        "net_arch": list(extractor_kwargs.get("net_arch", [256, 256])),
        "trained": dict(trained or {}),
    }
    weights, meta_path, card_path = policy_files(target, folder)
    weights.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().to(torch.float32).clone() for k, v in model.actor.state_dict().items()}
    torch.save(state, weights)
    meta_path.write_text(json.dumps(meta, indent=2) + "\n")
    card_path.write_text(card)
    return weights
