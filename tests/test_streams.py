"""Counter-based reset streams (dvrl_marl.core.streams): a world's draws depend on its seed, its episode and the
quantity drawn only, so world i is the same world in a batch of any size, whatever the other worlds do, and on
every array library."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dvrl_marl.core.streams import STREAMS, ResetStreams, uniforms
from dvrl_marl.envs import suction_debris_v8


def _words(keys):
    keys = np.asarray(keys, dtype=np.uint64)
    return (keys & np.uint64(0xFFFFFFFF)).astype(np.int64), (keys >> np.uint64(32)).astype(np.int64)


@given(st.lists(st.integers(0, 2**64 - 1), min_size=1, max_size=8), st.integers(0, 10**6),
       st.sampled_from(sorted(STREAMS.values())), st.integers(1, 12))
@settings(max_examples=60, deadline=None)
def test_draws_lie_in_the_unit_interval_and_depend_on_nothing_but_their_inputs(keys, episode, stream, count):
    low, high = _words(keys)
    episodes = np.full(len(keys), episode)
    draws = uniforms(low, high, episodes, stream, count)
    assert draws.shape == (len(keys), count) and draws.dtype == np.float64
    assert np.all((draws >= 0.0) & (draws < 1.0))
    # each row alone, and in reverse order: the same numbers
    for row in range(len(keys)):
        np.testing.assert_array_equal(uniforms(low[row:row + 1], high[row:row + 1], episodes[row:row + 1], stream,
                                               count)[0], draws[row])
    np.testing.assert_array_equal(uniforms(low[::-1], high[::-1], episodes[::-1], stream, count), draws[::-1])


def test_streams_are_uniform_and_apart():
    streams = ResetStreams(20000)
    streams.seed(3)
    worlds = np.arange(20000)
    a, b = streams.uniforms(worlds, "tips", 4), streams.uniforms(worlds, "pin_yaws", 4)
    counts, _ = np.histogram(a, bins=10, range=(0.0, 1.0))
    assert np.all(np.abs(counts - 8000) < 5 * np.sqrt(8000))  # 5 sigma
    assert abs(np.corrcoef(a[:, 0], b[:, 0])[0, 1]) < 0.03  # two quantities of one world
    assert abs(np.corrcoef(a[:-1, 0], a[1:, 0])[0, 1]) < 0.03  # neighbouring seeds
    streams.next_episode(np.ones(20000, dtype=bool))
    assert abs(np.corrcoef(a[:, 0], streams.uniforms(worlds, "tips", 1)[:, 0])[0, 1]) < 0.03  # the next episode


def test_torch_draws_the_same_numbers():
    torch = pytest.importorskip("torch")
    low, high = _words([0, 7, 2**40 + 3, 2**64 - 1])
    episode = np.array([0, 1, 5, 1000])
    expected = uniforms(low, high, episode, 2, 6)
    got = uniforms(torch.from_numpy(low), torch.from_numpy(high), torch.from_numpy(episode), 2, 6)
    np.testing.assert_array_equal(got.numpy(), expected)


def test_jax_draws_the_same_numbers():
    jax = pytest.importorskip("jax")
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    low, high = _words([0, 7, 2**40 + 3, 2**64 - 1])
    episode = np.array([0, 1, 5, 1000])
    expected = uniforms(low, high, episode, 2, 6)
    got = jax.jit(lambda a, b, c: uniforms(a, b, c, 2, 6))(jnp.asarray(low), jnp.asarray(high), jnp.asarray(episode))
    np.testing.assert_array_equal(np.asarray(got), expected)


def _start(env, world):
    core = env.core
    return np.concatenate([core.debris_position[world].ravel(), core.arms["suction"].tip[world],
                           core.arms["grasper"].tip[world], core.bleed_onset[world], core.bleed_rate[world],
                           core.remaining_ml[world], [core.limit[world]]])


@given(st.integers(0, 2**32), st.integers(2, 6), st.data())
@settings(max_examples=15, deadline=None)
def test_a_world_is_the_same_world_in_any_batch_whatever_the_others_do(seed, size, data):
    """World i of a batch seeded s starts, episode after episode, what world 0 of a batch seeded s + i starts, even
    when the other worlds reset at other times; easy start levels and bleeding draw from streams too."""
    options = dict(bleeding_ml_s=0.1, start_level=0.4)
    batch = suction_debris_v8.batched_env(num_envs=size, autoreset_mode="disabled", **options)
    batch.reset(seed=seed)
    world = data.draw(st.integers(0, size - 1))
    alone = suction_debris_v8.batched_env(num_envs=1, autoreset_mode="disabled", **options)
    alone.reset(seed=seed + world)
    np.testing.assert_array_equal(_start(batch, world), _start(alone, 0))
    for _ in range(3):
        others = np.array(data.draw(st.lists(st.booleans(), min_size=size, max_size=size)))
        others[world] = False
        if others.any():  # the others start new episodes; world i does not
            batch.reset(options={"reset_mask": others})
        mask = np.zeros(size, dtype=bool)
        mask[world] = True
        batch.reset(options={"reset_mask": mask})
        alone.reset(options={"reset_mask": np.array([True])})
        np.testing.assert_array_equal(_start(batch, world), _start(alone, 0))
