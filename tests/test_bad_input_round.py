"""The bad-input round (benchmarks/bad_input_round.py) at a small scale, on seeds of its own: every case is taken and
well behaved or refused by name; none is a defect (another exception, a traceback, a refusal that changed a world,
NaN out). The recorded round (1,320 cases, both backends) is on the results page."""

from pathlib import Path

import pytest
from conftest import load_script

ROOT = Path(__file__).resolve().parents[1]


def _round():
    return load_script(ROOT / "benchmarks" / "bad_input_round.py")


@pytest.mark.parametrize("seed", [100, 101])
def test_a_small_round_of_bad_input_finds_no_defect(seed, capsys):
    assert _round().main(["--scale", "0.15", "--seed", str(seed)]) == 0, capsys.readouterr().out
