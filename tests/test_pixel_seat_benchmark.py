"""benchmarks/pixel_seat.py's ways to try a pixel seat without training again: another privileged seat acting on its
estimates (``--acting``), its blood estimates raised (``--raise-blood``), its teacher given exact estimates
(``--exact``), its blood estimates near full read as full (``--full-above``); each refuses what it cannot do."""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from dvrl_marl import policies

BENCHMARKS = Path(__file__).parents[1] / "benchmarks"


@pytest.fixture(scope="module")
def bench():
    sys.path.insert(0, str(BENCHMARKS))  # it imports partner_zoo beside it, as when run from there
    try:
        spec = importlib.util.spec_from_file_location("pixel_seat_benchmark", BENCHMARKS / "pixel_seat.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.path.remove(str(BENCHMARKS))


def _observation(count=5, seed=0):
    rng = np.random.default_rng(seed)
    return {"observation": rng.uniform(-1, 1, (count, 30)),
            "image": rng.integers(0, 256, (count, 64, 64, 3), dtype=np.uint8),
            "image_right": rng.integers(0, 256, (count, 64, 64, 3), dtype=np.uint8)}  # (a stereo seat reads both)


def test_another_seat_acts_on_the_same_estimates(bench):
    pixel = policies.load("marl-suction-pixels")
    other = ({"marl-suction", "marl-suction-yielding"} - {pixel.spec["teacher"]}).pop()
    observation = _observation()
    estimated = pixel.features(observation)  # the teacher's observation, filled from the image
    acting = bench.acting_as(policies.load("marl-suction-pixels"), other)
    expected = policies.load(other)(estimated)
    if pixel.keep_clear is not None:  # the seat's own rule stays with it
        from dvrl_marl.suction_debris.instruments import keep_clear

        expected = keep_clear(expected, estimated, pixel.keep_clear)
    np.testing.assert_allclose(acting(observation), expected, atol=1e-6)
    assert not np.allclose(acting(observation), pixel(observation), atol=1e-3)


@pytest.mark.parametrize("name", ["marl-grasper", "marl-suction-pixels", "reach-lnd"])
def test_acting_refuses_a_seat_that_reads_another_observation(bench, name):
    with pytest.raises(ValueError, match=f"--acting {name}: not a privileged seat"):
        bench.acting_as(policies.load("marl-suction-pixels"), name)


def test_raising_the_blood_moves_only_the_estimates_kept_lowest(bench):
    pixel = policies.load("marl-suction-pixels")
    observation = _observation()
    before = pixel.features(observation)
    pixel.reset()
    after = bench.raised(policies.load("marl-suction-pixels"), 0.05).features(observation)
    kept = np.zeros(before.shape[-1], dtype=bool)
    kept[7:9] = True  # the blood left per cavity, the estimates it keeps at their lowest
    np.testing.assert_allclose(after[:, kept], before[:, kept] + 0.05, atol=1e-5)
    np.testing.assert_allclose(after[:, ~kept], before[:, ~kept], atol=1e-6)


def test_raising_refuses_a_seat_without_blood_estimates(bench):
    with pytest.raises(ValueError, match="keeps no estimate at its lowest"):
        bench.raised(policies.load("marl-suction"), 0.02)


def test_exact_estimates_are_the_teacher_on_the_truth_where_the_seat_estimates(bench):
    pixel = policies.load("marl-suction-pixels")
    template, estimates_at = pixel.encoder.fills
    state = np.random.default_rng(1).uniform(-1, 1, (6, 30))
    filled = bench.exactly_filled(pixel, state)
    given = np.zeros(30, dtype=bool)
    given[pixel.encoder.proprioception] = True
    given[estimates_at] = True
    np.testing.assert_array_equal(filled[:, given], state[:, given])  # its own tip and valve, the estimated truth
    np.testing.assert_array_equal(filled[:, ~given], np.broadcast_to(template, state.shape)[:, ~given])
    exact = bench.ExactEstimates("marl-suction-pixels")
    np.testing.assert_allclose(exact(state), policies.load(pixel.spec["teacher"])(filled))
    with pytest.raises(ValueError, match="--exact: marl-suction does not fill"):
        bench.ExactEstimates("marl-suction")


def test_keeping_clear_gives_the_seat_the_yielding_rule_on_what_it_fills(bench):
    from dvrl_marl.suction_debris.instruments import keep_clear

    pixel = bench.keeping_clear(policies.load("marl-suction-pixels"), 15.0)
    assert pixel.keep_clear["keep_mm"] == 15.0
    observation = _observation(32)
    filled = policies.load("marl-suction-pixels").features(observation)
    np.testing.assert_array_equal(pixel(observation),
                                  keep_clear(policies.load("marl-suction-pixels")(observation), filled,
                                             pixel.keep_clear))
    with pytest.raises(ValueError, match="--keep-clear-mm: the pixel seat does not fill"):
        bench.keeping_clear(policies.load("marl-suction"), 12.0)


def test_reading_full_above_reads_only_the_kept_estimates_at_the_threshold_or_more_as_full(bench):
    observation = _observation()
    before = policies.load("marl-suction-pixels").features(observation)
    after = bench.reading_full_above(policies.load("marl-suction-pixels"), 0.5).features(observation)
    kept = np.zeros(before.shape[-1], dtype=bool)
    kept[7:9] = True  # the blood left per cavity
    np.testing.assert_allclose(after[:, kept], np.where(before[:, kept] >= 0.5, 1.0, before[:, kept]), atol=1e-6)
    np.testing.assert_allclose(after[:, ~kept], before[:, ~kept], atol=1e-6)
    with pytest.raises(ValueError, match="keeps no estimate at its lowest"):
        bench.reading_full_above(policies.load("marl-suction"), 0.9)
    with pytest.raises(ValueError, match=r"in \(0, 1\]"):
        bench.reading_full_above(policies.load("marl-suction-pixels"), 1.5)
