"""Speed of the single-arm environments (issue targets: Reach >= 30,000 steps/s, Pick >= 10,000 steps/s on one
core; a 100-step rollout under 10 ms, against the paper's 2.09 s in V-REP).

Prints steps per second for each registered id (gym.make, random actions, resets included) and the paper's
Table II layout: seconds per 100-step rollout for 1, 2, 4, 6, 8 environments in a Gymnasium SyncVectorEnv.

    python benchmarks/single_arm_speed.py [--steps 50000]
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np

import dvrl_marl  # noqa: F401
from dvrl_marl.registration import SINGLE_ARM_ENV_IDS


def steps_per_second(env_id: str, steps: int, seed: int = 0) -> float:
    env = gym.make(env_id)
    actions = np.random.default_rng(seed).uniform(-1, 1, size=(steps,) + env.action_space.shape).astype(np.float32)
    env.reset(seed=seed)
    start = time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    elapsed = time.perf_counter() - start
    env.close()
    return steps / elapsed


def rollout_seconds(env_id: str, num_envs: int | None, repeats: int = 20) -> float:
    """Median seconds of a 100-step rollout: one plain env (num_envs None) or a SyncVectorEnv of num_envs."""
    if num_envs is None:
        envs = gym.make(env_id)
    else:
        envs = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="sync")
    rng = np.random.default_rng(0)
    times = []
    for r in range(repeats):
        envs.reset(seed=r)
        actions = rng.uniform(-1, 1, size=(100,) + envs.action_space.shape).astype(np.float32)
        start = time.perf_counter()
        for action in actions:
            envs.step(action)
        times.append(time.perf_counter() - start)
    envs.close()
    return float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=50_000)
    args = parser.parse_args()
    print("steps per second (single env, random actions, resets included)")
    for env_id in sorted(SINGLE_ARM_ENV_IDS):
        print(f"  {env_id:28s} {steps_per_second(env_id, args.steps):10,.0f}")
    print("\none 100-step rollout, single env (paper: 2.09 s in V-REP)")
    for env_id in ("dvrl_marl/PSMReach-v1", "dvrl_marl/PSMPick-v1"):
        print(f"  {env_id:28s} {1000 * rollout_seconds(env_id, None, repeats=50):8.2f} ms")
    print("\nseconds per 100-step rollout in gymnasium's SyncVectorEnv (its own overhead is ~80 us/step; paper Table II: 2.09 s for 1 env ... 3.27 s for 8 envs, V-REP)")
    print(f"  {'envs':>4s}  {'PSM Reach':>10s}  {'PSM Pick':>10s}")
    for n in (1, 2, 4, 6, 8):
        reach = rollout_seconds("dvrl_marl/PSMReach-v1", n)
        pick = rollout_seconds("dvrl_marl/PSMPick-v1", n)
        print(f"  {n:4d}  {reach:10.4f}  {pick:10.4f}")


if __name__ == "__main__":
    main()
