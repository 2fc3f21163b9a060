"""PSM Pick's learning options (start levels, the switch jaw, the guided reward) and Pick learnt from scratch:
the options leave the registered task as it is, start where the scripted expert goes, reward as documented and
refuse bad values; PPO's runs export a policy that acts as the model did; the shipped policy picks by its default
call."""

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import dvrl_marl  # noqa: F401  (registers the ids)
from dvrl_marl import policies
from dvrl_marl.agents import PickExpert
from dvrl_marl.core.pick import GRASP_BONUS_STEPS

PICK = "dvrl_marl/PSMPick-v1"
OPTIONS = {"start_level": 0.0, "jaw_command": "switch", "reward_type": "guided"}


def _jaws(env):
    unwrapped = env.unwrapped
    return unwrapped.arm.to_base(unwrapped.arm.tool_point_world())


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), actions_seed=st.integers(0, 1000))
def test_level_one_is_the_registered_task_bit_for_bit(seed, actions_seed):
    plain, levelled = gym.make(PICK), gym.make(PICK, start_level=0.0)
    rng = np.random.default_rng(actions_seed)
    first, _ = plain.reset(seed=seed)
    second, _ = levelled.reset(seed=seed, options={"level": 1.0})
    for _ in range(30):
        for key in first:
            np.testing.assert_array_equal(first[key], second[key])
        action = rng.uniform(-1, 1, 4).astype(np.float32)
        first, reward, *_ = plain.step(action)
        second, reward_levelled, *_ = levelled.step(action)
        assert reward == reward_levelled


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_an_easy_start_lies_on_the_experts_way_with_the_object_held_after_the_grasp(seed):
    env = gym.make(PICK, start_level=0.0)
    unwrapped = env.unwrapped
    observation, info = env.reset(seed=seed)
    drop = np.array([0.0, 0.0, unwrapped.arm.tool_point_drop])
    start = unwrapped.workspace_centre
    grasp_tip = np.array([start[0], start[1], unwrapped.object_rest_height]) + drop
    goal_tip = unwrapped.goal + drop
    tip = np.asarray(unwrapped.arm.tip)
    assert np.all(tip >= unwrapped.tip_low - 1e-12) and np.all(tip <= unwrapped.tip_high + 1e-12)
    if info["grasped"]:  # on the carry: jaws closed on the object, which sits where the grasp rule holds it
        assert unwrapped.arm.jaw == 0.0 and observation["observation"][3] == -1.0
        np.testing.assert_allclose(unwrapped.object_position(), _jaws(env), atol=1e-12)
        segment = (grasp_tip, goal_tip)
    else:  # on the way down: the jaws open, the object at rest below the start
        assert unwrapped.arm.jaw == 1.0
        np.testing.assert_allclose(unwrapped.object_position()[:2], start[:2], atol=1e-9)
        segment = (start, grasp_tip)
    a, b = segment
    share = np.dot(tip - a, b - a) / max(np.dot(b - a, b - a), 1e-18)
    np.testing.assert_allclose(tip, a + np.clip(share, 0, 1) * (b - a), atol=1e-9)


def test_the_expert_finishes_every_easy_episode_and_half_the_resets_are_easy_at_level_half():
    env = gym.make(PICK, **OPTIONS)
    expert = PickExpert.for_env(env)
    held = 0
    for episode in range(40):
        observation, info = env.reset(seed=episode)
        held += info["grasped"]
        for _ in range(100):
            observation, _, _, _, info = env.step(expert(observation))
        assert info["is_success"], episode
    assert 8 <= held <= 35  # most easy starts lie on the longer way, the carry
    half = gym.make(PICK, start_level=0.5)
    starts = [half.reset(seed=seed)[0]["observation"][:3] for seed in range(400)]
    default = np.array([gym.make(PICK).unwrapped.normalise(half.unwrapped.workspace_centre)])
    easy = np.mean(np.any(np.abs(np.array(starts) - default) > 1e-12, axis=1))
    assert 0.4 < easy < 0.6


def test_the_guided_reward_is_the_sparse_one_plus_the_potentials_change():
    guided, sparse = gym.make(PICK, reward_type="guided"), gym.make(PICK)
    expert = PickExpert.for_env(guided)
    unwrapped = guided.unwrapped
    step = unwrapped.step_size

    def potential():
        carry = np.linalg.norm(unwrapped.object_position() - unwrapped.goal) / step
        if unwrapped.grasped:
            return GRASP_BONUS_STEPS - carry
        return -np.linalg.norm(_jaws(guided) - unwrapped.object_position()) / step - carry

    for seed in range(5):
        observation, _ = guided.reset(seed=seed)
        sparse.reset(seed=seed)
        before, grasps = potential(), 0
        for _ in range(100):
            action = expert(observation)
            was_grasped = unwrapped.grasped
            observation, reward, _, _, info = guided.step(action)
            _, sparse_reward, *_ = sparse.step(action)
            after = potential()
            assert reward == pytest.approx(sparse_reward + after - before, abs=1e-9)
            if info["grasped"] and not was_grasped:
                grasps += 1
                assert reward > GRASP_BONUS_STEPS - 2.0  # the grasp pays its bonus at once
            before = after
        assert grasps == 1 and info["is_success"]


def test_bad_learning_options_are_refused_by_name():
    with pytest.raises(ValueError, match="start_level"):
        gym.make(PICK, start_level=1.5)
    with pytest.raises(ValueError, match="start_level"):
        gym.make(PICK, start_level="hard")
    with pytest.raises(ValueError, match="jaw_command"):
        gym.make(PICK, jaw_command="toggle")
    with pytest.raises(ValueError, match="reward_type"):
        gym.make(PICK, reward_type="shaped")
    env = gym.make(PICK)
    with pytest.raises(ValueError, match="reset option 'level'"):
        env.reset(options={"level": -0.1})
    with pytest.raises(ValueError, match="set_start_level"):
        env.unwrapped.set_start_level(float("nan"))
    with pytest.raises(ValueError, match="HER"):  # the guided reward is not a function of the goals alone
        gym.make(PICK, reward_type="guided").unwrapped.compute_reward(np.zeros(3), np.zeros(3), {})
    with pytest.raises(ValueError, match="no start levels"):
        gym.make_vec("dvrl_marl/PSMReach-v1", 2, vectorization_mode="vector_entry_point").set_start_level(0.5)


def test_a_curriculum_sets_the_level_of_every_worlds_later_resets():
    envs = gym.make_vec(PICK, 64, vectorization_mode="vector_entry_point", start_level=1.0)
    observations, _ = envs.reset(seed=0)
    centre = observations["observation"][0, :3]
    assert np.all(observations["observation"][:, :3] == centre)  # the default start
    envs.set_start_level(0.0)
    observations, infos = envs.reset(seed=0)
    assert np.all(np.any(observations["observation"][:, :3] != centre, axis=1))  # every world easy
    assert 0 < infos["grasped"].sum() < 64


def test_the_pick_magnifier_reads_the_jaws_and_goal_offsets_alike_in_numpy_and_torch():
    torch = pytest.importorskip("torch")
    from dvrl_marl.suction_debris import features

    env = gym.make(PICK)
    spec = features.pick_spec(env)
    observation, _ = env.reset(seed=3)
    flat = np.concatenate([observation[key] for key in ("achieved_goal", "desired_goal", "observation")])
    out = features.apply(spec, flat)
    assert out.shape == (13 + 6,) and np.array_equal(out[:13], flat)
    unwrapped = env.unwrapped
    jaws = unwrapped.normalise(_jaws(env))
    obj, goal = observation["achieved_goal"], observation["desired_goal"]
    np.testing.assert_allclose(out[13:16], np.tanh((obj - jaws) / spec["zoom"]), atol=1e-12)
    np.testing.assert_allclose(out[16:19], np.tanh((goal - obj) / spec["zoom"]), atol=1e-12)
    assert spec["zoom"] * unwrapped.workspace_range == pytest.approx(0.005)  # 5 mm through the magnifier
    batch = np.random.default_rng(0).uniform(-1, 1, (32, 13))
    np.testing.assert_allclose(features.apply(spec, torch.as_tensor(batch)).numpy(), features.apply(spec, batch),
                               atol=1e-12)


def test_run_configurations_refuse_what_their_algorithm_cannot_use(tmp_path):
    pytest.importorskip("stable_baselines3")
    from dvrl_marl.training.runner import load_config

    base = ('[run]\nenv_id = "dvrl_marl/PSMPick-v1"\nalgorithm = "{algorithm}"\ntotal_timesteps = 1000\n{run}\n'
            '[train_env]\nstart_level = 0.5\n{tables}')
    cases = {"ppo": [("demonstrations = 5", "", "demonstrations"), ("", "[her]\nn_sampled_goal = 4\n", "her"),
                     ("", "[env]\nstart_level = 0.5\n", "both"),
                     ('observation_features = "zoom"', "", "observation_features")],
             "ddpg": [("num_envs = 8", "", "num_envs"), ("normalize_reward = true", "", "normalize_reward")]}
    for algorithm, rows in cases.items():
        for run, tables, named in rows:
            path = tmp_path / "config.toml"
            path.write_text(base.format(algorithm=algorithm, run=run, tables=tables))
            with pytest.raises(ValueError, match=named):
                load_config(path)
    path.write_text(base.format(algorithm="ppo", run='observation_features = "psm_pick_zoom"', tables="")
                    .replace("PSMPick", "PSMReach"))
    with pytest.raises(ValueError, match="not a Pick env"):
        load_config(path)
