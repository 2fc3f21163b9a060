"""The envs as the libraries researchers already use meet them: checkers with their default arguments on a machine
without a display, TorchRL's GymEnv, copies after rendering, Python's conventions for bad arguments, and the CLI
without the training extra."""

from __future__ import annotations

import copy
import os
import pickle
import subprocess
import sys
import textwrap
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import dvrl_marl  # noqa: F401
from dvrl_marl.envs import suction_debris_v8

ROOT = Path(__file__).resolve().parents[1]
SINGLE_IDS = ["dvrl_marl/PSMReach-v1", "dvrl_marl/PSMPick-v1"]


def _headless(code: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "MUJOCO_GL")}
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, timeout=300,
                          cwd=cwd, env=env)


@pytest.mark.parametrize("checker", ["gymnasium", "pettingzoo"])
def test_checkers_pass_with_their_default_arguments_headless(tmp_path, checker):
    code = {
        "gymnasium": """
            import gymnasium as gym, dvrl_marl
            from gymnasium.utils.env_checker import check_env
            check_env(gym.make("dvrl_marl/PSMReach-v1").unwrapped)
        """,
        "pettingzoo": """
            from pettingzoo.test import render_test
            from dvrl_marl.envs import suction_debris_v8
            render_test(suction_debris_v8.env)
        """,
    }[checker]
    result = _headless(code, tmp_path)
    # They pass with their defaults on a headless server: "human" is advertised only where a window can open.
    assert result.returncode == 0, result.stderr
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


@pytest.mark.parametrize("make", [lambda: gym.make("dvrl_marl/PSMReach-v1", render_mode="human"),
                                  lambda: suction_debris_v8.parallel_env(render_mode="human")])
def test_human_mode_without_display_raises_in_python(monkeypatch, make):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    from dvrl_marl.rendering import DisplayUnavailableError

    env = make()  # (PettingZoo's render_test builds it to read its metadata: that must work)
    with pytest.raises(DisplayUnavailableError, match="needs a display"):
        env.reset(seed=0)
        env.render()


@pytest.mark.parametrize("env_id", SINGLE_IDS)
def test_unknown_keyword_is_a_type_error_and_bad_value_a_value_error(env_id):
    with pytest.raises(TypeError, match="frameskip"):
        gym.make(env_id, frameskip=4)
    with pytest.raises(ValueError):
        gym.make(env_id, step_size=-1.0)
    with pytest.raises(TypeError, match="frameskip"):
        suction_debris_v8.parallel_env(frameskip=4)
    with pytest.raises(TypeError, match="frameskip"):
        suction_debris_v8.batched_env(num_envs=2, frameskip=4)
    with pytest.raises(TypeError, match="frameskip"):
        gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", frameskip=4)


def _collaborative():
    env = suction_debris_v8.parallel_env(render_mode="rgb_array")
    return env


@pytest.mark.parametrize("make", [lambda: gym.make(SINGLE_IDS[0], render_mode="rgb_array"),
                                  lambda: gym.make(SINGLE_IDS[1], render_mode="rgb_array"),
                                  _collaborative,
                                  lambda: suction_debris_v8.batched_env(num_envs=2, render_mode="rgb_array"),
                                  lambda: gym.make_vec(SINGLE_IDS[1], num_envs=2, render_mode="rgb_array",
                                                       vectorization_mode="vector_entry_point")],
                         ids=["reach", "pick", "collaborative", "batched", "vector"])
@pytest.mark.parametrize("copier", [lambda e: pickle.loads(pickle.dumps(e)), copy.deepcopy], ids=["pickle", "deepcopy"])
@pytest.mark.slow
def test_envs_copy_after_rendering(make, copier):
    env = make()
    env.reset(seed=3)
    frame = env.render()
    twin = copier(env)
    # The copy rebuilds its renderer and draws the same world. (Once, at the dependency floors late in a long run,
    # the software rasteriser drew 339 edge pixels of 307,200 differently; another world differs in far more.)
    differing = (np.asarray(twin.render()) != np.asarray(frame)).any(axis=-1).mean()
    assert differing < 0.002, f"{differing:.2%} of the pixels differ"
    if hasattr(env, "action_space") and not callable(env.action_space) and not hasattr(env, "num_envs"):
        action = env.action_space.sample()
        a, b = env.step(action), twin.step(action)
        np.testing.assert_array_equal(a[0]["observation"], b[0]["observation"])
    env.close()
    twin.close()


@pytest.mark.skipif(tuple(int(v) for v in gym.__version__.split(".")[:2]) < (1, 1),
                    reason="TorchRL refuses gymnasium 1.0.x itself (pytorch/rl discussion 2483)")
@pytest.mark.parametrize("env_id", SINGLE_IDS)
def test_torchrl_gym_env_specs_and_rollout(env_id):
    pytest.importorskip("torchrl")
    from torchrl.envs import DoubleToFloat, GymEnv, TransformedEnv
    from torchrl.envs.utils import check_env_specs

    env = TransformedEnv(GymEnv(env_id), DoubleToFloat())
    check_env_specs(env)
    env.set_seed(0)
    rollout = env.rollout(40)
    assert rollout.batch_size[0] >= 1
    assert rollout["next", "observation"].dtype.is_floating_point


def test_train_without_the_extra_prints_one_line_and_exits_2(tmp_path):
    code = f"""
        import sys
        class Block:
            def find_spec(self, name, path=None, target=None):
                if name.split(".")[0] in ("torch", "torchrl", "tensordict", "stable_baselines3"):
                    raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
        sys.meta_path.insert(0, Block())
        from dvrl_marl.cli import main
        sys.exit(main(["train", {str(ROOT / 'baselines/configs/suction_debris_mappo.toml')!r}, "--steps", "10",
                       "--out", {str(tmp_path / 'run')!r}]))
    """
    result = _headless(code, tmp_path)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and 'pip install "dvrl-marl[train]"' in lines[0] and "Traceback" not in result.stderr


@pytest.mark.parametrize("blocked", [("minari",), ("starlette", "uvicorn"), ("ray",)])
@pytest.mark.slow
def test_commands_without_their_extra_print_one_line_and_exit_2(tmp_path, blocked):
    if blocked == ("ray",):
        pytest.importorskip("torch")  # (without torch, train names the [train] extra first)
    command = ('["train", "x.toml", "--num-collectors", "2"]' if blocked == ("ray",)
               else '["teleop", "--port", "0"]')
    config = tmp_path / "x.toml"
    config.write_text((ROOT / "baselines/configs/suction_debris_mappo.toml").read_text())
    code = f"""
        import sys
        class Block:
            def find_spec(self, name, path=None, target=None):
                if name.split(".")[0] in {blocked!r}:
                    raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
        sys.meta_path.insert(0, Block())
        from dvrl_marl.cli import main
        sys.exit(main({command}))
    """
    result = _headless(code, tmp_path)
    extra = "ray" if blocked == ("ray",) else "teleop"
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2, result.stderr
    assert len(lines) == 1 and f'pip install "dvrl-marl[{extra}]"' in lines[0] and "Traceback" not in result.stderr
