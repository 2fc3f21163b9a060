"""The README's test command: its second pytest run names the real-time files (collecting the rest would import the
whole suite again), and .ci/run runs the command as the README writes it."""

import re
from pathlib import Path

from conftest import REAL_TIME_FILES

ROOT = Path(__file__).resolve().parents[1]


def test_the_readmes_test_command_runs_every_real_time_file_and_ci_runs_that_command():
    readme = (ROOT / "README.md").read_text()
    command = next(line for line in readme.splitlines() if line.startswith("python3 -m venv .venv && ") and "pytest" in line)
    realtime = command.split("-m realtime", 1)[1]
    assert {Path(name).name for name in re.findall(r"tests/\S+\.py", realtime)} == REAL_TIME_FILES
    assert command in (ROOT / ".ci" / "run").read_text()
