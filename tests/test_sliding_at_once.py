"""A blocked move's candidates tried all at once (numpy, few rows: ``sliding.ALL_AT_ONCE_ROWS``) choose what trying
them one after another chooses, row by row, bit for bit: the same worlds, stepped both ways, stay equal."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from dvrl_marl.envs import suction_debris
from dvrl_marl.suction_debris import scene_state, sliding

WORLDS = 5


def _run(rows: int, pushes, preset: str):
    kept = sliding.ALL_AT_ONCE_ROWS
    sliding.ALL_AT_ONCE_ROWS = rows
    try:
        return _steps(pushes, preset)
    finally:
        sliding.ALL_AT_ONCE_ROWS = kept


def _steps(pushes, preset: str):
    env = suction_debris.batched_env(num_envs=WORLDS, preset=preset)
    env.reset(seed=2)
    states = []
    for push, steps in pushes:  # a policy pressing one way for a while (into walls, the other arm, the limits)
        action = np.tile(np.asarray(push, dtype=np.float64), (WORLDS, 1))
        for _ in range(steps):
            env.step({"suction": action[:, :4], "grasper": action[:, 4:]})
        states.append(env.core.get_state())
    return states


@settings(max_examples=12, deadline=None)
@given(pushes=st.lists(st.tuples(st.tuples(*[st.floats(-1.0, 1.0)] * 8), st.integers(5, 60)), min_size=1,
                       max_size=4), preset=st.sampled_from(["default", "benchmark"]))
def test_all_at_once_is_one_after_another(pushes, preset):
    at_once = _run(10**6, pushes, preset)
    in_turn = _run(0, pushes, preset)
    for a, b in zip(at_once, in_turn):
        for name in scene_state.SPECS:
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_a_world_pressing_into_blockers_slides_alike_both_ways():
    """Both arms pressing one way for 400 steps (a case that slides on most steps): the fallbacks are exercised."""
    calls = []
    resolve = sliding.resolve_blocked

    def counted(*args, **kwargs):
        calls.append(len(args[3]))
        return resolve(*args, **kwargs)

    sliding.resolve_blocked = counted
    try:
        push = np.random.default_rng(4).uniform(-1, 1, 8)
        at_once, in_turn = _run(10**6, [(push, 400)], "default"), _run(0, [(push, 400)], "default")
    finally:
        sliding.resolve_blocked = resolve
    assert len(calls) > 200
    for name in scene_state.SPECS:
        np.testing.assert_array_equal(getattr(at_once[0], name), getattr(in_turn[0], name), err_msg=name)
