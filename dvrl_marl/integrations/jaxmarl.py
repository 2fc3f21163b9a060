"""The collaborative scene as a JaxMARL environment (``pip install "dvrl-marl[jaxmarl]"``): a subclass of JaxMARL's
``MultiAgentEnv`` over :func:`dvrl_marl.envs.suction_debris_v8.jax_env`, so that JaxMARL's wrappers
(``LogWrapper`` and the rest) and its baselines take it as one of their own.

>>> from jaxmarl.wrappers.baselines import LogWrapper
>>> from dvrl_marl.integrations.jaxmarl import suction_debris_env
>>> env = LogWrapper(suction_debris_env(preset="benchmark"))     # doctest: +SKIP

Its ``step`` is the scene's own, not ``MultiAgentEnv.step``'s: an ended episode starts the next one inside the step
from the world's own streams (the next episode of its seed), where JaxMARL's default would reset it from the step's
key; ``step_env`` is the same step, for code that calls it.
"""

from __future__ import annotations

from jaxmarl.environments.multi_agent_env import MultiAgentEnv

from dvrl_marl.envs.suction_debris_jax import SuctionDebrisJaxEnv
from dvrl_marl.suction_debris.task import TASK

__all__ = ["SuctionDebrisJaxMARLEnv", "suction_debris_env"]


class SuctionDebrisJaxMARLEnv(SuctionDebrisJaxEnv, MultiAgentEnv):
    """:class:`~dvrl_marl.envs.suction_debris_jax.SuctionDebrisJaxEnv` as a JaxMARL ``MultiAgentEnv``."""

    def __init__(self, **options):
        SuctionDebrisJaxEnv.__init__(self, **options)
        agents = list(self.agents)
        MultiAgentEnv.__init__(self, num_agents=len(agents))
        self.agents = agents  # (MultiAgentEnv names its agents agent_0, agent_1, ...)
        self.observation_spaces = {agent: self.observation_space(agent) for agent in agents}
        self.action_spaces = {agent: self.action_space(agent) for agent in agents}

    def step(self, key, state, actions, reset_state=None):
        if reset_state is not None:
            raise ValueError(f"{self.name}: an ended episode starts the next one of the world's own seed; "
                             "reset_state is not taken")
        return SuctionDebrisJaxEnv.step(self, key, state, actions)

    def step_env(self, key, state, actions):
        return SuctionDebrisJaxEnv.step(self, key, state, actions)

    @property
    def name(self) -> str:
        return TASK

    @name.setter
    def name(self, value) -> None:  # (the base classes set it)
        pass


def suction_debris_env(**options) -> SuctionDebrisJaxMARLEnv:
    """The scene as a JaxMARL ``MultiAgentEnv``; the parallel env's keyword arguments (as ``jax_env``)."""
    return SuctionDebrisJaxMARLEnv(**options)
