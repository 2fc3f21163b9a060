"""Invariants of every registered single-arm environment, plus Reach/Pick specifics."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import TOOL_POINT

import dvrl_marl  # noqa: F401  (registers the ids)
from dvrl_marl import kinematics
from dvrl_marl.agents import PickExpert, ReachExpert
from dvrl_marl.registration import SINGLE_ARM_ENV_IDS

ENV_IDS = sorted(SINGLE_ARM_ENV_IDS)


def make(env_id, **kwargs):
    return gym.make(env_id, **kwargs)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_gymnasium_env_checker(env_id):
    env = make(env_id)
    gym_check_env(env.unwrapped, skip_render_check=True)
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_stable_baselines3_env_checker(env_id):
    pytest.importorskip("stable_baselines3")
    from stable_baselines3.common.env_checker import check_env

    env = make(env_id)
    check_env(env.unwrapped, warn=True)  # Gymnasium 1.x wrappers do not forward compute_reward
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_episode_is_100_steps_with_no_termination(env_id):
    env = make(env_id)
    env.reset(seed=0)
    for step in range(100):
        _, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert not terminated
        assert truncated == (step == 99)
        assert type(reward) is float
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_same_seed_and_actions_give_identical_trajectories_for_300_steps(env_id):
    rng = np.random.default_rng(0)
    action_dim = make(env_id).action_space.shape[0]
    actions = rng.uniform(-1.2, 1.2, size=(300, action_dim))
    trajectories = []
    for _ in range(2):
        env = make(env_id)
        obs, _ = env.reset(seed=123)
        record = [obs]
        for action in actions:
            obs, reward, terminated, truncated, info = env.step(action)
            record.append((obs, reward, info))
            if truncated:
                obs, _ = env.reset()
                record.append(obs)
        trajectories.append(record)
    first, second = trajectories
    assert len(first) == len(second)
    for a, b in zip(first, second):
        assert repr(a) == repr(b)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_observations_do_not_alias_internal_state(env_id):
    env = make(env_id)
    obs, _ = env.reset(seed=1)
    before = {k: v.copy() for k, v in obs.items()}
    for value in obs.values():
        value[:] = 123.0
    obs2, *_ = env.step(np.zeros(env.action_space.shape))
    for key in obs:
        assert not np.any(obs2[key] == 123.0)
    # And two successive observations are distinct arrays.
    obs3, *_ = env.step(np.zeros(env.action_space.shape))
    for key in obs:
        assert obs3[key] is not obs2[key]
        assert not np.shares_memory(obs3[key], obs2[key])
    assert before  # the reset observation was valid before being overwritten


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_compute_reward_is_vectorised_and_matches_step(env_id):
    env = make(env_id)
    obs, _ = env.reset(seed=2)
    achieved, desired, rewards = [], [], []
    expert = (ReachExpert if "Reach" in env_id else PickExpert).for_env(env)
    for _ in range(100):
        obs, reward, _, _, info = env.step(expert(obs))
        achieved.append(obs["achieved_goal"])
        desired.append(obs["desired_goal"])
        rewards.append(reward)
    batch = env.unwrapped.compute_reward(np.array(achieved), np.array(desired), [{}] * 100)
    assert batch.shape == (100,)
    np.testing.assert_allclose(batch, rewards, rtol=0, atol=1e-12)
    if "Dense" not in env_id:
        assert set(np.unique(batch)) <= {-1.0, 0.0} and batch[-1] == 0.0


@pytest.mark.parametrize("env_id", ["dvrl_marl/PSMReach-v1", "dvrl_marl/PSMPick-v1"])
def test_bad_actions_raise_clear_errors(env_id):
    env = make(env_id)
    env.reset(seed=0)
    n = env.action_space.shape[0]
    with pytest.raises(ValueError, match="NaN or inf"):
        env.step(np.full(n, np.nan))
    with pytest.raises(ValueError, match="NaN or inf"):
        env.step(np.array([np.inf] + [0.0] * (n - 1)))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(n + 1))
    with pytest.raises(ValueError, match="not numeric"):
        env.step(["a"] * n)
    # Out-of-range values are clipped: a huge action moves by exactly eta per axis.
    unwrapped = env.unwrapped
    env.reset(seed=0, options={"start": unwrapped.workspace_centre, "goal": unwrapped.workspace_centre})
    before = np.array(unwrapped.arm.tip)
    env.step(np.array([1e6, -1e6, 0.0] + [0.0] * (n - 3)))
    np.testing.assert_allclose(np.array(unwrapped.arm.tip) - before, [unwrapped.step_size, -unwrapped.step_size, 0.0])


def test_invalid_constructor_arguments_and_reset_options_raise():
    with pytest.raises(ValueError, match="reward_type"):
        make("dvrl_marl/PSMReach-v1", reward_type="shaped")
    with pytest.raises(ValueError, match="tool"):
        make("dvrl_marl/PSMReach-v1", tool="scissors")
    with pytest.raises(ValueError, match="workspace_range"):
        make("dvrl_marl/PSMReach-v1", workspace_range=-1.0)
    with pytest.raises(ValueError, match="render_mode"):
        make("dvrl_marl/PSMReach-v1", render_mode="ascii")
    env = make("dvrl_marl/PSMPick-v1")
    with pytest.raises(ValueError, match="unknown reset option"):
        env.reset(options={"target": [0, 0, -0.1]})
    with pytest.raises(ValueError, match="'goal'"):
        env.reset(options={"goal": [0.0, 0.0, 0.5]})
    with pytest.raises(ValueError, match="'start'"):
        env.reset(options={"start": [np.nan, 0.0, -0.1]})
    with pytest.raises(ValueError, match="'object'"):
        env.reset(options={"object": [0.0, 0.0, -0.2]})  # inside the table
    with pytest.raises(ValueError, match="3"):
        env.reset(options={"goal": [0.0, -0.1]})


def test_reset_options_set_goal_start_and_object_in_metres():
    env = make("dvrl_marl/PSMPick-v1")
    u = env.unwrapped
    goal = np.array([0.01, -0.01, -0.09])
    start = np.array([0.005, 0.0, -0.1])
    obj = np.array([-0.01, 0.01, u.object_rest_height])
    obs, _ = env.reset(seed=0, options={"goal": goal, "start": start, "object": obj})
    np.testing.assert_allclose(obs["desired_goal"], u.normalise(goal))
    np.testing.assert_allclose(obs["observation"][:3], u.normalise(start))
    np.testing.assert_allclose(obs["achieved_goal"], u.normalise(obj), atol=1e-12)
    # Without an object option, the object lies on the table directly below the start.
    obs, _ = env.reset(seed=0, options={"start": start})
    np.testing.assert_allclose(u.object_position()[:2], start[:2], atol=1e-12)


@pytest.mark.parametrize("tool", ["lnd", "suction_irrigation"])
def test_reach_goals_and_starts_are_reachable_and_inside_the_workspace(tool):
    env = make("dvrl_marl/PSMReach-v1", tool=tool)
    u = env.unwrapped
    goals, starts = [], []
    for seed in range(300):
        obs, _ = env.reset(seed=seed)
        goals.append(u.goal)
        starts.append(np.array(u.arm.tip))
    for points in (np.array(goals), np.array(starts)):
        assert np.all(points >= u.tip_low - 1e-12) and np.all(points <= u.tip_high + 1e-12)
        assert np.all(kinematics.within_limits(u.tool, points))
        assert np.all(points[:, 2] >= u.table_height)
    # Uniform over the reachable box: the samples spread over (nearly) all of it.
    spread = np.array(goals).max(0) - np.array(goals).min(0)
    assert np.all(spread > 0.9 * (u.tip_high - u.tip_low))


def test_pick_goals_are_never_below_the_resting_object():
    env = make("dvrl_marl/PSMPick-v1")
    u = env.unwrapped
    for seed in range(200):
        env.reset(seed=seed)
        assert u.goal[2] >= u.object_rest_height - 1e-12


@settings(max_examples=30, deadline=None)
@given(
    env_id=st.sampled_from(["dvrl_marl/PSMReach-v1", "dvrl_marl/PSMPick-v1"]),
    tool=st.sampled_from(["lnd", "suction_irrigation"]),
    seed=st.integers(0, 2**16),
    actions=st.lists(st.lists(st.floats(-3.0, 3.0, allow_nan=False), min_size=4, max_size=4), min_size=1, max_size=150),
)
def test_tip_stays_in_workspace_joint_limits_and_above_table(env_id, tool, seed, actions):
    kwargs = {"tool": tool} if "Reach" in env_id else {}
    env = make(env_id, **TOOL_POINT[env_id], **kwargs)
    u = env.unwrapped
    env.reset(seed=seed)
    n = env.action_space.shape[0]
    for action in actions:
        env.step(np.array(action[:n]))
        tip = np.array(u.arm.tip)
        assert np.all(tip >= u.tip_low - 1e-12) and np.all(tip <= u.tip_high + 1e-12)
        assert tip[2] > u.table_height
        q = np.array(u.arm.q)
        assert np.all(q >= np.asarray(u.tool.lower)) and np.all(q <= np.asarray(u.tool.upper))
        np.testing.assert_allclose(kinematics.forward_kinematics(u.tool, q)[:3, 3], tip, atol=1e-12)


def test_joint_limit_projection_keeps_the_tip_reachable():
    # A workspace centred far to the side: its outer part needs a wrist yaw beyond the limit.
    env = make("dvrl_marl/PSMReach-v1", **TOOL_POINT["dvrl_marl/PSMReach-v1"], workspace_centre=(0.09, 0.0, -0.08), workspace_range=0.05)
    u = env.unwrapped
    env.reset(seed=0, options={"start": (0.09, 0.0, -0.08)})
    for _ in range(80):
        env.step(np.array([1.0, 0.0, 1.0]))
        assert kinematics.within_limits(u.tool, np.array(u.arm.tip))
    assert not kinematics.within_limits(u.tool, np.array(u.arm.tip) + (0.001, 0.0, 0.001))


def _run_expert(env_id, expert_cls, seeds, **kwargs):
    env = make(env_id, **TOOL_POINT[env_id], **kwargs)
    expert = expert_cls.for_env(env)
    successes = 0
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        for _ in range(100):
            obs, reward, terminated, truncated, info = env.step(expert(obs))
        successes += bool(info["is_success"])
    return successes / len(seeds)


@pytest.mark.parametrize("tool", ["lnd", "suction_irrigation"])
def test_reach_expert_solves_at_least_99_percent(tool):
    assert _run_expert("dvrl_marl/PSMReach-v1", ReachExpert, range(200), tool=tool) >= 0.99


def test_pick_expert_solves_at_least_95_percent():
    assert _run_expert("dvrl_marl/PSMPick-v1", PickExpert, range(200)) >= 0.95


def test_pick_expert_lifts_the_object_to_the_goal_by_the_grasp_rule():
    env = make("dvrl_marl/PSMPick-v1", **TOOL_POINT["dvrl_marl/PSMPick-v1"])
    u = env.unwrapped
    expert = PickExpert.for_env(env)
    obs, _ = env.reset(seed=5, options={"goal": [0.01, 0.015, -0.08]})
    rest = u.object_position()
    grasped_at = None
    for t in range(100):
        obs, reward, _, _, info = env.step(expert(obs))
        if info["grasped"] and grasped_at is None:
            grasped_at = t
            assert u.arm.jaw < u.grasp_threshold
    assert grasped_at is not None
    assert u.object_position()[2] > rest[2] + 0.01  # lifted
    assert np.linalg.norm(u.object_position() - u.goal) <= u.distance_threshold
    assert info["is_success"] and reward == 0.0


def test_an_open_jaw_never_carries_the_object():
    env = make("dvrl_marl/PSMPick-v1", **TOOL_POINT["dvrl_marl/PSMPick-v1"])
    u = env.unwrapped
    env.reset(seed=0)
    rest = u.object_position()
    # Descend onto the object with the jaw open (phi = +1: j = 1), then rise with it still open.
    for _ in range(30):
        env.step(np.array([0.0, 0.0, -1.0, 1.0]))
    assert u.arm.grasp_sensor(u.arm.to_world(rest))
    for _ in range(30):
        _, _, _, _, info = env.step(np.array([0.0, 0.0, 1.0, 1.0]))
        assert not info["grasped"]
    np.testing.assert_allclose(u.object_position(), rest, atol=1e-9)
    # A jaw just at the threshold (j = 0.25) does not grasp either.
    for _ in range(30):
        env.step(np.array([0.0, 0.0, -1.0, 2 * u.grasp_threshold - 1.0]))
    assert not u.grasped


def test_closing_away_from_the_object_does_not_grasp():
    env = make("dvrl_marl/PSMPick-v1")
    u = env.unwrapped
    env.reset(seed=0)
    for _ in range(5):
        _, _, _, _, info = env.step(np.array([1.0, 0.0, -1.0, -1.0]))  # closed jaw, 10 mm off to the side
    assert not info["grasped"]


def test_releasing_drops_the_object_to_the_table():
    env = make("dvrl_marl/PSMPick-v1", **TOOL_POINT["dvrl_marl/PSMPick-v1"])
    u = env.unwrapped
    expert = PickExpert.for_env(env)
    obs, _ = env.reset(seed=3, options={"goal": [0.0, 0.0, -0.08]})
    for _ in range(60):
        obs, *_ = env.step(expert(obs))
    assert u.grasped and u.object_position()[2] > u.object_rest_height + 0.02
    _, _, _, _, info = env.step(np.array([0.0, 0.0, 0.0, 1.0]))  # open
    assert not info["grasped"]
    heights = []
    for _ in range(40):
        _, _, _, truncated, info = env.step(np.array([0.0, 0.0, 0.0, 1.0]))
        heights.append(u.object_position()[2])
        assert "sim_unstable" not in info
    assert heights[0] < u.object_rest_height + 0.04  # it fell
    assert u.table_height < heights[-1] <= u.object_rest_height + 1e-3  # and lies on the table
    assert np.all(np.isfinite(u.data.qpos))


def test_pick_tool_is_fixed_to_the_needle_driver():
    env = make("dvrl_marl/PSMPick-v1")
    assert env.unwrapped.tool is kinematics.LND
    assert env.unwrapped.grasp_threshold == 0.25
    assert make("dvrl_marl/PSMPick-v1", grasp_threshold=0.3).unwrapped.grasp_threshold == 0.3


def test_paper_defaults():
    reach = make("dvrl_marl/PSMReach-v1").unwrapped
    pick = make("dvrl_marl/PSMPick-v1").unwrapped
    assert reach.workspace_range == 0.05 and pick.workspace_range == 0.025
    assert reach.step_size == pick.step_size == 0.001
    assert reach.distance_threshold == pick.distance_threshold == 0.003
    assert reach.dt == pick.dt == 0.02
    np.testing.assert_allclose(reach.workspace_centre, [0, 0, -0.11])
    np.testing.assert_allclose(pick.workspace_centre, [0, 0, -0.10])
    assert make("dvrl_marl/PSMReach-v1").spec.max_episode_steps == 100


@pytest.mark.parametrize("mode", ["rgb_array", "depth_array"])
@pytest.mark.parametrize("env_id", ["dvrl_marl/PSMReach-v1", "dvrl_marl/PSMPick-v1"])
def test_rendering_from_the_endoscope(env_id, mode):
    env = make(env_id, render_mode=mode, width=96, height=64)
    env.reset(seed=0)
    frame = env.render()
    if mode == "rgb_array":
        assert frame.shape == (64, 96, 3) and frame.dtype == np.uint8 and frame.std() > 1
    else:
        assert frame.shape == (64, 96) and np.all(np.isfinite(frame)) and frame.max() > frame.min()
    env.close()


@pytest.mark.slow
def test_vector_envs_and_sb3_her_smoke():
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import SAC, HerReplayBuffer

    vec = gym.make_vec("dvrl_marl/PSMReach-v1", num_envs=3, vectorization_mode="sync")
    obs, _ = vec.reset(seed=0)
    assert obs["observation"].shape == (3, 3)
    obs, rewards, *_ = vec.step(vec.action_space.sample())
    assert rewards.shape == (3,)
    vec.close()
    for env_id in ("dvrl_marl/PSMReach-v1", "dvrl_marl/PSMPick-v1"):
        model = SAC(
            "MultiInputPolicy", make(env_id), replay_buffer_class=HerReplayBuffer,
            replay_buffer_kwargs={"n_sampled_goal": 4, "goal_selection_strategy": "future"},
            learning_starts=100, batch_size=32, buffer_size=5000, policy_kwargs={"net_arch": [32, 32]}, seed=0, verbose=0,
        )
        model.learn(300)
