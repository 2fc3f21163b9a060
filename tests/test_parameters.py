"""Every numeric parameter of every environment is checked where it enters: a bad value is a ValueError naming it."""

import math

import gymnasium as gym
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import dvrl_marl  # noqa: F401  (registration)
from dvrl_marl.envs import suction_debris_v8
from dvrl_marl.validation import check_integer, check_number, check_vector

POSITIVE = ("workspace_range", "step_size", "distance_threshold", "control_dt")


def _single(env_id):
    return lambda **kwargs: gym.make(env_id, **kwargs)


FACTORIES = {
    "PSMReach-v1": (_single("dvrl_marl/PSMReach-v1"), POSITIVE + ("tip_clearance",)),
    "PSMPick-v1": (_single("dvrl_marl/PSMPick-v1"), POSITIVE + ("tip_clearance", "grasp_threshold")),
    "suction_debris_v8": (suction_debris_v8.parallel_env,
                          POSITIVE + ("suction_rate_ml_s", "blood_threshold_ml", "contact_penalty", "tip_clearance",
                                      "grasp_threshold")),
    "suction_debris_v8 (batched)": (lambda **kwargs: suction_debris_v8.batched_env(num_envs=2, **kwargs),
                                    POSITIVE + ("suction_rate_ml_s",)),
}
NOT_FINITE = (math.inf, -math.inf, math.nan)


@pytest.mark.parametrize("name", sorted(FACTORIES))
@pytest.mark.parametrize("bad", NOT_FINITE + ("0.01", [0.01], True))
def test_every_float_parameter_must_be_a_finite_number(name, bad):
    make, keys = FACTORIES[name]
    for key in keys:
        with pytest.raises(ValueError, match=key):
            make(**{key: bad})


@pytest.mark.parametrize("name", sorted(FACTORIES))
def test_workspace_centres_must_be_three_finite_numbers(name):
    make, _ = FACTORIES[name]
    for bad in ([0.0, 0.0, math.nan], [0.0, math.inf, 0.06], [0.0, 0.0]):
        with pytest.raises(ValueError, match="workspace_centre"):
            make(workspace_centre=bad)


@settings(max_examples=40, deadline=None)
@given(key=st.sampled_from(POSITIVE), value=st.floats(max_value=0.0, allow_nan=False))
def test_positive_parameters_refuse_zero_and_below(key, value):
    for name in ("PSMReach-v1", "suction_debris_v8"):
        with pytest.raises(ValueError, match=key):
            FACTORIES[name][0](**{key: value})


@pytest.mark.parametrize("bad", [0, -1, 2.5, 10_000, "3", math.nan])
def test_debris_count_and_episode_length_are_checked(bad):
    with pytest.raises(ValueError, match="debris_count"):
        suction_debris_v8.parallel_env(debris_count=bad)
    if bad != 10_000:
        with pytest.raises(ValueError, match="max_cycles"):
            suction_debris_v8.parallel_env(max_cycles=bad)


def test_blood_volumes_are_checked_one_by_one():
    for bad, match in (([8.0, math.nan], r"blood_ml\[1\]"), ([-1.0, 8.0], r"blood_ml\[0\]"), ([8.0], "blood_ml")):
        with pytest.raises(ValueError, match=match):
            suction_debris_v8.parallel_env(blood_ml=bad)


@settings(max_examples=60, deadline=None)
@given(value=st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10, 10), st.booleans(),
                       st.text(max_size=3)))
def test_the_checks_accept_exactly_finite_numbers_in_range(value):
    ok = (not isinstance(value, (bool, str))) and math.isfinite(value) and 0 < value <= 1
    if ok:
        assert check_number("owner", "key", value, low=0.0, low_open=True, high=1.0) == float(value)
    else:
        with pytest.raises(ValueError, match="owner: key"):
            check_number("owner", "key", value, low=0.0, low_open=True, high=1.0)


def test_integer_and_vector_checks():
    assert check_integer("o", "k", 3.0, low=1) == 3
    assert check_vector("o", "v", (1, 2.5, 0), 3) == (1.0, 2.5, 0.0)
    with pytest.raises(ValueError, match="o: v needs 3 values"):
        check_vector("o", "v", (1, 2), 3)
    with pytest.raises(ValueError, match="sequence"):
        check_vector("o", "v", 1.0)
