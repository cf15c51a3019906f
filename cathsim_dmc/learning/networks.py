"""Feature extractors for stable-baselines3: the expert navigation network (ENN).

The paper's ENN encodes every modality separately and concatenates the codes into Z:

* each image (top view ``pixels``, ``guidewire_mask``; 1 x 80 x 80 uint8) goes through
  Conv2d(32, 8, stride 4) -> Conv2d(64, 4, stride 2) -> Conv2d(64, 3, stride 1), ReLU
  after each, flatten, Linear(256) + ReLU;
* the joint positions and velocities, concatenated, go through Linear(256) -> ReLU ->
  Linear(128) -> ReLU (with them any other vector observation the task was asked for,
  such as ``wire_slack`` or ``drive_force``).

`LayerNormSACPolicy` is SB3's SAC policy with layer normalisation after every hidden
layer of the critics (as in RLPD, Ball et al. 2023): it keeps Q-values from running away
when the batch mixes an expert's transitions with the agent's own.

A single-modality baseline is the same network over the subset of keys its
observation preset enables (see `cathsim_dmc.tasks.presets.OBSERVATION_PRESETS`).
"""

from __future__ import annotations

import gymnasium
import numpy as np
import torch
from stable_baselines3.common.policies import ContinuousCritic
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, create_mlp
from stable_baselines3.sac.policies import MultiInputPolicy
from torch import nn

IMAGE_KEYS = ("pixels", "guidewire_mask", "roadmap_overlay")
JOINT_KEYS = ("joint_pos", "joint_vel")
IMAGE_FEATURES = 256
JOINT_FEATURES = 128


def image_encoder(channels: int, height: int, width: int, features: int = IMAGE_FEATURES) -> nn.Module:
    """The paper's CNN for one image modality (uint8 input scaled to [0, 1] by the caller)."""
    conv = nn.Sequential(
        nn.Conv2d(channels, 32, kernel_size=8, stride=4),
        nn.ReLU(),
        nn.Conv2d(32, 64, kernel_size=4, stride=2),
        nn.ReLU(),
        nn.Conv2d(64, 64, kernel_size=3, stride=1),
        nn.ReLU(),
        nn.Flatten(),
    )
    with torch.no_grad():
        flat = conv(torch.zeros(1, channels, height, width)).shape[1]
    return nn.Sequential(conv, nn.Linear(flat, features), nn.ReLU())


def joint_encoder(inputs: int) -> nn.Module:
    return nn.Sequential(nn.Linear(inputs, 256), nn.ReLU(), nn.Linear(256, JOINT_FEATURES), nn.ReLU())


class ENNExtractor(BaseFeaturesExtractor):
    """Z = concat(CNN(image) for each image key, MLP(joint_pos ++ joint_vel))."""

    def __init__(self, observation_space: gymnasium.spaces.Dict):
        keys = set(observation_space.spaces)
        image_keys = [k for k in IMAGE_KEYS if k in keys]
        # Joint state first, then any other vector observation, in a fixed order.
        joint_keys = [k for k in JOINT_KEYS if k in keys] + sorted(keys - set(IMAGE_KEYS) - set(JOINT_KEYS))
        flat = [k for k in joint_keys if len(observation_space[k].shape) != 1]
        if flat:
            raise ValueError(f"ENNExtractor takes images {IMAGE_KEYS} and vectors; {flat} are neither")
        joint_size = sum(int(observation_space[k].shape[0]) for k in joint_keys)
        features = IMAGE_FEATURES * len(image_keys) + (JOINT_FEATURES if joint_keys else 0)
        super().__init__(observation_space, features_dim=features)
        self.image_keys, self.joint_keys = image_keys, joint_keys
        self.images = nn.ModuleDict({k: image_encoder(*observation_space[k].shape) for k in image_keys})
        self.joints = joint_encoder(joint_size) if joint_keys else None

    def forward(self, observations: dict) -> torch.Tensor:
        # SB3 has already turned uint8 images into floats in [0, 1] (normalize_images).
        codes = [self.images[k](observations[k]) for k in self.image_keys]
        if self.joints is not None:
            codes.append(self.joints(torch.cat([observations[k] for k in self.joint_keys], dim=1)))
        return torch.cat(codes, dim=1)


class LayerNormCritic(ContinuousCritic):
    """SB3's ContinuousCritic with LayerNorm after each hidden Linear layer."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        action_dim = int(np.prod(kwargs["action_space"].shape))
        for idx in range(len(self.q_networks)):
            q_net = nn.Sequential(
                *create_mlp(
                    kwargs["features_dim"] + action_dim,
                    1,
                    kwargs["net_arch"],
                    kwargs.get("activation_fn", nn.ReLU),
                    post_linear_modules=[nn.LayerNorm],
                )
            )
            self.add_module(f"qf{idx}", q_net)
            self.q_networks[idx] = q_net


class LayerNormSACPolicy(MultiInputPolicy):
    """SAC's multi-input policy whose critics normalise every hidden layer."""

    def make_critic(self, features_extractor=None):
        critic_kwargs = self._update_features_extractor(self.critic_kwargs, features_extractor)
        return LayerNormCritic(**critic_kwargs).to(self.device)
