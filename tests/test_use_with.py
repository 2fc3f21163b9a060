"""Every Python block of docs/use_with.md runs (the page cannot rot)."""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "use_with.md"


def _blocks():
    text = PAGE.read_text()
    blocks = []
    for match in re.finditer(r"^## (.+?)$|^```python\n(.*?)^```", text, flags=re.S | re.M):
        if match.group(1):
            section = match.group(1).strip()
        else:
            blocks.append(pytest.param(match.group(2), id=section.lower().replace(" ", "-")))
    return blocks


def test_the_page_has_a_block_per_library():
    ids = [p.id for p in _blocks()]
    for expected in ("gymnasium", "stable-baselines3-+-her", "pettingzoo", "supersuit-+-stable-baselines3", "torchrl",
                     "multi-agent-ppo-(mappo-/-ippo)", "benchmarl", "rllib", "headless-rendering"):
        assert expected in ids


@pytest.mark.parametrize("code", _blocks())
@pytest.mark.slow
def test_block_runs(code, tmp_path):
    first = code.splitlines()[0]
    if first.startswith("# requires:"):
        module = first.split(":", 1)[1].strip()
        if importlib.util.find_spec(module) is None:
            pytest.skip(f"{module} is not installed")
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    # BenchMARL writes its experiment folder into the working directory: keep it out of the checkout.
    cwd = tmp_path if "benchmarl" in first else ROOT
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, cwd=cwd,
                            env=env)
    assert result.returncode == 0, result.stderr[-3000:]
