"""The ``normalize_observations`` option of the collaborative scene: fixed, measured centres and spreads.

The collaborative observation is in the paper's normalised workspace coordinates, and several of its dimensions vary
over a small part of that range: the pins lie in a narrow band of y (spread 0.03), a carried pin's offset to the
hand-off point across it (0.02-0.04), how far a tip lies below a rim (0.01-0.06). A trainer that normalises its
inputs (this project's MAPPO: running mean and spread) sees them at the scale of the rest; a network that reads
them as they come (BenchMARL's and RLlib's default MLPs) must grow its first weights 25-100 times before it can act
on them. ``normalize_observations=True`` hands every library the first kind of input: each dimension of every
agent's observation (features included) and of ``state()`` becomes ``(x - centre) / spread``.

The centres and spreads are constants, not running statistics, so an episode's observations depend on nothing but
the episode (determinism, evaluation equal to training, a policy that runs anywhere). They were measured by
:func:`dvrl_marl.envs.observation_measure.measure` (``python -m dvrl_marl.envs.observation_measure`` rewrites
``observation_scales.json``; a test measures again and compares): :data:`MEASURE_WORLDS` worlds of the default task at
the default level, one episode of the scripted team (which clears, grasps, carries and delivers) and one of uniformly
random actions (what a policy meets first), per feature set. A spread is floored at :data:`MIN_SPREAD` (the floor of this project's
trainer's normaliser) so that constant dimensions (the hand-off point) stay finite.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from dvrl_marl.suction_debris.task import TASK

__all__ = ["ObservationScaling", "SCALES_FILE", "MEASURE_WORLDS", "MEASURE_SEED", "MIN_SPREAD", "MEASURE_TASK"]

#: Where the measured centres and spreads are kept (package data).
SCALES_FILE = Path(__file__).with_name("observation_scales.json")
#: Worlds per measured episode (each world one scripted and one random episode).
MEASURE_WORLDS = 16
#: The seed of the measured episodes (worlds and random actions).
MEASURE_SEED = 0
#: The smallest spread (normalised units), also the floor of this project's trainer's running normaliser
#: (dvrl_marl.training.models reads it from here).
MIN_SPREAD = 0.01
#: The task the statistics were measured on (its observation is every version's).
MEASURE_TASK = TASK


class ObservationScaling:
    """The affine map of one env's observations and state: ``(x - centre) / spread`` per dimension."""

    def __init__(self, statistics: dict, agents, state_observations: bool):
        self.agents = tuple(agents)
        self._observation = {agent: self._pair(statistics[agent]) for agent in self.agents}
        centre, spread = self._pair(statistics["state"])
        if state_observations:  # the state, then every arm's observation: each part by its own statistics
            centre = np.concatenate([centre, *(self._observation[agent][0] for agent in self.agents)])
            spread = np.concatenate([spread, *(self._observation[agent][1] for agent in self.agents)])
        self._state = (centre, spread)

    @staticmethod
    def _pair(entry: dict) -> tuple[np.ndarray, np.ndarray]:
        return np.asarray(entry["centre"], dtype=np.float64), np.asarray(entry["spread"], dtype=np.float64)

    @classmethod
    def for_env(cls, name: str, feature_set: str, agents, observation_dim: int, state_dim: int,
                state_observations: bool) -> "ObservationScaling":
        """The scaling of an env whose observations have ``observation_dim`` dimensions with ``feature_set``
        (``""``: none) and whose plain state has ``state_dim``; a ``ValueError`` naming what was never measured."""
        shipped = json.loads(SCALES_FILE.read_text())["feature_sets"]
        if feature_set not in shipped:
            raise ValueError(f"{name}: normalize_observations has no statistics for observation_features "
                             f"{feature_set!r} (measured: {sorted(shipped)})")
        statistics = shipped[feature_set]
        for agent in agents:
            if len(statistics[agent]["centre"]) != observation_dim:
                raise ValueError(f"{name}: normalize_observations was measured on {len(statistics[agent]['centre'])}"
                                 f"-dimensional observations (the task's debris and cavities), this env's have "
                                 f"{observation_dim}")
        if len(statistics["state"]["centre"]) != state_dim:
            raise ValueError(f"{name}: normalize_observations was measured on a {len(statistics['state']['centre'])}"
                             f"-dimensional state, this env's has {state_dim}")
        return cls(statistics, agents, state_observations)

    def observation(self, agent: str, x: np.ndarray) -> np.ndarray:
        centre, spread = self._observation[agent]
        return (x - centre) / spread

    def observation_affine(self, agent: str) -> tuple[np.ndarray, np.ndarray]:
        """``agent``'s centres and spreads (copies): what a policy exported to read the scene's units folds in."""
        centre, spread = self._observation[agent]
        return centre.copy(), spread.copy()

    def plain_observation(self, agent: str, x: np.ndarray) -> np.ndarray:
        """The observation in the scene's units back from a normalised one (for what reads positions: a scripted
        expert, a failure analysis)."""
        centre, spread = self._observation[agent]
        return x * spread + centre

    def state(self, x: np.ndarray) -> np.ndarray:
        centre, spread = self._state
        return (x - centre) / spread

    def observation_bounds(self, agent: str, low: np.ndarray, high: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The observation space's bounds mapped (spreads are positive: the order is kept)."""
        return self.observation(agent, low), self.observation(agent, high)

    def state_bounds(self, low: np.ndarray, high: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.state(low), self.state(high)
