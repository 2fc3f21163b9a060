"""Expert demonstrations for the single-arm goal environments: generation, file format, replay-buffer seeding.

File format (``.npz``, no pickles): one row per transition, episodes back to back.

| key | shape | content |
|---|---|---|
| ``observation``, ``achieved_goal``, ``desired_goal`` | (M, d) | the observation dict before the action |
| ``next_observation``, ``next_achieved_goal``, ``next_desired_goal`` | (M, d) | after it |
| ``action`` | (M, act_dim) float32 | the expert's action |
| ``reward`` | (M,) | the environment's reward |
| ``episode`` | (M,) int | episode index |
| ``metadata`` | () str | JSON: format, env_id, expert, seed, episodes, success_rate |

Only successful episodes are kept (the paper's demonstrations reach the goal).
"""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np

import dvrl_marl  # noqa: F401  (registers the environments)
from dvrl_marl.agents import PickExpert, ReachExpert

__all__ = ["DEMONSTRATION_FILE_FORMAT", "generate_demonstrations", "save_demonstrations", "load_demonstrations"]

DEMONSTRATION_FILE_FORMAT = "dvrl-marl-goal-demonstrations-v1"
_KEYS = ("observation", "achieved_goal", "desired_goal")


def _expert_for(env):
    return (PickExpert if "Pick" in env.spec.id else ReachExpert).for_env(env)


def generate_demonstrations(env_id: str, episodes: int = 100, seed: int = 0, env_kwargs: dict | None = None) -> dict:
    """Roll out the scripted expert until ``episodes`` successful episodes are collected."""
    env = gym.make(env_id, **(env_kwargs or {}))
    expert = _expert_for(env)
    rows: dict[str, list] = {k: [] for k in _KEYS + tuple(f"next_{k}" for k in _KEYS) + ("action", "reward", "episode")}
    kept = attempts = 0
    while kept < episodes:
        obs, _ = env.reset(seed=seed + attempts)
        attempts += 1
        episode = {k: [] for k in rows}
        truncated = terminated = False
        while not (terminated or truncated):
            action = expert(obs)
            next_obs, reward, terminated, truncated, info = env.step(action)
            for key in _KEYS:
                episode[key].append(obs[key])
                episode[f"next_{key}"].append(next_obs[key])
            episode["action"].append(action)
            episode["reward"].append(reward)
            episode["episode"].append(kept)
            obs = next_obs
        if info["is_success"]:
            for key in rows:
                rows[key].extend(episode[key])
            kept += 1
        if attempts > 10 * episodes:
            raise RuntimeError(f"the {env_id} expert succeeded in only {kept} of {attempts} episodes")
    env.close()
    data = {key: np.asarray(values) for key, values in rows.items()}
    data["action"] = data["action"].astype(np.float32)
    data["metadata"] = {"format": DEMONSTRATION_FILE_FORMAT, "env_id": env_id, "expert": type(expert).__name__,
                        "seed": seed, "episodes": episodes, "success_rate": episodes / attempts}
    return data


def save_demonstrations(data: dict, path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {k: v for k, v in data.items() if k != "metadata"}
    with path.open("wb") as handle:
        np.savez_compressed(handle, metadata=np.array(json.dumps(data["metadata"])), **arrays)
    return path


def load_demonstrations(path) -> dict:
    from dvrl_marl.files import read_metadata, read_npz

    data = read_npz(path)
    data["metadata"] = read_metadata(data, path, DEMONSTRATION_FILE_FORMAT)
    lengths = {key: len(value) for key, value in data.items() if key != "metadata"}
    if len(set(lengths.values())) > 1:
        raise ValueError(f"{path}: arrays of different lengths {lengths} (a truncated or edited file)")
    for key, value in data.items():
        if key != "metadata" and np.issubdtype(value.dtype, np.floating) and not np.all(np.isfinite(value)):
            raise ValueError(f"{path}: array {key!r} holds NaN or inf")
    return data


def observation_batch(data: dict, prefix: str = "") -> dict:
    """The observation dict (``prefix="next_"`` for next observations) as arrays of shape (M, d)."""
    return {key: data[f"{prefix}{key}"] for key in _KEYS}
