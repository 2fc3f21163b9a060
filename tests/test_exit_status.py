"""tests/conftest.py ends a pytest process with pytest's own exit status once it has reported (skipping the
interpreter's teardown, where a native library once crashed a green run): a failing test must still fail the run."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

PROBE = os.environ.get("DVRL_MARL_EXIT_PROBE")


@pytest.mark.skipif(PROBE is None, reason="run by test_the_exit_status_is_pytests_own, in a process of its own")
def test_probe():
    assert PROBE == "pass"


@pytest.mark.parametrize("probe,status", [("pass", 0), ("fail", 1)])
@pytest.mark.slow
def test_the_exit_status_is_pytests_own(probe, status):
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                             f"{Path(__file__)}::test_probe"], capture_output=True, text=True, timeout=120,
                            env={**os.environ, "DVRL_MARL_EXIT_PROBE": probe}, cwd=Path(__file__).parents[1])
    assert result.returncode == status, result.stdout[-2000:]
    assert ("1 passed" if status == 0 else "1 failed") in result.stdout  # the report came before the exit

