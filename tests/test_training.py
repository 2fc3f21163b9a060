"""Training extensions and the run machinery (fast versions only; the real runs are in baselines/)."""

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch as th

from dvrl_marl import policies
from dvrl_marl.files import read_extended_toml
from dvrl_marl.training import bc_loss, export_policy, load_config, q_filter_mask, train
from dvrl_marl.training.demonstrations import generate_demonstrations, load_demonstrations, save_demonstrations
from dvrl_marl.training.runner import ON_POLICY, sb3_algorithms, evaluate_policy

# The goal-env configurations (the PPO ones for the collaborative env are tested in test_marl_training.py).
CONFIGS = sorted(p for p in (Path(__file__).parents[1] / "baselines" / "configs").glob("*.toml")  # goal-env runs
                 if "env_id" in read_extended_toml(p).get("run", {}))


def test_bc_loss_on_a_hand_made_batch():
    policy = th.tensor([[0.0, 0.0], [1.0, -1.0], [0.5, 0.5]])
    demo = th.tensor([[1.0, 0.0], [1.0, 1.0], [0.5, 0.5]])
    assert bc_loss(policy, demo).item() == pytest.approx(1.0 + 4.0 + 0.0)
    mask = th.tensor([1.0, 0.0, 1.0])
    assert bc_loss(policy, demo, mask).item() == pytest.approx(1.0)


def test_q_filter_keeps_only_demonstrations_the_critic_prefers():
    q_demo = th.tensor([[1.0], [0.0], [2.0], [-1.0]])
    q_policy = th.tensor([[0.5], [0.0], [3.0], [-2.0]])
    assert q_filter_mask(q_demo, q_policy).tolist() == [1.0, 0.0, 0.0, 1.0]


@pytest.mark.slow
def test_bc_gradient_pulls_the_actor_towards_the_demonstrations():
    from stable_baselines3 import HerReplayBuffer

    from dvrl_marl.training import DDPGBC

    env = gym.make("dvrl_marl/PSMReach-v1")
    model = DDPGBC("MultiInputPolicy", env, replay_buffer_class=HerReplayBuffer, learning_starts=100, batch_size=16,
                   buffer_size=5000,
                   bc_weight=1.0, demo_batch_size=8, action_l2=0.0, policy_kwargs={"net_arch": [16]}, seed=0,
                   learning_rate=1e-2)
    obs, _ = env.reset(seed=0)
    demo_obs = {k: np.repeat(v[None], 8, axis=0) for k, v in obs.items()}
    demo_actions = np.tile(np.array([[1.0, -1.0, 0.5]], dtype=np.float32), (8, 1))
    model.set_demonstrations(demo_obs, demo_actions)
    model.learn(300)  # fills the buffer and trains
    before = np.abs(model.predict(obs, deterministic=True)[0] - demo_actions[0]).sum()
    model.bc_weight = 100.0  # BC dominates: the actor must move to the demonstrated action
    model.train(gradient_steps=200, batch_size=16)
    after = np.abs(model.predict(obs, deterministic=True)[0] - demo_actions[0]).sum()
    assert after < before and after < 0.3


def test_random_action_probability_replaces_exploration_steps_with_uniform_actions():
    from dvrl_marl.training import DDPGBC

    def sampled_actions(probability):
        env = gym.make("dvrl_marl/PSMReach-v1")
        model = DDPGBC("MultiInputPolicy", env, learning_starts=0, buffer_size=100, bc_weight=0.0,
                       policy_kwargs={"net_arch": [8]}, seed=3, random_action_probability=probability)
        model._last_obs = {k: v[None] for k, v in env.reset(seed=0)[0].items()}
        actions = np.array([model._sample_action(learning_starts=0)[0][0] for _ in range(400)])
        return actions

    policy_only = sampled_actions(0.0)
    assert np.allclose(policy_only, policy_only[0])  # no noise: the deterministic actor's action every time
    mixed = sampled_actions(0.3)
    replaced = ~np.all(np.isclose(mixed, policy_only[0]), axis=1)
    assert 0.2 < replaced.mean() < 0.4  # about 30 % uniform random actions
    assert np.all(np.abs(mixed) <= 1.0) and mixed[replaced].std(axis=0).min() > 0.4  # uniform on [-1, 1] has 0.58
    with pytest.raises(ValueError, match="random_action_probability"):
        DDPGBC("MultiInputPolicy", gym.make("dvrl_marl/PSMReach-v1"), random_action_probability=1.5)


def _tiny(config):
    algorithm_kwargs = dict(config.algorithm_kwargs)
    if config.algorithm in ON_POLICY:  # 2 worlds x 25 steps a rollout: evaluations land on 150 and 300
        algorithm_kwargs.update(n_steps=25, batch_size=25, n_epochs=2)
        return dataclasses.replace(config, total_timesteps=300, eval_every=150, eval_episodes=2, num_envs=2,
                                   algorithm_kwargs=algorithm_kwargs, policy={"net_arch": [16, 16]})
    algorithm_kwargs.update(learning_starts=100, gradient_steps=2, buffer_size=2000, batch_size=32)
    if config.algorithm == "ddpg_bc":
        algorithm_kwargs.update(demo_batch_size=16)
    return dataclasses.replace(config, total_timesteps=300, eval_every=150, eval_episodes=2,
                               demonstrations=min(config.demonstrations, 2), algorithm_kwargs=algorithm_kwargs,
                               policy={"net_arch": [16, 16]})


@pytest.mark.parametrize("config_path", CONFIGS, ids=lambda p: p.stem)
@pytest.mark.slow
def test_every_configuration_trains_end_to_end(config_path, tmp_path):
    config = _tiny(load_config(config_path))
    if config.algorithm not in sb3_algorithms():
        pytest.skip(f"{config.algorithm} needs sb3-contrib")
    history = train(config, seed=0, out_dir=tmp_path, progress=False)
    assert [row["timesteps"] for row in history] == [150, 300]
    kept = ("vecnormalize.pkl" if config.normalize_reward else "config.toml") if config.algorithm in ON_POLICY \
        else "replay_buffer.pkl"  # what a resume needs beside the model
    for name in ("progress.csv", "checkpoint.zip", kept, "final_model.zip", "best_model.zip", "config.toml"):
        assert (tmp_path / name).is_file(), name
    if config.demonstrations:
        demos = load_demonstrations(tmp_path / "demonstrations.npz")
        assert demos["metadata"]["episodes"] == 2


def test_tensorboard_logs_carry_the_evaluations(tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    config = _tiny(load_config(next(p for p in CONFIGS if p.stem == "reach_lnd_ddpg_her")))
    history = train(config, seed=0, out_dir=tmp_path, progress=False, tensorboard=True)
    events = EventAccumulator(str(next((tmp_path / "sb3_log").glob("events.out.tfevents.*")))).Reload()
    success = events.Scalars("eval/success_rate")
    assert [e.step for e in success] == [150, 300]
    assert [e.value for e in success] == pytest.approx([row["success_rate"] for row in history])
    assert "train/critic_loss" in events.Tags()["scalars"]


def test_tensorboard_without_the_package_is_a_clear_error(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "tensorboard", None)  # makes `import tensorboard` fail
    config = _tiny(load_config(next(p for p in CONFIGS if p.stem == "reach_lnd_ddpg_her")))
    with pytest.raises(ImportError, match="pip install 'dvrl-marl\\[train\\]'"):
        train(config, seed=0, out_dir=tmp_path / "run", progress=False, tensorboard=True)
    assert not (tmp_path / "run").exists()  # failed before doing any work


@pytest.mark.parametrize("stem", ["reach_lnd_ddpg_her", "pick_lnd_ppo_scratch"])
@pytest.mark.slow
def test_resume_continues_from_the_checkpoint(tmp_path, stem):
    config = _tiny(load_config(next(p for p in CONFIGS if p.stem == stem)))
    train(config, seed=0, out_dir=tmp_path, progress=False)
    history = train(dataclasses.replace(config, total_timesteps=500), seed=0, out_dir=tmp_path, progress=False,
                    resume=True)
    # The first two evaluations come from the first run's progress.csv; training resumed at step 300.
    assert [row["timesteps"] for row in history] == [150, 300, 450, 500]


def test_demonstrations_file_round_trip(tmp_path):
    data = generate_demonstrations("dvrl_marl/PSMPick-v1", episodes=3, seed=0)
    path = save_demonstrations(data, tmp_path / "demos.npz")
    loaded = load_demonstrations(path)
    assert loaded["metadata"]["episodes"] == 3 and set(np.unique(loaded["episode"])) == {0, 1, 2}
    np.testing.assert_array_equal(loaded["action"], data["action"])
    assert loaded["observation"].shape[1] == 7 and loaded["action"].shape[1] == 4
    with pytest.raises(ValueError):
        np.savez(tmp_path / "other.npz", metadata=np.array(json.dumps({"format": "x"})))
        load_demonstrations(tmp_path / "other.npz")


@pytest.mark.parametrize("algorithm", ["ddpg", "sac", "ppo"])
def test_exported_numpy_policy_matches_the_torch_policy(algorithm, tmp_path):
    from stable_baselines3 import DDPG, PPO, SAC, HerReplayBuffer

    env = gym.make("dvrl_marl/PSMPick-v1")
    if algorithm == "ppo":  # the Gaussian's mean, clipped; its jaw learnt as a switch is sent as -1 or 1
        model = PPO("MultiInputPolicy", env, policy_kwargs={"net_arch": [32, 24]}, seed=1)
        switches = [3]
    else:
        cls = {"ddpg": DDPG, "sac": SAC}[algorithm]
        model = cls("MultiInputPolicy", env, replay_buffer_class=HerReplayBuffer,
                    policy_kwargs={"net_arch": [32, 24]}, buffer_size=1000, seed=1)
        switches = []
    export_policy(model, tmp_path / "exported", name="test", env_id="dvrl_marl/PSMPick-v1",
                  switch_dimensions=switches)
    policy = policies.load(tmp_path / "exported")
    rng = np.random.default_rng(0)
    batch = {k: rng.uniform(-1, 1, (64,) + s.shape) for k, s in env.observation_space.spaces.items()}
    torch_actions, _ = model.predict(batch, deterministic=True)
    if switches:
        assert set(np.unique(policy(batch)[:, 3])) <= {-1.0, 1.0}
        torch_actions[:, 3] = np.where(torch_actions[:, 3] > 0, 1.0, -1.0)
    np.testing.assert_allclose(policy(batch), torch_actions, atol=1e-5)
    single = {k: v[0] for k, v in batch.items()}
    np.testing.assert_allclose(policy(single), torch_actions[0], atol=1e-5)


def test_policies_load_and_run_without_torch():
    code = (
        "import sys, gymnasium as gym, dvrl_marl\n"
        "from dvrl_marl import policies\n"
        "names = policies.available()\n"
        "assert names, 'no shipped policies'\n"
        "import importlib, numpy as np\n"
        "for name in names:\n"
        "    policy = policies.load(name)\n"
        "    if policy.spec['env_id'].startswith('dvrl_marl/'):  # a Gymnasium id\n"
        "        env = gym.make(policy.spec['env_id'])\n"
        "        obs, _ = env.reset(seed=0)\n"
        "        env.step(policy(obs))\n"
        "    else:  # a multi-agent seat: a PettingZoo module of dvrl_marl.envs and the agent it acts for\n"
        "        # (a pixel policy names the image options its observation needs)\n"
        "        module = importlib.import_module('dvrl_marl.envs.' + policy.spec['env_id'])\n"
        "        # (and a policy of a preset's scene, the preset: the irrigation level's observations are wider)\n"
        "        env = module.parallel_env(**(policy.image_options or {}),\n"
        "                                  **({'preset': policy.spec['preset']} if policy.spec.get('preset') else {}))\n"
        "        obs, _ = env.reset(seed=0)\n"
        "        agent = policy.spec['agent']\n"
        "        env.step({a: policy(obs[a]) if a == agent else np.zeros(4) for a in env.agents})\n"
        "assert 'torch' not in sys.modules, 'torch was imported'\n"
        "assert 'stable_baselines3' not in sys.modules\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_load_rejects_unknown_names():
    with pytest.raises(FileNotFoundError, match="no policy"):
        policies.load("does-not-exist")


@pytest.mark.parametrize("name", ["reach-lnd", "reach-suction-irrigation", "pick-lnd", "pick-lnd-scratch"])
@pytest.mark.slow
def test_shipped_policies_reach_their_stated_success_rate(name):
    assert name in policies.available()
    policy = policies.load(name)
    env_kwargs = {"tool": policy.spec["tool"]} if "tool" in policy.spec else {}
    result = evaluate_policy(policy, policy.spec["env_id"], 20, seed=2_000_000, env_kwargs=env_kwargs)
    stated = policy.spec["evaluation"]["success_rate"]
    assert result["success_rate"] >= stated - 0.1, (result, stated)


def test_cli_evaluate_and_plot(tmp_path, capsys):
    from dvrl_marl.cli import main

    assert main(["evaluate", "reach-lnd", "--episodes", "2", "--tool", "suction_irrigation"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["tool"] == "suction_irrigation" and 0.0 <= result["success_rate"] <= 1.0
    run = tmp_path / "reach-seed0"
    run.mkdir()
    (run / "progress.csv").write_text("timesteps,success_rate,mean_final_distance,wall_seconds\n10,0.5,0.01,1\n20,1.0,0.0,2\n")
    assert main(["plot", str(run), "--out", str(tmp_path / "curves")]) == 0
    assert (tmp_path / "curves.png").stat().st_size > 1000
    assert "reach,10,0.5" in (tmp_path / "curves.csv").read_text()
    assert main(["evaluate", "no-such-policy"]) == 2


def test_a_goal_env_configuration_extends_another_and_keeps_the_chain(tmp_path):
    """``[run] extends`` for the goal-env runner too (the MAPPO reader's mechanism): the base's settings, key by key
    overridden; the run folder's copy of the configuration holds every file of the chain."""
    base = Path(__file__).parents[1] / "baselines" / "configs" / "reach_lnd_ddpg_her.toml"
    (tmp_path / "base.toml").write_text(base.read_text())
    (tmp_path / "short.toml").write_text("[run]\nextends = 'base.toml'\ntotal_timesteps = 500\n")
    short, record = load_config(tmp_path / "short.toml"), load_config(base)
    assert (short.name, short.total_timesteps) == ("short", 500)
    assert (short.env_id, short.algorithm, short.her) == (record.env_id, record.algorithm, record.her)
    assert short.source.startswith(base.read_text()) and "# --- short.toml ---" in short.source


@pytest.mark.parametrize("config", ["reach_lnd_ddpg_her", "pick_lnd_ppo_scratch"])
def test_the_cli_exports_what_it_trained(tmp_path, config):
    """``train --export``: an off-policy HER run (SB3 will not load its buffer without an env) and an on-policy one
    both write a policy that loads and acts."""
    from dvrl_marl import policies
    from dvrl_marl.cli import main

    exported = tmp_path / "exported"
    assert main(["train", config, "--steps", "200", "--out", str(tmp_path / "run"), "--export", str(exported),
                 "--no-progress"]) == 0
    policy = policies.load(exported)
    env = gym.make(policy.spec["env_id"])
    observation, _ = env.reset(seed=0)
    assert env.action_space.contains(policy(observation))


@pytest.mark.parametrize("config", ["reach_lnd_ddpg_her", "pick_lnd_ppo_scratch"])
def test_a_seeds_run_is_reproduced_bit_for_bit(tmp_path, config):
    """An SB3 run of record (off-policy with HER, on-policy), twice from one seed: the same exported policy to the
    last bit, gradient steps included."""
    from dvrl_marl.cli import resolve_config
    from dvrl_marl.training.runner import load_final_model

    config = _tiny(load_config(resolve_config(config)))
    weights = []
    for run in ("first", "second"):
        train(config, seed=5, out_dir=tmp_path / run, progress=False)
        model = load_final_model(config, tmp_path / run)
        export_policy(model, tmp_path / run / "policy", name="p", env_id=config.env_id)
        weights.append(np.load(tmp_path / run / "policy" / "policy.npz"))
    for name in weights[0].files:
        np.testing.assert_array_equal(weights[0][name], weights[1][name], err_msg=name)
