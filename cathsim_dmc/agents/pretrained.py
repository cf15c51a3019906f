"""Pretrained navigators shipped with the package: the actor's weights only, with a model card.
This module writes them (`export_actor`); cathsim_dmc.agents.trained loads them.

    from cathsim_dmc.agents.trained import load_pretrained
    policy = load_pretrained("lcca")          # a CheckpointPolicy: action = policy(observation, env)

    cathsim-eval policy=pretrained task=lcca aorta=type3       # any shipped name or asset folder
    cathsim-eval policy=pretrained_fluoro task=lcca aorta=type3   # from what a C-arm shows

`policy=pretrained` reads the roadmap around the wire's tip tracked in 3-D;
`policy=pretrained_fluoro` reads only the image plane's tracking, the projected roadmap,
the C-arm's angles and the robot's encoders (its files are `navigator_fluoro_<target>.*`).
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

from cathsim_dmc.agents.trained import PRETRAINED, policy_files


def export_actor(
    checkpoint,
    target: str,
    card: str,
    folder: Path | None = None,
    trained: dict | None = None,
    kind: str = PRETRAINED,
) -> Path:
    """Write the actor of a cathsim-train `checkpoint` (a .zip or a run folder: the policy
    its report evaluated) as the shipped navigator of `kind` (policy=pretrained or
    policy=pretrained_fluoro) for `target`, with the model card `card` (markdown) and
    `trained` (how it was trained) in its metadata. Returns the .pt."""
    import torch

    from cathsim_dmc.agents.trained import load_checkpoint_policy

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
    weights, meta_path, card_path = policy_files(target, folder, kind)
    weights.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().to(torch.float32).clone() for k, v in model.actor.state_dict().items()}
    torch.save(state, weights)
    meta_path.write_text(json.dumps(meta, indent=2) + "\n")
    card_path.write_text(card)
    return weights
