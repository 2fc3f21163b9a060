"""Observation features a policy computes from its own observation: the same arithmetic in numpy and torch.

A collaborative agent's observation lists every pin slot (position, visible, held, delivered; hidden pins read as
zeros, the workspace centre) and the hand-off point as absolute, normalised positions. What the grasper must act
on is a choice among those slots: the nearest pin still to collect, or, while it holds one, the way to the
assistant. A tanh network computes differences of positions easily (they are linear) but a masked minimum over
slots poorly (measured: beside the scripted suction the grasper's plain-observation actor held a pin in about half
of its lessons and still carried it toward a phantom target). :func:`suction_debris_targets` hands it that choice
as vectors relative to its own tip, from nothing but the agent's observation (no privileged state): the trainer's
actors read ``observation + features`` and the exported numpy policy computes the same features before its first
layer (its ``policy.json`` names them, see :func:`apply`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["suction_debris_targets", "feature_count", "apply", "FEATURES"]

#: A distance no pin in the normalised workspace reaches (masked slots).
_FAR = 1e6


class _Ops:
    """The handful of array operations that differ between numpy and torch."""

    def __init__(self, x):
        self.numpy = isinstance(x, np.ndarray)
        self.dtype = x.dtype
        if not self.numpy:
            import torch

            self.torch, self.device = torch, x.device

    def where(self, condition, a, b):
        return np.where(condition, a, b) if self.numpy else self.torch.where(condition, a, b)

    def concatenate(self, parts):
        return np.concatenate(parts, axis=-1) if self.numpy else self.torch.cat(parts, dim=-1)

    def as_float(self, mask):
        return mask.astype(self.dtype) if self.numpy else mask.to(self.dtype)

    def arange(self, count):
        return np.arange(count) if self.numpy else self.torch.arange(count, device=self.device)


def feature_count(name: str) -> int:
    """How many features ``name`` appends."""
    if name not in FEATURES:
        raise ValueError(f"unknown observation features {name!r} (known: {sorted(FEATURES)})")
    return FEATURES[name]


def suction_debris_targets(observation, *, cavities: int, debris: int):
    """``(..., obs_dim)`` -> ``(..., 14)``, for either agent of ``suction_debris_v0``/``v1``:

    - ``to_pin`` (3): from the agent's tip to the nearest pin that is visible, not held and not delivered (zeros
      when there is none), and ``has_pin`` (1): whether there is one;
    - ``holding`` (1): whether the grasper holds a pin; ``carry`` (3): from the held pin to the hand-off point
      (zeros when nothing is held);
    - ``to_handoff`` (3): from the tip to the hand-off point; ``to_other`` (3): from the tip to the other arm's tip.
    """
    ops = _Ops(observation)
    tip, other = observation[..., 0:3], observation[..., 4:7]
    first = 7 + cavities
    slots = observation[..., first:first + 6 * debris].reshape(*observation.shape[:-1], debris, 6)
    position = slots[..., 0:3]
    visible, held, delivered = slots[..., 3] > 0.5, slots[..., 4] > 0.5, slots[..., 5] > 0.5
    pending = visible & ~held & ~delivered
    offset = position - tip[..., None, :]
    distance = ops.where(pending, (offset * offset).sum(-1), _FAR)
    chosen = ops.as_float(distance.argmin(-1)[..., None] == ops.arange(debris))  # one-hot of the nearest slot
    has_pin = pending.any(-1)
    to_pin = (offset * (chosen * ops.as_float(has_pin)[..., None])[..., None]).sum(-2)
    holding = held.any(-1)
    handoff = observation[..., -3:]
    held_position = (position * ops.as_float(held)[..., None]).sum(-2)  # at most one pin is held
    carry = (handoff - held_position) * ops.as_float(holding)[..., None]
    return ops.concatenate([to_pin, ops.as_float(has_pin)[..., None], ops.as_float(holding)[..., None], carry,
                            handoff - tip, other - tip])


#: Known feature sets and how many values each appends.
FEATURES = {"suction_debris_targets": 14}
_FUNCTIONS = {"suction_debris_targets": suction_debris_targets}


def apply(spec: dict, observation):
    """``observation`` with the features ``spec`` names appended (``spec``: ``{"name": ..., **arguments}`` as a
    policy's ``policy.json`` keeps it under ``"features"``)."""
    name = spec.get("name")
    if name not in _FUNCTIONS:
        raise ValueError(f"unknown observation features {name!r} (known: {sorted(_FUNCTIONS)})")
    arguments = {k: v for k, v in spec.items() if k != "name"}
    return _Ops(observation).concatenate([observation, _FUNCTIONS[name](observation, **arguments)])
