"""Stable-Baselines3 adapter: a native vector env of Reach or Pick as an SB3 ``VecEnv`` (HER included).

```python
from stable_baselines3 import SAC, HerReplayBuffer
from dvrl_marl.integrations.sb3 import make_sb3_vec_env
venv = make_sb3_vec_env("dvrl_marl/PSMReach-v1", num_envs=64, seed=0)
model = SAC("MultiInputPolicy", venv, replay_buffer_class=HerReplayBuffer)
```

SB3 resets finished episodes inside ``step`` and reads the last observation from
``infos[i]["terminal_observation"]`` (and ``"TimeLimit.truncated"``); the adapter runs the vector env in
``same_step`` autoreset mode and provides both. ``env_method("compute_reward", ...)`` reaches the batched reward.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

__all__ = ["GoalVecEnvForSB3", "make_sb3_vec_env", "make_collaborative_vec_env"]


class GoalVecEnvForSB3(VecEnv):
    """Wraps a :class:`dvrl_marl.envs.vector.GoalVectorEnv` created with ``autoreset_mode="same_step"``."""

    def __init__(self, vector_env):
        if vector_env.autoreset_mode != "same_step":
            raise ValueError("GoalVecEnvForSB3 needs a vector env with autoreset_mode='same_step'")
        self.vector_env = vector_env
        super().__init__(vector_env.num_envs, vector_env.single_observation_space, vector_env.single_action_space)
        self._actions = None
        self.render_mode = vector_env.render_mode

    def reset(self):
        seed = self._seeds[0] if any(s is not None for s in self._seeds) else None
        observations, infos = self.vector_env.reset(seed=seed)
        self._reset_seeds()
        self.reset_infos = [{"is_success": bool(s)} for s in infos["is_success"]]
        return observations

    def step_async(self, actions):
        self._actions = actions

    def step_wait(self):
        observations, rewards, terminations, truncations, infos = self.vector_env.step(self._actions)
        dones = terminations | truncations
        extra = [key for key in infos if not key.startswith("_") and key not in ("final_obs", "final_info")]
        out = [{key: infos[key][i].item() for key in extra} for i in range(self.num_envs)]
        if dones.any():
            final, final_info = infos["final_obs"], infos["final_info"]
            for i in np.flatnonzero(dones).tolist():
                out[i]["terminal_observation"] = {key: value[i] for key, value in final.items()}
                out[i]["is_success"] = bool(final_info["is_success"][i])
                out[i]["TimeLimit.truncated"] = bool(truncations[i] and not terminations[i])
        return observations, rewards.astype(np.float32), dones, out

    def close(self):
        self.vector_env.close()

    def get_attr(self, attr_name, indices=None):
        return [getattr(self.vector_env, attr_name)] * len(self._get_indices(indices))

    def set_attr(self, attr_name, value, indices=None):
        setattr(self.vector_env, attr_name, value)

    def env_method(self, method_name, *method_args, indices=None, **method_kwargs):
        # One batched call answers for every index (HER asks for indices=[0] with whole batches).
        result = getattr(self.vector_env, method_name)(*method_args, **method_kwargs)
        return [result] * len(self._get_indices(indices))

    def env_is_wrapped(self, wrapper_class, indices=None):
        return [False] * len(self._get_indices(indices))

    def get_images(self):
        return [self.vector_env.render()]


def make_sb3_vec_env(env_id: str, num_envs: int, seed: int | None = None, **kwargs) -> GoalVecEnvForSB3:
    """``gym.make_vec(env_id, num_envs, vector_entry_point, same_step)`` wrapped for SB3, seeded with ``seed``."""
    vector_env = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point",
                              autoreset_mode="same_step", **kwargs)
    venv = GoalVecEnvForSB3(vector_env)
    if seed is not None:
        venv.seed(seed)
    return venv


def make_collaborative_vec_env(n_envs: int = 4, seed: int | None = None, surgeon=None, **env_kwargs):
    """The collaborative env's learning agents as one seeded SB3 ``VecEnv`` (each agent of each copy is a slot,
    through SuperSuit: padded spaces, a one-hot agent indicator when both arms learn).

    SuperSuit's ``ConcatVecEnv`` has no ``seed()``, which SB3 calls when a model is given ``seed=``; this adds it
    (reset with that seed). ``seed`` here seeds the first reset.

    >>> venv = make_collaborative_vec_env(n_envs=2, seed=0, reward_type="dense")  # doctest: +SKIP
    >>> PPO("MlpPolicy", venv, seed=0).learn(10_000)                               # doctest: +SKIP
    """
    import supersuit as ss

    from dvrl_marl.envs import suction_debris
    from dvrl_marl.schemas import PositiveInt, validated

    n_envs = validated(PositiveInt, n_envs, "make_collaborative_vec_env: n_envs")
    env = suction_debris.parallel_env(surgeon=surgeon, **env_kwargs)
    env = ss.pad_observations_v0(env)
    env = ss.pad_action_space_v0(env)
    if len(env.possible_agents) > 1:
        env = ss.agent_indicator_v0(env, type_only=False)
    vec = ss.pettingzoo_env_to_vec_env_v1(env)
    vec = ss.concat_vec_envs_v1(vec, int(n_envs), num_cpus=0, base_class="stable_baselines3")
    concat = vec.venv
    if not hasattr(concat, "seed"):

        def seed_all(value=None):
            concat.reset(seed=value)
            return [value] * concat.num_envs

        concat.seed = seed_all
    if seed is not None:
        vec.seed(seed)
    return vec
