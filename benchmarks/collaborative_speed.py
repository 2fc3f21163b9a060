"""Speed of the collaborative environment (target: >= 5,000 parallel steps/s on one core).

A parallel step is one call of ``step`` in which every agent acts once. Random actions, resets included.

    python benchmarks/collaborative_speed.py [--steps 30000]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from dvrl_marl.agents import ScriptedSuction, ScriptedSurgeon
from dvrl_marl.envs import suction_debris_v8


def parallel_steps_per_second(steps: int, **kwargs) -> float:
    env = suction_debris_v8.parallel_env(**kwargs)
    env.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-1, 1, size=(steps, 2, 4)).astype(np.float32)
    start = time.perf_counter()
    for step_actions in actions:
        if not env.agents:
            env.reset()
        env.step({agent: step_actions[i] for i, agent in enumerate(env.agents)})
    return steps / (time.perf_counter() - start)


def scripted_team(episodes: int) -> tuple[float, float, float]:
    env = suction_debris_v8.parallel_env()
    suction, surgeon = ScriptedSuction.for_env(env), ScriptedSurgeon.for_env(env)
    successes, lengths = 0, []
    start = time.perf_counter()
    for seed in range(episodes):
        observations, _ = env.reset(seed=seed)
        steps = 0
        while env.agents:
            observations, _, _, _, infos = env.step(
                {"suction": suction(observations["suction"]), "grasper": surgeon(observations["grasper"])}
            )
            steps += 1
        successes += infos["suction"]["is_success"]
        lengths.append(steps)
    return successes / episodes, float(np.mean(lengths)), sum(lengths) / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=30_000)
    parser.add_argument("--episodes", type=int, default=50)
    args = parser.parse_args()
    print(f"parallel steps/s, both arms learning     {parallel_steps_per_second(args.steps):10,.0f}")
    print(f"parallel steps/s, scripted surgeon seat  {parallel_steps_per_second(args.steps, surgeon='scripted'):10,.0f}")
    success, mean_steps, rate = scripted_team(args.episodes)
    print(f"scripted team: success {success:.0%} over {args.episodes} seeds, mean {mean_steps:.0f} steps, "
          f"{rate:,.0f} steps/s with the experts")


if __name__ == "__main__":
    main()
