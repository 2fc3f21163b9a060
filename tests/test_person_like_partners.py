"""Person-like partners (dvrl_marl.agents.partners): late, slow, smooth, shaky, hesitant, seeded; the held-out zoo
lies outside the training ranges, and the scripted seat can work beside every kind of it."""

import numpy as np
import pytest

from dvrl_marl.agents.collaborative import ScriptedSurgeon
from dvrl_marl.agents.partners import (HELD_OUT, PERSON, TRAINING_RANGES, PersonLikePartner, Profile, draw_profiles,
                                       zoo_partner)
from dvrl_marl.envs import suction_debris_v8
from dvrl_marl.training import teams

pytestmark = pytest.mark.extended  # whole episodes of seats beside their partners (.ci/extended runs them)

ENV = suction_debris_v8.parallel_env()


def _observations(steps=12, worlds=3, seed=0):
    """Observations of a scene the scripted team plays, so every step differs."""
    env = suction_debris_v8.batched_env(num_envs=worlds, surgeon="scripted")
    suction = teams.seat("scripted", "suction")
    observations, _ = env.reset(seed=seed)
    seen = []
    for _ in range(steps):
        seen.append(observations["suction"])
        observations, *_ = env.step({"suction": suction(observations["suction"])})
    return seen


def test_profiles_are_drawn_reproducibly_within_their_ranges():
    first, again = draw_profiles(TRAINING_RANGES, 20, seed=3), draw_profiles(TRAINING_RANGES, 20, seed=3)
    assert first == again and first != draw_profiles(TRAINING_RANGES, 20, seed=4)
    for profile in first:
        for name, (low, high) in TRAINING_RANGES.items():
            assert low <= getattr(profile, name) <= high
        assert isinstance(profile.reaction_steps, int) and isinstance(profile.pause_steps, int)
    with pytest.raises(ValueError, match="out of range"):
        Profile(speed=1.5)


@pytest.mark.parametrize("kind", sorted(HELD_OUT))
def test_each_held_out_kind_leaves_the_training_ranges(kind):
    ranges = HELD_OUT[kind]
    outside = [name for name, (low, high) in ranges.items()
               if low > TRAINING_RANGES[name][1] or high < TRAINING_RANGES[name][0]]
    assert outside, f"{kind} overlaps the training ranges in every parameter"
    assert all(TRAINING_RANGES[name][0] <= PERSON[name][0] <= TRAINING_RANGES[name][1] for name in PERSON)


def test_the_partner_acts_on_what_it_saw_reaction_steps_ago_at_its_speed():
    profile = Profile(reaction_steps=4, speed=0.5)
    partner = PersonLikePartner("grasper", ENV, profile)
    expert = ScriptedSurgeon.for_env(ENV)
    seen = _observations()
    for step, observations in enumerate(seen):
        actions = partner(observations)
        expected = expert(seen[max(step - 4, 0)]).astype(np.float64)
        expected[:, :3] *= 0.5
        np.testing.assert_allclose(actions, expected, atol=1e-6)
    single = PersonLikePartner("grasper", ENV, profile)
    assert single(seen[0][0]).shape == (4,)  # one observation in, one action out


def test_noise_and_pauses_are_seeded_hold_the_tool_and_start_over_on_reset():
    profile = Profile(reaction_steps=0, speed=1.0, approach=1.0, motor_noise=0.1, pause_probability=0.2,
                      pause_steps=3)
    partner = PersonLikePartner("grasper", ENV, profile, seed=7)
    seen = _observations(steps=30)
    first = [partner(o).copy() for o in seen]
    partner.reset()
    assert all(np.array_equal(a, b) for a, b in zip(first, [partner(o) for o in seen]))
    stacked = np.stack(first)  # (steps, worlds, 4)
    paused = np.all(stacked[:, :, :3] == 0.0, axis=2)
    assert paused.sum() >= 6  # some steps of pause happened...
    steps, worlds = np.nonzero(paused[1:])
    np.testing.assert_array_equal(stacked[steps + 1, worlds, 3], stacked[steps, worlds, 3])  # ...the tool held


def test_the_scripted_seat_works_beside_every_held_out_kind():
    # (the scripted seat beside a partner is what a learned seat is measured against: it must be able to win)
    kinds = ["person", *sorted(HELD_OUT)]
    for agent, other in (("grasper", "suction"), ("suction", "grasper")):
        results = teams.evaluate_beside(other, teams.seat("scripted", other),
                                        {kind: zoo_partner(kind, agent, ENV) for kind in kinds}, 8,
                                        task="suction_debris_v8", max_cycles=6000)
        for kind, result in results.items():
            assert result["success_rate"] >= 0.75, (kind, agent, result["success_rate"])
    with pytest.raises(ValueError, match="unknown partner kind"):
        zoo_partner("sleepy", "grasper", ENV)


def test_team_evaluation_reports_each_seats_path_and_smoothness():
    team = {"suction": teams.seat("scripted", "suction"), "grasper": teams.seat("scripted", "grasper")}
    result = teams.evaluate_team_batched(team, 4, task="suction_debris_v8")
    for agent in ("suction", "grasper"):
        assert 50.0 < result["mean_tip_path_mm"][agent] < 2000.0  # a few centimetres per pin or cavity
        assert 0.0 < result["mean_action_change"][agent] < 2.0
    slowed = {**team, "grasper": PersonLikePartner("grasper", ENV, Profile(speed=0.5, approach=0.1))}
    smoother = teams.evaluate_team_batched(slowed, 4, task="suction_debris_v8", max_cycles=6000)
    assert smoother["mean_action_change"]["grasper"] < result["mean_action_change"]["grasper"]


def test_a_trainer_names_the_person_like_partners_as_a_seat():
    population = teams.seat("person-like", "grasper", ENV)
    assert len(population.members) == 8 and all(isinstance(m, PersonLikePartner) for m in population.members)
    for member in population.members:  # drawn from the training ranges, never the held-out zoo's
        for name, (low, high) in TRAINING_RANGES.items():
            assert low <= getattr(member.profile, name) <= high
    actions = population(np.stack([o for o in _observations(steps=1, worlds=16)[0]]))
    assert actions.shape == (16, 4)


def test_the_deployable_suction_works_by_its_mean_action_beside_people_it_never_met():
    # The shipped marl-suction, called the way the README shows (policy(observation): its mean action), beside
    # the scripted surgeon, the learned grasper and held-out person-like surgeons, on test seeds.
    from dvrl_marl import policies

    suction = policies.load("marl-suction")
    assert suction.spec["agent"] == "suction" and suction.spec["env_id"] == "suction_debris_v8"
    graspers = {partner: zoo_partner(partner, "grasper", ENV) if partner in HELD_OUT else teams.seat(partner, "grasper")
                for partner in ("scripted", "marl-grasper", "late", "slow")}
    results = teams.evaluate_beside("suction", suction, graspers, 12, task="suction_debris_v8", max_cycles=6000)
    for partner, result in results.items():
        assert result["success_rate"] == 1.0 and result["mean_contact_steps"] <= 2.0, (partner, result)
