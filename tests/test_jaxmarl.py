"""The scene as a JaxMARL MultiAgentEnv: JaxMARL's own LogWrapper runs it, jitted and vmapped, and counts its episodes
(in .ci/extended's environment: pip install "dvrl-marl[jaxmarl]")."""

import numpy as np
import pytest

jax = pytest.importorskip("jax")
pytest.importorskip("jaxmarl")

from jaxmarl.environments.multi_agent_env import MultiAgentEnv  # noqa: E402
from jaxmarl.wrappers.baselines import LogWrapper  # noqa: E402

from dvrl_marl.integrations.jaxmarl import suction_debris_env  # noqa: E402


def test_jaxmarls_log_wrapper_runs_the_scene_and_counts_its_episodes():
    env = suction_debris_env(max_cycles=20)
    assert isinstance(env, MultiAgentEnv) and env.agents == ["suction", "grasper"] and env.num_agents == 2
    wrapped = LogWrapper(env)
    keys = jax.random.split(jax.random.key(0), 8)
    observations, state = jax.vmap(wrapped.reset)(keys)
    step = jax.jit(jax.vmap(wrapped.step))
    actions = {agent: jax.numpy.zeros((8, 4)) for agent in env.agents}
    ended = 0
    for _ in range(45):
        observations, state, rewards, dones, infos = step(keys, state, actions)
        ended += int(np.asarray(dones["__all__"]).sum())
    assert ended == 2 * 8  # each world's 20-step episode ended twice
    assert np.all(np.asarray(infos["returned_episode_lengths"]) == 20)
    assert np.all(np.isfinite(np.asarray(infos["returned_episode_returns"])))
    assert observations["suction"].shape == (8, env.observation_space("suction").shape[0])
