"""The irrigation rule (issue 78): the Suction & Irrigation valve signed (a negative command irrigates), saline that
mixes with the liquid blood and breaks clots up, suction drawing the mix, overflow and its spill, saline wasted in
the air; off by default (the goldens hold: tests/test_golden.py)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dvrl_marl.core import tools
from dvrl_marl.envs import suction_debris
from dvrl_marl.suction_debris import layout
from dvrl_marl.suction_debris.scripted_team import ScriptedSuction, ScriptedSurgeon

WORLDS = 3
IRRIGATE, SUCK = -1.0, 1.0


def _env(**options):
    env = suction_debris.batched_env(num_envs=WORLDS, autoreset_mode="disabled", **options)
    env.reset(seed=5)
    return env


def _work(env, valve: float, steps: int, cavity: int = 0, height: float | None = None) -> None:
    """The suction's tip driven to ``cavity``'s floor (or ``height`` above the phantom's top over its centre), its
    valve commanded ``valve`` throughout; the grasper still."""
    c = env.core.cavities
    for _ in range(steps):
        tip = env.core.arms["suction"].tip_world()
        z = c.floor_z[cavity] if height is None else env.core.phantom.top_z + height
        goal = np.array([c.centre_x[cavity], c.centre_y[cavity], z])
        move = np.clip((goal - tip) / env.params.step_size, -1.0, 1.0)
        env.step({"suction": np.concatenate([move, np.full((WORLDS, 1), valve)], axis=1),
                  "grasper": np.zeros((WORLDS, 4))})


def _at_floor(env, cavity: int = 0) -> None:
    """The tip down in ``cavity``, the valve shut (it got there without drawing)."""
    _work(env, tools.SHUT, 120, cavity)


def test_off_by_default_a_negative_command_shuts_the_valve():
    env = _env()
    assert env.params.irrigation_ml_s == 0.0 and not env.core.fluids
    assert layout.plain_width(env.observation_layout) == env.observation_layout["handoff"].stop
    _work(env, IRRIGATE, 150)
    state = env.core.get_state()
    np.testing.assert_array_equal(state.saline_ml, 0.0)
    np.testing.assert_array_equal(state.saline_used_ml, 0.0)
    np.testing.assert_array_equal(state.remaining_ml, np.asarray(env.params.blood_ml)[None, :].repeat(WORLDS, 0))
    assert "saline_used_ml" not in env.core.info()


def test_irrigation_breaks_a_clot_up_and_suction_then_draws_the_mix():
    env = _env(irrigation_ml_s=1.0, clot_share=0.5, clot_per_saline_ml=1.0)
    p = env.params
    start = env.core.get_state()
    np.testing.assert_allclose(start.clot_ml, 0.5 * start.remaining_ml)
    _at_floor(env)
    _work(env, SUCK, 150)  # the liquid half drawn; the clot left
    state = env.core.get_state()
    np.testing.assert_allclose(state.remaining_ml[:, 0], state.clot_ml[:, 0], atol=1e-9)
    clot_before = state.clot_ml[:, 0].copy()
    _work(env, IRRIGATE, 50)  # 1 s of saline at 1 ml/s: 1 ml in, 1 ml of clot broken up
    after = env.core.get_state()
    flow = p.irrigation_ml_s * p.control_dt * 50
    np.testing.assert_allclose(after.saline_ml[:, 0], flow, atol=1e-9)
    np.testing.assert_allclose(after.clot_ml[:, 0], clot_before - p.clot_per_saline_ml * flow, atol=1e-9)
    np.testing.assert_allclose(after.remaining_ml[:, 0], state.remaining_ml[:, 0], atol=1e-9)  # no blood added
    np.testing.assert_allclose(after.saline_used_ml, flow)
    np.testing.assert_array_equal(after.saline_wasted_ml, 0.0)
    assert np.all(after.surface_z[:, 0] > state.surface_z[:, 0])  # the saline raised the fluid
    # suction draws the mix: blood in proportion to its share of the liquid
    blood = after.remaining_ml[:, 0] - after.clot_ml[:, 0]
    share = blood / (blood + after.saline_ml[:, 0])
    env.step({"suction": np.tile([0.0, 0.0, 0.0, SUCK], (WORLDS, 1)), "grasper": np.zeros((WORLDS, 4))})
    drawn = env.core.get_state()
    removed = after.remaining_ml[:, 0] - drawn.remaining_ml[:, 0]
    saline_removed = after.saline_ml[:, 0] - drawn.saline_ml[:, 0]
    np.testing.assert_allclose(removed + saline_removed, p.suction_rate_ml_s * p.control_dt, atol=1e-12)
    np.testing.assert_allclose(removed, share * p.suction_rate_ml_s * p.control_dt, atol=1e-12)
    np.testing.assert_allclose(drawn.drawn_ml, removed, atol=1e-12)  # the blood drawn is what the reward counts


def test_saline_in_the_air_is_wasted():
    env = _env(irrigation_ml_s=1.0)
    _work(env, IRRIGATE, 60, height=0.01)  # 10 mm over the phantom's top
    state = env.core.get_state()
    assert np.all(state.saline_used_ml > 0.0)
    np.testing.assert_allclose(state.saline_wasted_ml, state.saline_used_ml)
    np.testing.assert_array_equal(state.saline_ml, 0.0)


def test_an_overflow_spills_is_counted_and_covers_the_pins_around_it_for_a_while():
    env = _env(irrigation_ml_s=5.0, spill_s=1.0, blood_ml=[10.5, 8.0])
    core = env.core
    capacity = core.cavities.capacity_ml
    _at_floor(env)
    # the tip irrigates a cavity already nearly full: it fills, then spills
    _work(env, IRRIGATE, 40)
    state = core.get_state()
    fluid = state.remaining_ml + state.saline_ml
    assert np.all(fluid <= capacity[None, :] + 1e-9)
    np.testing.assert_allclose(fluid[:, 0], capacity[0], atol=1e-9)
    assert np.all(state.overflow_ml > 0.0) and np.all(state.overflow_steps > 0)
    np.testing.assert_array_equal(state.overflow_events, 1)  # one overflow, however long
    assert np.all(state.spilling[:, 0]) and np.all(state.spill_s[:, 0] == 1.0)
    # the spill covers the first cavity's pins: observations show them unseen, though they stay revealed
    covered = core.covered_pins()
    assert covered[core.debris_cavity == 0].all() and not covered[core.debris_cavity == 1].any()
    core.visible[:] = True
    slots = core.observation("suction")[:, env.observation_layout["debris"]].reshape(WORLDS, -1, layout.PIN_WIDTH)
    np.testing.assert_array_equal(slots[..., layout.PIN_VISIBLE], ~covered)
    fluids = core.observation("suction")
    assert np.all(fluids[:, env.observation_layout["spill"]][:, 0] == 1.0)
    # it dries when the irrigation stops
    _work(env, tools.SHUT, 60)
    state = core.get_state()
    np.testing.assert_array_equal(state.spill_s, 0.0)
    assert not core.covered_pins().any()
    info = core.info()
    np.testing.assert_allclose(info["overflow_s"], state.overflow_steps * env.params.control_dt)


def test_the_observation_names_the_fluids_and_stays_in_its_space():
    env = _env(preset="irrigation")
    names = env.observation_layout
    for name, _ in layout.FLUID_FIELDS:
        assert name in names and name in env.state_layout
    observations, _ = env.reset(seed=1)
    for agent in env.agents:
        assert all(env.observation_space(agent).contains(row) for row in observations[agent])
        row = observations[agent][0]
        np.testing.assert_allclose(row[names["clot"]], 0.5 * np.asarray(env.params.blood_ml) /
                                   env.core.cavities.capacity_ml)
        np.testing.assert_allclose(row[names["concentration"]], 1.0)  # liquid blood, no saline yet
        assert row[names["irrigation"]][0] == -1.0
    assert env.state().shape[1] == env.state_space.shape[0]


@settings(max_examples=25, deadline=None)
@given(valves=st.lists(st.floats(-1.0, 1.0), min_size=1, max_size=40), rate=st.floats(0.0, 30.0),
       share=st.floats(0.0, 1.0), moves=st.tuples(*[st.floats(-1.0, 1.0)] * 3))
def test_volumes_stay_finite_non_negative_and_within_capacity(valves, rate, share, moves):
    env = _env(irrigation_ml_s=max(rate, 1e-3), clot_share=share, clot_per_saline_ml=2.0, spill_s=0.5,
               clotting_ml_s=0.2, bleeding_ml_s=0.3, bleeding_onset_s=0.0)
    capacity = env.core.cavities.capacity_ml[None, :]
    for valve in valves:
        env.step({"suction": np.tile([*moves, valve], (WORLDS, 1)), "grasper": np.zeros((WORLDS, 4))})
        s = env.core.get_state()
        for name in ("remaining_ml", "clot_ml", "saline_ml", "spill_s", "saline_used_ml", "saline_wasted_ml",
                     "overflow_ml"):
            value = getattr(s, name)
            assert np.all(np.isfinite(value)) and np.all(value >= 0.0), name
        assert np.all(s.clot_ml <= s.remaining_ml + 1e-12)
        assert np.all(s.remaining_ml + s.saline_ml <= capacity + 1e-9)
        assert np.all(s.saline_wasted_ml <= s.saline_used_ml + 1e-12)
        obs = env.core.observation("suction")
        assert np.all(np.isfinite(obs)) and np.all(np.abs(obs) <= 10.0)


@pytest.mark.parametrize("option, value", [("irrigation_ml_s", -1.0), ("irrigation_ml_s", float("nan")),
                                           ("clot_share", 1.5), ("clot_share", -0.1), ("clot_share", float("nan")),
                                           ("clot_per_saline_ml", -2.0), ("spill_s", float("inf"))])
def test_a_bad_value_is_named(option, value):
    with pytest.raises(ValueError, match=option):
        suction_debris.batched_env(num_envs=1, **{option: value})
    with pytest.raises(ValueError, match=option):
        suction_debris.parallel_env(**{option: value})


def test_irrigation_asked_where_the_valve_cannot_irrigate_is_named():
    env = _env()  # the scene's valve only sucks
    with pytest.raises(ValueError, match="irrigat"):
        ScriptedSuction.for_env(env).__class__(env.layout(), env.observation_layout, env.workspace_range,
                                               irrigate=True)


def test_the_scripted_team_irrigates_where_the_scene_has_clots_and_the_suction_only_plan_cannot_finish():
    env = suction_debris.batched_env(num_envs=4, preset="irrigation", autoreset_mode="disabled")
    for irrigate, finishes in ((True, True), (False, False)):
        suction = ScriptedSuction(env.layout(), env.observation_layout, env.workspace_range, irrigate=irrigate)
        surgeon = ScriptedSurgeon.for_env(env)
        env.reset(seed=11)
        done = np.zeros(4, dtype=bool)
        success = np.zeros(4, dtype=bool)
        while not done.all():
            actions = {"suction": suction(env.core.observation("suction")),
                       "grasper": surgeon(env.core.observation("grasper"))}
            _, _, terminated, truncated, infos = env.step(actions)
            success |= terminated["suction"] & ~done
            done |= terminated["suction"] | truncated["suction"]
        info = infos["suction"]
        assert success.all() == finishes and success.any() == finishes
        if finishes:
            assert np.all(info["saline_used_ml"] > 0.0) and np.all(info["overflow_events"] == 0)
            assert np.all(info["blood_remaining"] <= 0.05 * np.sum(env.params.blood_ml))
        else:
            np.testing.assert_array_equal(info["saline_used_ml"], 0.0)  # its shut valve (0) never irrigates


def test_the_scripted_suction_acts_alike_on_a_batch_and_on_one_row():
    """Its suction-only plan on the level takes the batched path (its shut valve 0 there); row by row the same."""
    env = _env(preset="irrigation")
    suction = ScriptedSuction(env.layout(), env.observation_layout, env.workspace_range, irrigate=False)
    for _ in range(300):
        obs = env.core.observation("suction")
        np.testing.assert_array_equal(suction(obs), np.stack([suction(row) for row in obs]))
        env.step({"suction": suction(obs), "grasper": np.zeros((WORLDS, 4))})


def test_the_single_env_reports_the_fluid_figures():
    env = suction_debris.parallel_env(preset="irrigation")
    env.reset(seed=2)
    for _ in range(10):  # (the preset's valve opens a tenth of its stroke a step)
        _, _, _, _, infos = env.step({agent: np.array([0.0, 0.0, 0.0, -1.0]) for agent in env.agents})
    info = infos["suction"]
    assert info["saline_used_ml"] > 0.0 and info["saline_wasted_ml"] == info["saline_used_ml"]  # in the air
    for key in ("clot_remaining", "overflow_events", "overflow_s", "overflow_ml"):
        assert key in info


def test_saline_wasted_costs_every_agent_its_penalty_per_ml():
    """``waste_penalty``: each ml irrigated into no cavity costs every agent that much; saline into a cavity costs
    nothing (off by default: the rewards unchanged)."""
    for height, wasting in ((0.01, True), (None, False)):  # over the phantom, then down in a cavity
        rewards = {}
        for penalty in (0.0, 0.5):
            env = _env(irrigation_ml_s=1.0, reward_type="dense", waste_penalty=penalty)
            _work(env, tools.SHUT, 120, height=height)  # (there, the valve shut)
            before = env.core.get_state().saline_used_ml.copy()
            command = {"suction": np.array([[0.0, 0.0, 0.0, IRRIGATE]] * WORLDS), "grasper": np.zeros((WORLDS, 4))}
            for _ in range(3):  # (the irrigating side's stroke opens at once: tool_speed 1)
                rewards[penalty] = env.step(command)[1]
            state = env.core.get_state()
        assert np.all(state.saline_used_ml > before)
        wasted = 0.5 * env.params.irrigation_ml_s * env.params.control_dt if wasting else 0.0
        for agent in ("suction", "grasper"):
            np.testing.assert_allclose(rewards[0.5][agent] - rewards[0.0][agent], -wasted, rtol=0, atol=1e-12)
    assert not any("waste_penalty" in preset for preset in suction_debris.PRESETS.values())  # (a learning choice)


def test_the_rule_runs_alike_under_jax():
    jax = pytest.importorskip("jax")
    jax.config.update("jax_enable_x64", True)
    from dvrl_marl.suction_debris import scene_state

    env = _env(preset="irrigation", spill_s=0.5, blood_ml=[10.0, 8.0])
    core = env.core
    scene_state.register_with_jax()
    step = jax.jit(core.step_state)
    state = core.get_state()
    device = scene_state.map_arrays(jax.numpy.asarray, state)
    plan = [(np.array([0.0, 0.0, -1.0, 0.0]), 60), (np.array([0.0, 0.0, -1.0, -1.0]), 80),
            (np.array([0.0, 0.0, -1.0, 1.0]), 60)]
    c = core.cavities
    for command, steps in plan:
        for _ in range(steps):
            tip = np.asarray(state.suction_tip) + core.arms["suction"].base_position
            goal = np.array([c.centre_x[0], c.centre_y[0], c.floor_z[0]])
            move = np.clip((goal - tip) / env.params.step_size, -1.0, 1.0)
            suction = np.concatenate([move, np.full((WORLDS, 1), command[3])], axis=1)
            commands = {"suction": suction, "grasper": np.zeros((WORLDS, 4))}
            state, rewards = core.step_state(state, commands)[:2]
            device, device_rewards = step(device, {agent: jax.numpy.asarray(value)
                                                   for agent, value in commands.items()})[:2]
            for agent in rewards:  # (the saline's cost among them: the preset's penalty)
                np.testing.assert_allclose(np.asarray(device_rewards[agent]), rewards[agent], rtol=0, atol=1e-9)
    assert np.all(np.asarray(state.saline_used_ml) > 0.0)
    for name in ("clot_ml", "saline_ml", "remaining_ml", "surface_z", "spill_s", "overflow_ml", "overflow_events",
                 "saline_wasted_ml"):
        np.testing.assert_allclose(np.asarray(getattr(device, name)), getattr(state, name), rtol=0, atol=1e-9)


def test_pins_under_a_clot_stay_hidden_until_it_is_broken_up():
    env = _env(irrigation_ml_s=1.0, clot_share=0.5, blood_ml=[8.0, 8.0])
    core = env.core
    mine = core.debris_cavity == 0
    _at_floor(env)
    _work(env, SUCK, 150)  # the liquid drawn: the clot (half the blood) stays on the floor
    clot_level = core.cavities.floor_z[0] + core.cavities.fill_depth(np.zeros(WORLDS, np.int64), core.clot_ml[:, 0])
    top = core.debris_position[..., 2] + 0.0015
    under = mine & (top <= clot_level[:, None])
    assert under.any()
    assert not core.visible[under].any()
    for _ in range(8):  # bursts: irrigate, then draw the mix
        _work(env, IRRIGATE, 40)
        _work(env, SUCK, 60)
    assert np.all(core.clot_ml[:, 0] < 1e-9)
    assert core.visible[mine].all()


def test_the_keyboard_irrigates_while_i_is_held_and_its_shut_valve_is_zero():
    from dvrl_marl.teleop import KeyboardDevice

    plain = KeyboardDevice(initial_tool=-1.0)
    plain.key_event(73, 1)
    assert plain.action(None)[3] == -1.0 and not plain.irrigating  # (I means nothing where nothing irrigates)
    device = KeyboardDevice(initial_tool=-1.0, irrigate=True)
    assert device.action(None)[3] == tools.SHUT
    device.key_event(73, 1)
    assert device.action(None)[3] == -1.0 and device.irrigating
    device.key_event(73, 0)
    assert device.action(None)[3] == tools.SHUT
    device.key_event(32, 1)  # SPACE: the valve sucks
    assert device.action(None)[3] == 1.0
    device.key_event(32, 1)
    assert device.action(None)[3] == tools.SHUT
    assert ("I (held)", "irrigate") in device.key_help
    with pytest.raises(ValueError, match="irrigate"):
        KeyboardDevice(irrigate="yes")


def test_an_irrigating_device_in_the_grasper_seat_or_a_scene_that_does_not_irrigate_is_named():
    from dvrl_marl.teleop import BrowserDevice, KeyboardDevice

    with pytest.raises(ValueError, match="Needle Driver\\) cannot irrigate"):
        suction_debris.parallel_env(preset="irrigation", surgeon=KeyboardDevice(irrigate=True),
                                    surgeon_seat="grasper")
    with pytest.raises(ValueError, match="does not irrigate"):
        suction_debris.parallel_env(surgeon=KeyboardDevice(initial_tool=-1.0, irrigate=True),
                                    surgeon_seat="suction")
    assert BrowserDevice(irrigate=True).key_help[4] == ("I (held)", "irrigate")


def test_a_person_in_the_suction_seat_irrigates_with_the_key_and_the_cues_say_so():
    from dvrl_marl.envs.scene_view import SceneView
    from dvrl_marl.teleop import KeyboardDevice

    device = KeyboardDevice(initial_tool=-1.0, irrigate=True)
    env = suction_debris.parallel_env(preset="irrigation", surgeon=device, surgeon_seat="suction")
    env.reset(seed=0)
    device.key_event(73, 1)
    for _ in range(12):
        env.step({"grasper": np.zeros(4, dtype=np.float32)})
    view = SceneView(env)
    assert view.cues("suction")["irrigating"] and view.progress()["saline_used_ml"] > 0.0
    labels, values = view.cue_rows("suction")
    assert values[labels.index("Valve")].startswith("IRRIGATING") and "Saline" in labels


def test_a_feature_set_of_a_scene_with_fluids_reads_its_whole_plain_observation():
    from dvrl_marl.suction_debris import features

    env = _env(preset="irrigation")
    spec = env.feature_spec
    assert spec["fluids"] is True
    features.check_spec(spec)
    assert features.observation_width(spec) == layout.plain_width(env.observation_layout)
    observations, _ = env.reset(seed=8)  # what the env gives: the plain observation, then its features
    np.testing.assert_allclose(features.apply(spec, env.core.observation("suction")), observations["suction"],
                               rtol=0, atol=1e-12)
    assert "fluids" not in _env(preset="benchmark").feature_spec  # (the other scenes' specs as before)
    with pytest.raises(ValueError, match="fluids"):
        features.check_spec({**spec, "fluids": 1})


def test_the_pipeline_and_a_person_like_suction_irrigate_where_the_scene_does():
    from dvrl_marl.agents.partners import zoo_partner
    from dvrl_marl.training import teams

    scene = suction_debris.parallel_env(preset="irrigation")
    for suction in (teams.seat("pipeline", "suction", scene), zoo_partner("person", "suction", scene)):
        result = teams.evaluate_team_batched({"suction": suction, "grasper": teams.seat("scripted", "grasper", scene)},
                                             3, preset="irrigation", max_cycles=4000)
        assert result["success_rate"] == 1.0 and result["mean_saline_used_ml"] > 0.0
        assert result["overflowed_episodes"] == 0.0


def test_the_guided_reward_counts_clot_broken_up_as_progress():
    env = _env(preset="irrigation")
    guided = env._guided
    before = guided.potentials(env.state(), env.core.remaining_ml)["suction"]
    env.core.clot_ml[:, 0] -= 1.0  # 1 ml of clot made liquid (the blood the same)
    after = guided.potentials(env.state(), env.core.remaining_ml)["suction"]
    np.testing.assert_allclose(after - before, env.guidance.clot_broken * 1.0, rtol=1e-9)
    plain = _env(preset="benchmark")  # (no clot slots: the term is not there)
    assert plain._guided.route.clot_broken == 0.0


def test_normalized_observations_of_a_scene_with_fluids_are_refused_by_name():
    with pytest.raises(ValueError, match="normalize_observations.*fluids"):
        suction_debris.batched_env(num_envs=1, preset="irrigation", normalize_observations=True)


def test_a_look_tints_the_fluids_as_it_tints_the_blood():
    """Domain randomisation's colour gain reaches the fluids' colours (drawn per cavity by what they hold), as it
    reaches liquid blood's material in a scene without fluids; the pins and the phantom's segments stay."""
    pytest.importorskip("OpenGL")
    from dvrl_marl.suction_debris.appearance import Appearance

    colour_only = Appearance(colour=0.3, light=0.0, light_degrees=0.0, camera_mm=0.0, camera_degrees=0.0, noise=0.0)
    images = {}
    for name, look in (("own", None), ("tinted", colour_only)):
        env = suction_debris.batched_env(num_envs=2, preset="irrigation", image_size=48, image_segmentation=True,
                                         image_appearance=look)
        observations, _ = env.reset(seed=4)
        images[name] = observations["suction"]
    blood = images["own"]["segmentation"] == 2
    assert blood.sum() > 20
    np.testing.assert_array_equal(images["own"]["segmentation"], images["tinted"]["segmentation"])
    own, tinted = (images[name]["image"][blood].astype(float) for name in ("own", "tinted"))
    assert np.abs(own - tinted).mean() > 2.0  # (of 255: the fluids drawn in the look's colours, not the scene's)
