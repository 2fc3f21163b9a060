"""Golden trajectories: the collaborative scene's behaviour held still across refactors.

``tests/golden/suction_debris_v8.npz`` was recorded at commit 36a42a0 on suction_debris_v7 (the same rules) by
``tests/golden/record.py``: random actions and the scripted team, with the defaults, the benchmark's setting, a
bleeding field and the tool and jaw options. Every step's scene state, rewards and flags must come back to 1e-9, and a
difference names the case, the first step and the column where it appears.
"""

from pathlib import Path

import numpy as np
import pytest

GOLDEN = Path(__file__).resolve().parent / "golden"


@pytest.fixture(scope="module")
def recorded():
    return dict(np.load(GOLDEN / "suction_debris_v8.npz"))


@pytest.fixture(scope="module")
def recorder():
    import importlib.util

    spec = importlib.util.spec_from_file_location("golden_record", GOLDEN / "record.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_benchmark_preset_is_the_recorded_benchmark_setting(recorder):
    from dvrl_marl.envs.presets import PRESETS

    assert dict(PRESETS["benchmark"]) == recorder.BENCHMARK


def test_the_scene_replays_its_golden_trajectories(recorded, recorder):
    replayed = recorder.record("suction_debris_v8")
    assert set(replayed) == set(recorded)
    for case, expected in recorded.items():
        got = replayed[case]
        assert got.shape == expected.shape, case
        differs = np.abs(got - expected) > 1e-9
        if differs.any():
            step, world, column = (int(i[0]) for i in np.nonzero(differs))
            pytest.fail(f"{case}: first difference at step {step}, world {world}, column {column}: "
                        f"{got[step, world, column]!r} != {expected[step, world, column]!r}")
