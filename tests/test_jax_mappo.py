"""The JAX trainer (dvrl_marl.training.jax_mappo): a minibatch's losses and gradients, the reward scaling and GAE
equal the same algorithm written in torch (tests/torch_reference.py) on the same weights and data; its compiled cycle
is deterministic over many steps; a tiny run on the CPU validates and exports numpy policies that act as its actors;
what it does not do is refused by name."""

import dataclasses
import csv
import os
from dataclasses import replace

import numpy as np
import pytest

pytest.importorskip("torchrl")
jax = pytest.importorskip("jax")
pytest.importorskip("optax")

import torch  # noqa: E402

from dvrl_marl import policies  # noqa: E402
from dvrl_marl.envs import suction_debris_v8  # noqa: E402
from dvrl_marl.training import jax_mappo, run_progress  # noqa: E402
from dvrl_marl.training.mappo_config import MappoConfig  # noqa: E402

import torch_reference as reference  # noqa: E402

TINY = MappoConfig(total_steps=512, num_envs=8, rollout_steps=16, eval_every=256, eval_episodes=2, hidden=[16, 16],
                   env={"preset": "benchmark", "max_cycles": 40}, tool_head="switch", epochs=2, minibatches=2,
                   critic_input="state_and_observation", levels=[(0.0, 0.0), (1.0, 1.0)], bounds_loss_coef=1.0,
                   initial_tool_logit={"suction": 3.0}, entropy_coef=0.01, max_grad_norm=1e9)

CRITICS = {"state_and_observation": {}, "state": {"critic_input": "state"},
           "ippo": {"algorithm": "ippo", "critic_input": "state"}}


def _batch(config, rows: int, seed: int):
    """Observations and states the env gives (moved apart by noise), actions, old log-probabilities, advantages and
    returns, as a minibatch; the JAX learner's parameters and normalisers (moved off their start), and torch's
    models holding the same."""
    env = suction_debris_v8.batched_env(num_envs=rows, **config.env)
    observations, _ = env.reset(seed=seed)
    agents = list(env.possible_agents)
    random = np.random.default_rng(seed)
    seen = np.stack([observations[agent] for agent in agents], axis=1).astype(np.float32)
    seen = seen + random.normal(0.0, 0.1, seen.shape).astype(np.float32)
    state = env.state().astype(np.float32) + random.normal(0.0, 0.1, (rows, env.state_space.shape[0])).astype(
        np.float32)
    actions = random.normal(0.0, 0.7, (rows, len(agents), 4)).astype(np.float32)
    actions[..., -1] = np.where(random.random((rows, len(agents))) < 0.5, 1.0, -1.0)
    batch = {"observations": seen, "states": state, "actions": actions,
             "log_probs": random.normal(-4.0, 0.5, (rows, len(agents))).astype(np.float32),
             "advantages": random.normal(0.0, 1.0, (rows, len(agents))).astype(np.float32),
             "returns": random.normal(0.0, 2.0, (rows, len(agents))).astype(np.float32)}
    obs_dim, state_dim = seen.shape[-1], state.shape[-1]
    params = jax_mappo.init_params(jax.random.PRNGKey(seed), config, agents, obs_dim, state_dim)
    # the actors' last layers made larger, so the means reach past the box (the bounds loss) and the ratios move
    params["actors"] = [[*layers[:-1], {**layers[-1], "weight": layers[-1]["weight"] * 300.0}]
                        for layers in params["actors"]]
    norms = jax_mappo.init_norms(config, obs_dim, state_dim)
    norms = {name: jax_mappo._merged(norm, batch["states"] if name == "state" else batch["observations"])
             for name, norm in norms.items()}
    models = reference.build_learner(config, env, torch.device("cpu"))
    reference.load_into_torch(params, norms, models, critic=True)
    return agents, batch, params, norms, models


class _Recorder:
    """An optimiser that keeps the gradients it is given (the reference update's loss, no step taken)."""

    def __init__(self, parameters):
        self.parameters = list(parameters)
        self.gradients = None

    def zero_grad(self):
        for parameter in self.parameters:
            parameter.grad = None

    def step(self):
        self.gradients = [parameter.grad.clone() for parameter in self.parameters]


@pytest.mark.parametrize("critic", sorted(CRITICS))
@pytest.mark.parametrize("tool_head", ["switch", "gaussian"])
def test_a_minibatch_loss_and_its_gradients_equal_the_torch_references(critic, tool_head):
    config = replace(TINY, tool_head=tool_head, epochs=1, minibatches=1, **CRITICS[critic])
    agents, batch, params, norms, models = _batch(config, 64, seed=5)
    (loss, parts), gradients = jax.value_and_grad(jax_mappo.minibatch_loss, has_aux=True)(
        params, norms, config, {key: jax.numpy.asarray(value) for key, value in batch.items()})
    as_time_major = lambda x: torch.from_numpy(np.asarray(x))[None]  # noqa: E731  (T = 1, N = rows)
    rollout = reference.Rollout(
        observations=as_time_major(batch["observations"]), states=as_time_major(batch["states"]),
        actions=as_time_major(batch["actions"]), log_probs=as_time_major(batch["log_probs"]), values=None,
        rewards=None, done=None, terminated=None, next_values=None)
    recorder = _Recorder(models["parameters"])
    sums = reference.update(models, recorder, rollout, as_time_major(batch["advantages"]),
                            as_time_major(batch["returns"]), config)
    for name, value in zip(("policy", "value", "entropy"), parts):
        assert float(value) == pytest.approx(sums[name], rel=1e-5, abs=1e-6), name
    assert abs(float(parts[0])) > 1e-3 and float(parts[1]) > 1e-3  # (a loss that moves, not zeros compared)
    # the gradients, parameter by parameter in torch's order: the log standard deviations, the actors, the critic
    flat = [gradients["log_std"]]
    for layers in gradients["actors"]:
        for layer in layers:
            flat += [layer["weight"], layer["bias"]]
    critic_layers = gradients["critic"] if isinstance(gradients["critic"][0], list) else [gradients["critic"]]
    for layers in critic_layers:
        for layer in layers:
            flat += [layer["weight"], layer["bias"]]
    assert len(flat) == len(recorder.gradients)
    for mine, theirs in zip(flat, recorder.gradients):
        np.testing.assert_allclose(np.asarray(mine), theirs.numpy(), rtol=2e-4, atol=2e-6)


def test_the_reward_scaling_and_gae_equal_the_torch_references():
    random = np.random.default_rng(2)
    steps, worlds, agents = 12, 5, 2
    rewards = random.normal(0.0, 1.0, (steps, worlds, agents)).astype(np.float32)
    done = random.random((steps, worlds)) < 0.2
    terminated = done & (random.random((steps, worlds)) < 0.5)
    values = random.normal(0.0, 1.0, (steps, worlds, agents)).astype(np.float32)
    next_values = random.normal(0.0, 1.0, (steps, worlds, agents)).astype(np.float32)
    theirs = reference.ReturnScale(agents, 0.9, torch.device("cpu"))
    scale = {"mean": jax.numpy.zeros(agents), "var": jax.numpy.ones(agents), "count": jax.numpy.asarray(1e-4),
             "discounted": jax.numpy.zeros((worlds, agents))}
    for _ in range(2):  # twice: the discounted returns carry over to the next rollout
        mine, scale = jax_mappo.scaled_rewards(jax.numpy.asarray(rewards), jax.numpy.asarray(done), scale, 0.9)
        expected = torch.from_numpy(rewards) / theirs.update(torch.from_numpy(rewards), torch.from_numpy(done))
        np.testing.assert_allclose(np.asarray(mine), expected.numpy(), rtol=1e-5)
    rollout = reference.Rollout(observations=None, states=None, actions=None, log_probs=None,
                                values=torch.from_numpy(values), rewards=torch.from_numpy(rewards),
                                done=torch.from_numpy(done), terminated=torch.from_numpy(terminated),
                                next_values=torch.from_numpy(next_values))
    expected = reference.advantages(rollout, 0.9, 0.8)
    mine = jax_mappo.advantages(*(jax.numpy.asarray(x) for x in (rewards, values, next_values, terminated, done)),
                                0.9, 0.8)
    for a, b in zip(mine, expected):
        np.testing.assert_allclose(np.asarray(a), b.numpy(), rtol=1e-5, atol=1e-6)


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("jax")
    last = jax_mappo.train(TINY, 3, folder / "run", validate_beside=False, cache=folder / "compiled",
                           log=lambda *_: None)
    return folder / "run", last


@pytest.mark.extended
def test_a_tiny_run_validates_and_exports_policies_that_act(tiny_run):
    folder, last = tiny_run
    rows = list(csv.DictReader((folder / "progress.csv").open()))
    assert [int(row["steps"]) for row in rows] == [256, 512]
    assert last["steps"] == 512 and 0.0 <= last["success_rate"] <= 1.0 and last["env_steps_per_s"] > 0
    observations, _ = suction_debris_v8.parallel_env(preset="benchmark").reset(seed=0)
    for agent in ("suction", "grasper"):
        policy = policies.load(folder / "policies" / f"marl-{agent}")
        assert policy.spec["agent"] == agent and policy.spec["training"]["trainer"] == "jax_mappo"
        action = policy(observations[agent])
        assert action.shape == (4,) and np.all(np.abs(action) <= 1.0)


def test_the_compiled_cycle_is_kept_for_the_next_run(tiny_run):
    assert any((tiny_run[0].parent / "compiled").iterdir())


def test_the_exported_policies_act_as_the_jax_actors(tmp_path):
    """What the numpy policy computes from the env's observation is the JAX actor's mean, clipped to the box (the
    switch tool: the sign of its logit), the normaliser folded into its first layer: the policy the torch reference
    exports from the same weights."""
    agents, _, params, norms, models = _batch(TINY, 16, seed=4)
    params["actors"] = [[*layers[:-1], {**layers[-1], "weight": layers[-1]["weight"] * 10.0}]
                        for layers in params["actors"]]  # (means past the box: the clip is exercised)
    reference.load_into_torch(params, norms, models)
    env = suction_debris_v8.batched_env(num_envs=16, **TINY.env)
    observations, _ = env.reset(seed=9)
    seen = np.stack([observations[agent] for agent in agents], axis=1)
    loc = np.asarray(jax_mappo.actor_loc(params, norms, seen.astype(np.float32)))
    folders = run_progress.export(jax_mappo.actors(params, norms, agents), TINY, tmp_path, 0, 0, env)
    torch_folders = run_progress.export(reference.actors(models), TINY, tmp_path / "torch", 0, 0, env)
    for index, agent in enumerate(agents):
        expected = np.concatenate([np.clip(loc[:, index, :3], -1.0, 1.0), np.sign(loc[:, index, 3:])], axis=1)
        assert np.abs(loc[:, index, :3]).max() > 1.0  # (the clip is exercised)
        np.testing.assert_allclose(policies.load(folders[agent])(seen[:, index]), expected, atol=2e-4)
        # the same policy as the export of the torch reference's actors of the same weights
        mine, theirs = policies.load(folders[agent]), policies.load(torch_folders[agent])
        np.testing.assert_allclose(mine(seen[:, index]), theirs(seen[:, index]), atol=1e-6)
        assert mine.spec["exploration"] == theirs.spec["exploration"]


@pytest.mark.extended
def test_the_compiled_cycle_is_deterministic_over_many_steps():
    """Two runs of eight cycles (1,024 world steps) from the same seed give the same parameters bit for bit (on
    ``DVRL_MARL_TEST_DEVICE``, the CPU here)."""
    config = replace(TINY, rollout_steps=16)
    device = os.environ.get("DVRL_MARL_TEST_DEVICE", "cpu")
    env = suction_debris_v8.batched_env(num_envs=8, device=device, arrays="jax", check_actions=False, **config.env)
    cycle = jax.jit(jax_mappo.make_cycle(env, config))
    outcomes = []
    for _ in range(2):
        carry = jax_mappo.start(env, config, seed=7)
        for _ in range(8):
            carry, figures = cycle(carry, np.float32(config.learning_rate), None)
        outcomes.append(jax.tree_util.tree_leaves(carry[3]) + [figures["losses"]])
    for first, second in zip(*outcomes):
        np.testing.assert_array_equal(np.asarray(first), np.asarray(second))
    assert np.all(np.isfinite(np.asarray(outcomes[0][-1])))


def test_what_it_does_not_do_is_refused_by_name(tmp_path):
    for option, value in (("bc_expert", "scripted"), ("surgeon", "scripted"), ("critic_warmup_steps", 64),
                          ("init_policy", {"suction": "marl-suction"})):
        with pytest.raises(ValueError, match=f"{option} = .* is the TorchRL trainer's"):
            jax_mappo.train(replace(TINY, **{option: value}), 0, tmp_path / option, cache=None)
        assert not (tmp_path / option).exists()  # (refused before the run folder is made)
    (tmp_path / "used").mkdir()
    (tmp_path / "used" / "progress.csv").write_text("steps\n")
    with pytest.raises(ValueError, match="holds a run already"):
        jax_mappo.train(TINY, 0, tmp_path / "used", cache=None)


def test_advantages_bootstrap_truncations_and_not_terminations():
    values, rewards, next_values = np.zeros((2, 1, 1)), np.ones((2, 1, 1)), np.full((2, 1, 1), 10.0)
    done = np.array([[True], [False]])
    advantage, _ = jax_mappo.advantages(rewards, values, next_values, np.array([[False], [False]]), done, 0.5, 1.0)
    # step 0 was truncated: 1 + 0.5 x 10 (its final state's value), nothing carried over from the next episode
    assert float(advantage[0, 0, 0]) == pytest.approx(6.0)
    advantage, _ = jax_mappo.advantages(rewards, values, next_values, np.array([[True], [False]]), done, 0.5, 1.0)
    assert float(advantage[0, 0, 0]) == pytest.approx(1.0)  # terminated: no bootstrap


@pytest.mark.parametrize("beside", [True, pytest.param(False, marks=pytest.mark.extended)])
def test_a_run_stops_at_its_first_validation_that_reaches_the_target(tmp_path, beside):
    """Validations score beside the learner or in its process alike: the run stops at the first that reaches
    ``stop_at``, keeps the policies that validation scored and leaves no half-validated folder."""
    last = jax_mappo.train(replace(TINY, total_steps=2048), 3, tmp_path / "run", stop_at=0.0, validate_beside=beside,
                           cache=tmp_path / "compiled", log=lambda *_: None)
    rows = list(csv.DictReader((tmp_path / "run" / "progress.csv").open()))
    assert len(rows) == 1 and int(rows[0]["steps"]) == last["steps"] and last["steps"] < 2048
    spec = policies.load(tmp_path / "run" / "policies" / "marl-suction").spec
    assert spec["training"]["steps"] == last["steps"]
    assert not (tmp_path / "run" / "validating").exists()


@pytest.mark.extended
def test_diverged_networks_stop_the_run_by_name(tmp_path, monkeypatch):
    """Networks that diverge (NaN weights) stop the run at its next validation with an error that says so, never
    a validation of NaN actors."""
    made = jax_mappo.init_params

    def diverged(*args, **kwargs):
        params = made(*args, **kwargs)
        params["critic"] = jax.tree_util.tree_map(lambda x: x * float("nan"), params["critic"])
        return params

    monkeypatch.setattr(jax_mappo, "init_params", diverged)
    with pytest.raises(FloatingPointError, match="not finite"):
        jax_mappo.train(TINY, 3, tmp_path / "run", validate_beside=False, cache=None, log=lambda *_: None)


@pytest.mark.extended
def test_the_command_line_trains_with_it_by_default(tmp_path, capsys, monkeypatch):
    from dvrl_marl.cli import main

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))  # (the compiled cycle kept there, not in ~)
    config = tmp_path / "tiny.toml"
    config.write_text('[run]\nalgorithm = "mappo"\ntotal_steps = 128\nnum_envs = 8\nrollout_steps = 16\n'
                      'eval_every = 128\neval_episodes = 2\n[env]\npreset = "benchmark"\nmax_cycles = 40\n'
                      '[model]\nhidden = [16, 16]\n')
    assert main(["train", str(config), "--out", str(tmp_path / "run"), "--export", str(tmp_path / "exported")]) == 0
    printed = capsys.readouterr().out
    assert "validation success" in printed and "trainer:" not in printed  # (the default: nothing passed over)
    spec = policies.load(tmp_path / "exported" / "marl-grasper").spec
    assert spec["agent"] == "grasper" and spec["training"]["trainer"] == "jax_mappo"
    assert spec["preset"] == "benchmark"  # (the scene it learnt on, named in its configuration file)


@pytest.mark.extended
def test_the_device_env_gives_its_state_to_a_loop_of_its_own_and_takes_it_back():
    env = suction_debris_v8.batched_env(num_envs=4, device="cpu", arrays="jax", **TINY.env)
    env.reset(seed=1)
    env.step({agent: np.full((4, 4), 0.3) for agent in env.possible_agents})
    after = np.asarray(env.state())
    env.world_state = env.world_state.replace()  # (given back from outside: the global state is computed from it)
    np.testing.assert_allclose(np.asarray(env.state()), after, atol=1e-12)
    with pytest.raises(ValueError, match="the state must be the EnvState reset gave"):
        env.world_state = {"positions": 0}
    with pytest.raises(ValueError, match=r"state.elapsed must be int of shape \(4,\)"):
        env.world_state = env.world_state.replace(scene=env.world_state.scene.replace(elapsed=np.zeros(3, int)))
    numpy_env = suction_debris_v8.batched_env(num_envs=4, autoreset_mode="disabled", **TINY.env)
    with pytest.raises(AttributeError):
        numpy_env.step_function  # noqa: B018  (the numpy env steps eagerly: no traced step to give)


def test_a_tiny_run_on_the_irrigation_level_exports_policies_that_read_its_observations(tmp_path):
    """The level's observations end with the fluids' slots: an exported policy's features read them whole (a run's
    validation once refused its own policies over it)."""
    config = dataclasses.replace(TINY, env={"preset": "irrigation", "max_cycles": 40}, tool_head="gaussian",
                                 initial_tool_logit={}, total_steps=256, eval_every=256)
    last = jax_mappo.train(config, 1, tmp_path / "run", validate_beside=False, cache=tmp_path / "compiled",
                           log=lambda *_: None)
    assert last["steps"] == 256
    observations, _ = suction_debris_v8.parallel_env(preset="irrigation").reset(seed=0)
    for agent in ("suction", "grasper"):
        policy = policies.load(tmp_path / "run" / "policies" / f"marl-{agent}")
        assert policy.spec["features"]["fluids"] is True
        action = policy(observations[agent])
        assert action.shape == (4,) and np.all(np.abs(action) <= 1.0)
