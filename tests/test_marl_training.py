"""The multi-agent training path: SB3 PPO through SuperSuit on the parallel env (smoke)."""

import json
from pathlib import Path

import numpy as np
import pytest

from dvrl_marl.training.marl import TeamPolicy, evaluate_team, make_vec_env, train_ppo

CONFIGS = Path(__file__).parents[1] / "baselines" / "configs"


def test_vector_env_has_one_slot_per_learning_agent_with_an_agent_indicator():
    vec = make_vec_env(n_envs=2)
    assert vec.num_envs == 4  # 2 copies x 2 agents
    obs = vec.reset()
    assert obs.shape[1] == 30 + 2  # observation + one-hot agent indicator (scaled to the space's bound)
    indicator = obs[:, -2:] / obs[:, -2:].max()
    np.testing.assert_array_equal(indicator, np.array([[1, 0], [0, 1], [1, 0], [0, 1]]))
    vec.close()
    single = make_vec_env(n_envs=2, surgeon="scripted")
    assert single.num_envs == 2 and single.reset().shape[1] == 30
    single.close()


@pytest.mark.extended
def test_ppo_trains_both_arms_and_the_suction_arm_with_the_scripted_surgeon(tmp_path):
    for config in ("suction_debris_ppo", "suction_debris_ppo_scripted_surgeon"):
        result = train_ppo(CONFIGS / f"{config}.toml", seed=0, out_dir=tmp_path / config, total_timesteps=1024,
                           eval_episodes=1)
        assert (tmp_path / config / "final_model.zip").is_file()
        assert json.loads((tmp_path / config / "result.json").read_text())["config"] == config
        assert 0.0 <= result["success_rate"] <= 1.0 and result["mean_steps"] > 0


@pytest.mark.slow
def test_evaluate_team_reports_the_scripted_team():
    from dvrl_marl.agents import ScriptedSuction, ScriptedSurgeon
    from dvrl_marl.envs import suction_debris_v8

    env = suction_debris_v8.parallel_env()
    suction, surgeon = ScriptedSuction.for_env(env), ScriptedSurgeon.for_env(env)
    result = evaluate_team(lambda o: {"suction": suction(o["suction"]), "grasper": surgeon(o["grasper"])}, 2)
    assert result["success_rate"] == 1.0 and result["mean_blood_removed_ml"] > 14.0
    assert TeamPolicy  # exported for users
