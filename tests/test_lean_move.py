"""One world's moves in floats (suction_debris/lean_move.py) are the array path's, bit for bit, under every rule set.

The parallel env takes an arm's common move in Python floats and hands every move that needs a rare rule (a wall,
the surface, a joint limit, the other instrument, a descent without headway) to the array path. Each test steps the
same episode twice, once with the lean path and once with the array path alone, and compares the whole state record,
the rewards and the flags exactly, step by step; it also asserts that both paths were taken.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from dvrl_marl.agents.collaborative import ScriptedSuction, ScriptedSurgeon
from dvrl_marl.envs import suction_debris_v8
from dvrl_marl.suction_debris import lean_move, scene_state

AGENTS = suction_debris_v8.AGENTS


def _env(lean: bool, **kwargs):
    env = suction_debris_v8.parallel_env(**kwargs)
    if not lean:
        env.core._lean = None
    return env


class _Counting:
    """Counts the lean path's moves and those it hands back (None)."""

    def __init__(self, lean):
        self.lean, self.made, self.handed_back = lean, 0, 0

    def move(self, *args):
        made = self.lean.move(*args)
        if made is None:
            self.handed_back += 1
        else:
            self.made += 1
        return made


def _same_episodes(kwargs: dict, actions: np.ndarray, seed: int) -> _Counting:
    lean, arrays = _env(True, **kwargs), _env(False, **kwargs)
    counting = lean.core._lean = _Counting(lean.core._lean)
    for env in (lean, arrays):
        env.reset(seed=seed)
    for step, row in enumerate(actions):
        commands = {agent: row[index * 4:(index + 1) * 4].astype(np.float32) for index, agent in enumerate(AGENTS)}
        results = [env.step(commands) for env in (lean, arrays)]
        assert results[0][1] == results[1][1], f"step {step}: rewards differ"
        assert results[0][2] == results[1][2] and results[0][3] == results[1][3], f"step {step}: flags differ"
        left, right = (scene_state.SceneState.as_dict(env.core.get_state()) for env in (lean, arrays))
        for name in left:
            assert np.array_equal(left[name], right[name], equal_nan=True), f"step {step}: {name} differs"
        for name in ("suction", "grasper"):
            assert np.array_equal(results[0][0][name], results[1][0][name]), f"step {step}: {name}'s observation"
        if not lean.agents:
            for env in (lean, arrays):
                env.reset()
    return counting


@pytest.mark.parametrize("blocked_moves", ["stop", "slide", "climb", "climb_ahead", "settle"])
@pytest.mark.parametrize("preset", ["default", "benchmark", "irrigation"])
def test_the_lean_path_is_the_array_path_bit_for_bit(blocked_moves, preset):
    # actions pressing down and sideways half the time, so that walls, the surface and the other arm come into play
    rng = np.random.default_rng(3)
    actions = rng.uniform(-1.0, 1.0, (400, 8))
    actions[::2, [2, 6]] = -1.0
    counting = _same_episodes(dict(preset=preset, blocked_moves=blocked_moves, max_cycles=150), actions, seed=5)
    assert counting.made > 100 and counting.handed_back > 10, (counting.made, counting.handed_back)


@pytest.mark.parametrize("preset", ["default", "irrigation"])
def test_a_scripted_team_plays_alike_on_both_paths(preset):
    """The scripted team grasps pins, hands them off and (irrigation) irrigates: the grasp's reach check and the
    moves near the pins and the other arm, which random actions seldom reach, on both paths."""
    lean, arrays = _env(True, preset=preset), _env(False, preset=preset)
    experts = [{"suction": ScriptedSuction.for_env(env), "grasper": ScriptedSurgeon.for_env(env)}
               for env in (lean, arrays)]
    observations = [env.reset(seed=11)[0] for env in (lean, arrays)]
    grasped = False
    for step in range(1500):
        results = [env.step({agent: team[agent](seen[agent]) for agent in AGENTS})
                   for env, team, seen in zip((lean, arrays), experts, observations)]
        left, right = (scene_state.SceneState.as_dict(env.core.get_state()) for env in (lean, arrays))
        for name in left:
            assert np.array_equal(left[name], right[name], equal_nan=True), f"step {step}: {name} differs"
        grasped = grasped or bool(left["held"].any())
        observations = [result[0] for result in results]
        if not lean.agents:
            break
    assert grasped and not lean.agents, "the scripted team should grasp and finish"


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10_000), bias=st.floats(-1.0, 1.0), steps=st.integers(1, 60))
def test_random_episodes_alike_on_both_paths(seed, bias, steps):
    rng = np.random.default_rng(seed)
    actions = np.clip(rng.uniform(-1.0, 1.0, (steps, 8)) + bias, -1.0, 1.0)
    _same_episodes(dict(preset="benchmark"), actions, seed=seed)


def test_only_one_numpy_world_takes_it():
    assert isinstance(suction_debris_v8.parallel_env().core._lean, lean_move.LeanMove)
    assert suction_debris_v8.batched_env(num_envs=2).core._lean is None
