"""suction_debris_v8.jax_env: one world as pure functions in JaxMARL's form, jitted and vmapped; the one step (world i
of a vmapped batch is world i of the numpy batched env seeded seed_of(key_i), automatic resets included),
deterministic for a key, and bad input named at trace time."""

import numpy as np
import pytest

jax = pytest.importorskip("jax")
jnp = jax.numpy

from dvrl_marl.envs import suction_debris_v8  # noqa: E402
from dvrl_marl.envs.suction_debris_jax import seed_of  # noqa: E402

WORLDS, STEPS = 16, 150
#: Short episodes: every world ends and starts again several times within the run (the benchmark's setting, with its
#: features, guided reward and start levels).
OPTIONS = dict(preset="benchmark", max_cycles=40, start_level=0.5)


@pytest.fixture(scope="module")
def compiled():
    env = suction_debris_v8.jax_env(**OPTIONS)
    return env, jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))


def _run(compiled, key, actions):
    env, reset, step = compiled
    keys = jax.random.split(key, WORLDS)
    observations, states = reset(keys)
    trajectory = [observations]
    for action in actions:
        observations, states, rewards, dones, infos = step(keys, states, action)
        trajectory.append((observations, rewards, dones, infos))
    return keys, trajectory


def test_a_vmapped_batch_is_the_numpy_env_world_by_world(compiled):
    env = compiled[0]
    rng = np.random.default_rng(0)
    actions = [{agent: rng.uniform(-1.1, 1.1, (WORLDS, 4)) for agent in env.agents} for _ in range(STEPS)]
    keys, trajectory = _run(compiled, jax.random.key(3), [{a: jnp.asarray(v) for a, v in act.items()} for act in actions])
    host = suction_debris_v8.batched_env(num_envs=WORLDS, **OPTIONS)
    first, _ = host.reset(seed=[int(seed_of(key)) for key in keys])
    for agent in env.agents:
        np.testing.assert_allclose(np.asarray(trajectory[0][agent]), first[agent], rtol=0, atol=1e-9)
    ended = 0
    for index, action in enumerate(actions):
        observations, rewards, terminations, truncations, infos = host.step(action)
        got_observations, got_rewards, dones, got_infos = trajectory[index + 1]
        done = terminations["suction"] | truncations["suction"]
        for agent in env.agents:
            np.testing.assert_allclose(np.asarray(got_observations[agent]), observations[agent], rtol=0, atol=1e-9,
                                       err_msg=f"step {index}, {agent}")
            np.testing.assert_allclose(np.asarray(got_rewards[agent]), rewards[agent], rtol=0, atol=1e-9)
            np.testing.assert_array_equal(np.asarray(dones[agent]), done)
        np.testing.assert_array_equal(np.asarray(dones["__all__"]), done)
        np.testing.assert_array_equal(np.asarray(got_infos["terminated"]), terminations["suction"])
        np.testing.assert_array_equal(np.asarray(got_infos["is_success"])[done], infos["suction"]["is_success"][done])
        ended += int(done.sum())
    assert ended >= 2 * WORLDS  # the automatic resets were taken, alike


def test_a_key_gives_the_same_run_and_another_key_another(compiled):
    env = compiled[0]
    rng = np.random.default_rng(1)
    actions = [{agent: jnp.asarray(rng.uniform(-1, 1, (WORLDS, 4))) for agent in env.agents} for _ in range(30)]
    runs = [_run(compiled, jax.random.key(seed), actions)[1] for seed in (5, 5, 6)]
    for agent in env.agents:
        last = [np.asarray(run[-1][0][agent]) for run in runs]
        assert np.all(np.isfinite(last[0]))
        np.testing.assert_array_equal(last[0], last[1])
        assert not np.allclose(last[0], last[2])


def test_spaces_and_agents_are_the_parallel_envs():
    env = suction_debris_v8.jax_env()
    parallel = suction_debris_v8.parallel_env()
    assert env.agents == parallel.possible_agents
    for agent in env.agents:
        assert env.observation_space(agent) == parallel.observation_space(agent)
        assert env.action_space(agent) == parallel.action_space(agent)


def test_bad_input_is_named_at_trace_time(compiled):
    env = compiled[0]
    observations, state = env.reset(jax.random.key(0))
    key = jax.random.key(1)
    good = {agent: jnp.zeros(4) for agent in env.agents}
    with pytest.raises(ValueError, match="actions must be a dict over the agents"):
        env.step(key, state, {"suction": jnp.zeros(4)})
    with pytest.raises(ValueError, match="'grasper''s action must have shape \\(4,\\)"):
        env.step(key, state, {**good, "grasper": jnp.zeros(5)})
    with pytest.raises(ValueError, match="the state must be the EnvState reset gave, got dict"):
        env.step(key, {"scene": state.scene, "levels": state.levels}, good)
    with pytest.raises(ValueError, match=r"state.remaining_ml must be float of shape \(2,\), got float64 of shape "
                                         r"\(1, 2\)"):
        env.step(key, state.replace(scene=state.scene.replace(remaining_ml=state.scene.remaining_ml[None])), good)
    with pytest.raises(ValueError, match="state.holding must be int of shape"):
        env.step(key, state.replace(scene=state.scene.replace(holding=jnp.zeros(()))), good)
    with pytest.raises(ValueError, match="state.levels must have shape"):
        env.step(key, state.replace(levels=jnp.zeros(2)), good)
    for bad in (0, np.zeros(3), jax.random.split(jax.random.key(0), 2)):
        with pytest.raises(ValueError, match="key must be one JAX key"):
            env.reset(bad)
    with pytest.raises(ValueError, match="jax_env\\(\\) is one world"):
        suction_debris_v8.jax_env(num_envs=4)
    nan = {**good, "suction": jnp.full(4, jnp.nan)}
    _, held, _, _, infos = env.step(key, state, nan)  # a compiled step reads nothing back: it holds, and says so
    assert not bool(infos["actions_finite"])
    for (path, value), kept in zip(jax.tree_util.tree_flatten_with_path(state)[0], jax.tree_util.tree_leaves(held)):
        np.testing.assert_array_equal(np.asarray(kept), np.asarray(value), err_msg=jax.tree_util.keystr(path))


def test_the_ippo_example_trains_in_one_compiled_function():
    """examples/jax_ippo.py: collection by lax.scan over jit(vmap(step)), GAE, a PPO update per agent; its loop
    runs and changes the actors."""
    from pathlib import Path

    from conftest import load_script

    pytest.importorskip("optax")
    example = load_script(Path(__file__).resolve().parents[1] / "examples" / "jax_ippo.py")
    params, rewards = example.make_train(worlds=8, rollout=8, updates=2, seed=0, max_cycles=6)()
    assert rewards.shape == (2,) and np.all(np.isfinite(np.asarray(rewards)))
    untrained = example.make_train(worlds=8, rollout=8, updates=0, seed=0, max_cycles=6)()[0]
    assert not np.allclose(np.asarray(params["suction"]["actor"][0][0]), np.asarray(untrained["suction"]["actor"][0][0]))
