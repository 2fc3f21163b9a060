"""Surgeons that get in the suction's way (dvrl_marl.agents.in_the_way): where they rest, when they yield, world by
world as alone, the scripted suction pushing into them, and bad settings named."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from dvrl_marl.agents.in_the_way import (HELD_OUT, TRAINING_RANGES, InTheWayPartner, Obstruction, draw_obstructions,
                                         held_out_obstructors, training_obstructors)
from dvrl_marl.agents.partners import zoo_partner
from dvrl_marl.envs import suction_debris_v8
from dvrl_marl.training import teams

pytestmark = pytest.mark.slow  # whole episodes of seats beside their partners (CI runs them)


def _still(observations):
    return np.zeros((len(observations), 4))


def _play(partner, suction, steps, seed=5, worlds=1):
    env = suction_debris_v8.batched_env(num_envs=worlds, autoreset_mode="disabled")
    observations, _ = env.reset(seed=seed)
    seen = []
    for _ in range(steps):
        actions = {"suction": suction(observations["suction"]), "grasper": partner(observations["grasper"])}
        observations, _, _, _, info = env.step(actions)
        seen.append((observations["grasper"].copy(), info["grasper"]["collision"].copy()))
    return env, seen


def test_it_rests_on_the_suctions_route_and_never_yields_to_a_suction_that_keeps_away():
    env = suction_debris_v8.batched_env(num_envs=1)
    obstruction = Obstruction(along=0.4, height_mm=10.0, near_mm=20.0, patience_steps=30)
    partner = InTheWayPartner("grasper", env, obstruction)
    env, seen = _play(partner, _still, 300)
    layout, scale = env.layout(), env.workspace_range
    tip, suction = seen[-1][0][0, 0:3], seen[-1][0][0, 4:7]
    first = np.asarray(layout.cavity_centres[1])  # the scripted suction's first: the cavity farther from its RCM
    rest = first + 0.4 * (suction[:2] - first)
    np.testing.assert_allclose(tip[:2], rest, atol=0.5e-3 / scale)
    assert abs(tip[2] - (layout.phantom_top + 0.010 / scale)) < 0.5e-3 / scale
    assert not partner._yielded.any()


@given(patience=st.integers(1, 60))
@settings(max_examples=15, deadline=None)
def test_it_yields_after_the_suction_waited_near_it_for_its_patience_in_a_row(patience):
    """Hand-made observations: the suction's tip beside the LND's axis for patience - 1 steps, away once (the count
    starts again), then beside it: the LND yields on the patience-th step in a row and then acts as the scripted
    surgeon."""
    env = suction_debris_v8.parallel_env()
    partner = InTheWayPartner("grasper", env, Obstruction(along=0.3, height_mm=10.0, near_mm=20.0,
                                                          patience_steps=patience))
    observations, _ = env.reset(seed=2)
    near, far = observations["grasper"].copy(), observations["grasper"].copy()
    near[4:7] = near[0:3] + np.array([0.010, 0.0, 0.0]) / env.workspace_range  # 10 mm beside its tip
    far[4:7] = near[0:3] + np.array([-0.060, 0.0, 0.0]) / env.workspace_range
    partner(far)
    for _ in range(patience - 1):
        partner(near)
    partner(far)
    for _ in range(patience - 1):
        partner(near)
        assert not partner._yielded[0]
    action = partner(near)
    assert partner._yielded[0]
    np.testing.assert_allclose(action, partner.expert(near), atol=1e-6)


def test_each_world_acts_as_one_partner_alone_and_restarts_alone():
    env = suction_debris_v8.parallel_env()
    batch_partner = training_obstructors("grasper", env, members=2)
    _, batch = _play(batch_partner, teams.seat("scripted", "suction"), 200, seed=11, worlds=2)
    for world in range(2):
        alone = InTheWayPartner("grasper", env, batch_partner.members[world].obstruction)
        _, single = _play(alone, teams.seat("scripted", "suction"), 200, seed=11 + world)
        np.testing.assert_allclose(np.stack([s[0][0] for s in single]), np.stack([b[0][world] for b in batch]),
                                   atol=1e-9)
    member = batch_partner.members[0]
    member._yielded[:], member._fresh[:] = True, False
    batch_partner.reset([1])  # world 1 is member 1's: member 0 goes on as it was
    assert member._yielded.all() and not member._fresh.any()
    batch_partner.reset([0])
    assert not member._yielded.any() and member._fresh.all()


@pytest.mark.extended
def test_the_scripted_suction_finishes_beside_them_by_pushing_into_them():
    """The premise of a seat that yields: the scripted suction gets through only by pushing (every kind)."""
    env = suction_debris_v8.parallel_env()
    results = teams.evaluate_beside("suction", teams.seat("scripted", "suction"),
                                    {"training": training_obstructors("grasper", env),
                                     "held out": held_out_obstructors("grasper", env)}, 16, max_cycles=3000)
    for kind, result in results.items():
        assert result["success_rate"] == 1.0 and result["mean_contact_steps"] > 10.0, (kind, result)
        # each episode's contact steps, whose mean is the figure
        assert len(result["contact_steps"]) == 16 and np.mean(result["contact_steps"]) == result["mean_contact_steps"]
        # each episode's contact steps, whose mean is the figure
        assert len(result["contact_steps"]) == 16 and np.mean(result["contact_steps"]) == result["mean_contact_steps"]


def test_the_held_out_kind_lies_outside_the_training_ranges_and_is_the_zoos():
    for place, ranges in TRAINING_RANGES.items():  # longer patience; everything else as in training
        assert HELD_OUT[place]["patience_steps"][0] > ranges["patience_steps"][1]
        assert {k: v for k, v in HELD_OUT[place].items() if k != "patience_steps"} == {
            k: v for k, v in ranges.items() if k != "patience_steps"}
    drawn = draw_obstructions(HELD_OUT, 4, 1)
    assert drawn == draw_obstructions(HELD_OUT, 4, 1) and len(set(drawn)) == 4
    assert [o.height_mm > 5.0 for o in drawn] == [True, False, True, False]  # the route, the cavity, in turn
    env = suction_debris_v8.parallel_env()
    zoo = zoo_partner("in-the-way", "grasper", env)
    assert [m.obstruction for m in zoo.members] == [m.obstruction for m in held_out_obstructors("grasper", env).members]
    assert teams.seat("in-the-way", "grasper", env).names[0] == "in-the-way-0"


@pytest.mark.parametrize("make, message", [
    (lambda env: InTheWayPartner("suction", env, Obstruction()), "fills the LND seat"),
    (lambda env: InTheWayPartner("grasper", env, {"along": 0.3}), "must be an Obstruction"),
    (lambda env: Obstruction(along=1.5), "out of range"),
    (lambda env: Obstruction(patience_steps=2.5), "whole number of steps"),
    (lambda env: Obstruction(near_mm=0.0), "out of range"),
    (lambda env: teams.seat("in-the-way", "suction", env), "fill the LND seat"),
    (lambda env: zoo_partner("in-the-way", "suction", env), "fill the LND seat"),
])
def test_bad_settings_are_named(make, message):
    with pytest.raises(ValueError, match=message):
        make(suction_debris_v8.parallel_env())


@pytest.mark.extended
def test_the_yielding_script_passes_them_without_a_contact_and_otherwise_is_the_scripted_suction():
    from dvrl_marl.agents.collaborative import ScriptedSuction, YieldingSuction

    env = suction_debris_v8.parallel_env()
    results = teams.evaluate_beside("suction", YieldingSuction.for_env(env),
                                    {"training": training_obstructors("grasper", env),
                                     "held out": held_out_obstructors("grasper", env)}, 16, max_cycles=3000)
    for kind, result in results.items():
        assert result["success_rate"] == 1.0 and result["mean_contact_steps"] == 0.0, (kind, result)
    batched = suction_debris_v8.batched_env(num_envs=4, surgeon="scripted", surgeon_seat="grasper")
    observations, _ = batched.reset(seed=8)
    yielding, scripted = YieldingSuction.for_env(batched), ScriptedSuction.for_env(batched)
    for _ in range(300):  # beside the scripted surgeon, which keeps out of its way, nothing is held back
        action = yielding(observations["suction"])
        np.testing.assert_array_equal(action, scripted(observations["suction"]))
        np.testing.assert_array_equal(yielding(observations["suction"][0]), action[0])
        observations, *_ = batched.step({"suction": action})
