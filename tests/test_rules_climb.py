"""v5_rules: a descending move the wall leaves no headway gives up its descent (it climbs); v4 stays as it
was."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pettingzoo.test import api_test, parallel_api_test

import dvrl_marl  # noqa: F401  (registration)
from dvrl_marl.suction_debris import sliding
from dvrl_marl.suction_debris.rules import Cavities
from rule_sets import v4_rules, v5_rules

pytestmark = pytest.mark.extended  # each rule against the one it replaced, over whole episodes (.ci/extended runs them)

# The suction on the wall of the left cavity near its rim, heading for the other cavity: out and down, into the
# bowl (the measured end of issue 37's failed mean-action episodes on v4).
ON_THE_WALL = [-0.121, -0.12]
OUT_AND_DOWN = np.array([1.0, -0.23, -0.64, -1.0])


def test_pettingzoo_api_and_registration():
    parallel_api_test(v5_rules.parallel_env(max_cycles=200), num_cycles=300)
    api_test(v5_rules.env(max_cycles=100), num_cycles=200)
    env = v5_rules.parallel_env()
    assert env.params.blocked_moves == "climb" and env.params.held_pin_at_grip  # v4's change kept
    assert v4_rules.parallel_env().params.blocked_moves == "slide"  # v4 stays as it was


def on_the_surface(env, where):
    """The tip's place (world) on the phantom's surface at ``where`` (normalised x, y)."""
    x, y, _ = env.workspace_centre + env.workspace_range * np.array([*where, 0.0])
    return [x, y, env.phantom.surface_height(x, y) + env.params.tip_clearance]


def suction_on_the_wall(module, where=ON_THE_WALL, blood_ml=(0.0, 0.0), valve_open=False, grasper_at=None):
    """One hidden pin left (the episode goes on), the suction on the surface at ``where`` (by default the left
    cavity's wall near its rim), ``blood_ml`` in the cavities; the grasper on the surface at ``grasper_at``, else
    above the right cavity."""
    env = module.parallel_env(blood_ml=list(blood_ml))
    env.reset(seed=0)
    count = len(env.debris)
    grasper = (on_the_surface(env, grasper_at) if grasper_at is not None
               else env.workspace_centre + env.workspace_range * np.array([0.6, 0.0, 0.2]))
    tips = {"suction": env.arms["suction"].to_base(on_the_surface(env, where)),
            "grasper": env.arms["grasper"].to_base(grasper)}
    env.set_state(tips=tips, jaw=1.0, valve_open=valve_open, blood_ml=list(blood_ml),
                  debris_positions=[[0.0, 0.0, env.phantom.top_z]] * count, debris_yaws=[0.0] * count,
                  visible=[False] * count, delivered=[False] + [True] * (count - 1))
    return env


def suction_path(env, command, steps):
    path = [np.array(env.arms["suction"].tip_world())]
    for _ in range(steps):
        env.step({"suction": command, "grasper": np.zeros(4)})
        path.append(np.array(env.arms["suction"].tip_world()))
    return np.array(path)


def test_a_tip_pressed_out_and_down_against_a_wall_rides_over_the_rim_in_v5_and_stays_in_v4():
    stuck = suction_path(suction_on_the_wall(v4_rules), OUT_AND_DOWN, 60)
    assert np.linalg.norm(stuck[-1] - stuck[0]) < 0.0005  # v4: under half a millimetre in 60 steps
    env = suction_on_the_wall(v5_rules)
    path = suction_path(env, OUT_AND_DOWN, 60)
    top = env.phantom.top_z + env.params.tip_clearance
    assert path[:, 2].max() >= top - 1e-9  # up the wall onto the phantom's top
    assert env.normalise(path[-1])[0] > 0.0  # and on, the way it was heading (+x), past the ridge
    assert 1000 * np.linalg.norm(path[-1] - path[0]) > 40.0


def move_over_the_surface(env, where, command):
    """A tip ``where`` (normalised x, y and a lift above the surface) and a command: the cavities, the parameters,
    the tip (1, 3), the move (1, 3) and the workspace box, as :func:`dvrl_marl.suction_debris.sliding.surface_target` takes
    them."""
    cavities, p = Cavities(env.phantom), env.params
    x, y, lift = env.workspace_centre + env.workspace_range * np.array(where)
    old = np.array([[x, y, float(cavities.surface_height(np.array([x]), np.array([y]))[0]) + p.tip_clearance
                     + lift * env.workspace_range]])
    delta = p.step_size * np.array([command])
    low, high = env.workspace_centre - env.workspace_range, env.workspace_centre + env.workspace_range
    return cavities, p, old, delta, low, high


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(where=st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(0.0, 0.2)),
       command=st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(-1.0, 1.0)))
def test_climbing_changes_only_descents_that_make_no_headway_and_keeps_tips_above_the_surface(where, command):
    env = v5_rules.parallel_env()
    cavities, p, old, delta, low, high = move_over_the_surface(env, where, command)
    plain = sliding.surface_target(cavities, p.tip_clearance, p.step_size, low, high, old, delta)
    climbed = sliding.surface_target(cavities, p.tip_clearance, p.step_size, low, high, old, delta, climb=True)
    made = np.linalg.norm(plain - old)
    if command[2] >= 0.0 or made >= sliding.NO_HEADWAY * np.linalg.norm(delta):
        np.testing.assert_array_equal(climbed, plain)
    else:  # the level part, by the same rules
        level = sliding.surface_target(cavities, p.tip_clearance, p.step_size, low, high, old,
                                       delta * np.array([1.0, 1.0, 0.0]))
        np.testing.assert_array_equal(climbed, level)
    assert np.all(climbed >= low - 1e-12) and np.all(climbed <= high + 1e-12)
    ground = cavities.surface_height(climbed[:, 0], climbed[:, 1]) + p.tip_clearance
    assert climbed[0, 2] >= ground[0] - 1e-9


# The scripted team plays v4 step for step on v5: tests/test_suction_debris_v3.py (the earlier version's episodes).
