"""A seat that feels the other instrument (``felt_contact``, dvrl_marl.policies.felt_contact): moves made as
commanded change nothing; a move stopped near the other instrument keeps the tip behind the touch for its steps, then
lets go; a world's episode start forgets its touch; and beside a surgeon resting in its way, a seat that pushes on
pushes into it for fewer steps with the rule than without."""

import json
import shutil

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from dvrl_marl import policies
from dvrl_marl.agents.collaborative import ScriptedSuction, YieldingSuction
from dvrl_marl.agents.in_the_way import InTheWayPartner, Obstruction
from dvrl_marl.envs import suction_debris_v8
from dvrl_marl.policies.felt_contact import FeltContact
from dvrl_marl.suction_debris.scripted_team import felt_contact_rule
from dvrl_marl.training import teams


@pytest.fixture(scope="module")
def geometry():
    env = suction_debris_v8.parallel_env()
    keep = YieldingSuction(env.layout(), env.observation_layout, env.workspace_range, 12.0).rule
    yield keep, env.workspace_range
    env.close()


def _felt(geometry, near_mm=30.0, retreat_mm=2.0, hold=20, threshold_mm=0.3):
    keep, workspace_range = geometry
    return FeltContact(felt_contact_rule(workspace_range, near_mm, retreat_mm, hold, threshold_mm), keep)


def _observation(tips, others):
    observation = np.zeros((len(tips), 30))
    observation[:, 0:3], observation[:, 4:7] = tips, others
    return observation


@settings(max_examples=40, deadline=None)
@given(start=arrays(np.float64, (8, 3), elements=st.floats(-0.8, 0.8)),
       offsets=arrays(np.float64, (8, 3), elements=st.floats(-0.2, 0.2)),
       actions=arrays(np.float64, (6, 8, 4), elements=st.floats(-1.0, 1.0)))
def test_moves_made_as_commanded_change_nothing(geometry, start, offsets, actions):
    felt, gain = _felt(geometry), geometry[0]["gain"]
    tip = start.copy()
    for action in actions:
        out = felt(action, _observation(tip, start + offsets))
        np.testing.assert_array_equal(out, action)
        tip = tip + action[:, :3] / gain  # the scene made every move


def test_a_move_stopped_near_the_other_instrument_keeps_the_tip_back_for_its_steps(geometry):
    keep, workspace_range = geometry
    gain, retreat = keep["gain"], 2.0e-3 / workspace_range
    felt = _felt(geometry, hold=20)
    tip, other = np.array([[0.1, 0.0, 0.3]]), np.array([[0.2, 0.0, 0.3]])  # the other tip 8 mm ahead along x
    push = np.array([[1.0, 0.0, 0.0, 0.5]])
    felt(push, _observation(tip, other))
    backed = []
    for step in range(20):  # the move was refused: the tip did not move
        out = felt(push, _observation(tip, other))
        assert out[0, 3] == 0.5  # the valve as commanded
        backed.append(out[0, 0])
        tip = tip + out[:, :3] / gain
        assert tip[0, 0] <= 0.1 - min(retreat, (step + 1) / gain) + 1e-12  # behind the touch, a step at a time
    assert backed[0] == -1.0 and backed[-1] == pytest.approx(0.0, abs=1e-9)  # backed off, then held there
    np.testing.assert_array_equal(felt(push, _observation(tip, other)), push)  # its steps over: as commanded


def test_a_stopped_move_far_from_the_other_instrument_is_a_wall_not_a_touch(geometry):
    felt = _felt(geometry, near_mm=30.0)
    tip, far = np.array([[0.1, 0.0, 0.3]]), np.array([[0.6, -0.5, 0.3]])  # the axes 57 mm apart
    push = np.array([[1.0, 0.0, 0.0, 0.0]])
    for _ in range(5):
        np.testing.assert_array_equal(felt(push, _observation(tip, far)), push)


def test_an_episode_start_forgets_the_touch_of_its_world_only(geometry):
    felt = _felt(geometry, hold=50)
    tip = np.array([[0.1, 0.0, 0.3], [0.1, 0.0, 0.3]])
    other = tip + np.array([0.1, 0.0, 0.0])
    push = np.array([[1.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]])
    felt(push, _observation(tip, other))
    out = felt(push, _observation(tip, other))  # both refused: both touched, both back off
    assert np.all(out[:, 0] == -1.0)
    tip = tip + out[:, :3] / geometry[0]["gain"]  # backed off as commanded
    felt.reset([1])
    out = felt(push, _observation(tip, other))
    assert out[0, 0] < 1.0 and out[1, 0] == 1.0  # world 1 begins again: no last move to compare, no touch
    felt.reset()
    np.testing.assert_array_equal(felt(push, _observation(tip, other)), push)


@pytest.mark.parametrize("change, message", [
    ({"near": -0.1}, "near"),
    ({"hold_steps": 2.5}, "hold_steps"),
    ({"retreat": "far"}, "retreat"),
])
def test_a_table_that_does_not_fit_is_refused_by_name(geometry, tmp_path, change, message):
    folder = _seat(tmp_path, geometry, felt=True)
    spec = json.loads((folder / "policy.json").read_text())
    spec["felt_contact"].update(change)
    (folder / "policy.json").write_text(json.dumps(spec))
    with pytest.raises(ValueError, match=message):
        policies.load(folder)


def test_felt_contact_needs_keep_clear_and_positive_settings(geometry, tmp_path):
    folder = _seat(tmp_path, geometry, felt=True)
    spec = json.loads((folder / "policy.json").read_text())
    del spec["keep_clear"]
    (folder / "policy.json").write_text(json.dumps(spec))
    with pytest.raises(ValueError, match="felt_contact reads .* keep_clear"):
        policies.load(folder)
    with pytest.raises(ValueError, match="hold_steps must be a whole number"):
        felt_contact_rule(0.08, 30.0, 2.0, 0, 0.3)
    with pytest.raises(ValueError, match="retreat_mm must be positive"):
        felt_contact_rule(0.08, 30.0, 0.0, 10, 0.3)


def _seat(tmp_path, geometry, felt: bool):
    """The yielding suction's network keeping 12 mm clear, with or without the felt-contact rule."""
    keep, workspace_range = geometry
    folder = tmp_path / ("felt" if felt else "plain")
    shutil.copytree(policies.shipped_dir() / "marl-suction-yielding", folder)
    spec = json.loads((folder / "policy.json").read_text())
    spec["keep_clear"] = keep
    if felt:
        spec["felt_contact"] = felt_contact_rule(workspace_range, 30.0, 2.0, 20, 0.3)
    (folder / "policy.json").write_text(json.dumps(spec))
    return folder


def test_a_policy_naming_the_rule_acts_by_it_by_its_default_call_and_with_noise(geometry, tmp_path):
    felt, plain = policies.load(_seat(tmp_path, geometry, True)), policies.load(_seat(tmp_path, geometry, False))
    rule = _felt(geometry, hold=20)
    rng = np.random.default_rng(0)
    observation = rng.uniform(-0.5, 0.5, (16, 30))
    observation[:, 4:7] = observation[:, 0:3] + rng.uniform(-0.1, 0.1, (16, 3))
    acted = False
    for _ in range(3):  # the tips never move: every move the seat sends is stopped, and it feels it near the other
        expected = rule(plain(observation), observation)
        np.testing.assert_allclose(felt(observation), expected.astype(np.float32))
        acted = acted or np.any(np.abs(expected[:, :3] - plain(observation)[:, :3]) > 1e-6)
    assert acted
    felt.reset()
    noisy = felt.with_noise(seed=3)
    noisy(observation)
    assert np.all(np.abs(noisy(observation)) <= 1.0)


class _Feeling:
    """The scripted suction (which pushes on into an instrument in its way), its actions through ``felt``."""

    def __init__(self, env, felt):
        self.suction, self.felt = ScriptedSuction.for_env(env), felt

    def reset(self, worlds=None):
        if self.felt is not None:
            self.felt.reset(worlds)

    def __call__(self, observation):
        action = self.suction(observation)
        return action if self.felt is None else self.felt(action, np.asarray(observation, dtype=np.float64))


def test_beside_a_surgeon_in_its_way_a_seat_that_pushes_on_pushes_into_it_less_when_it_feels(geometry):
    env = suction_debris_v8.parallel_env()
    partner = InTheWayPartner("grasper", env, Obstruction(along=0.4, height_mm=4.0, near_mm=20.0,
                                                          patience_steps=150))
    contacts = {}
    for felt in (None, _felt(geometry, hold=100)):
        result = teams.evaluate_team_batched({"suction": _Feeling(env, felt), "grasper": partner}, episodes=4)
        contacts[felt is not None] = result["mean_contact_steps"]
    assert contacts[False] > 20.0  # the scripted suction pushes into the surgeon in its way
    assert contacts[True] < 0.25 * contacts[False], contacts  # (measured: 124.5 and 3.0 contact steps)
