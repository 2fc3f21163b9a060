"""The bad-input round (benchmarks/bad_input_round.py) at a small scale, on seeds of its own: every case is taken and
well behaved or refused by name; none is a defect (another exception, a traceback, a refusal that changed a world,
NaN out). The recorded round (1,320 cases, both backends) is on the results page."""

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _round():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    spec = importlib.util.spec_from_file_location("bad_input_round", ROOT / "benchmarks" / "bad_input_round.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("seed", [100, 101])
def test_a_small_round_of_bad_input_finds_no_defect(seed, capsys):
    assert _round().main(["--scale", "0.15", "--seed", str(seed)]) == 0, capsys.readouterr().out
