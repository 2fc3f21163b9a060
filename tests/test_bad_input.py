"""Bad input, round 2: each case gave a silent wrong result or a raw traceback before its fix; now the seat's filler
reads what it reads everywhere, refused input changes nothing and names what was wrong."""

import gymnasium as gym
import numpy as np
import pytest

import dvrl_marl  # noqa: F401  (registration)
from dvrl_marl.envs import suction_debris_v8


def _blood_after(env, steps: int) -> float:
    env.reset(seed=3)
    for _ in range(steps):
        *_, info = env.step(np.zeros(4, dtype=np.float32))
    return info["blood_remaining"]


def test_the_seat_envs_partner_reads_the_scenes_units_with_normalised_observations():
    """With normalize_observations the scripted partner once read normalised positions: its actions saturated and
    the blood stayed; it must play as without the option, as the vector form's partner does."""
    plain = gym.make("dvrl_marl/SurgeonSeat-v8", partner="scripted", max_cycles=600)
    scaled = gym.make("dvrl_marl/SurgeonSeat-v8", partner="scripted", max_cycles=600, normalize_observations=True,
                      observation_features="suction_debris_cleared_pins_zoom")
    left = _blood_after(plain, 500)
    assert left < 2.0 and _blood_after(scaled, 500) == pytest.approx(left)


@pytest.mark.parametrize("kwargs, message", [
    ({"partner": "marl-grasper"}, "trained for the 'grasper' seat, not the 'suction' seat"),
    ({"seat": "suction", "partner": "marl-suction"}, "trained for the 'suction' seat, not the 'grasper' seat"),
    ({"partner": "reach-lnd"}, "is a single-arm policy"),
])
def test_a_partner_of_the_wrong_seat_is_refused_in_every_form(kwargs, message):
    with pytest.raises(ValueError, match=message):
        gym.make("dvrl_marl/SurgeonSeat-v8", **kwargs)
    with pytest.raises(ValueError, match=message):
        gym.make_vec("dvrl_marl/SurgeonSeat-v8", num_envs=2, vectorization_mode="vector_entry_point", **kwargs)


def test_a_refused_reset_changes_nothing():
    env = suction_debris_v8.parallel_env()
    with pytest.raises(ValueError, match="a level below 1"):
        env.reset(seed=0, options={"level": 0, "blood_ml": [1, 1]})
    env.reset(seed=0)
    assert env.start_level == 1.0 and env._limit == env.params.max_cycles
    batch = suction_debris_v8.batched_env(num_envs=2)
    with pytest.raises(ValueError, match="a level below 1"):
        batch.reset(seed=0, options={"level": 0, "blood_ml": [1, 1]})
    batch.reset(seed=0)
    assert list(batch.levels) == [1.0, 1.0]


@pytest.mark.parametrize("seed", [1.5, "0", [0, 1, 2], -1, True])
def test_a_bad_seed_is_named_by_the_single_env(seed):
    with pytest.raises(ValueError, match=r"reset\(seed=\.\.\.\)"):
        suction_debris_v8.parallel_env().reset(seed=seed)


@pytest.mark.parametrize("num_envs", [1.5, 0, "2", True])
def test_a_bad_number_of_worlds_is_named(num_envs):
    with pytest.raises(ValueError, match="num_envs"):
        suction_debris_v8.batched_env(num_envs=num_envs)


def test_the_first_reset_starts_every_world():
    batch = suction_debris_v8.batched_env(num_envs=3)
    with pytest.raises(ValueError, match="the first reset starts every world"):
        batch.reset(seed=0, options={"reset_mask": [True, False, False]})
    batch.reset(seed=0)
    batch.reset(options={"reset_mask": [True, False, False]})


def test_the_surgeon_sees_the_same_observation_in_the_single_and_the_batched_env():
    widths = []

    def surgeon(observation):
        widths.append(np.shape(observation)[-1])
        return np.zeros(np.shape(observation)[:-1] + (4,))

    features = "suction_debris_cleared_pins_zoom"
    single = suction_debris_v8.parallel_env(surgeon=surgeon, observation_features=features)
    single.reset(seed=0)
    single.step({"suction": np.zeros(4)})
    batch = suction_debris_v8.batched_env(num_envs=2, surgeon=surgeon, observation_features=features)
    batch.reset(seed=0)
    batch.step({"suction": np.zeros((2, 4))})
    assert widths[0] == widths[-1] == single.observation_layout["handoff"].stop
