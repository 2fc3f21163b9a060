"""What the sliding rules cost per step: suction_debris_v8 with ``blocked_moves="stop"`` against its own rules
(``"settle"``), batched, measured in the same run.

A move that nothing blocks costs what it costs when moves stop (one more test); a blocked one runs the candidates of
:func:`dvrl_marl.suction_debris.sliding.resolve_blocked`. Uniform random commands block in most steps (the adversarial case:
they push into the phantom, the joint limits and each other); the scripted experts' commands never do.

    python benchmarks/sliding_cost.py [--worlds 256 4096]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from dvrl_marl.agents import ScriptedSuction, ScriptedSurgeon
from dvrl_marl.envs import suction_debris_v8


def world_steps_per_second(blocked_moves: str, worlds: int, commands: str, steps: int = 200, repeats: int = 3) -> float:
    env = suction_debris_v8.batched_env(num_envs=worlds, blocked_moves=blocked_moves)
    observations, _ = env.reset(seed=0)
    rng = np.random.default_rng(0)
    experts = {"suction": ScriptedSuction.for_env(env), "grasper": ScriptedSurgeon.for_env(env)}
    uniform = [{agent: rng.uniform(-1.0, 1.0, (worlds, 4)) for agent in env.agents} for _ in range(16)]
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        for step in range(steps):
            if commands == "uniform":
                actions = uniform[step % 16]
            else:
                actions = {agent: experts[agent](observations[agent]) for agent in env.agents}
            observations, *_ = env.step(actions)
        best = min(best, time.perf_counter() - start)
    return worlds * steps / best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worlds", type=int, nargs="+", default=[256, 4096])
    args = parser.parse_args()
    print("batched world-steps/s (best of 3; the scripted rows include the experts' own arithmetic)")
    print(f"  {'worlds':>7s} {'commands':>9s} {'stop':>12s} {'settle':>12s} {'ratio':>8s}")
    for worlds in args.worlds:
        for commands in ("uniform", "scripted"):
            stop = world_steps_per_second("stop", worlds, commands)
            settle = world_steps_per_second("settle", worlds, commands)
            print(f"  {worlds:7,d} {commands:>9s} {stop:12,.0f} {settle:12,.0f} {settle / stop:8.2f}")


if __name__ == "__main__":
    main()
