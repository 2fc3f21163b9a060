"""v3_rules: a blocked move slides (dvrl_marl.suction_debris.sliding) instead of stopping; v2 stays as it was."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pettingzoo.test import api_test, parallel_api_test

import dvrl_marl  # noqa: F401  (registration)
from dvrl_marl import kinematics
from dvrl_marl.agents import ScriptedSuction, ScriptedSurgeon
from dvrl_marl.envs import suction_debris_v8
from rule_sets import v2_rules, v3_rules, v4_rules, v5_rules, v6_rules

pytestmark = pytest.mark.extended  # each rule against the one it replaced, over whole episodes (.ci/extended runs them)

PUSH_SUCTION_PAST_GRASPER = np.array([1.0, 0.0, -0.1, 1.0])


def test_pettingzoo_api_and_registration():
    parallel_api_test(v3_rules.parallel_env(max_cycles=200), num_cycles=300)
    api_test(v3_rules.env(max_cycles=100), num_cycles=200)
    env = v3_rules.parallel_env()
    assert env.params.blocked_moves == "slide" and env.params.deliver_at_grip and env.params.pins_stay_on_phantom
    assert v2_rules.parallel_env().params.blocked_moves == "stop"  # v2 stays as it was


def test_an_unknown_blocked_moves_rule_is_refused_by_name():
    with pytest.raises(ValueError, match="blocked_moves"):
        v3_rules.parallel_env(blocked_moves="bounce")


def _scene(module, suction, grasper):
    """No blood, one hidden pin left to deliver (the episode goes on), the tips at normalised positions."""
    env = module.parallel_env(blood_ml=[0.0, 0.0])
    env.reset(seed=0)
    count = len(env.debris)
    world = {agent: env.workspace_centre + env.workspace_range * np.asarray(tip)
             for agent, tip in (("suction", suction), ("grasper", grasper))}
    env.set_state(tips={agent: env.arms[agent].to_base(tip) for agent, tip in world.items()}, jaw=1.0,
                  valve_open=False, blood_ml=[0.0, 0.0], debris_positions=[[0.0, 0.0, env.phantom.top_z]] * count,
                  debris_yaws=[0.0] * count, visible=[False] * count, delivered=[False] + [True] * (count - 1))
    return env


def _push(env, agent, action, steps):
    """``action`` on ``agent`` (the other arm still) for ``steps`` steps: the tip's path (world, m) and the least
    clearance between the instruments."""
    hold = np.zeros(4)
    path, least = [np.array(env.arms[agent].tip_world())], np.inf
    for _ in range(steps):
        env.step({a: (action if a == agent else hold) for a in env.agents})
        path.append(np.array(env.arms[agent].tip_world()))
        least = min(least, env.instrument_clearance())
    return np.array(path), least


@pytest.mark.parametrize("module", [v2_rules, v3_rules])
def test_a_tip_pushed_sideways_against_a_cavity_wall_rides_up_it_and_over_the_rim_in_v3_only(module):
    # The suction on the floor of the left cavity (centre x~ = -0.375) pushes straight toward -x, no vertical
    # command: in v2 the wall keeps it where it is; in v3 it slides up the bowl and leaves the cavity.
    env = _scene(module, suction=[-0.375, -0.0625, -0.52], grasper=[0.6, 0.0, 0.2])
    path, _ = _push(env, "suction", np.array([-1.0, 0.0, 0.0, -1.0]), 80)
    left_edge = env.workspace_centre[0] + env.workspace_range * (-0.375 - 0.275)
    if module is v3_rules:
        assert path[-1, 2] > env.phantom.top_z  # over the rim
        assert path[-1, 0] < left_edge  # and out of the cavity, beyond its mouth
        assert np.all(np.diff(path[:, 2]) >= -1e-12)  # riding up, never down
    else:
        assert path[-1, 0] > left_edge and path[-1, 2] < env.phantom.top_z  # still in the cavity
        assert np.abs(path[-1] - path[20]).max() < 1e-12  # and motionless against its wall


@pytest.mark.parametrize("module", [v2_rules, v3_rules])
def test_a_move_into_the_other_instrument_slides_past_it_in_v3_only(module):
    # The grasper's tip hangs 16 mm above the phantom's top between the cavities; the suction, on the top, pushes
    # toward +x into its shaft (the measured deadlock of issue 37's mean-action teams).
    env = _scene(module, suction=[-0.05, -0.04, -0.362], grasper=[0.0, -0.003, -0.156])
    path, least = _push(env, "suction", PUSH_SUCTION_PAST_GRASPER, 60)
    assert least >= 0.0  # the instruments never pass through each other, either version
    travelled = 1000 * (path[-1, 0] - path[0, 0])
    if module is v3_rules:
        assert travelled > 40.0  # mm of the 60 commanded: around the shaft
    else:
        assert travelled < 10.0 and np.abs(path[-1] - path[-20]).max() < 1e-12  # stopped against it


def test_a_move_into_a_joint_limit_slides_along_it_in_v3():
    # Near its RCM the suction's outer pitch is at its limit and every axis of this command pushes further into it:
    # v2 stops dead there; v3 slides along the limit (the pitch held at it) until the workspace box's face stops it
    # too, the joints always within their limits.
    travelled = {}
    for module in (v2_rules, v3_rules):
        env = _scene(module, suction=[-0.6, -0.12, 0.55], grasper=[0.6, 0.0, 0.2])
        tool = env.arms["suction"].tool
        path, _ = _push(env, "suction", np.array([-0.7, 0.1, 0.9, -1.0]), 10)
        q = np.asarray(env.arms["suction"].q)
        assert abs(q[1] - tool.lower[1]) < 1e-6  # at the outer-pitch limit
        path, _ = _push(env, "suction", np.array([-0.7, 0.1, 0.9, -1.0]), 50)
        q = np.asarray(env.arms["suction"].q)
        assert np.all(q >= np.asarray(tool.lower) - 1e-12) and np.all(q <= np.asarray(tool.upper) + 1e-12)
        travelled[module] = 1000 * np.linalg.norm(path[-1] - path[0])
    assert travelled[v2_rules] < 1e-9  # pinned
    assert travelled[v3_rules] > 20.0  # mm along the limit


@pytest.mark.parametrize("before,after", [(v2_rules, v3_rules), (v4_rules, v5_rules),
                                          (v5_rules, v6_rules),
                                          (v6_rules, suction_debris_v8)])
def test_the_scripted_team_plays_the_earlier_version_step_for_step(before, after):
    # An expert never pushes into a blocker (v3) nor presses a descent into a wall (v5): its episodes are the earlier
    # version's exactly (the change is only where moves block).
    traces = []
    for module in (before, after):
        env = module.batched_env(num_envs=6, autoreset_mode="disabled")
        experts = {"suction": ScriptedSuction.for_env(env), "grasper": ScriptedSurgeon.for_env(env)}
        observations, _ = env.reset(seed=3)
        trace, success = [], np.zeros(6, dtype=bool)
        for _ in range(1200):
            observations, _, _, _, infos = env.step({a: experts[a](observations[a]) for a in env.agents})
            trace.append(np.concatenate([observations[a] for a in env.agents], axis=1))
            success |= infos["suction"]["is_success"]
        assert success.all()
        traces.append(np.array(trace))
    np.testing.assert_array_equal(traces[0], traces[1])


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), action_seed=st.integers(0, 2**31 - 1),
       bias=st.sampled_from(["into_phantom", "into_each_other", "up_and_out", "uniform"]),
       module=st.sampled_from([v3_rules, v5_rules, v6_rules, suction_debris_v8]))
def test_sliding_keeps_every_tip_in_the_box_above_the_surface_within_its_joints_and_apart(seed, action_seed, bias,
                                                                                          module):
    # Commands biased into the blockers (the phantom, the other instrument, the joint limits near the RCMs): however
    # moves slide (and, in v5, climb), the tips stay in the workspace box, above every surface, within the joint
    # limits, and the instruments never intersect.
    worlds = 8
    env = module.batched_env(num_envs=worlds)
    env.reset(seed=seed)
    core = env.core
    rng = np.random.default_rng(action_seed)
    pulls = {"into_phantom": {"suction": [0.9, 0.0, -1.0], "grasper": [-0.9, 0.0, -1.0]},
             "into_each_other": {"suction": [1.0, 0.1, -0.3], "grasper": [-1.0, -0.1, -0.3]},
             "up_and_out": {"suction": [-0.8, -0.3, 1.0], "grasper": [0.8, -0.3, 1.0]},
             "uniform": {"suction": [0.0, 0.0, 0.0], "grasper": [0.0, 0.0, 0.0]}}[bias]
    for _ in range(300):
        actions = {agent: np.concatenate([np.asarray(pulls[agent]) + rng.normal(0.0, 0.5, (worlds, 3)),
                                          rng.uniform(-1.0, 1.0, (worlds, 1))], axis=1) for agent in env.agents}
        env.step(actions)
        for agent, arm in core.arms.items():
            tip = arm.tip_world()
            assert np.all(tip >= core.low - 1e-12) and np.all(tip <= core.high + 1e-12)
            assert np.all(tip[:, 2] >= core.cavities.surface_height(tip[:, 0], tip[:, 1])
                          + core.params.tip_clearance - 1e-9)
            _, reachable = kinematics.inverse_kinematics_batch(arm.tool, arm.tip)
            assert reachable.all()
        assert np.all(core.instrument_clearance() >= 0.0)
