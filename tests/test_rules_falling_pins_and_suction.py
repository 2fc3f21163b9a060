"""v1_rules: released pins fall, suction needs the surface, cavities may bleed."""

import math

import numpy as np
import pytest
from pettingzoo.test import api_test, parallel_api_test

import dvrl_marl  # noqa: F401  (registration)
from dvrl_marl.agents import KeepClearSuction, KeepClearSurgeon, ScriptedSuction, ScriptedSurgeon
from dvrl_marl.suction_debris.rules import GRAVITY, PIN_RADIUS
from rule_sets import v0_rules, v1_rules

pytestmark = pytest.mark.extended  # each rule against the one it replaced, over whole episodes (.ci/extended runs them)


def test_pettingzoo_api_with_bleeding():
    parallel_api_test(v1_rules.parallel_env(bleeding_ml_s=0.3, max_cycles=200), num_cycles=300)
    api_test(v1_rules.env(bleeding_ml_s=0.3, max_cycles=100), num_cycles=200)


def _carry_a_pin(module, seed=0):
    """Run the scripted team until the grasper carries a pin well above the surface; the env and that pin."""
    env = module.parallel_env()
    suction, surgeon = ScriptedSuction.for_env(env), ScriptedSurgeon.for_env(env)
    observations, _ = env.reset(seed=seed)
    for _ in range(1500):
        pin = next((p for p in env.debris if p.held), None)
        if pin is not None:
            floor = env.phantom.surface_height(pin.position[0], pin.position[1]) + PIN_RADIUS
            if pin.position[2] > floor + 0.01:
                return env, pin, floor
        observations, *_ = env.step({"suction": suction(observations["suction"]),
                                     "grasper": surgeon(observations["grasper"])})
    raise AssertionError("the scripted team never carried a pin 1 cm up")


def _drop(env, pin):
    heights = []
    for _ in range(10):
        env.step({"suction": np.zeros(4), "grasper": np.array([0.0, 0.0, 0.0, 1.0])})
        heights.append(pin.position[2])
    return heights


def test_a_released_pin_falls_under_gravity_onto_the_surface():
    env, pin, floor = _carry_a_pin(v1_rules)
    start = pin.position[2]
    heights = _drop(env, pin)
    assert not pin.held
    landed = next(i for i, z in enumerate(heights) if z == floor)
    assert landed >= 1  # a centimetre takes more than one 20 ms step to fall...
    dt = env.params.control_dt
    assert heights[0] == pytest.approx(start - GRAVITY * dt * dt, abs=1e-12)  # ...at g (speed g dt after one step)
    assert all(z >= floor for z in heights) and np.all(np.diff(heights) <= 0)  # never into the surface
    assert heights[-1] == floor


def test_v0_pins_still_appear_on_the_surface_at_once():
    env, pin, floor = _carry_a_pin(v0_rules)
    assert _drop(env, pin)[0] == floor


def _drawn(height: float, reach: float) -> tuple[float, float]:
    """(ml drawn in one step with the valve open and the tube's tip ``height`` above the blood, the full step's ml)."""
    env = v1_rules.parallel_env(suction_reach=reach)
    env.reset(seed=0)
    cavity, arm = env.phantom.cavities[0], env.arms["suction"]
    arm.set_tip(*arm.to_base((cavity.centre_x, cavity.centre_y, env.blood.surface_z[0] + height)).tolist())
    before = env.blood.remaining_ml[0]
    env.step({"suction": np.array([0.0, 0.0, 0.0, 1.0]), "grasper": np.array([0.0, 0.0, 0.0, 1.0])})
    return before - env.blood.remaining_ml[0], env.params.suction_rate_ml_s * env.params.control_dt


def test_suction_flow_falls_off_above_the_surface():
    for height, fraction in ((-0.003, 1.0), (0.0, 1.0), (0.0005, 0.75), (0.001, 0.5), (0.002, 0.0), (0.01, 0.0)):
        removed, full = _drawn(height, reach=0.002)
        assert removed == pytest.approx(fraction * full, abs=1e-12), height
    assert _drawn(0.0, reach=0.0)[0] == 0.0  # v0's box: nothing at the surface itself
    removed, full = _drawn(-1e-6, reach=0.0)
    assert removed == pytest.approx(full)


def test_bleeding_refills_the_cavities_from_a_seeded_onset():
    env = v1_rules.parallel_env(bleeding_ml_s=0.5, bleeding_onset_s=4.0, max_cycles=400)
    env.reset(seed=3)
    onsets = [onset for onset, _ in env.bleeding]
    assert all(0.0 <= t <= 4.0 for t in onsets) and len(set(onsets)) == 2
    assert all(0.25 <= rate <= 0.5 for _, rate in env.bleeding)
    history = []
    while env.agents:
        env.step({agent: np.zeros(4) for agent in env.agents})
        history.append(list(env.blood.remaining_ml))
    history = np.array(history)
    for cavity, (onset, rate) in enumerate(env.bleeding):
        step = math.ceil(onset / env.params.control_dt)
        assert history[max(step - 1, 0), cavity] == 8.0 or step == 0
        grown = min(8.0 + rate * (400 - step) * env.params.control_dt, env.phantom.cavities[cavity].capacity_ml)
        assert history[-1, cavity] == pytest.approx(grown, abs=0.05)
    # Bookkeeping stays exact: removed + remaining == initial + added.
    for initial, added, remaining, removed in zip(env.blood.initial_ml, env.blood.added_ml, env.blood.remaining_ml,
                                                  env.blood.removed_ml):
        assert removed + remaining == pytest.approx(initial + added, abs=1e-12) and removed == pytest.approx(0.0)
    env.reset(seed=3)
    assert [t for t, _ in env.bleeding] == onsets  # seeded
    env.reset(seed=4)
    assert [t for t, _ in env.bleeding] != onsets


def test_no_bleeding_draws_nothing_so_v0_streams_are_unchanged():
    blood_free = v1_rules.parallel_env()
    blood_free.reset(seed=9)
    assert blood_free.bleeding == []
    v0 = v0_rules.parallel_env()
    observations_v0, _ = v0.reset(seed=9)
    observations_v1, _ = blood_free.reset(seed=9)
    for agent in v0.agents:  # the same start: the same draws
        np.testing.assert_array_equal(observations_v0[agent], observations_v1[agent])
    first = observations_v1
    observations_v0, _ = v0.reset()  # the stream goes on: any extra draw in v1 would shift this episode
    observations_v1, _ = blood_free.reset()
    for agent in v0.agents:
        np.testing.assert_array_equal(observations_v0[agent], observations_v1[agent])
    bleeding, _ = v1_rules.parallel_env(bleeding_ml_s=0.2).reset(seed=9)
    for agent in v0.agents:  # bleeding draws come after everything else: the start is the same
        np.testing.assert_array_equal(bleeding[agent], first[agent])


def _scripted_team_success(episodes, **kwargs):
    successes = 0
    for seed in range(episodes):
        env = v1_rules.parallel_env(surgeon="scripted", **kwargs)
        suction = ScriptedSuction.for_env(env)
        observations, _ = env.reset(seed=1000 + seed)
        while env.agents:
            observations, _, _, _, infos = env.step({"suction": suction(observations["suction"])})
        successes += bool(infos["suction"]["is_success"])
    return successes


def test_the_scripted_team_solves_v1_but_not_the_bleeding_field():
    assert _scripted_team_success(4) == 4
    assert _scripted_team_success(2, bleeding_ml_s=0.3) == 0  # sequencing is not enough when the field bleeds


@pytest.mark.parametrize("bad", [{"suction_reach": -0.001}, {"bleeding_ml_s": math.inf},
                                 {"bleeding_onset_s": math.nan}, {"pins_fall": "yes"}])
def test_bad_v1_parameters_are_refused(bad):
    with pytest.raises(ValueError, match=next(iter(bad))):
        v1_rules.parallel_env(**bad)


def test_the_keep_clear_team_solves_the_bleeding_field():
    # The Meta-World-style proof that the bleeding variant is solvable: both arms at work at once, the last hand-off
    # timed to a clear field. (benchmarks/bleeding_field.py: 75 % at 0.1 ml/s over 100 episodes, 21 % at 0.3.)
    from dvrl_marl.training import teams

    env = v1_rules.parallel_env()
    team = {"suction": KeepClearSuction.for_env(env), "grasper": KeepClearSurgeon.for_env(env)}
    clear = teams.evaluate_team_batched(team, 6, **v1_rules.rules)
    assert clear["success_rate"] == 1.0 and clear["mean_contact_steps"] == 0.0
    bleeding = teams.evaluate_team_batched(team, 10, **v1_rules.rules, bleeding_ml_s=0.1)
    assert bleeding["success_rate"] >= 0.5 and bleeding["mean_contact_steps"] == 0.0
    # The single-row and batched forms act alike.
    observations, _ = v1_rules.parallel_env(bleeding_ml_s=0.1).reset(seed=5)
    for agent, expert in team.items():
        np.testing.assert_array_equal(expert(observations[agent][None])[0], expert(observations[agent]))
