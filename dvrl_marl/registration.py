"""Gymnasium registration of the single-arm environments (PettingZoo envs register in their own modules)."""

from __future__ import annotations

import gymnasium as gym

__all__ = ["register_envs", "SINGLE_ARM_ENV_IDS"]

_PAPER_EPISODE_STEPS = 100  # paper Sec. IV-A (also tasks/*.toml max_episode_steps)

#: id -> (entry point, kwargs)
SINGLE_ARM_ENV_IDS = {
    "dvrl_marl/PSMReach-v0": ("dvrl_marl.envs.psm_reach:PSMReachEnv", {"reward_type": "sparse"}),
    "dvrl_marl/PSMReachDense-v0": ("dvrl_marl.envs.psm_reach:PSMReachEnv", {"reward_type": "dense"}),
    "dvrl_marl/PSMPick-v0": ("dvrl_marl.envs.psm_pick:PSMPickEnv", {"reward_type": "sparse"}),
    "dvrl_marl/PSMPickDense-v0": ("dvrl_marl.envs.psm_pick:PSMPickEnv", {"reward_type": "dense"}),
}


def register_envs() -> None:
    """Register every single-arm id with Gymnasium (idempotent)."""
    for env_id, (entry_point, kwargs) in SINGLE_ARM_ENV_IDS.items():
        if env_id in gym.registry:
            continue
        gym.register(id=env_id, entry_point=entry_point, kwargs=kwargs, max_episode_steps=_PAPER_EPISODE_STEPS)
