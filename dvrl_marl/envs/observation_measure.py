"""How the centres and spreads of ``normalize_observations`` were measured (:mod:`dvrl_marl.suction_debris.observation_scaling`):
episodes of the scripted team and of random actions in the batched scene. ``python -m dvrl_marl.envs.observation_measure``
rewrites the file the option reads."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from dvrl_marl.suction_debris import layout
from dvrl_marl.suction_debris.observation_scaling import (MEASURE_SEED, MEASURE_TASK, MEASURE_WORLDS, MIN_SPREAD,
                                                          SCALES_FILE)

__all__ = ["measure", "write"]


def _statistics(samples: np.ndarray) -> dict:
    spread = np.maximum(samples.std(axis=0), MIN_SPREAD)
    return {"centre": [round(float(v), 6) for v in samples.mean(axis=0)],
            "spread": [round(float(v), 6) for v in spread]}


def measure(feature_set: str, worlds: int = MEASURE_WORLDS, seed: int = MEASURE_SEED) -> dict:
    """Centres and spreads of every agent's observation (with ``feature_set``) and of the plain state, over one
    episode of the scripted team and one of uniformly random actions in each of ``worlds`` worlds."""
    from dvrl_marl.envs.suction_debris_batched import SuctionDebrisBatchedEnv
    from dvrl_marl.suction_debris.scripted_team import ScriptedSuction, ScriptedSurgeon

    env = SuctionDebrisBatchedEnv(num_envs=worlds, task=MEASURE_TASK, observation_features=feature_set,
                                  autoreset_mode="disabled")
    experts = {"suction": ScriptedSuction.for_env(env), "grasper": ScriptedSurgeon.for_env(env)}
    random = np.random.default_rng(seed)
    samples = {agent: [] for agent in env.agents} | {"state": []}
    plain = layout.plain_width(env.observation_layout)  # the experts read the plain observation
    for scripted, episode_seed in ((True, seed), (False, seed + 1)):
        observations, _ = env.reset(seed=episode_seed)
        done = np.zeros(worlds, dtype=bool)
        while not done.all():
            for agent in env.agents:
                samples[agent].append(observations[agent][~done])
            samples["state"].append(env.core.state()[~done])
            actions = {agent: (experts[agent](observations[agent][:, :plain]) if scripted
                               else random.uniform(-1.0, 1.0, (worlds, layout.ACTION_WIDTH))) for agent in env.agents}
            observations, _, terminations, truncations, _ = env.step(actions)
            done |= terminations[env.agents[0]] | truncations[env.agents[0]]
    env.close()
    return {key: _statistics(np.concatenate(rows)) for key, rows in samples.items()}


def write(path: Path = SCALES_FILE) -> dict:
    """Measure every feature set (and none) and write the file the option reads."""
    from dvrl_marl.suction_debris.features import SCENE_FEATURE_SETS

    content = {"source": "dvrl_marl.envs.observation_measure.measure", "task": MEASURE_TASK,
               "worlds": MEASURE_WORLDS, "seed": MEASURE_SEED, "min_spread": MIN_SPREAD,
               "feature_sets": {name: measure(name) for name in ["", *sorted(SCENE_FEATURE_SETS)]}}
    path.write_text(json.dumps(content, indent=1) + "\n")
    return content


if __name__ == "__main__":
    write()
    print(f"wrote {SCALES_FILE}")
