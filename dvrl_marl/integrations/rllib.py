"""RLlib adapter: the collaborative env and the single-arm envs registered with RLlib, rendering included.

```python
from ray.rllib.algorithms.ppo import PPOConfig
from dvrl_marl.integrations.rllib import register_suction_debris, policy_per_agent

name = register_suction_debris()                    # "dvrl_marl/suction_debris-v8" in RLlib's registry
config = PPOConfig().environment(name).multi_agent(**policy_per_agent())
```

RLlib runs a PettingZoo parallel env through its ``ParallelPettingZooEnv``, whose ``render()`` passes a mode
argument that PettingZoo's ``render()`` does not take (a ``TypeError``); :class:`RenderableParallelPettingZooEnv`
renders the scene's endoscope view instead (``render_mode="rgb_array"`` in the env config). Goal envs (Reach, Pick)
have a ``Dict`` observation that RLlib's default models do not read: :func:`register_single_arm` flattens it
(observation, achieved goal, desired goal, in that order). See ``examples/rllib_*.py`` for whole recipes.
"""

from __future__ import annotations

import gymnasium as gym

__all__ = ["RenderableParallelPettingZooEnv", "register_suction_debris", "register_single_arm", "policy_per_agent",
           "shared_policy", "init_ray", "train", "AGENTS"]

AGENTS = ("suction", "grasper")

try:
    from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv
except ImportError as error:  # the optional extra
    raise ModuleNotFoundError('the RLlib adapter needs RLlib: pip install "dvrl-marl[rllib]"', name="ray") from error


class RenderableParallelPettingZooEnv(ParallelPettingZooEnv):
    """RLlib's wrapper of a PettingZoo parallel env, with a ``render()`` that works (the endoscope frame)."""

    def __init__(self, env):
        super().__init__(env)
        self.render_mode = getattr(env, "render_mode", None)

    def render(self):
        return self.par_env.render()


def register_suction_debris(name: str = "dvrl_marl/suction_debris-v8") -> str:
    """Register the collaborative env (``suction_debris_v8``) under ``name`` with RLlib; the env config
    (``PPOConfig().environment(name, env_config={...})``, ``{"preset": "benchmark"}`` for the benchmark's setting)
    goes to ``parallel_env(**env_config)``."""
    from ray.tune.registry import register_env

    from dvrl_marl.envs import suction_debris

    register_env(name, lambda env_config: RenderableParallelPettingZooEnv(
        suction_debris.parallel_env(**dict(env_config))))
    return name


def register_single_arm(env_id: str = "dvrl_marl/PSMReach-v1", name: str | None = None) -> str:
    """Register a single-arm Gymnasium env (its ``Dict`` observation flattened) with RLlib under ``name``
    (default ``env_id`` with ``-flat``); the env config goes to ``gym.make``."""
    from ray.tune.registry import register_env

    import dvrl_marl  # noqa: F401  (registration)

    name = name or f"{env_id}-flat"
    register_env(name, lambda env_config: gym.wrappers.FlattenObservation(gym.make(env_id, **dict(env_config))))
    return name


def policy_per_agent() -> dict:
    """``PPOConfig().multi_agent(**policy_per_agent())``: one policy per arm, named after it."""
    return {"policies": set(AGENTS), "policy_mapping_fn": lambda agent_id, episode, **kwargs: agent_id}


def shared_policy() -> dict:
    """``PPOConfig().multi_agent(**shared_policy())``: both arms act with one policy (their spaces agree)."""
    return {"policies": {"shared"}, "policy_mapping_fn": lambda agent_id, episode, **kwargs: "shared"}


def init_ray(address: str | None = None) -> None:
    """Join the Ray cluster at ``address`` (``"auto"``, ``"host:port"``), or start Ray in this process (``None``)."""
    import ray

    if address is None:
        ray.init(include_dashboard=False, ignore_reinit_error=True, log_to_driver=False)
    else:
        ray.init(address=address, ignore_reinit_error=True, log_to_driver=False)


def train(algo, iterations: int, log=print) -> dict:
    """``iterations`` of ``algo.train()``, a line each (env steps so far, mean episode return, seconds since the
    start); the last result."""
    import time

    result, start = {}, time.perf_counter()
    for iteration in range(int(iterations)):
        result = algo.train()
        runners = result.get("env_runners", {})
        log(f"iteration {iteration + 1}: {result.get('num_env_steps_sampled_lifetime', 0):,.0f} env steps, "
            f"episode return {runners.get('episode_return_mean', float('nan')):.2f}, "
            f"{time.perf_counter() - start:.0f} s")
    return result
