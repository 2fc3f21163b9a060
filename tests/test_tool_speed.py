"""The ``tool_speed`` option (dvrl_marl.core.tools): the jaw and the valve move at most that fraction of their
stroke per control step; 1 (the default) is the paper's instant tool. Single and batched alike; bad values
refused by name; the exploration noise of a Gaussian policy's tool dimension averages out."""

import importlib.util
import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dvrl_marl.envs import suction_debris_v8

ROOT = Path(__file__).resolve().parents[1]


def _tool_noise():
    spec = importlib.util.spec_from_file_location("tool_noise", ROOT / "benchmarks" / "tool_noise.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@settings(max_examples=25, deadline=None)
@given(speed=st.floats(0.01, 1.0), seed=st.integers(0, 2**16))
@pytest.mark.slow
def test_the_tool_moves_at_most_its_speed_towards_the_command(speed, seed):
    env = suction_debris_v8.batched_env(num_envs=4, tool_speed=speed, autoreset_mode="disabled")
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    core = env.core
    for _ in range(40):
        jaw, opening = core.arms["grasper"].jaw.copy(), core.valve_opening.copy()
        actions = {agent: rng.uniform(-1, 1, (4, 4)) for agent in env.agents}
        observations, *_ = env.step(actions)
        jaw_target = (actions["grasper"][:, 3] + 1.0) * 0.5
        valve_target = (actions["suction"][:, 3] > 0.0).astype(float)
        new_jaw, new_opening = core.arms["grasper"].jaw, core.valve_opening
        # at most `speed`, towards the target, never past it, within the stroke
        assert np.all(np.abs(new_jaw - jaw) <= speed + 1e-12)
        assert np.all(np.abs(new_opening - opening) <= speed + 1e-12)
        assert np.all(np.abs(new_jaw - jaw_target) <= np.abs(jaw - jaw_target) + 1e-12)
        assert np.all(np.abs(new_opening - valve_target) <= np.abs(opening - valve_target) + 1e-12)
        assert np.all((new_jaw >= 0.0) & (new_jaw <= 1.0) & (new_opening >= 0.0) & (new_opening <= 1.0))
        # the valve draws while more than half open; the observations show both strokes
        assert np.array_equal(core.valve_open, new_opening > 0.5)
        assert np.allclose(observations["suction"][:, 3], 2.0 * new_opening - 1.0)
        assert np.allclose(observations["grasper"][:, 3], 2.0 * new_jaw - 1.0)


def test_a_steady_command_opens_the_valve_and_closes_the_jaw_after_a_stroke():
    speed = 0.05
    env = suction_debris_v8.parallel_env(tool_speed=speed)
    env.reset(seed=0)
    command = {"suction": np.array([0.0, 0.0, 0.0, 1.0]), "grasper": np.array([0.0, 0.0, 0.0, -1.0])}
    opened_after = closed_after = None
    for step in range(1, 30):
        env.step(command)
        if opened_after is None and env.valve_open:
            opened_after = step
        if closed_after is None and env.arms["grasper"].jaw < env.params.grasp_threshold:
            closed_after = step
    # a half stroke to open (it draws beyond it), 0.75 of one to close past the grasp threshold (to rounding)
    assert abs(opened_after - 0.5 / speed) <= 1
    assert abs(closed_after - (1.0 - env.params.grasp_threshold) / speed) <= 1
    instant = suction_debris_v8.parallel_env()
    instant.reset(seed=0)
    instant.step(command)
    assert instant.valve_open and instant.arms["grasper"].jaw == 0.0  # the paper's: at once


@pytest.mark.extended
def test_single_and_batched_agree_with_a_slow_tool():
    """Random commands (the tool's half-strokes included), easy and default starts, guided reward and features:
    the batched worlds are the single envs bit for bit."""
    kwargs = dict(task="suction_debris_v8", tool_speed=0.07, reward_type="guided",
                  observation_features="suction_debris_cleared_pins_zoom")
    batched = suction_debris_v8.batched_env(num_envs=3, **kwargs)
    batched.reset(seed=5, options={"level": [0.0, 0.5, 1.0]})
    singles = [suction_debris_v8.parallel_env(**kwargs) for _ in range(3)]
    for index, single in enumerate(singles):
        single.reset(seed=5 + index, options={"level": [0.0, 0.5, 1.0][index]})
    rng = np.random.default_rng(1)
    for _ in range(400):
        actions = {agent: rng.uniform(-1, 1, (3, 4)) for agent in batched.agents}
        observations, rewards, terminations, truncations, _ = batched.step(actions)
        for index, single in enumerate(singles):
            obs, reward, term, trunc, _ = single.step({agent: actions[agent][index] for agent in single.agents})
            if term["suction"] or trunc["suction"]:
                obs, _ = single.reset()
            for agent in batched.agents:
                assert np.array_equal(obs[agent], observations[agent][index])
                assert abs(reward[agent] - rewards[agent][index]) < 1e-9


def test_the_api_checkers_pass_with_a_slow_tool():
    from pettingzoo.test import parallel_api_test

    parallel_api_test(suction_debris_v8.parallel_env(tool_speed=0.1), num_cycles=300)


@pytest.mark.parametrize("value, message", [
    (0.0, "tool_speed"), (1.5, "tool_speed"), (float("nan"), "tool_speed"), ("fast", "tool_speed"), (True, "tool_speed"),
])
def test_bad_tool_speeds_are_refused_by_name(value, message):
    with pytest.raises(ValueError, match=message):
        suction_debris_v8.parallel_env(tool_speed=value)
    with pytest.raises(ValueError, match=message):
        suction_debris_v8.batched_env(num_envs=2, tool_speed=value)


@pytest.mark.extended
def test_a_slow_tool_averages_out_the_noise_of_a_gaussian_tool_dimension():
    """The scripted team, its tool command sampled from a tanh-Gaussian of scale 1 (a Gaussian policy's start):
    with the paper's instant jaw one sample past the threshold drops the pin; at 0.05 of a stroke per step the
    noise averages out (benchmarks/tool_noise.py prints the whole sweep)."""
    tool_noise = _tool_noise()
    instant = tool_noise.success_rate("suction_debris_v8", 1.0, 1.0, worlds=16)
    slow = tool_noise.success_rate("suction_debris_v8", 0.05, 1.0, worlds=16)
    assert slow >= 0.9 and instant <= 0.25, (instant, slow)


def test_every_form_takes_the_option():
    """AEC, TorchRL, SB3 and the surgeon seat's Gymnasium env: the option reaches the scene and a steady closing
    command moves the jaw by the option's step (the paper's instant jaw would be shut after one step)."""
    import gymnasium as gym

    import dvrl_marl  # noqa: F401  (registers the environments)

    aec = suction_debris_v8.env(tool_speed=0.1)
    aec.reset(seed=0)
    for agent in aec.agent_iter(2):  # one step of each agent: the cycle's step
        aec.step(np.array([0.0, 0.0, 0.0, -1.0], dtype=np.float32))
    assert aec.unwrapped.arms["grasper"].jaw == pytest.approx(0.9)
    seat = gym.make("dvrl_marl/SurgeonSeat-v8", tool_speed=0.1)
    seat.reset(seed=0)
    scene = seat.unwrapped.scene
    if seat.unwrapped.seat == "grasper":
        seat.step(np.array([0.0, 0.0, 0.0, -1.0], dtype=np.float32))
        assert scene.arms["grasper"].jaw == pytest.approx(0.9)
    else:
        seat.step(np.array([0.0, 0.0, 0.0, 1.0], dtype=np.float32))
        assert scene.valve_opening == pytest.approx(0.1)
    assert scene.params.tool_speed == 0.1
    seat.close()
    if importlib.util.find_spec("torchrl") is not None:
        import torch

        from dvrl_marl.integrations.torchrl import SuctionDebrisTorchRLEnv

        env = SuctionDebrisTorchRLEnv(num_envs=2, seed=0, task="suction_debris_v8", tool_speed=0.1)
        td = env.reset()
        td["agents", "action"] = torch.tensor([[[0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0, -1.0]]] * 2)
        env.step(td)
        assert np.allclose(env.batched.core.valve_opening, 0.1) and np.allclose(env.batched.core.arms["grasper"].jaw, 0.9)
    if importlib.util.find_spec("supersuit") is not None:
        from dvrl_marl.integrations.sb3 import make_collaborative_vec_env

        venv = make_collaborative_vec_env(n_envs=1, seed=0, task="suction_debris_v8", tool_speed=0.1)
        venv.reset()
        observations, *_ = venv.step(np.array([[0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0, -1.0]], dtype=np.float32))
        venv.close()
        # slot 0 the suction, slot 1 the grasper: their own-tool entries (2 x stroke - 1) moved by one step of 0.1
        assert observations[0, 3] == pytest.approx(-0.8) and observations[1, 3] == pytest.approx(0.8)
