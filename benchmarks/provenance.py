"""What a record says of the code and libraries that made it: the commit (and whether the working tree differed from
it), and the versions of the libraries a figure depends on. A figure reproduces bit for bit only from the same
commit, the same versions and the same machine kind (docs/results.md, "Reproducing a figure")."""

from __future__ import annotations

import importlib.metadata
import os
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: The libraries whose versions a record names (those installed).
LIBRARIES = ("dvrl-marl", "numpy", "mujoco", "torch", "torchrl", "jax", "stable-baselines3", "benchmarl", "ray")


def commit() -> str:
    """The commit checked out (short hash), ``DVRL_MARL_COMMIT`` where there is no git (a device machine's copy), else
    ``"unknown"``."""
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=ROOT,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return os.environ.get("DVRL_MARL_COMMIT", "unknown")


def code_state() -> dict:
    """``{"commit", "modified", "versions"}``: ``modified`` lists the tracked files that differ from the commit (a
    record made from them is not the commit's)."""
    try:
        changed = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True,
                                 text=True, cwd=ROOT, check=True).stdout.splitlines()
    except (OSError, subprocess.CalledProcessError):
        changed = []
    versions = {}
    for name in LIBRARIES:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            pass
    return {"commit": commit(), "modified": [line[3:] for line in changed], "versions": versions}
