"""The rule by which a seat waits rather than push (``keep_clear``): the scripted yielding suction's, and any
policy's that names it in its ``policy.json``; a move is withheld exactly where it would bring the instrument within
``keep`` of the other's and nearer, and nothing else of the action changes."""

import json
import shutil

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from dvrl_marl import policies
from dvrl_marl.agents.collaborative import ScriptedSuction, YieldingSuction
from dvrl_marl.envs import suction_debris_v8
from dvrl_marl.suction_debris.instruments import keep_clear, segment_distance


@pytest.fixture(scope="module")
def env():
    env = suction_debris_v8.batched_env(num_envs=4)
    yield env
    env.close()


def _rule(env, keep_mm=12.0):
    return YieldingSuction(env.layout(), env.observation_layout, env.workspace_range, keep_mm).rule


_coordinates = arrays(np.float64, (16, 3), elements=st.floats(-1.0, 1.0))
_actions = arrays(np.float64, (16, 4), elements=st.floats(-1.0, 1.0))


@settings(max_examples=60, deadline=None)
@given(tips=_coordinates, offsets=arrays(np.float64, (16, 3), elements=st.floats(-0.3, 0.3)), actions=_actions,
       keep_mm=st.floats(2.0, 40.0))
def test_a_move_is_withheld_exactly_where_it_would_come_within_keep_and_nearer(env, tips, offsets, actions, keep_mm):
    rule = _rule(env, keep_mm)
    observation = np.zeros((16, 30))
    observation[:, slice(*rule["own_tip"])] = tips
    observation[:, slice(*rule["other_tip"])] = tips + offsets  # often near: the rule has something to withhold
    kept = keep_clear(actions, observation, rule)
    centres = np.asarray(rule["own_centre"]), np.asarray(rule["other_centre"])
    other = observation[:, slice(*rule["other_tip"])]
    now = segment_distance(tips, centres[0], other, centres[1])
    after = segment_distance(tips + actions[:, :3] / rule["gain"], centres[0], other, centres[1])
    withheld = (after < rule["keep"]) & (after < now)
    np.testing.assert_array_equal(kept[withheld, :3], 0.0)
    np.testing.assert_array_equal(kept[~withheld], actions[~withheld])
    np.testing.assert_array_equal(kept[:, 3], actions[:, 3])  # the valve as planned
    assert actions is not kept


def test_the_yielding_suction_is_the_scripted_suction_kept_clear_by_its_rule(env):
    observations, _ = env.reset(seed=5)
    yielding, scripted = YieldingSuction.for_env(env), ScriptedSuction.for_env(env)
    for _ in range(40):
        obs = observations["suction"].astype(np.float64)
        obs[:, slice(*yielding.rule["other_tip"])] = obs[:, slice(*yielding.rule["own_tip"])] + 0.05  # in its way
        np.testing.assert_array_equal(yielding(obs), keep_clear(scripted(obs), obs, yielding.rule))
        observations, *_ = env.step({"suction": scripted(observations["suction"]),
                                     "grasper": np.zeros((4, 4), dtype=np.float32)})
    assert yielding.rule["keep_mm"] == 12.0
    assert yielding.rule["keep"] == pytest.approx(0.012 / env.workspace_range)


def _with_rule(tmp_path, rule, name="marl-suction-yielding"):
    folder = tmp_path / "kept-clear"
    shutil.copytree(policies.shipped_dir() / name, folder)
    spec = json.loads((folder / "policy.json").read_text())
    spec["keep_clear"] = rule
    (folder / "policy.json").write_text(json.dumps(spec))
    return folder


def test_a_policy_naming_the_rule_acts_by_it_by_its_default_call_and_with_noise(env, tmp_path):
    rule = _rule(env)
    kept, plain = policies.load(_with_rule(tmp_path, rule)), policies.load("marl-suction-yielding")
    rng = np.random.default_rng(0)
    observation = rng.uniform(-1.0, 1.0, (64, 30))
    own = slice(*rule["own_tip"])
    observation[:, slice(*rule["other_tip"])] = observation[:, own] + rng.uniform(-0.1, 0.1, (64, 3))
    expected = keep_clear(plain(observation), observation, rule)
    np.testing.assert_array_equal(kept(observation), expected.astype(np.float32))
    withheld = np.all(expected[:, :3] == 0.0, axis=1) & np.any(plain(observation)[:, :3] != 0.0, axis=1)
    assert 0 < withheld.sum() < len(observation)  # the rule decided in some worlds, not all
    noisy = kept.with_noise(seed=3)(observation)
    assert np.all(noisy[withheld, :3] == 0.0)


@pytest.mark.parametrize("change, message", [
    ({"other_tip": [4, 6]}, "other_tip must span three"),
    ({"own_tip": [29, 32]}, "own_tip .* lies beyond"),
    ({"keep": -0.1}, "keep"),
    ({"own_centre": [0.0, 0.0]}, "own_centre"),
    ({"gain": "fast"}, "gain"),
])
def test_a_rule_that_does_not_fit_is_refused_by_name(env, tmp_path, change, message):
    folder = _with_rule(tmp_path, {**_rule(env), **change})
    with pytest.raises(ValueError, match=message):
        policies.load(folder)


def test_a_rule_keep_mm_must_be_positive(env):
    with pytest.raises(ValueError, match="keep_mm must be positive"):
        YieldingSuction(env.layout(), env.observation_layout, env.workspace_range, 0.0)


def test_a_pixel_policy_keeps_clear_only_of_a_tip_it_estimates(env, tmp_path):
    folder = _with_rule(tmp_path, _rule(env), name="marl-suction-pixels")
    assert policies.load(folder).keep_clear == _rule(env)
    spec = json.loads((folder / "policy.json").read_text())
    spec["image"]["fills"]["estimates_at"] = [7, 8]
    spec["image"]["readout"] = 2
    (folder / "policy.json").write_text(json.dumps(spec))
    with pytest.raises(ValueError, match=r"keep_clear.other_tip \[4, 7\] must be estimated from the image"):
        policies.load(folder)
