"""The README's test command: its second pytest run names the real-time files (collecting the rest would import the
whole suite again), .ci/run runs the command as the README writes it, and then what it leaves out (the tests marked
slow) but the longest (marked extended), which .ci/extended runs: every test is run by one of them."""

import re
from pathlib import Path

from conftest import REAL_TIME_FILES

ROOT = Path(__file__).resolve().parents[1]


def _marks(command: str) -> list[str]:
    return re.findall(r'-m "([^"]+)"', command)


def test_the_readmes_test_command_runs_every_real_time_file_and_ci_runs_that_command():
    readme = (ROOT / "README.md").read_text()
    command = next(line for line in readme.splitlines() if line.startswith("python3 -m venv .venv && ") and "pytest" in line)
    assert _marks(command) == ["not realtime and not slow", "realtime and not slow"]
    realtime = command.split('-m "realtime and not slow"', 1)[1]
    assert {Path(name).name for name in re.findall(r"tests/\S+\.py", realtime)} == REAL_TIME_FILES
    ci = (ROOT / ".ci" / "run").read_text()
    assert command in ci


def test_ci_runs_what_the_quick_run_leaves_out_after_it_and_ci_extended_the_rest():
    ci = (ROOT / ".ci" / "run").read_text()
    readme_at = ci.index('-m "realtime and not slow"')
    slow_at = ci.index('-m "slow and not realtime and not extended"')
    slow = ci[slow_at:].split("\ncpu ", 1)[0]  # (the command, over its continued lines)
    assert slow_at > readme_at and _marks(slow) == ["slow and not realtime and not extended",
                                                    "slow and realtime and not extended"]
    assert slow.rstrip().endswith("$REAL_TIME || slow_status=1")
    assert "exit $(( readme_status | slow_status" in ci  # (a failure inside an && list does not stop the script)
    real_time = re.search(r'^REAL_TIME="([^"]+)"', ci, re.M).group(1).split()
    assert {Path(name).name for name in real_time} == REAL_TIME_FILES
    extended = (ROOT / ".ci" / "extended").read_text()
    assert '-m "extended and not realtime"' in extended and "-m extended tests/" in extended
    # the other libraries' tests: every one of them in .ci/extended's environment (at each stop they skip: the
    # README's environment has not those libraries, JAX's runs the JAX files alone)
    others = extended.split(".venv-benchmarl/bin/pytest", 1)[1].split("-m extended", 1)[0]
    jax = ci.split(".venv-jax/bin/pytest", 1)[1].split('cpu "done"', 1)[0]
    for name in ("test_benchmarl.py", "test_marl_benchmark.py", "test_ray.py", "test_rllib.py"):
        assert f"tests/{name}" in others and f"tests/{name}" not in jax
