"""v6_rules: a descent's headway is what it advances the way it heads, so a tip pressed out of a cavity almost
along the wall's normal keeps climbing (v5's tip cycled in place); v5 stays as it was."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pettingzoo.test import api_test, parallel_api_test

import dvrl_marl  # noqa: F401  (registration)
from dvrl_marl.suction_debris import sliding
from dvrl_marl.suction_debris.rules import Cavities
from rule_sets import v5_rules, v6_rules
from test_rules_climb import move_over_the_surface, suction_on_the_wall, suction_path

pytestmark = pytest.mark.extended  # each rule against the one it replaced, over whole episodes (.ci/extended runs them)

# The suction on the wall of the left cavity near its rim (tests/test_suction_debris_v5.py's place), heading for the
# other cavity and down, almost along the wall's normal: the command a learnt BenchMARL suction sent there, by its
# mean action, for the rest of its failed test episodes on v5.
ALONG_THE_NORMAL = np.array([0.67, -0.03, -0.82, -1.0])


def test_pettingzoo_api_and_registration():
    parallel_api_test(v6_rules.parallel_env(max_cycles=200), num_cycles=300)
    api_test(v6_rules.env(max_cycles=100), num_cycles=200)
    env = v6_rules.parallel_env()
    assert env.params.blocked_moves == "climb_ahead" and env.params.held_pin_at_grip  # v4's change kept
    assert v5_rules.parallel_env().params.blocked_moves == "climb"  # v5 stays as it was


def test_a_tip_pressed_along_the_walls_normal_climbs_out_in_v6_and_cycles_in_place_in_v5():
    stuck = suction_on_the_wall(v5_rules)
    cycling = suction_path(stuck, ALONG_THE_NORMAL, 60)
    top = stuck.phantom.top_z + stuck.params.tip_clearance
    assert np.abs(cycling[:, 0] - cycling[0, 0]).max() < 0.002  # v5: within 2 mm of where it began, the way it heads
    assert cycling[:, 2].max() < top - 0.001  # never onto the top
    assert np.abs(np.diff(cycling[:, 2])).max() > 0.0005  # ... though it moves: up a step, then back down
    env = suction_on_the_wall(v6_rules)
    path = suction_path(env, ALONG_THE_NORMAL, 60)
    top = env.phantom.top_z + env.params.tip_clearance
    assert path[:, 2].max() >= top - 1e-9  # up the wall onto the phantom's top
    assert np.all(np.diff(path[:12, 0]) > 0.0)  # climbing all the way, the way it heads (+x): no slip back
    assert env.normalise(path[-1])[0] > 0.0 and 1000 * np.linalg.norm(path[-1] - path[0]) > 30.0


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(where=st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(0.0, 0.2)),
       command=st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(-1.0, 1.0)))
def test_ahead_changes_only_descents_that_advance_too_little_and_keeps_tips_above_the_surface(where, command):
    env = v6_rules.parallel_env()
    cavities, p, old, delta, low, high = move_over_the_surface(env, where, command)
    plain = sliding.surface_target(cavities, p.tip_clearance, p.step_size, low, high, old, delta)
    ahead = sliding.surface_target(cavities, p.tip_clearance, p.step_size, low, high, old, delta, climb=True, ahead=True)
    length = np.linalg.norm(delta)
    level = delta * np.array([1.0, 1.0, 0.0])
    heading = np.linalg.norm(level) >= sliding.NO_HEADWAY * length  # a move with a level part: its advance that way
    advance = (float(((plain - old) * level).sum()) / np.linalg.norm(level) if heading
               else float(np.linalg.norm(plain - old)))
    climbed = sliding.surface_target(cavities, p.tip_clearance, p.step_size, low, high, old, level)
    further = (not heading) or float(((climbed - old) * level).sum()) / np.linalg.norm(level) > advance
    if command[2] >= 0.0 or advance >= sliding.NO_HEADWAY * length or not further:
        np.testing.assert_array_equal(ahead, plain)
    else:  # the level part, by the same rules
        np.testing.assert_array_equal(ahead, climbed)
    assert np.all(ahead >= low - 1e-12) and np.all(ahead <= high + 1e-12)
    ground = cavities.surface_height(ahead[:, 0], ahead[:, 1]) + p.tip_clearance
    assert ahead[0, 2] >= ground[0] - 1e-9


def test_a_descent_pressed_into_the_boxs_face_is_made_as_in_v5():
    """Out through the workspace's face and down (a carry pressed toward the assistant): the face stops the level part,
    so the descent is made, as in v5 (giving it up would leave the tip where it was)."""
    env = v6_rules.parallel_env()
    cavities, p = Cavities(env.phantom), env.params
    low, high = env.workspace_centre - env.workspace_range, env.workspace_centre + env.workspace_range
    old = np.array([[high[0], env.workspace_centre[1], env.workspace_centre[2]]])
    delta = p.step_size * np.array([[0.6, 0.0, -0.43]])
    ahead = sliding.surface_target(cavities, p.tip_clearance, p.step_size, low, high, old, delta, climb=True, ahead=True)
    np.testing.assert_allclose(ahead - old, [[0.0, 0.0, -0.43 * p.step_size]], atol=1e-15)


# The scripted team plays v5 step for step on v6: tests/test_suction_debris_v3.py (the earlier version's episodes);
# single == batched on v6: tests/test_batched.py.
