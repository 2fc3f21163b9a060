"""The device trainer (dvrl_marl.training.device_mappo): a tiny run on the CPU writes its progress, exports numpy
policies that load and act, and refuses what it does not do by name."""

import csv
from dataclasses import replace

import numpy as np
import pytest

pytest.importorskip("torchrl")

from dvrl_marl import policies  # noqa: E402
from dvrl_marl.training import device_mappo  # noqa: E402
from dvrl_marl.training.mappo_config import MappoConfig  # noqa: E402

TINY = MappoConfig(total_steps=1024, num_envs=8, rollout_steps=32, eval_every=512, eval_episodes=2, hidden=[16, 16],
                   env={"preset": "benchmark", "max_cycles": 120}, tool_head="switch",
                   critic_input="state_and_observation", levels=[(0.0, 0.0), (1.0, 1.0)], bounds_loss_coef=1.0,
                   initial_tool_logit={"suction": 3.0})


def test_a_tiny_run_validates_and_exports_policies_that_act(tmp_path):
    last = device_mappo.train(TINY, 3, tmp_path / "run", log=lambda *_: None)
    rows = list(csv.DictReader((tmp_path / "run" / "progress.csv").open()))
    assert [int(row["steps"]) for row in rows] == [512, 1024]
    assert last["steps"] == 1024 and 0.0 <= last["success_rate"] <= 1.0 and last["env_steps_per_s"] > 0
    from dvrl_marl.envs import suction_debris_v8

    observations, _ = suction_debris_v8.parallel_env(preset="benchmark").reset(seed=0)
    for agent in ("suction", "grasper"):
        policy = policies.load(tmp_path / "run" / "policies" / f"marl-{agent}")
        assert policy.spec["agent"] == agent and policy.spec["training"]["trainer"] == "device_mappo"
        action = policy(observations[agent])
        assert action.shape == (4,) and np.all(np.abs(action) <= 1.0)


def test_advantages_bootstrap_truncations_and_not_terminations():
    import torch

    rollout = device_mappo.Rollout(
        observations=None, states=None, actions=None, log_probs=None,
        values=torch.zeros(2, 1, 1), rewards=torch.ones(2, 1, 1), done=torch.tensor([[True], [False]]),
        terminated=torch.tensor([[False], [False]]), next_values=torch.full((2, 1, 1), 10.0))
    advantage, returns = device_mappo.advantages(rollout, gamma=0.5, lam=1.0, torch=torch)
    # step 0 was truncated: 1 + 0.5 x 10 (its final state's value), nothing carried over from the next episode
    assert advantage[0, 0, 0] == pytest.approx(6.0)
    rollout.terminated = torch.tensor([[True], [False]])
    advantage, _ = device_mappo.advantages(rollout, gamma=0.5, lam=1.0, torch=torch)
    assert advantage[0, 0, 0] == pytest.approx(1.0)  # terminated: no bootstrap


def test_what_it_does_not_do_is_refused_by_name(tmp_path):
    with pytest.raises(ValueError, match="bc_expert"):
        device_mappo.train(replace(TINY, bc_expert="scripted"), 0, tmp_path / "a")
    with pytest.raises(ValueError, match="surgeon"):
        device_mappo.train(replace(TINY, surgeon="scripted"), 0, tmp_path / "b")
    device_mappo.train(replace(TINY, total_steps=256, eval_every=256), 0, tmp_path / "c", log=lambda *_: None)
    with pytest.raises(ValueError, match="holds a run already"):
        device_mappo.train(TINY, 0, tmp_path / "c")
