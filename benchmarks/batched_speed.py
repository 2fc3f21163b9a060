"""Speed of the batched core against the single environments, measured in the same run.

Targets (issue: a batched simulation core), on one core of this project's 2-core CPU machines, random actions,
resets included: at N = 4,096 worlds, Reach >= 5M steps/s (>= 50x the single env), Pick >= 2M steps/s (>= 30x),
collaborative >= 500k parallel steps/s (>= 50x). Prints every figure and ratio, the TorchRL adapter's rate, and a
scaling curve over N = 1 ... 65,536, saved as ``benchmarks/batched_scaling.csv`` and ``.png``.

    taskset -c 0 python benchmarks/batched_speed.py [--max-worlds 65536]
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import dvrl_marl  # noqa: F401
from dvrl_marl.envs import suction_debris_v8

HERE = Path(__file__).resolve().parent


def single_goal_env(env_id: str, steps: int = 30_000) -> float:
    env = gym.make(env_id)
    actions = np.random.default_rng(0).uniform(-1, 1, (steps,) + env.action_space.shape).astype(np.float32)
    env.reset(seed=0)
    start = time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    return steps / (time.perf_counter() - start)


def single_collaborative(steps: int = 5_000) -> float:
    env = suction_debris_v8.parallel_env()
    actions = np.random.default_rng(0).uniform(-1, 1, (steps, 2, 4)).astype(np.float32)
    env.reset(seed=0)
    start = time.perf_counter()
    for action in actions:
        env.step({"suction": action[0], "grasper": action[1]})
        if not env.agents:
            env.reset()
    return steps / (time.perf_counter() - start)


def _timed(step, num_worlds: int, min_steps: int, min_seconds: float = 0.5) -> float:
    steps, start = 0, time.perf_counter()
    while steps < min_steps or time.perf_counter() - start < min_seconds:
        step()
        steps += 1
    return steps * num_worlds / (time.perf_counter() - start)


def batched_goal_env(env_id: str, num_worlds: int) -> float:
    envs = gym.make_vec(env_id, num_envs=num_worlds, vectorization_mode="vector_entry_point")
    envs.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-1, 1, (8,) + envs.action_space.shape).astype(np.float32)
    counter = iter(range(10**9))
    # At least 110 steps: every world resets once (100-step episodes) inside the measurement.
    return _timed(lambda: envs.step(actions[next(counter) % 8]), num_worlds, min_steps=110)


def batched_collaborative(num_worlds: int) -> float:
    env = suction_debris_v8.batched_env(num_envs=num_worlds)
    env.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-1, 1, (8, 2, num_worlds, 4))
    counter = iter(range(10**9))

    def step():
        action = actions[next(counter) % 8]
        env.step({"suction": action[0], "grasper": action[1]})

    return _timed(step, num_worlds, min_steps=10)


def torchrl_collaborative(num_worlds: int) -> float | None:
    try:
        from dvrl_marl.integrations.torchrl import SuctionDebrisTorchRLEnv
    except ImportError:
        return None
    env = SuctionDebrisTorchRLEnv(num_envs=num_worlds, seed=0)
    env.reset()
    start = time.perf_counter()
    env.rollout(30, break_when_any_done=False)
    return 30 * num_worlds / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--max-worlds", type=int, default=65_536)
    args = parser.parse_args()
    n = 4096
    rows = [
        ("PSM Reach", single_goal_env("dvrl_marl/PSMReach-v1"), batched_goal_env("dvrl_marl/PSMReach-v1", n), 5e6, 50),
        ("PSM Pick", single_goal_env("dvrl_marl/PSMPick-v1"), batched_goal_env("dvrl_marl/PSMPick-v1", n), 2e6, 30),
        ("collaborative (parallel steps)", single_collaborative(), batched_collaborative(n), 5e5, 50),
    ]
    print(f"batched core at N = {n:,} worlds vs the single env, same run (random actions, resets included)")
    print(f"  {'env':32s} {'single/s':>12s} {'batched/s':>14s} {'ratio':>8s}   target")
    for name, single, batched, target, ratio in rows:
        print(f"  {name:32s} {single:12,.0f} {batched:14,.0f} {batched / single:7.0f}x   "
              f">= {target:,.0f}/s and >= {ratio}x")
    rate = torchrl_collaborative(n)
    if rate is not None:
        print(f"  {'collaborative via TorchRL EnvBase':32s} {'':12s} {rate:14,.0f}   (env.rollout, float32 tensors)")

    sizes = [4**k for k in range(0, 9) if 4**k <= args.max_worlds]
    if sizes[-1] != args.max_worlds:
        sizes.append(args.max_worlds)
    curve = {"reach": [], "pick": [], "collaborative": []}
    print(f"\nscaling (steps/s per env id, N worlds)\n  {'N':>7s} {'Reach':>14s} {'Pick':>14s} {'collaborative':>14s}")
    for size in sizes:
        curve["reach"].append(batched_goal_env("dvrl_marl/PSMReach-v1", size))
        curve["pick"].append(batched_goal_env("dvrl_marl/PSMPick-v1", size))
        curve["collaborative"].append(batched_collaborative(size))
        print(f"  {size:7d} {curve['reach'][-1]:14,.0f} {curve['pick'][-1]:14,.0f} {curve['collaborative'][-1]:14,.0f}")
    with open(HERE / "batched_scaling.csv", "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["num_worlds", "reach_steps_per_s", "pick_steps_per_s", "collaborative_parallel_steps_per_s"])
        for index, size in enumerate(sizes):
            writer.writerow([size] + [round(curve[key][index]) for key in ("reach", "pick", "collaborative")])
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("\n(matplotlib not installed: wrote the CSV only)")
        return
    figure, axis = plt.subplots(figsize=(6, 4))
    for key, style in (("reach", "o-"), ("pick", "s--"), ("collaborative", "^:")):
        axis.loglog(sizes, curve[key], style, label=key)
    axis.set_xlabel("worlds N")
    axis.set_ylabel("steps per second (one CPU core)")
    axis.set_title("dvrl-marl batched core: throughput vs. batch size")
    axis.grid(True, which="both", alpha=0.3)
    axis.legend()
    figure.tight_layout()
    figure.savefig(HERE / "batched_scaling.png", dpi=120)
    print(f"\nwrote {HERE / 'batched_scaling.csv'} and {HERE / 'batched_scaling.png'}")


if __name__ == "__main__":
    main()
