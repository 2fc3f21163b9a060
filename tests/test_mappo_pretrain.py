"""Behaviour cloning before MAPPO (``[pretrain]``): the recorded labels are the expert's own actions, the clone
acts like the expert, the run records what it cloned and evaluates the clone before PPO, the critic warm-up
freezes the actor, and the clone's observation scaling stays as it was fitted (bad settings: tests/test_mappo.py)."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torchrl")

from dvrl_marl.agents.collaborative import ScriptedSurgeon  # noqa: E402
from dvrl_marl.envs import suction_debris_v8  # noqa: E402
from dvrl_marl.training import mappo, models, pretrain  # noqa: E402

CONFIG = """
[run]
algorithm = "mappo"
total_steps = 2048
num_envs = 32
rollout_steps = 16
eval_every = 1024
eval_episodes = 4
checkpoint_every = 1024
surgeon = "scripted"
surgeon_seat = "suction"
[env]
reward_type = "dense"
max_cycles = {max_cycles}
blood_ml = [0.0, 0.0]
observation_features = "suction_debris_cleared_pins"
[ppo]
epochs = 2
minibatches = 2
[model]
hidden = [32, 32]
initial_std = 0.3
tool_head = "switch"
[pretrain]
bc_expert = "scripted"
bc_episodes = {episodes}
bc_action_noise = 0.3
bc_epochs = {epochs}
bc_dagger_rounds = {rounds}
critic_warmup_steps = 1024
"""


def _config(tmp_path, max_cycles=40, episodes=4, epochs=2, rounds=0):
    path = tmp_path / "bc.toml"
    path.write_text(CONFIG.format(max_cycles=max_cycles, episodes=episodes, epochs=epochs, rounds=rounds))
    return mappo.load_config(path)


def test_recorded_labels_are_the_experts_actions(tmp_path):
    config = _config(tmp_path, max_cycles=60)
    recorded = pretrain.record_expert(config, seed=0)
    assert list(recorded) == ["grasper"]  # only the learning seat; the scripted suction is the partner
    observations, labels = recorded["grasper"]
    env = suction_debris_v8.batched_env(num_envs=1, surgeon="scripted", surgeon_seat="suction",
                                        autoreset_mode="disabled", **config.env)
    expert = ScriptedSurgeon.for_env(env)
    assert observations.shape == (4 * 60, env.observation_space("grasper").shape[0]) and labels.shape == (240, 4)
    # (observations are kept as float32: a state on one of the expert's thresholds may round across it)
    same = np.all(np.abs(labels - expert(observations.astype(np.float64))) < 1e-4, axis=1)
    assert same.mean() > 0.99
    # DART: the executed motion was noisy, so the episodes leave the expert's own path (the states differ)
    noiseless = config.__class__(**{**config.__dict__, "bc_action_noise": 0.0})
    quiet, _ = pretrain.record_expert(noiseless, seed=0)["grasper"]
    assert not np.allclose(quiet, observations)


def test_a_dagger_round_records_where_the_learner_drove_labelled_by_the_expert(tmp_path):
    config = _config(tmp_path, max_cycles=30)
    calls = []

    def stand_still(index, observations, rng):  # the "clone": never moves, jaw closed
        calls.append(index)
        return np.tile([0.0, 0.0, 0.0, -1.0], (len(observations), 1))

    observations, labels = pretrain.record_expert(config, seed=0, act=stand_still, round_index=1)["grasper"]
    assert calls and set(calls) == {0}
    tips = observations[:, 0:3].reshape(30, 4, 3)
    np.testing.assert_allclose(tips, np.broadcast_to(tips[0], tips.shape), atol=1e-6)  # where it drove: nowhere
    env = suction_debris_v8.batched_env(num_envs=1, surgeon="scripted", surgeon_seat="suction",
                                        autoreset_mode="disabled", **config.env)
    expert = ScriptedSurgeon.for_env(env)
    assert np.mean(np.all(np.abs(labels - expert(observations.astype(np.float64))) < 1e-4, axis=1)) > 0.99
    assert np.abs(labels[:, :3]).max() > 0.5  # the expert would have moved


def test_the_clone_acts_like_the_expert(tmp_path):
    config = _config(tmp_path, max_cycles=150, episodes=16, epochs=40)
    observations, labels = pretrain.record_expert(config, seed=0)["grasper"]
    _, _, actor_net, _ = models.build_models(config, ["grasper"], observations.shape[1], 10, 4)
    before = actor_net.agent_forward(torch.from_numpy(observations), 0).detach().numpy()
    loss = pretrain.clone_actor(actor_net, 0, observations, labels, tool_head="switch", epochs=40,
                                learning_rate=3e-3, batch_size=256)
    after = actor_net.agent_forward(torch.from_numpy(observations), 0).detach().numpy()
    error_before = np.mean((before[:, :3] - labels[:, :3]) ** 2)
    error_after = np.mean((np.clip(after[:, :3], -1, 1) - labels[:, :3]) ** 2)
    assert np.isfinite(loss) and error_after < 0.25 * error_before
    assert np.mean(np.sign(after[:, 3]) == np.sign(labels[:, 3])) > 0.95  # the jaw opens and closes as the expert's
    assert actor_net.norm.count > len(observations)  # the normaliser saw the demonstrations first


@pytest.mark.slow
def test_run_clones_evaluates_the_clone_and_warms_up_the_critic(tmp_path):
    config = _config(tmp_path, rounds=1)  # the demonstrations, then one DAgger round
    run = tmp_path / "run"
    snapshots = []

    def snapshot(iteration, collectors):
        actor = collectors.collector.actor
        snapshots.append({k: v.detach().clone() for k, v in actor.state_dict().items()})

    mappo.train(config, 0, run, progress=False, log=lambda *_: None, on_iteration=snapshot)
    summary = json.loads((run / "pretrain.json").read_text())
    assert summary["expert"] == "scripted" and summary["agents"]["grasper"]["transitions"] == 2 * 4 * 40
    with (run / "progress.csv").open() as handle:
        assert [int(r["steps"]) for r in csv.DictReader(handle)] == [0, 1024, 2048]  # the clone, then PPO
    weights = [k for k in snapshots[0] if "nets" in k and "weight" in k]
    norm = [k for k in snapshots[0] if k.endswith("norm.mean")]
    assert weights and norm
    # iterations 1 and 2 (512 and 1024 steps) are the warm-up: the actor does not move
    assert all(torch.equal(snapshots[0][k], snapshots[1][k]) for k in weights)
    assert any(not torch.equal(snapshots[1][k], snapshots[3][k]) for k in weights)  # then PPO updates it
    assert all(torch.equal(snapshots[0][k], snapshots[3][k]) for k in norm)  # the clone's scaling stays
    from dvrl_marl import policies

    learnt_from = policies.load(run / "policies" / "marl-grasper").spec["training"]["demonstrations"]
    assert learnt_from == {"expert": "scripted", "episodes": 4, "action_noise": 0.3, "dagger_rounds": 1}
    # resuming does not clone again (the checkpoint holds the fine-tuned actor)
    messages = []
    mappo.train(config, 0, run, total_steps=2560, resume=True, progress=False, log=messages.append)
    assert not any("cloned" in m for m in messages)



INIT_CONFIG = """
[run]
algorithm = "mappo"
total_steps = 1024
num_envs = 16
rollout_steps = 16
eval_every = 1024
eval_episodes = 2
checkpoint_every = 1024
surgeon = "scripted"
surgeon_seat = "grasper"
[env]
observation_features = "suction_debris_routes"
max_cycles = 40
[model]
hidden = {hidden}
tool_head = "switch"
[pretrain]
init_policy = {{ suction = "marl-suction" }}
critic_warmup_steps = 1024
"""


def _init_config(tmp_path, hidden="[256, 256]"):
    path = tmp_path / "init.toml"
    path.write_text(INIT_CONFIG.format(hidden=hidden))
    return mappo.load_config(path)


def test_an_actor_started_from_a_policy_acts_as_that_policy(tmp_path):
    """init_policy: the torch actor's mean is the shipped policy's action (the tool's logit on the same side), the
    normaliser the identity, and a run records where it started and evaluates the policy before PPO."""
    from dvrl_marl import policies

    config = _init_config(tmp_path)
    env = suction_debris_v8.batched_env(num_envs=8, surgeon="scripted", surgeon_seat="grasper", **config.env)
    agents = list(env.possible_agents)
    _, _, actor_net, _ = models.build_models(config, agents, env.observation_space("suction").shape[0],
                                            env.state_space.shape[0], 4, feature_spec=env.feature_spec)
    summary = pretrain.start_from_policies(config, actor_net, agents, env.feature_spec)
    assert summary == {"started_from": {"suction": "marl-suction"}}
    observations, _ = env.reset(seed=3)
    shipped = policies.load("marl-suction")
    for _ in range(30):
        with torch.no_grad():
            loc = actor_net.agent_forward(torch.from_numpy(observations["suction"].astype(np.float32)), 0).numpy()
        expected = shipped(observations["suction"])
        np.testing.assert_allclose(np.clip(loc[:, :3], -1, 1), expected[:, :3], atol=1e-4)
        np.testing.assert_array_equal(np.where(loc[:, 3] > 0, 1.0, -1.0), expected[:, 3])
        observations, *_ = env.step({"suction": expected})
    run = mappo.train(config, 0, tmp_path / "run", progress=False, tensorboard=False, log=lambda *_: None)
    assert json.loads((tmp_path / "run" / "pretrain.json").read_text()) == summary
    with (tmp_path / "run" / "progress.csv").open() as handle:
        assert [row["steps"] for row in csv.DictReader(handle)][0] == "0"  # the policy before PPO
    spec = json.loads((tmp_path / "run" / "policies" / "marl-suction" / "policy.json").read_text())
    assert spec["training"]["started_from"] == {"suction": "marl-suction"} and run["steps"] >= 1024


def test_a_policy_of_another_network_is_refused_by_name(tmp_path):
    config = _init_config(tmp_path, hidden="[64, 64]")
    env = suction_debris_v8.batched_env(num_envs=1, surgeon="scripted", surgeon_seat="grasper", **config.env)
    _, _, actor_net, _ = models.build_models(config, ["suction"], env.observation_space("suction").shape[0],
                                            env.state_space.shape[0], 4, feature_spec=env.feature_spec)
    with pytest.raises(ValueError, match=r"init_policy suction = 'marl-suction': layers .* set \[model\] hidden"):
        pretrain.start_from_policies(config, actor_net, ["suction"], env.feature_spec)
    config = _init_config(tmp_path)
    _, _, actor_net, _ = models.build_models(config, ["suction"], env.observation_space("suction").shape[0],
                                            env.state_space.shape[0], 4, feature_spec={"name": "other"})
    with pytest.raises(ValueError, match="observation features 'suction_debris_routes' are not this run's 'other'"):
        pretrain.start_from_policies(config, actor_net, ["suction"], {"name": "other"})
