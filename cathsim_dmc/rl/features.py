"""Feature extractors for stable-baselines3: the expert navigation network (ENN).

The paper's ENN encodes every modality separately and concatenates the codes into Z:

* each image (top view ``pixels``, ``guidewire_mask``; 1 x 80 x 80 uint8) goes through
  Conv2d(32, 8, stride 4) -> Conv2d(64, 4, stride 2) -> Conv2d(64, 3, stride 1), ReLU
  after each, flatten, Linear(256) + ReLU;
* the joint positions and velocities, concatenated, go through Linear(256) -> ReLU ->
  Linear(128) -> ReLU.

A single-modality baseline is the same network over the subset of keys its
observation preset enables (see `cathsim_dmc.observables.OBSERVATION_PRESETS`).
"""

from __future__ import annotations

import gymnasium
import torch
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

IMAGE_KEYS = ("pixels", "guidewire_mask")
JOINT_KEYS = ("joint_pos", "joint_vel")
IMAGE_FEATURES = 256
JOINT_FEATURES = 128


def image_encoder(channels: int, height: int, width: int, features: int = IMAGE_FEATURES) -> nn.Module:
    """The paper's CNN for one image modality (uint8 input scaled to [0, 1] by the caller)."""
    conv = nn.Sequential(
        nn.Conv2d(channels, 32, kernel_size=8, stride=4), nn.ReLU(),
        nn.Conv2d(32, 64, kernel_size=4, stride=2), nn.ReLU(),
        nn.Conv2d(64, 64, kernel_size=3, stride=1), nn.ReLU(),
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
        joint_keys = [k for k in JOINT_KEYS if k in keys]
        unknown = keys - set(image_keys) - set(joint_keys)
        if unknown:
            raise ValueError(f"ENNExtractor does not know observation keys {sorted(unknown)}")
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
