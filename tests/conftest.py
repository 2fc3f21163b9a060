import importlib.util
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")  # headless rendering in CI
# One thread per BLAS / torch pool: on a 2-core machine two threads fight the other core's test (or training) and a
# 6 s docs block took minutes; the suite's figures are timed in benchmarks/, never here.
for _variable in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")


def load_script(path: Path, name: str | None = None):
    """A script of the checkout (benchmarks/, docs/, examples/) as a module, registered under its name (a dataclass
    in it looks its module up); the benchmarks' folder on the path for their shared helpers (provenance)."""
    name = name or path.stem
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="session")
def x_display():
    """A real X display (a virtual screen from Debian's ``xvfb``) for tests of windows a person uses; its name."""
    if shutil.which("Xvfb") is None:
        pytest.skip("Xvfb is not installed (Debian: apt-get install xvfb xdotool); .ci/run installs it")
    read_end, write_end = os.pipe()
    server = subprocess.Popen(["Xvfb", "-displayfd", str(write_end), "-screen", "0", "1024x768x24", "-nolisten", "tcp"],
                              pass_fds=(write_end,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(write_end)
    with os.fdopen(read_end) as announced:
        number = announced.readline().strip()  # Xvfb writes its display number once it accepts clients
    if not number:
        server.kill()
        pytest.skip("Xvfb did not start")
    yield f":{number}"
    server.terminate()
    server.wait(timeout=10)


# The run's result is final once pytest has reported it; native libraries loaded by the tests (MuJoCo's EGL contexts,
# torch, Ray) can still crash while the interpreter tears down (measured: one CI run of 778 passed tests ended in a
# segmentation fault after its summary, exit 139). So the process ends with pytest's own exit status, skipping that
# teardown: a failure still fails, a crash after the report does not turn a green run red.
_exit_status = None


def pytest_sessionfinish(session, exitstatus):
    global _exit_status
    _exit_status = int(exitstatus)


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config):
    if _exit_status is not None:
        import sys

        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(_exit_status)


#: The first single-arm frame as keywords of the current ids (p the tool point, Pick's first scene): tests of
#: invariants written in that frame hold it there (docs/deviations.md: ``tip_frame="tool_point"``).
TOOL_POINT = {"dvrl_marl/PSMReach-v1": {"tip_frame": "tool_point"},
              "dvrl_marl/PSMPick-v1": {"tip_frame": "tool_point", "scenes": {"lnd": "pick_lnd"}}}


#: Tests of a person's seats in real time (a window under Xvfb, a page in Chromium): they keep a real clock, so the
#: README's test command runs them after the rest, alone (``-m realtime``), never beside other tests' load.
REAL_TIME_FILES = {"test_browser_page.py", "test_browser_seat.py", "test_keyboard_seat.py"}


#: The longest tests (tens of seconds: Ray clusters, a benchmark row's run, compiled device envs), run first: the
#: README's two workers then share out the short ones around them (xdist's work stealing) instead of one worker
#: ending the run alone on a long test it picked up last.
LONG_FIRST = ("test_marl_benchmark.py::test_a_tiny_run_writes_its_record", "test_ray.py::test_training_on_two_nodes",
              "test_device_env.py::", "test_rllib.py::", "test_person_like_partners.py::", "test_use_with.py::")


def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.path.name in REAL_TIME_FILES:
            item.add_marker(pytest.mark.realtime)
        if item.get_closest_marker("extended") is not None:  # (what .ci/extended runs, nothing quicker runs)
            item.add_marker(pytest.mark.slow)
    # (a stable sort: within each group, the collection's order)
    items.sort(key=lambda item: not f"{item.path.name}::{item.name}".startswith(LONG_FIRST))


class DrivenClock:
    """A clock a test drives: reading it gives the time, ``sleep`` moves it on (no real waiting)."""

    def __init__(self, start: float = 0.0):
        self.t = start

    def __call__(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.t += max(seconds, 0.0)
