"""Demonstrations as Minari datasets, replayed exactly, and a surgeon cloned from them."""

import json

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import dvrl_marl  # noqa: F401  (registration)
from dvrl_marl.envs import suction_debris_v8

minari = pytest.importorskip("minari", reason='Minari is the "data" extra: pip install "dvrl-marl[data]"')

from dvrl_marl import datasets, policies  # noqa: E402
from dvrl_marl.agents import ScriptedSuction  # noqa: E402
from dvrl_marl.teleop import KeyboardDevice, Recorder  # noqa: E402

SCRIPTED_PARTNER = {"partner": "scripted"}  # fast: no pipelines to build


@pytest.fixture(autouse=True)
def _private_store(tmp_path, monkeypatch):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """Two episodes of the scripted surgeon, recorded once for the module."""
    import os

    store = tmp_path_factory.mktemp("store")
    previous = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(store)
    try:
        datasets.record("dvrl_marl/surgeon-test-v1", "scripted", episodes=2, seed=11, env_kwargs=SCRIPTED_PARTNER)
        yield minari.load_dataset("dvrl_marl/surgeon-test-v1")
    finally:
        if previous is None:
            os.environ.pop("MINARI_DATASETS_PATH")
        else:
            os.environ["MINARI_DATASETS_PATH"] = previous


def test_the_seat_env_passes_gymnasiums_checker_and_refuses_bad_arguments():
    env = gym.make("dvrl_marl/SurgeonSeat-v8", partner="scripted")
    check_env(env.unwrapped, skip_render_check=True)
    observation, info = env.reset(seed=0)
    assert observation.shape == env.observation_space.shape and info["partner_action"].shape == (4,)
    for bad in ({"seat": "assistant"}, {"version": "v2"}, {"partner": 3}):
        with pytest.raises((ValueError, TypeError), match=next(iter(bad))):
            gym.make("dvrl_marl/SurgeonSeat-v8", **bad)


@pytest.mark.slow
def test_a_recorded_dataset_is_a_minari_dataset_with_everything_needed(recorded):
    assert recorded.total_episodes == 2 and recorded.spec.env_spec.id == "dvrl_marl/SurgeonSeat-v8"
    assert recorded.spec.env_spec.kwargs["partner"] == "scripted"
    seeds = [meta["seed"] for meta in recorded.storage.get_episode_metadata([0, 1])]
    assert seeds == [11, 12]
    for episode in recorded.iterate_episodes():
        steps = len(episode.actions)
        assert episode.observations.shape == (steps + 1, 30) and episode.actions.shape == (steps, 4)
        assert episode.rewards.shape == episode.terminations.shape == episode.truncations.shape == (steps,)
        assert set(episode.infos) == {"is_success", "blood_remaining", "debris_delivered", "collision",
                                      "partner_action", "expert_action"}
        np.testing.assert_array_equal(episode.infos["expert_action"][1:], episode.actions)  # recorded without noise
        assert episode.infos["partner_action"].shape == (steps + 1, 4)
        assert bool(episode.infos["is_success"][-1]) and bool(episode.terminations[-1])
    observations, actions = datasets.transitions(recorded)
    assert len(observations) == len(actions) == recorded.total_steps


@pytest.mark.slow
def test_an_episode_replays_exactly(recorded):
    for index in range(2):
        result = datasets.replay(recorded, index)
        assert result["max_observation_difference"] == 0.0 and result["success"] == result["recorded_success"]


def test_a_replay_device_fills_the_surgeon_seat(recorded):
    device = datasets.replay_device(recorded, 1)
    env = suction_debris_v8.parallel_env(surgeon=device)
    suction = ScriptedSuction.for_env(env)
    observations, _ = env.reset(seed=12)
    while env.agents:
        observations, _, _, _, infos = env.step({"suction": suction(observations["suction"])})
    assert infos["suction"]["is_success"]


def test_recordings_convert_and_datasets_are_not_overwritten(tmp_path):
    keyboard = KeyboardDevice()
    recorder = Recorder(keyboard, seat="grasper", seed=3)
    env = suction_debris_v8.parallel_env(surgeon=recorder, max_cycles=60)
    suction = ScriptedSuction.for_env(env)
    observations, _ = env.reset(seed=3)
    keyboard.key_event(68, 1)  # D held: +x
    while env.agents:
        observations, *_ = env.step({"suction": suction(observations["suction"])})
    path = recorder.save(tmp_path / "session.npz")
    dataset = datasets.from_recording("dvrl_marl/keyboard-session-v1", [path],
                                      env_kwargs={**SCRIPTED_PARTNER, "max_cycles": 60})
    episode = next(dataset.iterate_episodes())
    np.testing.assert_array_equal(episode.actions, np.asarray(recorder.actions))
    assert datasets.replay(dataset, 0)["max_observation_difference"] == 0.0
    with pytest.raises(ValueError, match="exists already"):
        datasets.record("dvrl_marl/keyboard-session-v1", "scripted", episodes=1, env_kwargs=SCRIPTED_PARTNER)
    with pytest.raises(ValueError, match="not of the form"):  # refused before anything is written
        datasets.record("dvrl_marl/noise-0.3-v1", "scripted", episodes=1, env_kwargs=SCRIPTED_PARTNER)
    assert "dvrl_marl/keyboard-session-v1" in minari.list_local_datasets()  # the store still lists


def test_behaviour_cloning_learns_and_seats_its_clone(recorded, tmp_path):
    pytest.importorskip("torch")  # the clone trains in torch
    from dvrl_marl.training.clone import clone

    observations, actions = datasets.transitions(recorded)
    folder, losses = clone(observations, actions, tmp_path / "bc", hidden=(64,), epochs=15, batch_size=256)
    assert losses[-1] < 0.5 * losses[0]
    policy = policies.load(folder)
    predicted = np.stack([policy(o) for o in observations[:200]])
    assert predicted.shape == (200, 4) and np.all(np.abs(predicted) <= 1.0)
    env = suction_debris_v8.parallel_env(surgeon=policy, max_cycles=50)
    env.reset(seed=0)
    env.step({"suction": np.zeros(4)})  # the clone fills the seat like any policy


@pytest.mark.slow
def test_train_command_records_clones_and_evaluates(tmp_path, capsys):
    pytest.importorskip("torch")  # the clone trains in torch
    from dvrl_marl.cli import main

    config = tmp_path / "tiny_bc.toml"
    config.write_text('[run]\nalgorithm = "bc"\ndataset = "dvrl_marl/surgeon-tiny-v1"\n'
                      '[record]\npolicy = "scripted"\nepisodes = 1\nseed = 4\nenv_kwargs = { partner = "scripted" }\n'
                      '[bc]\nhidden = [32]\nepochs = 3\n[evaluate]\npartner = "scripted"\nepisodes = 3\n')
    assert main(["train", str(config), "--out", str(tmp_path / "run"), "--no-progress"]) == 0
    result = json.loads((tmp_path / "run" / "result.json").read_text())
    assert result["dataset"] == "dvrl_marl/surgeon-tiny-v1" and result["episodes"] == 3
    assert 0.0 <= result["success_rate"] <= 1.0 and "held-out episodes" in capsys.readouterr().out
    assert "dvrl_marl/surgeon-tiny-v1" in minari.list_local_datasets()


@pytest.mark.extended
def test_dagger_rounds_relabel_the_clones_own_states_with_the_expert(tmp_path):
    pytest.importorskip("torch")  # the clone trains in torch
    from dvrl_marl.agents.collaborative import ScriptedSurgeon
    from dvrl_marl.cli import main
    from dvrl_marl.training.clone import dagger_round, load_config

    config = tmp_path / "tiny_dagger.toml"
    config.write_text('[run]\nalgorithm = "bc"\ndataset = "dvrl_marl/surgeon-dagger-v1"\n'
                      '[record]\npolicy = "scripted"\nepisodes = 1\nseed = 4\nenv_kwargs = { partner = "scripted" }\n'
                      '[bc]\nhidden = [32]\nepochs = 2\n[dagger]\nrounds = 2\nepisodes = 2\n'
                      '[evaluate]\npartner = "scripted"\nepisodes = 2\n')
    assert main(["train", str(config), "--out", str(tmp_path / "run"), "--no-progress"]) == 0
    result = json.loads((tmp_path / "run" / "result.json").read_text())
    recorded = len(datasets.transitions("dvrl_marl/surgeon-dagger-v1")[1])
    assert [r["round"] for r in result["dagger"]] == [1, 2]
    assert result["transitions"] == recorded + sum(r["visited"] for r in result["dagger"])
    relabelled = np.load(tmp_path / "run" / "dagger.npz")
    expert = ScriptedSurgeon.for_env(suction_debris_v8.parallel_env())
    np.testing.assert_allclose(relabelled["actions"][:50], expert(relabelled["observations"][:50]), atol=1e-6)
    assert policies.load(tmp_path / "run" / "policies" / "bc-surgeon").spec["dagger_rounds"] == 2

    visited, labels = dagger_round(policies.load(tmp_path / "run" / "policies" / "bc-surgeon"), "scripted", 2, seed=7)
    assert len(visited) == len(labels) >= 2 and labels.shape[1] == 4

    bad = tmp_path / "bad.toml"
    bad.write_text('[run]\nalgorithm = "bc"\ndataset = "dvrl_marl/x-v1"\n[record]\npolicy = "reach-lnd"\n'
                   'episodes = 5\n[dagger]\nrounds = 1\nepisodes = 1\n')
    with pytest.raises(ValueError, match="scripted"):
        load_config(bad)
    bad.write_text('[run]\nalgorithm = "bc"\ndataset = "dvrl_marl/x-v1"\n[dagger]\nround = 1\n')
    with pytest.raises(ValueError, match="\\[dagger\\] round: unknown key"):
        load_config(bad)


def test_clone_options_sharp_cleared_inputs_weights_and_annealing(recorded, tmp_path):
    pytest.importorskip("torch")  # the clone trains in torch
    from dvrl_marl.training.clone import cleared_features, clone

    observations, actions = datasets.transitions(recorded)
    features = cleared_features()
    folder, losses = clone(observations, actions, tmp_path / "bc", hidden=(32,), epochs=4, threshold_features=features,
                           action_weights=[1.0, 1.0, 1.0, 4.0], anneal_lr=True)
    policy = policies.load(folder)
    weight, bias = policy.weights[0]
    assert weight.shape == (observations.shape[1] + len(features), observations.shape[1])
    for row, (index, level) in enumerate(features, start=observations.shape[1]):
        below, above = np.zeros(observations.shape[1]), np.zeros(observations.shape[1])
        below[index], above[index] = level - 0.002, level + 0.002  # 2 % of a fraction point either side
        assert np.tanh(weight[row] @ below + bias[row]) > 0.95 and np.tanh(weight[row] @ above + bias[row]) < -0.95
    action = policy(observations[0])
    assert action.shape == (4,) and np.all(np.abs(action) <= 1.0) and len(losses) == 4


@pytest.mark.slow
def test_the_shipped_clone_fills_the_seat_and_finishes_the_task(capsys):
    from dvrl_marl.cli import main

    assert "bc-surgeon" in policies.available()
    assert main(["evaluate", "bc-surgeon", "--episodes", "10"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["seat"] == "grasper" and result["seed"] >= 900_000_000  # held-out seeds
    assert result["success_rate"] >= 0.8, result  # 0.91 over 100 episodes (baselines/README.md)
    env = suction_debris_v8.parallel_env(surgeon=policies.load("bc-surgeon"), max_cycles=20)
    env.reset(seed=1)
    env.step({"suction": np.zeros(4)})


@pytest.mark.parametrize("episode", [2, 5, -1, 1.5, "0"])
def test_an_episode_past_the_end_is_named(recorded, episode):
    with pytest.raises(ValueError, match=r"episode must be an episode's index in \[0, 2\)"):
        datasets.replay(recorded, episode)
    with pytest.raises(ValueError, match="episode must be"):
        datasets.replay_device(recorded, episode)
