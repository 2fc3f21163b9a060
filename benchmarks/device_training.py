"""The device trainer's figures: env-steps/s end to end (collection, update, validation) and the wall clock from
process start to a validation success (the mean action, the exported policies), on one device.

The configuration of record (``baselines/configs/suction_debris_mappo.toml``) with ``--worlds`` worlds per batch (its
other settings unchanged: a starting point for a large batch, not a tuned one), stopped at ``--target`` validation
success or after ``--seconds``. One JSON line per run goes to ``--json`` (the device probe reads it).

    python benchmarks/device_training.py --device cpu --worlds 256 --seconds 120
    python benchmarks/device_training.py --device cuda --worlds 16384 --seconds 200 --json out.jsonl
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from dataclasses import replace
from pathlib import Path

STARTED = time.perf_counter()  # (process start, imports included, as the target counts it)

HERE = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--backend", choices=("numpy", "jax"), default=None, help="default: jax on a GPU, else numpy")
    parser.add_argument("--worlds", type=int, default=256)
    parser.add_argument("--rollout", type=int, default=32, help="steps per world per update")
    parser.add_argument("--eval-every", type=int, default=None, help="env steps between validations (default: 8 batches)")
    parser.add_argument("--target", type=float, default=0.9)
    parser.add_argument("--seconds", type=float, default=180.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--json", default=None)
    args = parser.parse_args()

    from dvrl_marl.training import device_mappo
    from dvrl_marl.training.mappo_config import load_config

    config = load_config(HERE / "baselines" / "configs" / "suction_debris_mappo.toml")
    batch = args.worlds * args.rollout
    config = replace(config, num_envs=args.worlds, rollout_steps=args.rollout, torch_threads=0,
                     eval_every=args.eval_every or 8 * batch, total_steps=max(config.total_steps, 1000 * batch))
    with tempfile.TemporaryDirectory() as folder:
        last = device_mappo.train(config, args.seed, Path(folder) / "run", device=args.device, backend=args.backend,
                                  stop_at=args.target, max_seconds=args.seconds)
    row = {"what": "device_trainer", "device": args.device, "worlds": args.worlds, "rollout": args.rollout,
           "seed": args.seed, "steps": last.get("steps"), "validation_success": last.get("success_rate"),
           "env_steps_per_s": last.get("env_steps_per_s"), "reached_target": (last.get("success_rate") or 0.0)
           >= args.target, "seconds_from_process_start": time.perf_counter() - STARTED}
    print(json.dumps(row), flush=True)
    if args.json:
        with open(args.json, "a") as handle:
            handle.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
