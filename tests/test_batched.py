"""The batched core: world i of a batch equals the single environment seeded s + i, step for step.

Covers the native Gymnasium vector envs of Reach and Pick (every registered id) and suction_debris_v8.batched_env,
Gymnasium's vector checks, autoreset modes, bad input and rendering of a chosen world.
"""

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rule_sets import v0_rules

import dvrl_marl  # noqa: F401  (registers the ids)
from dvrl_marl.agents import PickExpert, ScriptedSuction, ScriptedSurgeon
from dvrl_marl.core.pick import carried_floor, grasp_events
from dvrl_marl.envs import suction_debris_v8
from dvrl_marl.registration import SINGLE_ARM_ENV_IDS

ENV_IDS = sorted(SINGLE_ARM_ENV_IDS)


def make_vec(env_id, num_envs, **kwargs):
    return gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point", **kwargs)


def _pick_actions(observations, rng, expert):
    """The Pick expert with noise and random jaw flips: grasps, carries, releases (the object falls)."""
    actions = np.stack([expert({k: v[i] for k, v in observations.items()}) for i in range(len(observations["observation"]))])
    actions = actions + rng.normal(0.0, 0.4, actions.shape)
    flip = rng.random(len(actions)) < 0.05
    actions[flip, 3] = 1.0
    return actions


def assert_matches_single_envs(env_id, num_envs, seed, steps, action_seed, **kwargs):
    envs = make_vec(env_id, num_envs, **kwargs)
    singles = [gym.make(env_id, **kwargs) for _ in range(num_envs)]
    observations, infos = envs.reset(seed=seed)
    for world, single in enumerate(singles):
        single_observation, single_info = single.reset(seed=seed + world)
        for key in single_observation:
            np.testing.assert_array_equal(observations[key][world], single_observation[key])
        assert infos["is_success"][world] == single_info["is_success"]
    rng = np.random.default_rng(action_seed)
    expert = PickExpert.for_env(singles[0]) if "Pick" in env_id else None
    ended = np.zeros(num_envs, dtype=bool)
    resets = 0
    for _ in range(steps):
        if expert is not None:
            actions = _pick_actions(observations, rng, expert)
        else:
            actions = rng.uniform(-1.5, 1.5, envs.action_space.shape)
        observations, rewards, terminations, truncations, infos = envs.step(actions)
        for world, single in enumerate(singles):
            if ended[world]:  # next-step autoreset: this step started the world's next episode
                expected, info = single.reset()
                reward, terminated, truncated = 0.0, False, False
                resets += 1
            else:
                expected, reward, terminated, truncated, info = single.step(actions[world])
            for key in expected:
                np.testing.assert_allclose(observations[key][world], expected[key], rtol=0, atol=1e-12)
            assert rewards[world] == pytest.approx(reward, abs=1e-12)
            assert (terminations[world], truncations[world]) == (terminated, truncated)
            assert infos["is_success"][world] == info["is_success"]
            if "grasped" in info:
                assert infos["grasped"][world] == info["grasped"]
        ended = terminations | truncations
    assert resets >= num_envs * (steps // 101)  # several episodes per world
    envs.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.slow
def test_vector_env_equals_single_envs_over_1000_steps(env_id):
    assert_matches_single_envs(env_id, num_envs=3, seed=5, steps=1000, action_seed=0)


def test_suction_irrigation_tool_vector_env_equals_single_envs():
    assert_matches_single_envs("dvrl_marl/PSMReach-v1", num_envs=2, seed=9, steps=300, action_seed=1,
                               tool="suction_irrigation")


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(num_envs=st.integers(1, 5), seed=st.integers(0, 2**31 - 1), action_seed=st.integers(0, 1000),
       env_id=st.sampled_from(["dvrl_marl/PSMReach-v1", "dvrl_marl/PSMPickDense-v1"]))
@pytest.mark.slow
def test_vector_env_equivalence_property(num_envs, seed, action_seed, env_id):
    assert_matches_single_envs(env_id, num_envs=num_envs, seed=seed, steps=250, action_seed=action_seed)


def test_pick_batch_exercises_grasp_release_and_falling_physics():
    envs = make_vec("dvrl_marl/PSMPick-v1", 8)
    observations, _ = envs.reset(seed=0)
    rng = np.random.default_rng(0)
    expert = PickExpert.for_env(gym.make("dvrl_marl/PSMPick-v1"))
    grasps, falls = 0, 0
    for _ in range(300):
        observations, _, _, _, infos = envs.step(_pick_actions(observations, rng, expert))
        grasps += int(infos["grasped"].sum())
        falls += int((~envs.unwrapped.core.at_rest & ~envs.unwrapped.core.grasped).sum())
    assert grasps > 50 and falls > 5


@given(grasped=st.booleans(), jaw=st.floats(0.0, 1.0), sensed=st.booleans(), low=st.floats(-0.2, 0.0),
       span=st.floats(0.0, 0.2), rest=st.floats(-0.2, 0.0), offset=st.floats(-0.05, 0.05))
def test_pick_rules_give_one_world_what_they_give_a_batch(grasped, jaw, sensed, low, span, rest, offset):
    """The grasp rule and the carried floor, written once: on one world's bools and floats (the single env) as on a
    batch's arrays (the core), and as the paper says (release when the jaw opens to the threshold, grab when it closes
    below it over the object; the tip's floor keeps a hanging object above the table, within the box)."""
    threshold = 0.25
    closed = jaw < threshold
    release, grab = grasp_events(grasped, closed, sensed)
    assert (bool(release), bool(grab)) == (grasped and not closed, not grasped and closed and sensed)
    batch = grasp_events(np.array([grasped, not grasped]), np.array([closed, closed]), np.array([sensed, sensed]))
    assert (bool(batch[0][0]), bool(batch[1][0])) == (bool(release), bool(grab))
    high = low + span
    floor = carried_floor(low, high, rest, offset)
    assert low <= floor <= high
    assert floor == (min(rest - offset, high) if rest - offset > low else low)
    assert carried_floor(np.array([low, low]), high, rest, np.array([offset, offset]))[0] == floor


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_gymnasium_vector_checks(env_id):
    from gymnasium.utils.env_checker import data_equivalence

    envs = make_vec(env_id, 4)
    assert isinstance(envs, gym.vector.VectorEnv)
    observations, _ = envs.reset(seed=3)
    assert envs.observation_space.contains(observations)
    again, _ = envs.reset(seed=3)
    assert data_equivalence(observations, again)
    for _ in range(5):
        observations, rewards, terminations, truncations, infos = envs.step(envs.action_space.sample())
        assert envs.observation_space.contains(observations)
        assert rewards.shape == terminations.shape == truncations.shape == (4,)
        assert infos["is_success"].shape == (4,) and infos["_is_success"].all()
    # HER: compute_reward works on batches, equal to the step rewards.
    np.testing.assert_array_equal(envs.unwrapped.compute_reward(observations["achieved_goal"],
                                                                observations["desired_goal"], {}), rewards)
    envs.close()


def test_observations_do_not_alias_between_steps():
    envs = make_vec("dvrl_marl/PSMPick-v1", 2)
    first, _ = envs.reset(seed=0)
    kept = {k: v.copy() for k, v in first.items()}
    envs.step(envs.action_space.sample())
    for key in first:
        np.testing.assert_array_equal(first[key], kept[key])
    assert not np.shares_memory(first["observation"], first["achieved_goal"])


def test_same_step_autoreset_reports_final_observation():
    envs = make_vec("dvrl_marl/PSMReach-v1", 2, autoreset_mode="same_step")
    envs.reset(seed=0)
    for step in range(100):
        observations, _, _, truncations, infos = envs.step(np.zeros((2, 3)))
    assert truncations.all() and infos["_final_obs"].all()
    assert not np.array_equal(infos["final_obs"]["desired_goal"], observations["desired_goal"])
    _, _, _, truncations, _ = envs.step(np.zeros((2, 3)))
    assert not truncations.any()  # the new episode is already running


def test_disabled_autoreset_and_reset_mask():
    envs = make_vec("dvrl_marl/PSMReach-v1", 3, autoreset_mode="disabled")
    first, _ = envs.reset(seed=0)
    observations, _ = envs.reset(options={"reset_mask": np.array([False, True, False])})
    np.testing.assert_array_equal(observations["desired_goal"][[0, 2]], first["desired_goal"][[0, 2]])
    assert not np.array_equal(observations["desired_goal"][1], first["desired_goal"][1])


def test_reset_options_are_validated_like_the_single_env():
    envs = make_vec("dvrl_marl/PSMReach-v1", 2)
    observations, _ = envs.reset(seed=0, options={"goal": [0.0, 0.0, -0.1]})
    np.testing.assert_allclose(observations["desired_goal"], [[0.0, 0.0, 0.2]] * 2)
    with pytest.raises(ValueError, match="unknown reset option"):
        envs.reset(options={"gaol": [0, 0, 0]})


@pytest.mark.parametrize("bad, message", [
    (np.zeros((3, 3)), r"shape \(2, 4\)"),
    (np.zeros((2, 3)), r"shape \(2, 4\)"),
    (np.array([[0, 0, 0, 0], [0, np.nan, 0, 0]]), "world 1"),
    (np.array([[np.inf, 0, 0, 0], [0, 0, 0, 0]]), "world 0"),
])
def test_bad_action_batches_raise_naming_the_world(bad, message):
    envs = make_vec("dvrl_marl/PSMPick-v1", 2)
    envs.reset(seed=0)
    with pytest.raises(ValueError, match=message):
        envs.step(bad)


def test_vector_env_renders_the_chosen_world():
    envs = make_vec("dvrl_marl/PSMReach-v1", 3, render_mode="rgb_array", render_world=2, width=64, height=48)
    envs.reset(seed=0)
    frame = envs.render()
    assert frame.shape == (48, 64, 3) and frame.std() > 0
    assert np.allclose(envs.unwrapped.template.arm.tip, envs.unwrapped.core.arm.tip[2])


# --- the collaborative scene ------------------------------------------------------------------------------------


def assert_batched_collaborative_matches(num_envs, seed, steps, action_seed, surgeon=None, scripted=False,
                                        module=v0_rules, drop_probability=0.0, pull=None, **kwargs):
    env = module.batched_env(num_envs=num_envs, surgeon=surgeon, **kwargs)
    singles = [module.parallel_env(surgeon=surgeon, **kwargs) for _ in range(num_envs)]
    observations, _ = env.reset(seed=seed)
    for world, single in enumerate(singles):
        expected, _ = single.reset(seed=seed + world)
        for agent in env.agents:
            np.testing.assert_array_equal(observations[agent][world], expected[agent])
    experts = {"suction": ScriptedSuction.for_env(env), "grasper": ScriptedSurgeon.for_env(env)}
    rng = np.random.default_rng(action_seed)
    episodes = 0
    for _ in range(steps):
        if scripted:
            actions = {a: experts[a](observations[a]) + rng.normal(0.0, 0.3, (num_envs, 4)) for a in env.agents}
        elif pull is not None:  # commands around a direction per agent (into a blocker, say)
            actions = {a: np.concatenate([np.asarray(pull[a]) + rng.uniform(-0.4, 0.4, (num_envs, 3)),
                                          rng.uniform(-1.0, 1.0, (num_envs, 1))], axis=1) for a in env.agents}
        else:
            actions = {a: rng.uniform(-1.3, 1.3, (num_envs, 4)) for a in env.agents}
        if drop_probability and "grasper" in actions:  # open the jaw now and then: held pins drop mid-air
            actions["grasper"][rng.random(num_envs) < drop_probability, 3] = 1.0
        observations, rewards, terminations, truncations, infos = env.step(actions)
        for world, single in enumerate(singles):
            expected, reward, terminated, truncated, info = single.step({a: actions[a][world] for a in single.agents})
            for agent in env.agents:
                final = infos[agent].get("_final", np.zeros(num_envs, bool))[world]
                got = infos[agent]["final_observation"][world] if final else observations[agent][world]
                np.testing.assert_allclose(got, expected[agent], rtol=0, atol=1e-12)
                assert rewards[agent][world] == pytest.approx(reward[agent], abs=1e-12)
                assert (terminations[agent][world], truncations[agent][world]) == (terminated[agent], truncated[agent])
                for key in ("blood_remaining", "debris_delivered", "collision", "is_success"):
                    assert infos[agent][key][world] == pytest.approx(info[agent][key], abs=1e-12)
            if not single.agents:
                episodes += 1
                expected, _ = single.reset()
                for agent in env.agents:
                    np.testing.assert_allclose(observations[agent][world], expected[agent], rtol=0, atol=1e-12)
    assert episodes >= num_envs * 2
    env.close()


@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(num_envs=st.integers(1, 4), seed=st.integers(0, 2**31 - 1), action_seed=st.integers(0, 1000))
@pytest.mark.slow
def test_world_i_of_a_batch_is_the_single_env_seeded_s_plus_i(num_envs, seed, action_seed):
    # One step implementation serves both forms (the golden trajectories hold it still); what is left to hold here is
    # the seeding: world i draws the single env's episodes, automatic resets included.
    assert_batched_collaborative_matches(num_envs, seed=seed, steps=200, action_seed=action_seed, scripted=True,
                                         max_cycles=90)


@pytest.mark.slow
def test_scripted_team_succeeds_batched_as_often_as_single():
    env = suction_debris_v8.batched_env(num_envs=16, surgeon="scripted")
    suction = ScriptedSuction.for_env(env)
    observations, _ = env.reset(seed=100)
    finished = np.zeros(16, dtype=bool)
    wins = np.zeros(16, dtype=bool)
    for _ in range(1500):
        observations, _, terminations, truncations, _ = env.step({"suction": suction(observations["suction"])})
        wins |= terminations["suction"] & ~finished
        finished |= terminations["suction"] | truncations["suction"]
    assert wins.all()  # the single scripted team wins 20/20 (ecosystem facts); batched, every world


def test_batched_collaborative_shapes_state_and_bad_input():
    env = suction_debris_v8.batched_env(num_envs=5)
    observations, infos = env.reset(seed=0)
    assert observations["suction"].shape == (5, env.observation_space("suction").shape[0])
    assert env.state().shape == (5, env.state_space.shape[0])
    assert infos["grasper"]["blood_remaining_per_cavity"].shape == (5, 2)
    good = {a: np.zeros((5, 4)) for a in env.agents}
    with pytest.raises(ValueError, match="'grasper'.*world 3"):
        bad = np.zeros((5, 4))
        bad[3, 1] = np.nan
        env.step({**good, "grasper": bad})
    with pytest.raises(ValueError, match=r"'suction'.*shape \(5, 4\)"):
        env.step({**good, "suction": np.zeros((4, 4))})
    with pytest.raises(ValueError, match="unknown agent"):
        env.step({**good, "assistant": np.zeros((5, 4))})
    with pytest.raises(ValueError, match="no action"):
        env.step({"suction": good["suction"]})
    with pytest.raises(ValueError, match="unknown reset option"):
        env.reset(options={"blood": [1, 1]})
    with pytest.raises(ValueError, match="blood volumes"):
        env.reset(options={"blood_ml": [1.0, 99.0]})


def test_batched_collaborative_reset_mask_and_blood_option():
    env = suction_debris_v8.batched_env(num_envs=3, autoreset_mode="disabled")
    env.reset(seed=0, options={"blood_ml": [[4.0, 4.0], [8.0, 8.0], [2.0, 0.0]]})
    assert env.core.remaining_ml.tolist() == [[4.0, 4.0], [8.0, 8.0], [2.0, 0.0]]
    for _ in range(5):
        env.step({a: np.ones((3, 4)) for a in env.agents})
    before = env.state()
    after = env.reset(options={"reset_mask": np.array([True, False, False])})[0]
    np.testing.assert_array_equal(env.state()[1:], before[1:])
    assert not np.array_equal(env.state()[0], before[0])
    assert after["suction"].shape == (3, env.observation_space("suction").shape[0])


def test_batched_collaborative_renders_a_chosen_world():
    env = suction_debris_v8.batched_env(num_envs=2, render_mode="rgb_array", width=64, height=48)
    env.reset(seed=0)
    first = env.render(world=0)
    second = env.render(world=1)
    assert first.shape == (48, 64, 3) and not np.array_equal(first, second)


def test_teleop_devices_are_refused_by_the_batched_env():
    from dvrl_marl.teleop import ReplayDevice

    with pytest.raises(ValueError, match="parallel_env"):
        suction_debris_v8.batched_env(num_envs=2, surgeon=ReplayDevice([np.zeros(4)]))


@pytest.mark.slow
def test_batched_experts_act_as_the_single_experts_on_every_row():
    # Observations met along noisy team episodes (all phases: suction, reveal, grasp, carry, park).
    env = suction_debris_v8.batched_env(num_envs=16, reward_type="dense")
    experts = {"suction": ScriptedSuction.for_env(env), "grasper": ScriptedSurgeon.for_env(env)}
    observations, _ = env.reset(seed=0)
    rng = np.random.default_rng(0)
    compared, lifted, delivered = 0, 0, 0
    for step in range(1000):
        actions = {}
        for agent, expert in experts.items():
            batch = expert(observations[agent])
            if step % 10 == 0:
                rows = np.stack([expert(row) for row in observations[agent]])
                np.testing.assert_array_equal(batch, rows)
                compared += len(rows)
            actions[agent] = batch + rng.normal(0.0, 0.1, batch.shape)
        observations, _, _, _, _ = env.step(actions)
        lifted = max(lifted, int(env.core.lifted.sum()))
        delivered = max(delivered, int(env.core.delivered.sum()))
    assert compared > 3000 and lifted > 0 and delivered > 0


@pytest.mark.parametrize("level", [0.0, 0.4])
def test_picks_learning_options_keep_the_vector_env_equal_to_single_envs(level):
    """Easy starts (before and after the grasp), the switch jaw and the guided reward, across autoresets."""
    assert_matches_single_envs("dvrl_marl/PSMPick-v1", num_envs=3, seed=11, steps=350, action_seed=2,
                               start_level=level, jaw_command="switch", reward_type="guided")
