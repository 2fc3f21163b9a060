"""The surgeon seat as a Gymnasium vector env (``gym.make_vec(..., vectorization_mode="vector_entry_point")``)."""

import warnings

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import dvrl_marl  # noqa: F401  (registration)


@pytest.mark.parametrize("seat", ["suction", "grasper"])
@pytest.mark.slow
def test_the_batched_seats_follow_the_seat_env_world_by_world(seat):
    kwargs = {"partner": "scripted", "seat": seat, "max_cycles": 60}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        envs = gym.make_vec("dvrl_marl/SurgeonSeat-v8", num_envs=3, vectorization_mode="vector_entry_point", **kwargs)
        singles = [gym.make("dvrl_marl/SurgeonSeat-v8", **kwargs) for _ in range(3)]
    observations, infos = envs.reset(seed=5)
    np.testing.assert_array_equal(observations, np.stack([s.reset(seed=5 + i)[0] for i, s in enumerate(singles)]))
    assert infos["is_success"].shape == (3,) and infos["_is_success"].all()
    rng = np.random.default_rng(0)
    ended = [False] * 3
    episodes = 0
    for _ in range(200):
        actions = rng.uniform(-1, 1, (3, 4)).astype(np.float32)
        observations, rewards, terminations, truncations, infos = envs.step(actions)
        for world, single in enumerate(singles):
            if ended[world]:  # Gymnasium's next-step autoreset: this step reset the world
                expected, reward, terminated, truncated = single.reset()[0], 0.0, False, False
                ended[world] = False
                episodes += 1
            else:
                expected, reward, terminated, truncated, _ = single.step(actions[world])
                ended[world] = terminated or truncated
            np.testing.assert_allclose(observations[world], expected, rtol=0, atol=1e-12)
            assert (rewards[world], terminations[world], truncations[world]) == (reward, terminated, truncated)
    assert episodes >= 6
    assert envs.observation_space.shape == (3, singles[0].observation_space.shape[0])
    envs.close()


def test_the_pipeline_partner_gets_a_sync_vector_and_bad_arguments_are_named():
    envs = gym.make_vec("dvrl_marl/SurgeonSeat-v8", num_envs=2, vectorization_mode="vector_entry_point")
    assert isinstance(envs, gym.vector.SyncVectorEnv)
    observations, _ = envs.reset(seed=0)
    assert observations.shape[0] == 2
    envs.close()
    with pytest.raises(ValueError, match="num_envs"):
        gym.make_vec("dvrl_marl/SurgeonSeat-v8", num_envs=0, vectorization_mode="vector_entry_point")
    with pytest.raises(ValueError, match="autoreset_mode"):
        gym.make_vec("dvrl_marl/SurgeonSeat-v8", num_envs=2, vectorization_mode="vector_entry_point",
                     partner="scripted", autoreset_mode="sometimes")


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seat=st.sampled_from(["suction", "grasper"]),
       preset=st.sampled_from(["default", "benchmark"]),
       tool_speed=st.sampled_from([None, 1.0, 0.25]),
       jaw_command=st.sampled_from([None, "proportional", "switch"]),
       hold=st.sampled_from([None, False, True]),
       features=st.sampled_from([None, "", "suction_debris_cleared_pins_zoom", "suction_debris_routes"]),
       normalize=st.booleans(),
       bleeding=st.sampled_from([0.0, 0.3]),
       level=st.sampled_from(["default", "easy", 0.5]),
       seed=st.integers(0, 10_000))
@pytest.mark.slow
def test_random_option_combinations_give_the_same_worlds_in_the_seat_env_and_its_vector_form(
        seat, preset, tool_speed, jaw_command, hold, features, normalize, bleeding, level, seed):
    """Any combination of the scene's options: the vector form's world i is the seat env seeded s + i, step by step
    (the partner reads the plain observation in both)."""
    options = {key: value for key, value in (("tool_speed", tool_speed), ("jaw_command", jaw_command),
                                             ("hold_until_handoff", hold), ("observation_features", features))
               if value is not None}
    kwargs = {"partner": "scripted", "seat": seat, "max_cycles": 40, "preset": preset, "bleeding_ml_s": bleeding,
              "normalize_observations": normalize, "start_level": level, **options}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        envs = gym.make_vec("dvrl_marl/SurgeonSeat-v8", num_envs=2, vectorization_mode="vector_entry_point", **kwargs)
        singles = [gym.make("dvrl_marl/SurgeonSeat-v8", **kwargs) for _ in range(2)]
    observations, _ = envs.reset(seed=seed)
    expected = np.stack([single.reset(seed=seed + i)[0] for i, single in enumerate(singles)])
    np.testing.assert_allclose(observations, expected, rtol=0, atol=1e-12)
    rng = np.random.default_rng(seed)
    for _ in range(30):
        actions = rng.uniform(-1, 1, (2, 4)).astype(np.float32)
        observations, rewards, terminations, truncations, _ = envs.step(actions)
        for world, single in enumerate(singles):
            expected, reward, terminated, truncated, _ = single.step(actions[world])
            np.testing.assert_allclose(observations[world], expected, rtol=0, atol=1e-12)
            assert rewards[world] == pytest.approx(reward, abs=1e-12)
            assert (terminations[world], truncations[world]) == (terminated, truncated)
        if terminations.any() or truncations.any():
            break
    envs.close()
