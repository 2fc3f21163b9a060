"""SB3's features extractor for a policy that computes its own observation features (:mod:`dvrl_marl.suction_debris.features`).

The Dict observation is flattened key by key in the space's order (what SB3's ``CombinedExtractor`` and an exported
policy's ``observation_keys`` do) and the named features are appended, in torch, by the same arithmetic the exported
numpy policy runs before its first layer; the env stays as registered.
"""

from __future__ import annotations

import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

from dvrl_marl.suction_debris import features

__all__ = ["ObservationFeatures"]


class ObservationFeatures(BaseFeaturesExtractor):
    """``observation_space``'s keys flattened in order, then ``spec``'s features (``{"name": ..., **arguments}``)."""

    def __init__(self, observation_space: spaces.Dict, spec: dict):
        keys = list(observation_space.spaces)
        size = sum(int(np.prod(observation_space.spaces[key].shape)) for key in keys)
        super().__init__(observation_space, size + features.feature_count(spec.get("name")))
        self.keys = keys
        self.spec = dict(spec)

    def forward(self, observations: dict) -> torch.Tensor:
        flat = torch.cat([observations[key].flatten(1) for key in self.keys], dim=1)
        return features.apply(self.spec, flat)
