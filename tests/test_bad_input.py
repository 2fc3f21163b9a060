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
    assert env.start_level == 1.0 and env.core.limit[0] == env.params.max_cycles
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


@pytest.mark.parametrize("kwargs", [{"bleeding_ml_s": 1.0, "blood_ml": [0.01, 0.01]},
                                    {"start_level": "easy", "bleeding_ml_s": 0.2}])
def test_blood_fractions_stay_inside_the_observation_space_while_bleeding(kwargs):
    """A bleed into a cavity that started nearly empty once gave fractions of 1,103 against the bound of 10."""
    single = suction_debris_v8.parallel_env(max_cycles=400, **kwargs)
    observations, _ = single.reset(seed=0)
    batch = suction_debris_v8.batched_env(num_envs=2, max_cycles=400, **kwargs)
    batched, _ = batch.reset(seed=0)
    for _ in range(400):
        for agent in single.agents:
            assert single.observation_space(agent).contains(observations[agent]), observations[agent].max()
        assert single.state_space.contains(single.state())
        for agent in batch.agents:
            assert np.abs(batched[agent]).max() <= 10.0
        if not single.agents:
            break
        observations, *_ = single.step({agent: np.zeros(4) for agent in single.agents})
        batched, *_ = batch.step({agent: np.zeros((2, 4)) for agent in batch.agents})


def test_arguments_of_the_wrong_kind_are_named():
    from dvrl_marl.agents.partners import PersonLikePartner, Profile, zoo_partner

    env = suction_debris_v8.parallel_env()
    with pytest.raises(ValueError, match="task must be a task file's name or path, got None"):
        suction_debris_v8.parallel_env(task=None)
    with pytest.raises(TypeError, match="'surgeon'"):
        gym.make("dvrl_marl/SurgeonSeat-v8", partner="scripted", surgeon="scripted")
    with pytest.raises(ValueError, match="reaction_steps must be a whole number"):
        Profile(reaction_steps=1.5)
    for agent in ("Suction", "both"):
        with pytest.raises(ValueError, match="agent must be 'suction' or 'grasper'"):
            PersonLikePartner(agent, env, Profile())
    with pytest.raises(ValueError, match="agent must be 'suction' or 'grasper', got 'nope'"):
        zoo_partner("late", "nope", env)


def test_integration_arguments_are_named():
    pytest.importorskip("supersuit")
    from dvrl_marl.integrations.sb3 import make_collaborative_vec_env

    with pytest.raises(ValueError, match="n_envs"):
        make_collaborative_vec_env(n_envs=0)
    torch = pytest.importorskip("torch")
    pytest.importorskip("torchrl")
    from dvrl_marl.integrations.torchrl import SuctionDebrisTorchRLEnv

    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="needs CUDA"):
            SuctionDebrisTorchRLEnv(num_envs=2, device="cuda")
    with pytest.raises(ValueError, match="is not a torch device"):
        SuctionDebrisTorchRLEnv(num_envs=2, device="gpu7")


def _person_like(env):
    from dvrl_marl.agents.partners import PersonLikePartner, Profile

    profile = Profile(reaction_steps=6, speed=0.7, approach=0.5, motor_noise=0.08, pause_probability=0.02,
                      pause_steps=5)
    return PersonLikePartner("grasper", env, profile, seed=17)


def test_a_person_like_partner_keeps_its_state_world_by_world_across_autoresets():
    """After an automatic reset a world's person-like partner starts afresh (it once acted on the last episode's
    delayed views), and world i of a batch is the single env seeded s + i, episode after episode."""
    batch = suction_debris_v8.batched_env(num_envs=2, max_cycles=40)
    batch = suction_debris_v8.batched_env(num_envs=2, max_cycles=40, surgeon=_person_like(batch))
    singles = []
    for _ in range(2):
        probe = suction_debris_v8.parallel_env(max_cycles=40)
        singles.append(suction_debris_v8.parallel_env(max_cycles=40, surgeon=_person_like(probe)))
    observations, _ = batch.reset(seed=5)
    expected = [single.reset(seed=5 + i)[0]["suction"] for i, single in enumerate(singles)]
    rng = np.random.default_rng(1)
    for step in range(100):
        np.testing.assert_allclose(observations["suction"], np.stack(expected), rtol=0, atol=1e-7, err_msg=str(step))
        actions = rng.uniform(-1, 1, (2, 4))
        observations, *_ = batch.step({"suction": actions})
        for world, single in enumerate(singles):
            if not single.agents:
                single.reset()
            expected[world] = single.step({"suction": actions[world]})[0]["suction"]
            if not single.agents:
                expected[world] = single.reset()[0]["suction"]  # the batch resets in the same step


def test_a_masked_reset_leaves_the_other_worlds_partners_alone():
    def run(masked: bool) -> np.ndarray:
        probe = suction_debris_v8.batched_env(num_envs=2, autoreset_mode="disabled")
        env = suction_debris_v8.batched_env(num_envs=2, autoreset_mode="disabled", surgeon=_person_like(probe))
        env.reset(seed=3)
        rng = np.random.default_rng(0)
        for step in range(60):
            if masked and step == 20:
                env.reset(options={"reset_mask": [True, False]})
            observations, *_ = env.step({"suction": rng.uniform(-1, 1, (2, 4))})
        return observations["suction"][1]

    np.testing.assert_array_equal(run(masked=True), run(masked=False))
