"""The RLlib recipes (examples/rllib_*.py) at a tiny budget, and the adapter's rendering."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

import dvrl_marl

ray = pytest.importorskip("ray", reason='the RLlib recipes need the extra: pip install "dvrl-marl[rllib]"')
pytest.importorskip("ray.rllib", reason='the RLlib recipes need the extra: pip install "dvrl-marl[rllib]"')

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
TINY = ["--iterations", "1", "--train-batch", "200", "--minibatch", "100", "--epochs", "1"]


def load(name):
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def local_ray():
    yield
    ray.shutdown()


def test_the_adapter_renders_where_rllibs_own_wrapper_cannot():
    from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv

    from dvrl_marl.envs import suction_debris_v8
    from dvrl_marl.integrations.rllib import RenderableParallelPettingZooEnv

    with pytest.raises(TypeError):  # why the adapter exists: RLlib passes a mode PettingZoo's render() does not take
        ParallelPettingZooEnv(suction_debris_v8.parallel_env(render_mode="rgb_array")).render()
    env = RenderableParallelPettingZooEnv(suction_debris_v8.parallel_env(render_mode="rgb_array", max_cycles=5))
    observations, _ = env.reset(seed=0)
    assert set(observations) == {"suction", "grasper"}
    frame = env.render()
    assert frame.shape == (480, 640, 3) and frame.std() > 0
    _, _, terminated, truncated, _ = env.step({agent: np.zeros(4, np.float32) for agent in observations})
    assert "__all__" in terminated and "__all__" in truncated
    env.close()


@pytest.mark.extended
@pytest.mark.parametrize("shared", [False, True])
def test_multi_agent_recipe_trains_saves_and_films_a_team(tmp_path, local_ray, shared):
    recipe = load("rllib_suction_debris")
    args = [*TINY, "--max-cycles", "60", "--checkpoint", str(tmp_path / "checkpoint"), "--video",
            str(tmp_path / "team.mp4")] + (["--shared"] if shared else [])
    summary = recipe.main(args)
    assert summary["env_steps"] >= 200
    assert summary["policies"] == (["shared"] if shared else ["grasper", "suction"])
    assert summary["episode"]["steps"] == 60 and (tmp_path / "team.mp4").stat().st_size > 1000
    assert Path(summary["checkpoint"]).is_dir()


@pytest.mark.extended
def test_multi_agent_recipe_takes_the_envs_learning_options(local_ray):
    """--guided --level easy: the guided reward, the observation features and easy starts reach RLlib's env and the
    test episodes (the policies read the features they trained on)."""
    recipe = load("rllib_suction_debris")
    summary = recipe.main([*TINY, "--max-cycles", "60", "--guided", "--level", "easy", "--test-episodes", "2"])
    assert summary["test"]["episodes"] == 2 and summary["test"]["level"] == "easy" and summary["test"]["guided"]
    assert 0.0 <= summary["test"]["success_rate"] <= 1.0
    assert recipe.env_options(guided=True, level="easy")["preset"] == "benchmark"
    # the benchmark's options: its task file of each level
    import yaml

    for level in ("easy", "default"):
        task_file = Path(dvrl_marl.__file__).parent / "integrations" / "benchmarl_tasks" / f"suction_debris_{level}.yaml"
        shipped = yaml.safe_load(task_file.read_text())
        assert {k: v for k, v in recipe.env_options(guided=True, level=level).items() if k != "max_cycles"} == shipped


def test_guided_recipe_learns_with_the_benchmarks_ppo_settings():
    """--guided: RLlib's PPO gets the settings BenchMARL's MAPPO learns the task with, read from the shipped files
    (one place), and RLlib's defaults that differ from them (shared policy/value layers, lambda 1, a KL term, a value
    loss clipped at 10) are replaced."""
    import yaml

    recipe = load("rllib_suction_debris")
    tasks = Path(dvrl_marl.__file__).parent / "integrations" / "benchmarl_tasks"
    experiment, mappo, mlp = (yaml.safe_load((tasks / f"{name}.yaml").read_text())
                              for name in ("experiment", "mappo", "mlp"))
    config = recipe.build_config(ppo=recipe.benchmark_ppo_settings(), envs_per_runner=8,
                                 options=recipe.env_options(guided=True, level="easy"))
    assert config.lr == experiment["lr"] and config.grad_clip == experiment["clip_grad_val"]
    assert config.train_batch_size == experiment["on_policy_collected_frames_per_batch"]
    assert config.minibatch_size == experiment["on_policy_minibatch_size"]
    assert config.num_epochs == experiment["on_policy_n_minibatch_iters"]
    assert config.lambda_ == mappo["lmbda"] and config.entropy_coeff == mappo["entropy_coef"] > 0
    assert config.model_config["fcnet_hiddens"] == mlp["num_cells"] and not config.model_config["vf_share_layers"]
    assert not config.use_kl_loss and config.vf_clip_param == float("inf") and config.clip_param == 0.2
    assert config.num_envs_per_env_runner == 8
    plain = recipe.build_config()  # without --guided: RLlib's own model, the recipe's plain sizes
    assert plain.train_batch_size == recipe.PLAIN_PPO["train_batch"] and plain.lr == recipe.PLAIN_PPO["lr"]


@pytest.mark.parametrize("flag", ["--envs-per-runner", "--train-batch", "--minibatch", "--epochs"])
def test_recipe_refuses_sizes_below_one(flag, capsys):
    with pytest.raises(SystemExit):
        load("rllib_suction_debris").main([flag, "0"])
    assert flag in capsys.readouterr().err


@pytest.mark.extended
def test_single_arm_recipe_runs_a_vector_of_envs_per_runner(tmp_path, local_ray):
    recipe = load("rllib_single_arm")
    summary = recipe.main([*TINY, "--envs-per-runner", "4", "--episodes", "2", "--video", str(tmp_path / "reach.mp4")])
    assert summary["env_steps"] >= 200 and 0.0 <= summary["success_rate"] <= 1.0
    assert (tmp_path / "reach.mp4").stat().st_size > 1000
