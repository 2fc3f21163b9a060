"""Record the collaborative core's golden steps: each step's state before it, the commands, and what it gives.

    python tests/golden/record_steps.py <env module> <out.npz>

Run at commit 36a42a0 with ``suction_debris_v7`` (the rules of suction_debris_v8) from a checkout of it, e.g.
``PYTHONPATH=/tmp/at-36a42a0 python tests/golden/record_steps.py suction_debris_v7 tests/golden/steps_v8.npz``. Each case
of ``record.py`` is stepped through the batched env; around every call of its core's ``step`` the core's state is
read by attribute name (:data:`FIELDS`, the same names in every version of the core) before and after, with the
commands the core was given and the env's rewards (guided terms included) and flags. ``tests/test_golden.py`` puts
each recorded state into the current core, steps it with the recorded commands and compares, step by step.
"""

from __future__ import annotations

import sys
from importlib import import_module
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from record import CASES  # noqa: E402

#: The trajectory cases, and the scripted team with noise whose grasper opens its jaw now and then: held pins drop
#: mid-air, fall and land (on a cavity floor, the phantom's top or its edge), and are taken again.
STEP_CASES = {**{name: CASES[name] for name in ("default_random", "benchmark_random", "bleeding_random", "tools_random",
                                                "default_scripted", "benchmark_scripted", "bleeding_scripted")},
              "drops_scripted": ({}, 4, 600, "drops")}

FIELDS = ("valve_opening", "initial_ml", "remaining_ml", "surface_z", "debris_position", "debris_yaw", "debris_cavity",
          "visible", "held", "delivered", "lifted", "fall_speed", "added_ml", "bleed_onset", "bleed_rate", "holding",
          "hold_offset", "grip_offset", "elapsed", "limit", "contact", "complete")
AGENTS = ("suction", "grasper")


def snapshot(core) -> dict:
    state = {name: np.array(getattr(core, name)) for name in FIELDS}
    for agent in AGENTS:
        arm = core.arms[agent]
        state.update({f"{agent}.tip": arm.tip.copy(), f"{agent}.q": arm.q.copy(), f"{agent}.jaw": arm.jaw.copy(),
                      f"{agent}.work_distance": core.work_distance[agent].copy()})
    return state


def record(module_name: str) -> dict:
    module = import_module(f"dvrl_marl.envs.{module_name}")
    from dvrl_marl.agents.collaborative import ScriptedSuction, ScriptedSurgeon

    out = {}
    for case, (kwargs, worlds, steps, scripted) in STEP_CASES.items():
        env = module.batched_env(num_envs=worlds, **kwargs)
        core, rows = env.core, []
        step = core.step

        def recorded_step(commands, step=step, core=core, rows=rows):
            before = snapshot(core)
            result = step(commands)
            rows.append({"before": before, "commands": {a: np.array(commands[a]) for a in AGENTS},
                         "after": snapshot(core)})
            return result

        core.step = recorded_step
        observations, _ = env.reset(seed=7)
        experts = {"suction": ScriptedSuction.for_env(env), "grasper": ScriptedSurgeon.for_env(env)} if scripted else None
        rng = np.random.default_rng(11)
        for index in range(steps):
            if scripted == "drops":
                actions = {agent: experts[agent].act(observations[agent]) + rng.normal(0.0, 0.3, (worlds, 4))
                           for agent in env.agents}
                actions["grasper"][rng.random(worlds) < 0.05, 3] = 1.0
            elif scripted:
                actions = {agent: experts[agent].act(observations[agent]) for agent in env.agents}
            else:
                actions = {agent: rng.uniform(-1.0, 1.0, (worlds, 4)) for agent in env.agents}
            observations, rewards, terminations, truncations, _ = env.step(actions)
            rows[index].update(rewards={a: rewards[a] for a in AGENTS}, terminated=terminations["suction"],
                               truncated=truncations["suction"])
        for key in rows[0]["before"]:
            out[f"{case}/before/{key}"] = np.stack([row["before"][key] for row in rows])
            out[f"{case}/after/{key}"] = np.stack([row["after"][key] for row in rows])
        for agent in AGENTS:
            out[f"{case}/commands/{agent}"] = np.stack([row["commands"][agent] for row in rows])
            out[f"{case}/rewards/{agent}"] = np.stack([row["rewards"][agent] for row in rows])
        out[f"{case}/terminated"] = np.stack([row["terminated"] for row in rows])
        out[f"{case}/truncated"] = np.stack([row["truncated"] for row in rows])
    return out


if __name__ == "__main__":
    np.savez_compressed(sys.argv[2], **record(sys.argv[1]))
