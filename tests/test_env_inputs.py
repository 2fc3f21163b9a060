"""The environments' own inputs and messages, as a careless user meets them: every bad value is refused by name, and
every message names the environment (its version) and what to do."""

import gc
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import dvrl_marl  # noqa: F401  (registration)
from dvrl_marl.envs import suction_debris_v8

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("kwargs, message", [
    ({"teleop_timeout": -1}, "suction_debris_v8: teleop_timeout (seconds, or None): must be > 0, got -1"),
    ({"workspace_range": 1e-12}, "outside the observation space's bound"),
    ({"width": "abc"}, "render width: must be an integer, got 'abc'"),
    ({"height": 0}, "render height: must be >= 1"),
    ({"pins_fall": 1}, "suction_debris_v8: pins_fall: must be true or false, got 1"),
    ({"blood_ml": [8.0, "8"]}, "suction_debris_v8: blood_ml[1]: must be a number, got '8'"),
    ({"suction_rate_ml_s": float("inf")}, "suction_rate_ml_s: must be finite"),
])
def test_bad_scene_arguments_are_named_with_the_envs_version(kwargs, message):
    with pytest.raises(ValueError) as error:
        suction_debris_v8.parallel_env(**kwargs)
    assert message in str(error.value)


def test_the_envs_messages_name_their_own_version_and_the_right_mistake():
    env = suction_debris_v8.parallel_env()
    with pytest.raises(ValueError, match=r"^suction_debris_v8: step\(\) called before reset\(\)"):
        env.step({})
    env.reset(seed=0)
    with pytest.raises(ValueError, match="^suction_debris_v8: no action for agent"):
        env.step({"suction": np.zeros(4)})
    env = suction_debris_v8.parallel_env(max_cycles=1)
    env.reset(seed=0)
    env.step({agent: np.zeros(4) for agent in env.agents})
    with pytest.raises(ValueError, match="after the episode ended"):
        env.step({})
    batched = suction_debris_v8.batched_env(num_envs=2)
    with pytest.raises(ValueError, match="^suction_debris_v8: "):
        batched.step({"suction": np.full((2, 4), np.nan), "grasper": np.zeros((2, 4))})


@pytest.mark.parametrize("seed, message", [("1234", "must be an integer, got '1234'"), (1.5, "must be an integer"),
                                           (-1, "must be >= 0"), ([1, 2, 3], "expected an int or 4 seeds"),
                                           ([1, 2, 3, "4"], "[3]: must be an integer")])
def test_a_batched_seed_is_an_integer_or_one_per_world(seed, message):
    env = suction_debris_v8.batched_env(num_envs=4)
    with pytest.raises(ValueError) as error:
        env.reset(seed=seed)
    assert message in str(error.value)


@pytest.mark.parametrize("mask, message", [([-1], "world index -1 is outside [0, 4)"),
                                           ([4], "world index 4 is outside [0, 4)"),
                                           ([0.0, 1.0], "booleans of shape (4,) or world indices"),
                                           ([True, False], "reset mask must have shape (4,)")])
def test_a_reset_mask_never_wraps_or_overflows(mask, message):
    env = suction_debris_v8.batched_env(num_envs=4)
    env.reset(seed=0)
    with pytest.raises(ValueError) as error:
        env.reset(options={"reset_mask": mask})
    assert message in str(error.value)
    env.reset(options={"reset_mask": [3, 0]})  # indices that exist are fine


def test_make_vec_refuses_episodes_that_end_before_they_begin(monkeypatch):
    unraisable = []  # what Python reports from a __del__ that raised (the refused env is collected)
    monkeypatch.setattr(sys, "unraisablehook", unraisable.append)
    for env_id in ("dvrl_marl/PSMReach-v1", "dvrl_marl/PSMPick-v1"):
        with pytest.raises(ValueError, match="max_episode_steps: must be >= 1, got 0"):
            gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", max_episode_steps=0)
    gc.collect()
    assert not unraisable, [str(report.exc_value) for report in unraisable]  # the refused env closes cleanly


def test_render_lists_only_the_scenes_it_can_render(tmp_path):
    result = subprocess.run([sys.executable, "-m", "dvrl_marl.cli", "render", "--scene", "common", "--out",
                             str(tmp_path / "common.png")], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert result.returncode == 2 and "has no endoscope camera" in result.stderr, result.stderr
    assert "'common'" not in result.stderr.split("renderable scenes:")[1]


def test_the_rllib_examples_show_their_defaults():
    for example in ("rllib_suction_debris.py", "rllib_single_arm.py"):
        source = (ROOT / "examples" / example).read_text()
        assert "ArgumentDefaultsHelpFormatter" in source, example
    result = subprocess.run([sys.executable, str(ROOT / "examples" / "rllib_suction_debris.py"), "--help"],
                            capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert result.returncode == 0, result.stderr  # (it parses its flags before it imports Ray)
    assert "(default: 50)" in result.stdout


def test_a_shipped_configuration_is_found_by_name():
    from dvrl_marl.cli import resolve_config

    assert Path(resolve_config("suction_debris_mappo")).name == "suction_debris_mappo.toml"
    with pytest.raises(FileNotFoundError, match="shipped configurations: .*suction_debris_mappo"):
        resolve_config("suction_debris_mapo")
    assert '"baselines/configs" = "dvrl_marl/configs"' in (ROOT / "pyproject.toml").read_text()  # in the wheel


@pytest.mark.slow
def test_evaluate_takes_a_learned_seat_by_its_shipped_name():
    import json

    result = subprocess.run([sys.executable, "-m", "dvrl_marl.cli", "evaluate", "marl-suction", "--episodes", "3"],
                            capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert result.returncode == 0, result.stderr  # (it once died with NameNotFound for the scene's name)
    report = json.loads(result.stdout)
    assert report["seat"] == "suction" and report["env_id"] == "suction_debris_v8" and report["episodes"] == 3


def test_evaluate_team_runs_the_demos_scene_by_default_and_names_a_bad_preset():
    from dvrl_marl.cli import build_parser
    from dvrl_marl.demo import ENV_NAME

    from dvrl_marl.cli import _team_preset

    args = build_parser().parse_args(["evaluate-team", "--suction", "scripted", "--grasper", "scripted"])
    assert _team_preset(args.suction, args.grasper, args.preset) == "default" and ENV_NAME == "suction_debris_v8"
    with pytest.raises(SystemExit):
        build_parser().parse_args(["evaluate-team", "--preset", "fast"])


def test_tip_positions_that_are_not_a_table_of_agents_are_named():
    env = suction_debris_v8.batched_env(num_envs=2)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"^suction_debris_v8: tip_positions must be a dict \{agent: \(num_envs, 3\)"):
        env.reset(options={"tip_positions": [[0.0, 0.0, 0.05]] * 2})
    with pytest.raises(ValueError, match=r"^suction_debris_v8: tip positions must be a dict \{agent: "):
        env.set_tip_positions([[0.0, 0.0, 0.05]] * 2)


def test_seeds_past_64_bits_are_refused_rather_than_wrapped_to_another_seed():
    """World i plays seed + i, a 64-bit key: seed 2**64 once played seed 0, and a batch's last worlds wrapped."""
    from dvrl_marl.envs import suction_debris_v8

    single = suction_debris_v8.parallel_env()
    with pytest.raises(ValueError, match="must be <= 18446744073709551615"):
        single.reset(seed=2**64)
    single.reset(seed=2**64 - 1)
    batch = suction_debris_v8.batched_env(num_envs=3)
    with pytest.raises(ValueError, match="must stay below 2\\*\\*64 for the 3 worlds"):
        batch.reset(seed=2**64 - 2)
    with pytest.raises(ValueError, match="must be <= 18446744073709551615"):
        batch.reset(seed=[0, 1, 2**64])
    observations, _ = batch.reset(seed=2**64 - 3)
    np.testing.assert_array_equal(observations["suction"][2], single.reset(seed=2**64 - 1)[0]["suction"])
