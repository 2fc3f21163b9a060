"""Export an SB3 actor (DDPG/TD3, SAC/TQC or PPO's Gaussian mean) to the torch-free format of :mod:`dvrl_marl.policies`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from dvrl_marl.policies import POLICY_FORMAT

__all__ = ["export_policy", "actor_layers", "write_policy"]


def _collect(modules, layers):
    from torch import nn  # (torch only for SB3's actors: write_policy needs none)

    activation_names = {nn.ReLU: "relu", nn.Tanh: "tanh"}
    for module in modules:
        if isinstance(module, nn.Linear):
            layers.append([module.weight.detach().cpu().numpy().astype(np.float32),
                           module.bias.detach().cpu().numpy().astype(np.float32), "identity"])
        elif isinstance(module, tuple(activation_names)):  # (a subclass computes the same function another way)
            layers[-1][2] = next(name for kind, name in activation_names.items() if isinstance(module, kind))
        elif isinstance(module, nn.Sequential):
            _collect(module, layers)
        elif not isinstance(module, (nn.Flatten, nn.Identity)):
            raise ValueError(f"cannot export layer {module!r}")


def actor_layers(model) -> list[tuple[np.ndarray, np.ndarray, str]]:
    """The deterministic actor as (weight, bias, activation) layers."""
    layers: list = []
    if hasattr(model.policy, "mlp_extractor"):  # PPO: the Gaussian's mean, action_net(policy_net(x)), clipped
        _collect(model.policy.mlp_extractor.policy_net, layers)
        _collect([model.policy.action_net], layers)
        layers[-1][2] = "clip"
        return [tuple(layer) for layer in layers]
    actor = model.actor
    if hasattr(actor, "mu") and hasattr(actor, "latent_pi"):  # SAC / TQC: tanh(mu(latent_pi(x)))
        _collect(actor.latent_pi, layers)
        _collect([actor.mu], layers)
        layers[-1][2] = "tanh"
    else:  # DDPG / TD3: mu already ends in tanh
        _collect(actor.mu, layers)
    return [tuple(layer) for layer in layers]


def _observation_keys(model) -> list[str]:
    return list(model.observation_space.spaces.keys())


def export_policy(model, directory, *, name: str, env_id: str, **metadata) -> Path:
    """Write ``policy.npz`` and ``policy.json`` into ``directory``; returns the folder."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    return write_policy(directory, actor_layers(model), name=name, env_id=env_id, algorithm=type(model).__name__,
                        observation_keys=_observation_keys(model), action_low=model.action_space.low.tolist(),
                        action_high=model.action_space.high.tolist(), **metadata)


def write_policy(directory, layers, *, name: str, env_id: str, algorithm: str, observation_keys, action_low,
                 action_high, kernels=(), readout=None, keypoint_gains=None, **metadata) -> Path:
    """Write (weight, bias, activation) layers as ``policy.npz`` + ``policy.json`` in ``directory``; ``kernels``,
    ``readout`` and ``keypoint_gains``: a pixel policy's convolutions, read-out (weight, bias) and keypoints' softmax
    gains, whose ``image`` table goes in ``metadata``."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    arrays = {}
    for index, (weight, bias, _) in enumerate(layers):
        arrays[f"W{index}"], arrays[f"b{index}"] = weight, bias
    for index, (weight, bias) in enumerate(kernels):
        arrays[f"K{index}"], arrays[f"k{index}"] = weight, bias
    if readout is not None:
        arrays["R"], arrays["r"] = readout
    if keypoint_gains is not None:
        arrays["G"] = keypoint_gains
    with (directory / "policy.npz").open("wb") as handle:
        np.savez(handle, **arrays)
    spec = {
        "format": POLICY_FORMAT,
        "name": name,
        "env_id": env_id,
        "algorithm": algorithm,
        "observation_keys": list(observation_keys),
        "layer_sizes": [int(layers[0][0].shape[1])] + [int(w.shape[0]) for w, _, _ in layers],
        "activations": [activation for _, _, activation in layers],
        "action_low": list(action_low),
        "action_high": list(action_high),
        **metadata,
    }
    (directory / "policy.json").write_text(json.dumps(spec, indent=2) + "\n")
    return directory

