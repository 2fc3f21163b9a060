"""Environments in threads: two envs stepped from two threads follow the trajectories they follow one after the
other (models, data and renderers are per env; no shared mutable module state), and two envs render in one
process."""

from __future__ import annotations

import threading

import gymnasium as gym
import numpy as np
import pytest

import dvrl_marl  # noqa: F401
from dvrl_marl.envs import suction_debris_v8
from dvrl_marl.teleop import ReplayDevice


def _pick_trajectory(seed: int, steps: int = 300) -> np.ndarray:
    env = gym.make("dvrl_marl/PSMPick-v1")
    observation, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    rows = []
    for _ in range(steps):
        observation, reward, terminated, truncated, _ = env.step(rng.uniform(-1, 1, 4).astype(np.float32))
        rows.append(np.concatenate([observation["observation"], [reward]]))
        if terminated or truncated:
            observation, _ = env.reset()
    return np.array(rows)


def _collaborative_trajectory(seed: int, steps: int = 300) -> np.ndarray:
    rng = np.random.default_rng(seed)
    actions = rng.uniform(-1, 1, (steps, 4))
    # A device seat runs in its own thread inside the env (teleop_timeout): the replayed surgeon is such a device.
    env = suction_debris_v8.parallel_env(surgeon=ReplayDevice(actions), reward_type="dense")
    observations, _ = env.reset(seed=seed)
    rows = []
    for t in range(steps):
        observations, rewards, *_ = env.step({"suction": actions[t][::-1].copy()})
        rows.append(np.concatenate([observations["suction"], [rewards["suction"]]]))
    return np.array(rows)


def _in_threads(function, seeds):
    results = {}

    def run(seed):
        results[seed] = function(seed)

    threads = [threading.Thread(target=run, args=(seed,)) for seed in seeds]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    return results


def test_pick_envs_in_two_threads_match_sequential_runs():
    parallel = _in_threads(_pick_trajectory, [1, 2])
    for seed in (1, 2):
        np.testing.assert_array_equal(parallel[seed], _pick_trajectory(seed))


@pytest.mark.slow
def test_collaborative_envs_with_device_seats_in_two_threads_match_sequential_runs():
    parallel = _in_threads(_collaborative_trajectory, [3, 4])
    for seed in (3, 4):
        np.testing.assert_array_equal(parallel[seed], _collaborative_trajectory(seed))


def test_two_envs_render_in_one_process():
    reach = gym.make("dvrl_marl/PSMReach-v1", render_mode="rgb_array")
    collaborative = suction_debris_v8.parallel_env(render_mode="rgb_array", width=320, height=240)
    reach.reset(seed=0)
    collaborative.reset(seed=0)
    first = reach.render(), collaborative.render()
    second = reach.render(), collaborative.render()
    assert first[0].shape == (480, 640, 3) and first[1].shape == (240, 320, 3)
    np.testing.assert_array_equal(first[0], second[0])
    np.testing.assert_array_equal(first[1], second[1])
    assert first[0].std() > 0 and first[1].std() > 0
    reach.close()
    collaborative.close()
