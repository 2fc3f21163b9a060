"""The scene's state as one record: the step and the reset are pure functions of it, and every conversion (choosing,
writing, stacking worlds; checking a record; what the renderer draws) is written once over its fields."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dvrl_marl.envs import suction_debris
from dvrl_marl.suction_debris import scene_state
from dvrl_marl.suction_debris.scene_state import SPECS, SceneState

WORLDS = 3


def _env(**options):
    env = suction_debris.batched_env(num_envs=WORLDS, autoreset_mode="disabled", **options)
    env.reset(seed=11)
    return env


def _equal(a: SceneState, b: SceneState) -> None:
    for name in SPECS:
        np.testing.assert_array_equal(np.asarray(getattr(a, name)), np.asarray(getattr(b, name)), err_msg=name)


def _copy(state: SceneState) -> SceneState:
    return scene_state.map_arrays(np.array, state)


commands = st.lists(st.tuples(*[st.floats(-1.0, 1.0)] * 8), min_size=WORLDS, max_size=WORLDS)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(steps=st.lists(commands, min_size=1, max_size=6), preset=st.sampled_from(["default", "benchmark"]))
def test_the_pure_step_leaves_its_record_alone_and_is_the_cores_step(steps, preset):
    env = _env(preset=preset)
    core = env.core
    state = core.get_state()
    for rows in steps:
        given_commands = {"suction": np.array([r[:4] for r in rows]), "grasper": np.array([r[4:] for r in rows])}
        before = _copy(state)
        after, rewards, terminated, truncated = core.step_state(state, given_commands)
        _equal(state, before)  # the record given is not changed
        core.set_state(state)  # ...and the core's own step from it gives the same
        want_rewards, want_terminated, want_truncated = core.step(given_commands)
        _equal(after, core.get_state())
        for agent in rewards:
            np.testing.assert_array_equal(rewards[agent], want_rewards[agent])
        np.testing.assert_array_equal(terminated, want_terminated)
        np.testing.assert_array_equal(truncated, want_truncated)
        state = after


def test_the_pure_reset_is_the_cores_reset_of_the_same_worlds():
    env = _env(preset="benchmark")
    core = env.core
    for _ in range(5):
        core.step({agent: np.full((WORLDS, 4), 0.4) for agent in ("suction", "grasper")})
    state = core.get_state()
    before = _copy(state)
    mask = np.array([True, False, True])
    restarted = core.reset_state(state, mask)
    _equal(state, before)
    core.set_state(state)
    core.start_episodes(mask)
    _equal(restarted, core.get_state())
    # the world left alone is as it was; the others start again (their episode count moves on)
    _equal(scene_state.take_worlds(restarted, [1]), scene_state.take_worlds(state, [1]))
    np.testing.assert_array_equal(restarted.stream_episode, state.stream_episode + mask)
    np.testing.assert_array_equal(restarted.elapsed[mask], 0)


def test_worlds_are_chosen_written_and_stacked_over_the_records_fields():
    state = _env().core.get_state()
    other = _env(blood_ml=(2.0, 3.0)).core.get_state()
    written = scene_state.write_worlds(state, [2], scene_state.take_worlds(other, [0]))
    _equal(scene_state.take_worlds(written, [0, 1]), scene_state.take_worlds(state, [0, 1]))
    _equal(scene_state.take_worlds(written, [2]), scene_state.take_worlds(other, [0]))
    stacked = scene_state.stack_worlds([scene_state.take_worlds(state, [i]) for i in range(WORLDS)])
    _equal(stacked, state)
    assert stacked.num_worlds == WORLDS
    one = scene_state.one_world(state, 1)
    assert one.remaining_ml.shape == (2,) and one.elapsed.shape == ()


def test_what_the_renderer_draws_is_read_from_the_record():
    env = _env()
    core = env.core
    state = core.get_state()
    views = core.world_states([2, 0])
    np.testing.assert_array_equal(views["tips"]["grasper"], state.grasper_tip[[2, 0]])
    np.testing.assert_array_equal(views["blood_ml"], state.remaining_ml[[2, 0]])
    one = core.world_state(0)
    assert isinstance(one["valve_open"], bool) and isinstance(one["jaw"], float)
    np.testing.assert_array_equal(one["debris_positions"], state.debris_position[0])
    one["debris_positions"][:] = 0.0  # (a copy: the core's state is not the view's)
    np.testing.assert_array_equal(core.get_state().debris_position, state.debris_position)


def test_a_record_of_the_wrong_shape_or_kind_is_named_before_it_touches_the_core():
    core = _env().core
    state = core.get_state()
    cases = [
        (state.replace(remaining_ml=state.remaining_ml[:, :1]), r"state.remaining_ml must be float of shape \(3, 2\)"),
        (state.replace(holding=state.holding.astype(float)), r"state.holding must be int of shape \(3,\)"),
        (state.replace(visible=state.visible.astype(int)), r"state.visible must be bool"),
        (scene_state.take_worlds(state, [0]), r"state.suction_tip must be float of shape \(3, 3\), got float64 of "
                                              r"shape \(1, 3\)"),
        (state.as_dict(), "the state must be a SceneState record, got dict"),
    ]
    for bad, message in cases:
        with pytest.raises(ValueError, match=message):
            core.set_state(bad)
        _equal(core.get_state(), state)  # nothing was written


def test_every_field_is_started_made_and_counted():
    env = _env()
    state = env.core.get_state()
    shapes = env.core.world_shapes
    assert list(state.as_dict()) == list(SPECS) == list(shapes)
    for name, value in state.as_dict().items():
        assert value.shape == (WORLDS,) + shapes[name], name
        assert value.dtype == scene_state.dtype_of(name), name
    float32 = scene_state.bytes_per_world(state, float_bytes=4)
    assert 0 < float32 < scene_state.bytes_per_world(state)


def test_the_record_is_a_pytree_that_jit_and_vmap_carry_and_a_wrong_one_is_named_at_trace_time():
    jax = pytest.importorskip("jax")
    jax.config.update("jax_enable_x64", True)
    jnp = jax.numpy
    scene_state.register_with_jax()
    core = _env().core
    state = core.get_state()
    device = scene_state.map_arrays(jnp.asarray, state)
    assert len(jax.tree_util.tree_leaves(device)) == len(SPECS)
    blood = jax.jit(jax.vmap(lambda world: world.remaining_ml.sum()))(device)  # one world's fields, per world
    np.testing.assert_allclose(np.asarray(blood), state.remaining_ml.sum(axis=1))
    commands = {agent: jnp.zeros((WORLDS, 4)) for agent in ("suction", "grasper")}
    with pytest.raises(ValueError, match=r"state.debris_yaw must be float of shape \(3, 3\)"):
        jax.jit(core.step_state)(device.replace(debris_yaw=device.debris_yaw[:, :2]), commands)


def test_the_numpy_env_gives_and_takes_its_worlds_state_as_one_record():
    env = suction_debris.batched_env(num_envs=WORLDS, preset="benchmark")
    env.reset(seed=2)
    rng = np.random.default_rng(0)
    actions = [{agent: rng.uniform(-1, 1, (WORLDS, 4)) for agent in env.possible_agents} for _ in range(30)]
    saved = env.world_state
    assert sorted(saved.potential) == sorted(env.possible_agents)
    first = [env.step(a)[:2] for a in actions]
    env.world_state = saved  # back where it was: the same steps again give the same figures
    again = [env.step(a)[:2] for a in actions]
    for (obs_a, rew_a), (obs_b, rew_b) in zip(first, again):
        for agent in env.possible_agents:
            np.testing.assert_array_equal(obs_a[agent], obs_b[agent])
            np.testing.assert_array_equal(rew_a[agent], rew_b[agent])
    before = env.world_state
    for bad, message in ((saved.replace(levels=np.zeros(2)), "state.levels must have shape"),
                         (saved.replace(potential={}), "state.potential must hold"),
                         (saved.scene, "world_state must be an EnvState record")):
        with pytest.raises(ValueError, match=message):
            env.world_state = bad
    _equal(env.world_state.scene, before.scene)  # (nothing changed)
