"""The JAX trainer's env-steps/s here against the TorchRL trainer of another checkout, side by side in one run.

Each run is a fresh process training for ``--steps`` env steps from scratch, the runs alternating (``--repeats``
times each) so that a busy machine slows both alike; a run's figure is the trainer's own env-steps/s over its
training (collection and updates, no validation: each run validates only at its end, after its figure is taken).

- the checkout (``--against``, e.g. a worktree of commit 36a42a0, the issue's "today", whose ``train`` ran TorchRL's
  trainer): ``python -m dvrl_marl.cli train`` on its configuration of record (``baselines/configs/suction_debris_mappo.toml`` there), as it stands
  (``torch_threads = 1``: the issue's "today") or with ``--record-threads`` (0: every core);
- this checkout: ``benchmarks/device_training.py``'s run with the options given after ``--`` (the configuration of
  record, or a large-batch one: ``--worlds 1024 --epochs 1 --minibatches 16``).

    git worktree add /tmp/at-36a42a0 36a42a0
    python benchmarks/trainer_versus_commit.py --against /tmp/at-36a42a0 --steps 1048576 --repeats 3 -- \\
        --worlds 1024 --epochs 1 --minibatches 16 --learning-rate 0.0003
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]


def record_rate(checkout: Path, steps: int, threads: int | None) -> float:
    """The checkout's trainer of record for ``steps`` steps: the last env-steps/s it printed before validating."""
    config = (checkout / "baselines" / "configs" / "suction_debris_mappo.toml").read_text()
    if threads is not None:
        config, count = re.subn(r"(?m)^torch_threads\s*=.*$", f"torch_threads = {threads}", config)
        if count != 1:
            raise SystemExit(f"{checkout}: its configuration of record names no torch_threads")
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "suction_debris_mappo.toml"
        path.write_text(config)
        done = subprocess.run([sys.executable, "-m", "dvrl_marl.cli", "train", str(path), "--seed", "1", "--steps",
                               str(steps), "--out", str(Path(folder) / "run")], cwd=checkout, capture_output=True,
                              text=True, env={**os.environ, "PYTHONPATH": str(checkout)})
    rates = re.findall(r"([\d,]+) steps/s", done.stderr)
    if done.returncode != 0 or not rates:
        raise SystemExit(f"{checkout}: the trainer of record failed (exit {done.returncode}):\n{done.stderr[-2000:]}")
    return float(rates[-1].replace(",", ""))


def device_rate(steps: int, options: list) -> float:
    """This checkout's JAX trainer for ``steps`` steps (no validation before the last): its env-steps/s."""
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "row.jsonl"
        done = subprocess.run([sys.executable, str(HERE / "benchmarks" / "device_training.py"), "--device", "cpu",
                               "--eval-every", str(steps), "--total-steps", str(steps), "--seconds", "0",
                               "--test-episodes", "0", "--json", str(out), *options],
                              cwd=HERE, capture_output=True, text=True)
        if done.returncode != 0:
            raise SystemExit(f"the JAX trainer failed (exit {done.returncode}):\n{done.stderr[-2000:]}")
        return float(json.loads(out.read_text().splitlines()[-1])["env_steps_per_s"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--against", type=Path, required=True, help="a checkout of the project (a git worktree)")
    parser.add_argument("--steps", type=int, default=1_048_576)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--record-threads", type=int, default=None,
                        help="the trainer of record's torch_threads (default: its configuration's own, 1)")
    parser.add_argument("options", nargs="*", help="benchmarks/device_training.py's options, after --")
    args = parser.parse_args()
    rates = {"record": [], "device": []}
    for _ in range(args.repeats):
        rates["record"].append(record_rate(args.against, args.steps, args.record_threads))
        rates["device"].append(device_rate(args.steps, args.options))
    record, device = statistics.median(rates["record"]), statistics.median(rates["device"])
    print(json.dumps({"what": "trainer_versus_commit", "against": str(args.against), "steps": args.steps,
                      "record_threads": args.record_threads,
                      "device_options": args.options, "record_env_steps_per_s": rates["record"],
                      "device_env_steps_per_s": rates["device"], "median_ratio": device / record}))
    print(f"trainer of record at {args.against}: {record:,.0f} env-steps/s; JAX trainer {' '.join(args.options)}: "
          f"{device:,.0f}; {device / record:.2f}x (medians of {args.repeats})")


if __name__ == "__main__":
    main()
