"""The device trainer's collectors side by side on a CPU: ``inline`` (the learner steps the worlds between its
updates) against ``process`` (a worker process steps them while the learner updates), on the configuration of record
with ``--worlds`` worlds, ``--rollouts`` rollouts each, no validation but the last; alternated ``--repeats`` times.

    python benchmarks/collector_speed.py --rollouts 60 --repeats 2
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]


def seconds(collector: str, worlds: int, rollouts: int) -> float:
    from dvrl_marl.training import device_mappo
    from dvrl_marl.training.mappo_config import load_config

    config = load_config(HERE / "baselines" / "configs" / "suction_debris_mappo.toml")
    config = replace(config, num_envs=worlds, rollout_steps=32, torch_threads=0, evaluate_with_noise=False,
                     eval_every=10**12, total_steps=12_000_000)
    with tempfile.TemporaryDirectory() as folder:
        began = time.perf_counter()
        device_mappo.train(config, 1, Path(folder) / "run", collector=collector, validate_beside=False,
                           total_steps=worlds * 32 * rollouts, log=lambda *_: None)
        return time.perf_counter() - began


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worlds", type=int, default=256)
    parser.add_argument("--rollouts", type=int, default=60)
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    times = {"inline": [], "process": []}
    for _ in range(args.repeats):
        for collector in times:
            times[collector].append(seconds(collector, args.worlds, args.rollouts))
    steps = args.worlds * 32 * args.rollouts
    print(f"{os.cpu_count()} CPU cores, {args.worlds} worlds, {args.rollouts} rollouts ({steps:,d} steps), "
          "a final validation included")
    for collector, values in times.items():
        best = min(values)
        print(f"  {collector:8s} best {best:6.1f} s  ({steps / best:,.0f} env-steps/s; all: "
              f"{', '.join(f'{v:.1f}' for v in values)})")
    print(f"  process / inline: {min(times['inline']) / min(times['process']):.2f}x")


if __name__ == "__main__":
    main()
