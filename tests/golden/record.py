"""Record the collaborative scene's golden trajectories (tests/test_golden.py holds the current code to them).

    python tests/golden/record.py <env module> <out.npz>

``<env module>``: ``suction_debris_v8``. The file was first recorded at commit 36a42a0 (``suction_debris_v7``, the same
rules) and recorded again when resets moved to counter-based streams (``dvrl_marl.core.streams``: every reset draw
changed on purpose; the step goldens, ``record_steps.py``, held every step unchanged). Each case steps a batch of worlds
with seeded random actions (numpy's PCG64, stable across releases), or the scripted team in one world, and keeps
every step's state, rewards and flags; ``levels_random`` starts episodes at start level 0.3 (easy draws included).
"""

from __future__ import annotations

import sys
from importlib import import_module

import numpy as np

#: The benchmark's setting, spelt out (``preset="benchmark"`` on suction_debris_v8).
BENCHMARK = dict(reward_type="guided", observation_features="suction_debris_cleared_pins_zoom",
                 state_observations=True, contact_penalty=0.1, tool_speed=0.1, jaw_command="switch",
                 hold_until_handoff=True)
#: case -> (keyword arguments, worlds, steps, scripted team)
CASES = {
    "default_random": ({}, 3, 300, False),
    "benchmark_random": (BENCHMARK, 3, 300, False),
    "bleeding_random": ({"bleeding_ml_s": 0.3, "reward_type": "dense"}, 2, 300, False),
    "tools_random": ({"tool_speed": 0.25, "jaw_command": "switch", "hold_until_handoff": True}, 2, 300, False),
    "default_scripted": ({}, 1, 1000, True),
    "benchmark_scripted": (BENCHMARK, 1, 1000, True),
    "bleeding_scripted": ({"bleeding_ml_s": 0.1}, 1, 1000, True),
    "levels_random": ({"start_level": 0.3, "bleeding_ml_s": 0.1}, 4, 400, False),
}


def record(module_name: str) -> dict:
    module = import_module(f"dvrl_marl.envs.{module_name}")
    from dvrl_marl.agents.collaborative import ScriptedSuction, ScriptedSurgeon

    out = {}
    for name, (kwargs, worlds, steps, scripted) in CASES.items():
        env = module.batched_env(num_envs=worlds, **kwargs)
        observations, _ = env.reset(seed=7)
        experts = {"suction": ScriptedSuction.for_env(env), "grasper": ScriptedSurgeon.for_env(env)} if scripted else None
        rng = np.random.default_rng(11)
        rows = []
        for _ in range(steps):
            if scripted:
                actions = {agent: experts[agent].act(observations[agent]) for agent in env.agents}
            else:
                actions = {agent: rng.uniform(-1.0, 1.0, (worlds, 4)) for agent in env.agents}
            observations, rewards, terminations, truncations, _ = env.step(actions)
            plain = env.state()[:, :env.state_layout["handoff"].stop]  # the scene's state (not the observations)
            rows.append(np.concatenate([plain, *(rewards[a][:, None] for a in env.agents),
                                        *(terminations[a][:, None] for a in env.agents),
                                        *(truncations[a][:, None] for a in env.agents)], axis=1))
        out[name] = np.stack(rows)
    return out


if __name__ == "__main__":
    np.savez_compressed(sys.argv[2], **record(sys.argv[1]))
