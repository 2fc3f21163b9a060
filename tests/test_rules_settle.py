"""suction_debris_v8: the suction pressed down into a cavity's bowl slides down it, so a suction pressed straight down
on the slope above the last of the blood reaches the pool (v6's stayed where it was); the grasper pressing down onto a
pin stays over it; v6 stays as it was."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pettingzoo.test import api_test, parallel_api_test

import dvrl_marl  # noqa: F401  (registration)
from dvrl_marl.envs import suction_debris_v8
from dvrl_marl.suction_debris import sliding
from rule_sets import v6_rules
from test_rules_climb import move_over_the_surface, suction_on_the_wall, suction_path

pytestmark = pytest.mark.extended  # each rule against the one it replaced, over whole episodes (.ci/extended runs them)

# Where a learnt BenchMARL suction (seed 0, by its mean action) rested on v6 for the rest of its failed test episodes:
# on the left cavity's slope, toward the ridge, a few millimetres above the last half millilitre, pressing straight down
# with the valve open.
ON_THE_SLOPE = (-0.19, -0.12)
STRAIGHT_DOWN = np.array([0.0, 0.0, -0.7, 0.41])


def test_pettingzoo_api_and_registration():
    parallel_api_test(suction_debris_v8.parallel_env(max_cycles=200), num_cycles=300)
    api_test(suction_debris_v8.env(max_cycles=100), num_cycles=200)
    env = suction_debris_v8.parallel_env()
    assert env.params.blocked_moves == "settle" and env.params.held_pin_at_grip  # v4's change kept
    assert v6_rules.parallel_env().params.blocked_moves == "climb_ahead"  # v6 stays as it was


def _suction_above_the_last_blood(module, grasper_on_the_slope=False):
    return suction_on_the_wall(module, where=ON_THE_SLOPE, blood_ml=(0.56, 0.0), valve_open=True,
                               grasper_at=(-ON_THE_SLOPE[0], ON_THE_SLOPE[1]) if grasper_on_the_slope else None)


def test_a_suction_pressed_down_the_slope_reaches_the_last_blood_in_v7_and_rests_above_it_in_v6():
    stuck = _suction_above_the_last_blood(v6_rules)
    path = suction_path(stuck, STRAIGHT_DOWN, 100)
    assert np.linalg.norm(path[-1] - path[0]) < 1e-9 and stuck.blood.remaining_ml[0] == 0.56  # v6: not a drop
    env = _suction_above_the_last_blood(suction_debris_v8)
    path = suction_path(env, STRAIGHT_DOWN, 100)
    centre = env.phantom.cavities[0].centre_x
    assert abs(path[-1, 0] - centre) < abs(path[0, 0] - centre) - 0.005  # down the slope toward the floor's centre
    assert np.all(np.diff(path[:, 2]) <= 1e-12)  # never up
    assert env.blood.remaining_ml[0] < env.params.blood_threshold_ml  # the cavity cleared


def test_the_grasper_pressed_down_on_the_slope_stays_where_it_is_as_in_v6():
    # A grasper coming down onto a pin on the slope must stay over it: the slide is the suction's alone.
    for module in (v6_rules, suction_debris_v8):
        env = _suction_above_the_last_blood(module, grasper_on_the_slope=True)
        start = np.array(env.arms["grasper"].tip_world())
        for _ in range(50):
            env.step({"suction": np.zeros(4), "grasper": STRAIGHT_DOWN})
        assert np.linalg.norm(np.array(env.arms["grasper"].tip_world()) - start) < 1e-9, module.__name__


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(where=st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(0.0, 0.2)),
       command=st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(-1.0, 1.0)))
def test_settle_changes_only_descents_left_without_headway_over_a_cavity_and_keeps_tips_above_the_surface(where,
                                                                                                         command):
    env = suction_debris_v8.parallel_env()
    cavities, p, old, delta, low, high = move_over_the_surface(env, where, command)
    v6 = sliding.surface_target(cavities, p.tip_clearance, p.step_size, low, high, old, delta, climb=True, ahead=True)
    v7 = sliding.surface_target(cavities, p.tip_clearance, p.step_size, low, high, old, delta, climb=True, ahead=True,
                                settle=True)
    made = np.linalg.norm(v6 - old)
    resting = command[2] < 0.0 and made < sliding.NO_HEADWAY * np.linalg.norm(delta) and cavities.cavity_at(
        old[:, 0], old[:, 1])[0] >= 0
    if not resting:
        np.testing.assert_array_equal(v7, v6)
    else:  # the slide along the bowl, where it makes more
        slid = sliding.surface_target(cavities, p.tip_clearance, p.step_size, low, high, old,
                                      sliding.wall_slide(cavities, old, delta))
        assert np.array_equal(v7, slid) or np.array_equal(v7, v6)
        assert np.linalg.norm(v7 - old) >= made
    assert np.all(v7 >= low - 1e-12) and np.all(v7 <= high + 1e-12)
    ground = cavities.surface_height(v7[:, 0], v7[:, 1]) + p.tip_clearance
    assert v7[0, 2] >= ground[0] - 1e-9


# The scripted team plays v6 step for step on v7: tests/test_suction_debris_v3.py (the earlier version's episodes);
# single == batched on v7: tests/test_batched.py.


def test_the_move_rules_of_each_version_and_a_bad_value_named():
    rules = {value: {agent: sliding.MoveRules.of(value, agent) for agent in ("suction", "grasper")}
             for value in sliding.BLOCKED_MOVES}
    assert rules["stop"]["suction"] == sliding.MoveRules()
    assert rules["climb_ahead"]["suction"] == sliding.MoveRules(slide=True, climb=True, ahead=True)
    assert rules["settle"]["suction"].settle and not rules["settle"]["grasper"].settle  # the suction's alone
    assert rules["settle"]["grasper"] == rules["climb_ahead"]["grasper"]
    with pytest.raises(ValueError, match="blocked_moves.*'glide'"):
        sliding.MoveRules.of("glide", "suction")
