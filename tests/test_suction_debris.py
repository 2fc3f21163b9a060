"""The collaborative PettingZoo environment: API checkers, determinism, world rules, surgeon seat, bad input."""

import math

import numpy as np
import pettingzoo
import pytest
from pettingzoo.test import api_test, max_cycles_test, parallel_api_test
from pettingzoo.test.render_test import collect_render_results
from pettingzoo.test.state_test import test_state as pz_state_test
from pettingzoo.test.state_test import test_state_space as pz_state_space_test

import dvrl_marl  # noqa: F401  (PettingZoo registration)
from dvrl_marl.agents import ScriptedSuction, ScriptedSurgeon
from dvrl_marl.training import teams
from dvrl_marl.envs import suction_debris_v8
from dvrl_marl.teleop import KeyboardDevice, Recorder, ReplayDevice, load_demonstration


def scripted_episode(env, seed):
    suction, surgeon = ScriptedSuction.for_env(env), ScriptedSurgeon.for_env(env)
    observations, infos = env.reset(seed=seed)
    steps = 0
    while env.agents:
        observations, rewards, terminations, truncations, infos = env.step(
            {"suction": suction(observations["suction"]), "grasper": surgeon(observations["grasper"])}
        )
        steps += 1
    return steps, infos["suction"]


def test_pettingzoo_parallel_api():
    parallel_api_test(suction_debris_v8.parallel_env(), num_cycles=300)


def test_pettingzoo_aec_api_and_state():
    api_test(suction_debris_v8.env(), num_cycles=300)
    env = suction_debris_v8.env()
    pz_state_space_test(env)
    pz_state_test(env, num_cycles=50)


def test_max_cycles_truncates():
    max_cycles_test(suction_debris_v8)


def test_rgb_rendering_from_the_endoscope():
    env = suction_debris_v8.env(render_mode="rgb_array", width=96, height=72)
    for frame in collect_render_results(env):
        assert frame.shape == (72, 96, 3) and frame.dtype == np.uint8 and frame.std() > 1
    env.close()


def test_pettingzoo_render_test_with_a_display(x_display, monkeypatch):
    from pettingzoo.test import render_test

    monkeypatch.setenv("DISPLAY", x_display)
    render_test(suction_debris_v8.env)


@pytest.mark.skipif(not hasattr(pettingzoo, "make"), reason="this PettingZoo release has no registry (make)")
def test_registered_with_pettingzoo():
    env = pettingzoo.make("parallel", "dvrl_marl/suction_debris-v8")
    assert env.possible_agents == ["suction", "grasper"]
    aec = pettingzoo.make("aec", "dvrl_marl/suction_debris-v8", surgeon="scripted")
    assert aec.possible_agents == ["suction"]


def test_metadata_and_spaces_are_stable():
    env = suction_debris_v8.parallel_env()
    for key in ("name", "render_modes", "render_fps", "is_parallelizable"):
        assert key in env.metadata
    assert env.metadata["name"] == "suction_debris_v8"
    for agent in env.possible_agents:
        assert env.observation_space(agent) is env.observation_space(agent)
        assert env.action_space(agent) is env.action_space(agent)
        assert np.all(np.isfinite(env.observation_space(agent).low))
        assert np.all(np.isfinite(env.observation_space(agent).high))
    with pytest.raises(ValueError, match="unknown agent"):
        env.observation_space("camera")


def test_same_seed_and_actions_give_identical_runs_for_500_steps():
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1.2, 1.2, size=(500, 2, 4))
    runs = []
    for _ in range(2):
        env = suction_debris_v8.parallel_env(reward_type="dense")
        observations, infos = env.reset(seed=42)
        record = [(observations, infos)]
        for step_actions in actions:
            if not env.agents:
                observations, infos = env.reset()
                record.append((observations, infos))
            result = env.step({"suction": step_actions[0], "grasper": step_actions[1]})
            record.append(result)
        runs.append(record)
    assert len(runs[0]) == len(runs[1])
    for a, b in zip(*runs):
        assert repr(a) == repr(b)
    # A different seed gives a different scene.
    other = suction_debris_v8.parallel_env()
    first = other.reset(seed=42)[0]["grasper"]
    assert not np.array_equal(first, other.reset(seed=43)[0]["grasper"])


def test_scripted_team_completes_at_least_95_percent_within_max_cycles():
    # (20 episodes at once: the parallel env is the same core with one world, held to it by the golden steps)
    team = {agent: teams.seat("scripted", agent) for agent in ("suction", "grasper")}
    result = teams.evaluate_team_batched(team, 20, seed=0)
    assert sum(result["success"]) >= 19, result
    assert max(result["steps"]) <= suction_debris_v8.parallel_env().params.max_cycles


def test_blood_is_conserved_and_never_negative():
    env = suction_debris_v8.parallel_env()
    suction, surgeon = ScriptedSuction.for_env(env), ScriptedSurgeon.for_env(env)
    observations, infos = env.reset(seed=1)
    initial = env.blood.initial_ml
    removed_total = np.zeros(len(initial))
    previous = np.array(initial)
    while env.agents:
        observations, _, _, _, infos = env.step(
            {"suction": suction(observations["suction"]), "grasper": surgeon(observations["grasper"])}
        )
        remaining = np.array(infos["suction"]["blood_remaining_per_cavity"])
        assert np.all(remaining >= 0.0)
        assert np.all(remaining <= previous + 1e-15)  # blood only leaves
        removed_total += previous - remaining
        previous = remaining
        np.testing.assert_allclose(np.array(env.blood.removed_ml) + remaining, initial, rtol=0, atol=1e-12)
        assert infos["suction"]["blood_remaining"] == pytest.approx(remaining.sum())
    np.testing.assert_allclose(removed_total + previous, initial, atol=1e-12)
    assert np.all(previous < env.params.blood_threshold_ml)


def test_suction_needs_the_valve_and_the_tip_under_the_surface():
    env = suction_debris_v8.parallel_env()
    env.reset(seed=0)
    cavity = env.phantom.cavities[0]
    arm = env.arms["suction"]
    arm.set_tip(*arm.to_base((cavity.centre_x, cavity.centre_y, cavity.floor_z + 0.002)).tolist())
    hold = {"grasper": np.array([0, 0, 0, 1.0])}
    env.step({"suction": np.array([0, 0, 0, -1.0]), **hold})  # valve closed
    assert env.blood.remaining_ml[0] == env.blood.initial_ml[0]
    env.step({"suction": np.array([0, 0, 0, 1.0]), **hold})  # valve open, under the surface
    expected = env.params.suction_rate_ml_s * env.params.control_dt
    assert env.blood.initial_ml[0] - env.blood.remaining_ml[0] == pytest.approx(expected)
    surface_before = env.blood.surface_z[0]
    assert surface_before < cavity.top_z
    arm.set_tip(*arm.to_base((cavity.centre_x, cavity.centre_y, cavity.top_z + 0.01)).tolist())
    level = env.blood.remaining_ml[0]
    env.step({"suction": np.array([0, 0, 0, 1.0]), **hold})  # above the surface: nothing
    assert env.blood.remaining_ml[0] == level
    assert env.mirrored().blood_surface_height(0) == pytest.approx(surface_before)  # the picture shows the level


def test_hidden_debris_is_absent_from_observations_but_present_in_state():
    env = suction_debris_v8.parallel_env()
    observations, _ = env.reset(seed=3)
    layout = env.observation_layout
    debris_obs = observations["grasper"][layout["debris"]].reshape(-1, 6)
    state = env.state()
    n_cav = len(env.phantom.cavities)
    debris_state = state[8 + n_cav: 8 + n_cav + 6 * len(env.debris)].reshape(-1, 6)
    assert not any(pin.visible for pin in env.debris)
    assert np.all(debris_obs[:, :3] == 0.0) and np.all(debris_obs[:, 3] == 0.0)
    for pin, row in zip(env.debris, debris_state):
        np.testing.assert_allclose(row[:3], env.normalise(pin.position))
        assert np.any(row[:3] != 0.0)
    assert env.state_space.contains(state)


def test_debris_is_revealed_when_the_surface_falls_below_its_top():
    env = suction_debris_v8.parallel_env()
    suction = ScriptedSuction.for_env(env)
    observations, _ = env.reset(seed=0)
    seen = set()
    for _ in range(1200):
        observations, *_ = env.step({"suction": suction(observations["suction"]), "grasper": np.array([0, 0, 0, 1.0])})
        for index, pin in enumerate(env.debris):
            top = pin.position[2] + 0.0015
            assert pin.visible == (env.blood.surface_z[pin.cavity] < top)  # the level only falls
            if pin.visible:
                seen.add(index)
                row = observations["grasper"][env.observation_layout["debris"]].reshape(-1, 6)[index]
                np.testing.assert_allclose(row[:3], env.normalise(pin.position))
    assert len(seen) == len(env.debris)


def test_binding_the_surgeon_seat_changes_possible_agents():
    assert suction_debris_v8.parallel_env().possible_agents == ["suction", "grasper"]
    assert suction_debris_v8.parallel_env(surgeon="scripted").possible_agents == ["suction"]
    assert suction_debris_v8.parallel_env(surgeon="scripted", surgeon_seat="suction").possible_agents == ["grasper"]
    env = suction_debris_v8.parallel_env(surgeon="scripted")
    suction = ScriptedSuction.for_env(env)
    observations, _ = env.reset(seed=2)
    while env.agents:
        observations, rewards, terminations, truncations, infos = env.step({"suction": suction(observations["suction"])})
        assert set(rewards) == {"suction"}
    assert infos["suction"]["is_success"]
    with pytest.raises(ValueError, match="surgeon_seat"):
        suction_debris_v8.parallel_env(surgeon="scripted", surgeon_seat="camera")
    with pytest.raises(ValueError, match="surgeon"):
        suction_debris_v8.parallel_env(surgeon="expert")


def test_a_learned_callable_surgeon_drives_its_seat():
    calls = []

    def policy(observation):
        calls.append(observation.copy())
        return np.array([0.0, 0.0, 1.0, 1.0])

    env = suction_debris_v8.parallel_env(surgeon=policy)
    env.reset(seed=0)
    z0 = env.arms["grasper"].tip[2]
    env.step({"suction": np.zeros(4)})
    assert len(calls) == 1 and calls[0].shape == env.observation_space("grasper").shape
    assert env.arms["grasper"].tip[2] == pytest.approx(z0 + env.params.step_size)


class _BrokenDevice:
    def __init__(self, failure):
        self.failure = failure

    def reset(self):
        pass

    def action(self, observation):
        if self.failure == "raise":
            raise ConnectionError("haptic device unplugged")
        if self.failure == "nan":
            return np.array([np.nan, 0, 0, 0])
        if self.failure == "hang":
            import time

            time.sleep(1.0)
        return np.array([1.0, 0.0, 0.0, -1.0])

    def close(self):
        pass


@pytest.mark.parametrize("failure", ["raise", "nan", "hang"])
def test_a_failing_device_holds_the_seat_and_the_episode_goes_on(failure):
    env = suction_debris_v8.parallel_env(surgeon=_BrokenDevice(failure), teleop_timeout=0.05)
    env.reset(seed=0)
    grasper = env.arms["grasper"]
    tip, jaw = list(grasper.tip), grasper.jaw
    for _ in range(3):
        _, _, _, _, infos = env.step({"suction": np.zeros(4)})
        assert infos["suction"]["teleop_lost"] is True
    assert grasper.tip == tip and grasper.jaw == jaw
    env.close()


def test_keyboard_device_moves_the_seat_and_replay_and_recorder_round_trip(tmp_path):
    keyboard = KeyboardDevice(repeat=3)
    recorder = Recorder(keyboard, seat="grasper", note="test")
    env = suction_debris_v8.parallel_env(surgeon=recorder)
    env.reset(seed=0)
    start = np.array(env.arms["grasper"].tip)
    keyboard.key_callback(68)  # D: +x for 3 steps
    keyboard.key_callback(32)  # SPACE: toggle the jaw (closes it)
    for _ in range(5):
        env.step({"suction": np.zeros(4)})
    np.testing.assert_allclose(np.array(env.arms["grasper"].tip) - start, [0.003, 0.0, 0.0], atol=1e-12)
    assert env.arms["grasper"].jaw == 0.0
    path = recorder.save(tmp_path / "demo.npz")
    observations, actions, metadata = load_demonstration(path)
    assert observations.shape == (5, env.observation_space("grasper").shape[0]) and actions.shape == (5, 4)
    assert metadata["seat"] == "grasper" and metadata["note"] == "test"
    # Replaying the recording reproduces the motion.
    replay_env = suction_debris_v8.parallel_env(surgeon=ReplayDevice(path))
    replay_env.reset(seed=0)
    for _ in range(7):  # two steps past the end: the replay holds still
        _, _, _, _, infos = replay_env.step({"suction": np.zeros(4)})
        assert "teleop_lost" not in infos["suction"]
    assert replay_env.arms["grasper"].tip == env.arms["grasper"].tip


@pytest.mark.parametrize(
    "actions, message",
    [
        ({"suction": np.zeros(4)}, "no action for agent 'grasper'"),
        ({"suction": np.zeros(4), "grasper": np.zeros(4), "camera": np.zeros(4)}, "unknown agent 'camera'"),
        ({"suction": np.full(4, np.nan), "grasper": np.zeros(4)}, "'suction' contains NaN"),
        ({"suction": np.zeros(4), "grasper": np.array([0, 0, np.inf, 0])}, "'grasper' contains NaN or inf"),
        ({"suction": np.zeros(3), "grasper": np.zeros(4)}, "'suction' must have shape"),
        ([np.zeros(4), np.zeros(4)], "dict keyed by agent"),
    ],
)
def test_bad_actions_raise_naming_the_agent(actions, message):
    env = suction_debris_v8.parallel_env()
    env.reset(seed=0)
    with pytest.raises(ValueError, match=message):
        env.step(actions)


def test_out_of_range_actions_are_clipped_and_invalid_arguments_raise():
    env = suction_debris_v8.parallel_env()
    env.reset(seed=0)
    before = np.array(env.arms["suction"].tip)
    env.step({"suction": np.array([50.0, 0.0, 0.0, 0.0]), "grasper": np.zeros(4)})
    np.testing.assert_allclose(np.array(env.arms["suction"].tip) - before, [env.params.step_size, 0, 0], atol=1e-12)
    for kwargs, message in [({"reward_type": "shaped"}, "reward_type"), ({"debris_count": 0}, "debris_count"),
                            ({"blood_ml": [50.0, 1.0]}, "capacity"), ({"render_mode": "ascii"}, "render_mode"),
                            ({"suction_rate_ml_s": -1.0}, "suction_rate_ml_s")]:
        with pytest.raises(ValueError, match=message):
            suction_debris_v8.parallel_env(**kwargs)
    with pytest.raises(TypeError, match="unexpected keyword argument 'colour'"):  # a bad name, not a bad value
        suction_debris_v8.parallel_env(colour="red")
    with pytest.warns(UserWarning, match="reset option"):
        env.reset(options={"blood": 3})
    with pytest.raises(ValueError, match="capacity"):
        env.reset(options={"blood_ml": [3.0, 80.0]})
    env.reset(options={"blood_ml": [2.0, 0.0]})
    assert env.blood.remaining_ml == [2.0, 0.0]


@pytest.mark.slow
def test_tips_never_enter_the_phantom_and_instruments_never_pass_through_each_other():
    env = suction_debris_v8.parallel_env()
    rng = np.random.default_rng(7)
    env.reset(seed=7)
    contacts = 0
    for step in range(1200):
        if not env.agents:
            env.reset()
        # Each tip chases the other (with noise), to provoke contacts, and dips to provoke floor hits.
        suction_tip, grasper_tip = np.array(env.arms["suction"].tip_world()), np.array(env.arms["grasper"].tip_world())
        chase = np.clip((grasper_tip - suction_tip) * 1000, -1, 1)
        suction_action = np.append(chase + rng.normal(0, 0.3, 3) - [0, 0, 0.3], rng.uniform(-1, 1))
        grasper_action = np.append(-chase + rng.normal(0, 0.3, 3) - [0, 0, 0.3], rng.uniform(-1, 1))
        _, rewards, _, _, infos = env.step({"suction": suction_action, "grasper": grasper_action})
        for agent, arm in env.arms.items():
            x, y, z = arm.tip_world()
            assert z >= env.phantom.surface_height(x, y) + env.params.tip_clearance - 1e-9
        assert env.instrument_clearance() >= -1e-12
        if infos["suction"]["collision"]:
            contacts += 1
            assert rewards["suction"] == -1.0 - env.params.contact_penalty
    assert contacts > 0  # the test did exercise contacts


def test_more_debris_than_the_scene_file_holds():
    env = suction_debris_v8.parallel_env(debris_count=5)
    observations, _ = env.reset(seed=0)
    assert observations["grasper"].shape == env.observation_space("grasper").shape
    assert len(env.debris) == 5
    outcome = scripted_episode(env, 0)[1]
    assert outcome["debris_delivered"] == 5 and outcome["is_success"]
    fewer = suction_debris_v8.parallel_env(debris_count=1)
    assert scripted_episode(fewer, 0)[1]["is_success"]


def test_dense_rewards_reward_progress():
    env = suction_debris_v8.parallel_env(reward_type="dense")
    suction, surgeon = ScriptedSuction.for_env(env), ScriptedSurgeon.for_env(env)
    observations, _ = env.reset(seed=4)
    total = {"suction": 0.0, "grasper": 0.0}
    while env.agents:
        observations, rewards, *_ = env.step(
            {"suction": suction(observations["suction"]), "grasper": surgeon(observations["grasper"])}
        )
        for agent, value in rewards.items():
            assert math.isfinite(value)
            total[agent] += value
    # Removing ~15 ml, lifting and delivering 3 debris outweighs the distance terms of a good episode.
    assert total["suction"] > 0.0 and total["grasper"] > 0.0


from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

_action = st.lists(st.floats(-2.0, 2.0, allow_nan=False), min_size=4, max_size=4)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**16), actions=st.lists(st.tuples(_action, _action), min_size=1, max_size=120))
def test_arbitrary_actions_keep_tips_in_the_box_above_surfaces_and_joints_in_limits(seed, actions):
    env = suction_debris_v8.parallel_env()
    env.reset(seed=seed)
    low, high = env.workspace_centre - env.workspace_range, env.workspace_centre + env.workspace_range
    for suction_action, grasper_action in actions:
        if not env.agents:
            break
        observations, *_ = env.step({"suction": np.array(suction_action), "grasper": np.array(grasper_action)})
        for agent, arm in env.arms.items():
            tip = np.array(arm.tip_world())
            assert np.all(tip >= low - 1e-12) and np.all(tip <= high + 1e-12)
            assert tip[2] >= env.phantom.surface_height(tip[0], tip[1]) + env.params.tip_clearance - 1e-9
            q = np.array(arm.q)
            assert np.all(q >= np.asarray(arm.tool.lower)) and np.all(q <= np.asarray(arm.tool.upper))
            assert env.observation_space(agent).contains(observations[agent])
        assert env.instrument_clearance() >= -1e-12
