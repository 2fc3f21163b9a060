"""The device trainer (dvrl_marl.training.device_mappo): a tiny run on the CPU writes its progress, exports numpy
policies that load and act, and refuses what it does not do by name."""

import csv
from dataclasses import replace

import numpy as np
import pytest

pytest.importorskip("torchrl")

import torch  # noqa: E402

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


def _worlds(num_envs: int, max_cycles: int, seed: int):
    """A tiny batch seen through torch, its models and its first observations and state."""
    import torch

    from dvrl_marl.envs import suction_debris_v8

    config = replace(TINY, num_envs=num_envs, env={**TINY.env, "max_cycles": max_cycles})
    host = suction_debris_v8.batched_env(num_envs=config.num_envs, **config.env)
    env = device_mappo._TorchView(host, torch)
    models = device_mappo.build_learner(config, host, torch.device("cpu"), torch)
    observations, _ = env.reset(seed=seed)
    return env, models, device_mappo._stack(observations, models["agents"], torch).float(), env.state().float()


def test_collect_bootstraps_from_the_state_each_step_ended_on():
    """The live worlds' value after a step is the next step's value; an ended world's is its final state's (the critic
    values the rollout in one call and the ended worlds' final states in another)."""
    import torch

    env, models, observations, state = _worlds(6, 10, seed=5)
    finals = []
    step = env.step
    env.step = lambda actions: finals.append(result := step(actions)) or result
    rollout, *_ = device_mappo.collect(env, models, observations, state, 24, torch, torch.device("cpu"))
    done = rollout.done
    assert done.any() and (~done).any()  # (max_cycles 10: every world ends twice within 24 steps)
    live = ~done[:-1]
    assert torch.allclose(rollout.next_values[:-1][live], rollout.values[1:][live], atol=1e-6)
    agents = models["agents"]
    distinguishes = False  # (somewhere a final state's value differs from the new episode's: the test can fail)
    for t in range(24):
        rows = done[t].nonzero().squeeze(-1)
        if len(rows):
            info = finals[t][4][agents[0]]
            final = device_mappo._stack(info["final_observation"], agents, torch).float()[rows]
            with torch.no_grad():
                expected = models["critic"](info["final_state"].float()[rows], final)
            assert torch.allclose(rollout.next_values[t][rows], expected, atol=1e-6)
            distinguishes |= t < 23 and not torch.allclose(expected, rollout.values[t + 1][rows], atol=1e-3)
    assert distinguishes


@pytest.mark.parametrize("beside", [True, False])
@pytest.mark.slow
def test_a_run_stops_at_its_first_validation_that_reaches_the_target(tmp_path, beside):
    """Validations score beside the learner or in its process alike: the run stops at the first that reaches
    ``stop_at``, keeps the policies that validation scored and leaves no half-validated folder."""
    config = replace(TINY, total_steps=4096, torch_threads=0)
    threads = torch.get_num_threads()
    last = device_mappo.train(config, 3, tmp_path / "run", stop_at=0.0, validate_beside=beside, log=lambda *_: None)
    assert torch.get_num_threads() == threads  # (a learner that gave a validation a core gives it back)
    rows = list(csv.DictReader((tmp_path / "run" / "progress.csv").open()))
    assert len(rows) == 1 and int(rows[0]["steps"]) == last["steps"]
    assert last["steps"] == (512 if not beside else int(rows[0]["steps"])) and last["steps"] < 4096
    spec = policies.load(tmp_path / "run" / "policies" / "marl-suction").spec
    assert spec["training"]["steps"] == last["steps"]
    assert not (tmp_path / "run" / "validating").exists()


@pytest.mark.slow
def test_a_run_with_its_worlds_in_a_worker_process_validates_as_the_inline_one(tmp_path):
    """collector="process": the worlds step in a worker while the learner updates; the run's rows and policies are
    as the inline run's, and what it cannot do is refused by name."""
    last = device_mappo.train(TINY, 3, tmp_path / "run", collector="process", log=lambda *_: None)
    rows = list(csv.DictReader((tmp_path / "run" / "progress.csv").open()))
    assert [int(row["steps"]) for row in rows] == [512, 1024] and last["steps"] == 1024
    assert policies.load(tmp_path / "run" / "policies" / "marl-grasper").spec["training"]["steps"] == 1024
    with pytest.raises(ValueError, match="collector must be 'inline' or 'process'"):
        device_mappo.train(TINY, 3, tmp_path / "other", collector="ray")
    with pytest.raises(ValueError, match="collector='process' steps numpy's env"):
        device_mappo.train(TINY, 3, tmp_path / "other", collector="process", backend="jax")


def test_steps_become_a_rollout_whose_values_are_the_critics_of_each_step():
    import torch

    env, models, observations, state = _worlds(4, 6, seed=1)
    taken = device_mappo.step_worlds(env, models["head"], models["distribution"], models["agents"], observations,
                                     state, 8, torch, torch.device("cpu"))
    assert taken.observations.shape[0] == 9 and taken.actions.shape[:2] == (8, 4)
    assert len(taken.ended_at) == int(taken.done.sum()) == 4  # (every world ends at its 6th step)
    rollout = device_mappo.value_rollout(taken, models["critic"], torch)
    with torch.no_grad():
        for t in (0, 7):
            assert torch.allclose(rollout.values[t], models["critic"](taken.states[t], taken.observations[t]))


@pytest.mark.extended
def test_a_run_on_the_compiled_env_learns_from_what_the_numpy_env_would_give(tmp_path):
    """backend="jax" (a GPU's default; ``DVRL_MARL_TEST_DEVICE`` picks the device, the CPU here): env, policy and
    buffers on one device; its first rollout is the numpy env's, step by step, and the run exports policies that
    load and act."""
    pytest.importorskip("jax")
    import os

    device = os.environ.get("DVRL_MARL_TEST_DEVICE", "cpu")
    rollouts = {}
    for backend in ("numpy", "jax"):
        torch.manual_seed(0)
        env = _batched_env(backend, device)
        models = device_mappo.build_learner(TINY, env if backend == "jax" else env.env, torch.device(device), torch)
        observations, _ = env.reset(seed=5)
        agents = models["agents"]
        observations = device_mappo._stack(observations, agents, torch).to(device, torch.float32)
        torch.manual_seed(1)
        rollouts[backend] = device_mappo.step_worlds(env, models["head"], models["distribution"], agents,
                                                     observations, env.state().to(device, torch.float32), 24, torch,
                                                     torch.device(device))
    numpy_steps, compiled = rollouts["numpy"], rollouts["jax"]
    for key in ("observations", "states", "actions", "rewards"):  # (float32 on the device; float64 in numpy's env)
        assert torch.allclose(getattr(compiled, key).cpu(), getattr(numpy_steps, key).cpu(), atol=1e-4), key
    assert torch.equal(compiled.done.cpu(), numpy_steps.done.cpu())
    last = device_mappo.train(TINY, 3, tmp_path / "run", device=device, backend="jax", log=lambda *_: None)
    assert last["steps"] == 1024 and 0.0 <= last["success_rate"] <= 1.0
    assert policies.load(tmp_path / "run" / "policies" / "marl-suction").spec["training"]["steps"] == 1024


def _batched_env(backend: str, device: str):
    """TINY's 8 worlds with torch tensors in and out: the compiled env, or numpy's through the CPU learner's view."""
    from dvrl_marl.envs import suction_debris_v8

    if backend == "jax":
        return suction_debris_v8.batched_env(num_envs=8, device=device, **TINY.env)
    return device_mappo._TorchView(suction_debris_v8.batched_env(num_envs=8, **TINY.env), torch)


@pytest.mark.parametrize("backend", ["numpy", pytest.param("jax", marks=pytest.mark.extended)])
def test_diverged_actors_stop_the_run_by_name(tmp_path, monkeypatch, backend):
    """Diverged networks (NaN motions) stop the run at that step with an error that says so, on numpy's env and on
    the compiled one alike (which checks every step's actions: unchecked, a NaN motion reaches the next
    observations and the tool's Bernoulli fails with an error naming no cause)."""
    if backend == "jax":
        pytest.importorskip("jax")
    built = device_mappo.build_learner

    def diverged(*args, **kwargs):
        models = built(*args, **kwargs)
        with torch.no_grad():  # the motions' means (the tool's logit stays a number: a Bernoulli refuses NaN)
            for net in models["actor_net"].nets:
                net[-1].weight[:-1].fill_(float("nan"))
        return models

    monkeypatch.setattr(device_mappo, "build_learner", diverged)
    with pytest.raises(ValueError, match="NaN or inf"):
        device_mappo.train(TINY, 3, tmp_path / "run", backend=backend, log=lambda *_: None)


def test_validations_still_scoring_when_a_run_stops_are_stopped_not_waited_for(tmp_path):
    import multiprocessing
    import time

    before = set(multiprocessing.active_children())
    validations = device_mappo.Validations(tmp_path, TINY, 0, beside=True, workers=1)
    validations.pending.append((0, 0.0, tmp_path / "validating" / "0", validations.pool.apply_async(time.sleep, (60,))))
    began = time.perf_counter()
    validations.close()
    assert time.perf_counter() - began < 20.0  # (its worker's start included; the 60 s job was not waited for)
    assert not set(multiprocessing.active_children()) - before  # (no worker left behind)
