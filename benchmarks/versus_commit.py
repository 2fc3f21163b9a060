"""The collaborative scene's speed here against another checkout of the project, side by side in one run.

Each measurement runs in a fresh process pinned to one core (``taskset``), with uniformly random actions: the parallel
env (one world, resets included) and the batched env at each N, with the defaults and with the benchmark's setting.
Checkouts alternate, measurement by measurement, and each figure is the median of ``--repeats`` runs, so that a busy
machine slows both alike. ``--against`` takes ``path:module`` pairs, e.g. a worktree of commit 36a42a0 and the scene
versions it had:

    git worktree add /tmp/at-36a42a0 36a42a0
    git worktree add /tmp/at-5d1d265 5d1d265   # the last commit with the parallel env's own scalar path
    python benchmarks/versus_commit.py --against /tmp/at-36a42a0:suction_debris_v7 /tmp/at-36a42a0:suction_debris_v2 \
        /tmp/at-5d1d265:suction_debris_v8
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
import provenance  # noqa: E402

#: The benchmark's setting spelt out (a checkout from before ``preset=`` takes these keywords).
BENCHMARK = dict(reward_type="guided", observation_features="suction_debris_cleared_pins_zoom", state_observations=True,
                 contact_penalty=0.1, tool_speed=0.1, jaw_command="switch", hold_until_handoff=True)

MEASURE = """
import importlib, sys, time
import numpy as np
module, worlds, setting = sys.argv[1], int(sys.argv[2]), sys.argv[3]
m = importlib.import_module(f"dvrl_marl.envs.{module}")
kwargs = %r if setting == "benchmark" else {}
rng = np.random.default_rng(0)
if worlds == 0:
    env = m.parallel_env(**kwargs)
    env.reset(seed=0)
    steps = 3000
    actions = rng.uniform(-1, 1, (steps, 2, 4))
    env.step({agent: actions[0, k] for k, agent in enumerate(env.possible_agents)})  # (first-call costs apart)
    start = time.perf_counter()
    for i in range(steps):
        if not env.agents:
            env.reset()
        env.step({agent: actions[i, k] for k, agent in enumerate(env.possible_agents)})
    print(steps / (time.perf_counter() - start))
else:
    env = m.batched_env(num_envs=worlds, **kwargs)
    env.reset(seed=0)
    steps = max(20, 200000 // worlds)
    actions = rng.uniform(-1, 1, (steps, 2, worlds, 4))
    env.step({agent: actions[0, k] for k, agent in enumerate(env.possible_agents)})  # (first-call costs apart)
    start = time.perf_counter()
    for i in range(steps):
        env.step({agent: actions[i, k] for k, agent in enumerate(env.possible_agents)})
    print(steps * worlds / (time.perf_counter() - start))
""" % (BENCHMARK,)


def measure(root: Path, module: str, worlds: int, setting: str, cpu: int | None) -> float | None:
    command = [sys.executable, "-c", MEASURE, module, str(worlds), setting]
    if cpu is not None and shutil.which("taskset"):
        command = ["taskset", "-c", str(cpu), *command]
    env = {**os.environ, "PYTHONPATH": str(root)}
    done = subprocess.run(command, capture_output=True, text=True, env=env, cwd=root)
    if done.returncode != 0:  # (a checkout whose scene lacks a setting's keywords)
        return None
    return float(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--against", nargs="+", default=[], help="path:module of other checkouts")
    parser.add_argument("--module", default="suction_debris_v8", help="this checkout's scene module")
    parser.add_argument("--sizes", type=int, nargs="+", default=[0, 4096], help="0: the parallel env (one world)")
    parser.add_argument("--settings", nargs="+", default=["default", "benchmark"])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--cpu", type=int, default=1, help="the core to pin to (taskset); -1: none")
    parser.add_argument("--json", help="append each figure to this JSON-lines record (with the commits compared)")
    args = parser.parse_args()
    code = provenance.code_state()  # (as the run starts: what it measures here)
    cpu = None if args.cpu < 0 else args.cpu
    checkouts = [(HERE, args.module)] + [(Path(p), m) for p, m in (pair.rsplit(":", 1) for pair in args.against)]
    print(f"{'checkout':<28} {'scene':<20} {'form':<12} {'setting':<10} {'steps/s':>12} {'vs here':>8}")
    for worlds in args.sizes:
        for setting in args.settings:
            runs = {checkout: [] for checkout in checkouts}
            for _ in range(args.repeats):
                for checkout in checkouts:
                    runs[checkout].append(measure(*checkout, worlds, setting, cpu))
            medians = {checkout: (statistics.median(r) if None not in r else None) for checkout, r in runs.items()}
            here = medians[checkouts[0]]
            form = "parallel" if worlds == 0 else f"N={worlds}"
            for (root, module), value in medians.items():
                label = "here" if root == HERE else str(root)
                shown = "n/a" if value is None else f"{value:,.0f}"
                ratio = "" if value is None or here is None else f"{value / here:.2f}"
                print(f"{label:<28} {module:<20} {form:<12} {setting:<10} {shown:>12} {ratio:>8}")
                if args.json:
                    row = {"checkout": label, "commit": code["commit"] if root == HERE else _commit_of(root),
                           "scene": module, "form": form, "setting": setting, "repeats": args.repeats,
                           "steps_per_s": None if value is None else round(value),
                           "versus_here": None if value is None or here is None else round(value / here, 3),
                           "runs": runs[(root, module)], "command": "python benchmarks/versus_commit.py "
                           + " ".join(sys.argv[1:]), "code": code}
                    with open(args.json, "a") as handle:
                        handle.write(json.dumps(row) + "\n")


def _commit_of(root: Path) -> str:
    done = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    return done.stdout.strip() or "unknown"


if __name__ == "__main__":
    main()
