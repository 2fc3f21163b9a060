"""A training record from the compiled trainer's run folders: one JSON line per run, for docs/results.md.

Each run folder (``python -m dvrl_marl.training.jax_mappo CONFIG --out FOLDER --seed N ...``) holds ``progress.csv``
(one row per validation, by the mean action) and ``result.json`` (the configuration's name, the seed, the device). A
row gives the run's last validation, the first validation at or above ``--target`` (steps and seconds to it), its
speed, its whole curve and the command that made it (``--command``, with ``{out}`` and ``{seed}`` filled per run).

    python benchmarks/training_record.py runs/a-seed0 runs/a-seed1 --target 0.9 --commit 3df91b3 \\
        --command "python -m dvrl_marl.training.jax_mappo CONFIG --out {out} --seed {seed} --stop-at 0.98" \\
        --out benchmarks/results/irrigation_training_X.jsonl
"""

from __future__ import annotations

import argparse
import csv
import json
import math
from datetime import date
from pathlib import Path

#: What the rows say of the machine unless ``--machine`` says otherwise.
MACHINE = "this project's 2-core CPU machine"


def run_row(run: Path, target: float, command: str, commit: str, machine: str, note: str | None) -> dict:
    """One run folder's row; a ``ValueError`` naming the folder where it is not a finished run."""
    result_path, progress_path = run / "result.json", run / "progress.csv"
    if not result_path.is_file() or not progress_path.is_file():
        raise ValueError(f"{run}: not a finished run of the compiled trainer (result.json and progress.csv needed)")
    result = json.loads(result_path.read_text())
    with progress_path.open(newline="") as file:
        curve = [{key: float(value) for key, value in row.items()} for row in csv.DictReader(file)]
    if not curve:
        raise ValueError(f"{run}: progress.csv has no validation")
    if any(not math.isfinite(value) for row in curve for value in row.values()):
        raise ValueError(f"{run}: progress.csv holds a value that is not finite")
    reached = next((row for row in curve if row["success_rate"] >= target), None)
    last = curve[-1]
    row = {"what": "jax_trainer", "config": result["config"], "device": str(result.get("device", "cpu")).split(":")[0],
           "seed": int(result["seed"]), "commit": commit, "machine": machine, "date": date.today().isoformat(),
           "steps": int(last["steps"]), "validation_success": last["success_rate"], "target": target,
           "reached_target": reached is not None,
           "steps_to_target": None if reached is None else int(reached["steps"]),
           "seconds_to_target": None if reached is None else reached["wall_seconds"],
           "env_steps_per_s": last["env_steps_per_s"],
           "command": command.format(out=run.as_posix(), seed=int(result["seed"])), "curve": curve}
    if note:
        row["configuration"] = note
    return row


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="the compiled trainer's run folders")
    parser.add_argument("--target", type=float, default=0.9, help="the validation success counted as reached")
    parser.add_argument("--command", required=True, help="the training command, {out} and {seed} filled per run")
    parser.add_argument("--commit", required=True, help="the commit the runs were made at")
    parser.add_argument("--machine", default=MACHINE)
    parser.add_argument("--note", default=None, help="what else a reader needs to reproduce the runs")
    parser.add_argument("--out", type=Path, required=True, help="the record to write (.jsonl)")
    args = parser.parse_args(argv)
    if not 0.0 < args.target <= 1.0:
        parser.error(f"--target must be in (0, 1], got {args.target}")
    if "{seed}" not in args.command:
        parser.error("--command must hold {seed} (and may hold {out}): each row names the command of its own run")
    try:
        rows = [run_row(run, args.target, args.command, args.commit, args.machine, args.note) for run in args.runs]
    except (ValueError, KeyError) as error:
        parser.error(str(error))
    args.out.write_text("".join(json.dumps(row) + "\n" for row in rows))
    for row in rows:
        print(f"seed {row['seed']}: last validation {row['validation_success']:.2f} at {row['steps']:,d} steps; "
              f"{args.target} reached: {row['reached_target']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
