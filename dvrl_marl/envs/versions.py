"""The entry points of a version of the collaborative scene (``suction_debris_v1``, ``_v2``, ``_v3``): its task file
bound into v0's parallel, batched and AEC forms. A version module is its documentation page and its task name; what
it exports is the same four callables every time, made here once."""

from __future__ import annotations

from pettingzoo.utils.conversions import parallel_to_aec

from dvrl_marl.envs.suction_debris_v0 import SuctionDebrisEnv

__all__ = ["entry_points"]


def entry_points(task: str):
    """``(parallel_env, raw_env, batched_env, env)`` for the task file ``task``; keyword arguments as
    ``suction_debris_v0``'s (a ``task=`` given by the caller wins)."""

    def parallel_env(**kwargs) -> SuctionDebrisEnv:
        return SuctionDebrisEnv(**{"task": task, **kwargs})

    def batched_env(num_envs: int = 1, **kwargs):
        from dvrl_marl.envs.suction_debris_batched import SuctionDebrisBatchedEnv  # it builds on suction_debris_v0

        return SuctionDebrisBatchedEnv(num_envs, **{"task": task, **kwargs})

    def env(**kwargs):
        return parallel_to_aec(parallel_env(**kwargs))

    parallel_env.__doc__ = f"The parallel environment of ``{task}`` (the native form); keyword arguments as " \
                           "``suction_debris_v0.parallel_env``."
    batched_env.__doc__ = f"N worlds of ``{task}`` stepped as arrays (:mod:`dvrl_marl.envs.suction_debris_batched`)."
    env.__doc__ = f"The AEC form of ``{task}``, through PettingZoo's parallel-to-AEC conversion."
    return parallel_env, parallel_env, batched_env, env
