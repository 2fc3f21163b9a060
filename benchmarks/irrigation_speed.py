"""The batched step's speed with irrigation on (``preset="irrigation"``: the signed valve, clots, saline, spills)
against the same setting without it (``preset="benchmark"``), side by side in one run.

Target (issue 78): >= 0.8x at N = 4,096 worlds on one core. Uniformly random actions (the valve irrigates on a
quarter of the steps, sucks on half), resets included; the two settings alternate, measurement by measurement, in
fresh processes pinned to one core (``taskset``), and the ratio is the median of the pairs' ratios, so that a busy
machine slows both alike.

    python benchmarks/irrigation_speed.py [--worlds 4096] [--repeats 5] [--json benchmarks/results/<file>.jsonl]
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import provenance  # noqa: E402

MEASURE = """
import sys, time
import numpy as np
from dvrl_marl.envs import suction_debris
preset, worlds = sys.argv[1], int(sys.argv[2])
env = suction_debris.batched_env(num_envs=worlds, preset=preset)
env.reset(seed=0)
steps = max(20, 200000 // worlds)
actions = np.random.default_rng(0).uniform(-1, 1, (steps, 2, worlds, 4))
env.step({agent: actions[0, k] for k, agent in enumerate(env.possible_agents)})  # (first-call costs apart)
start = time.perf_counter()
for i in range(steps):
    env.step({agent: actions[i, k] for k, agent in enumerate(env.possible_agents)})
print(steps * worlds / (time.perf_counter() - start))
"""


def measure(preset: str, worlds: int, cpu: int | None) -> float:
    command = [sys.executable, "-c", MEASURE, preset, str(worlds)]
    if cpu is not None and shutil.which("taskset"):
        command = ["taskset", "-c", str(cpu), *command]
    done = subprocess.run(command, capture_output=True, text=True, check=True)
    return float(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worlds", type=int, default=4096)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--cpu", type=int, default=0, help="the core to pin to (-1: none)")
    parser.add_argument("--json", help="append the figures to this JSON-lines file")
    args = parser.parse_args()
    if args.worlds < 1 or args.repeats < 1:
        parser.error("--worlds and --repeats must be at least 1")
    cpu = None if args.cpu < 0 else args.cpu
    rates = {"irrigation": [], "benchmark": []}
    for _ in range(args.repeats):
        for preset in rates:
            rates[preset].append(measure(preset, args.worlds, cpu))
    ratios = [a / b for a, b in zip(rates["irrigation"], rates["benchmark"])]
    figures = {preset: statistics.median(values) for preset, values in rates.items()}
    ratio = statistics.median(ratios)
    print(f"N = {args.worlds:,}, one core, medians of {args.repeats}: irrigation {figures['irrigation']:,.0f} "
          f"env-steps/s, benchmark {figures['benchmark']:,.0f}; ratio {ratio:.2f}x "
          f"(pairs {min(ratios):.2f}-{max(ratios):.2f}; target >= 0.8x)")
    if args.json:
        record = {"benchmark": "irrigation_speed", "command": "python benchmarks/irrigation_speed.py "
                  + " ".join(sys.argv[1:]), **provenance.code_state(), "worlds": args.worlds,
                  "repeats": args.repeats, "irrigation_steps_s": figures["irrigation"],
                  "benchmark_steps_s": figures["benchmark"], "ratio": ratio, "ratios": ratios}
        with open(args.json, "a") as out:
            out.write(json.dumps(record) + "\n")


if __name__ == "__main__":
    main()
