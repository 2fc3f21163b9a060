"""Which part of the look a pixel seat needs: its estimates' errors and its success when each world's look varies in
one factor only (colour, light, camera, noise), in none (the scene's own look), or in all (the training range).

A diagnosis of the seat that fails on the scene's own look. The factors' ranges are the training range's own, one
at a time; they are registered as extra names of ``image_appearance`` in this process only.

    python benchmarks/pixel_look_factors.py --pixel runs/<name>-seed<N>/policies/<name> --worlds 8

Per look: the mean error of the read-out's blood estimates (the margin included) over every step, and where a
cavity's blood is under 0.15 (nearly empty), and the share of worlds that complete the task beside the scripted
surgeon within the task's 1,500 steps.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from dvrl_marl import policies
from dvrl_marl.envs import endoscope, suction_debris_v8
from dvrl_marl.training import teams

TRAIN = endoscope.APPEARANCES["train"]
NONE = endoscope.Appearance(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
#: one factor of the training range at a time (the others at the scene's own values)
FACTORS = {"scene": None, "colour only": replace(NONE, colour=TRAIN.colour),
           "light only": replace(NONE, light=TRAIN.light, light_degrees=TRAIN.light_degrees),
           "camera only": replace(NONE, camera_mm=TRAIN.camera_mm, camera_degrees=TRAIN.camera_degrees),
           "noise only": replace(NONE, noise=TRAIN.noise), "train": TRAIN}


def play(folder, look: str | None, worlds: int, seed: int) -> dict:
    """The seat beside the scripted surgeon in ``worlds`` worlds for one episode each; its estimates' errors."""
    seat, partner = policies.load(folder), teams.seat("scripted", "grasper")
    start, stop = seat.encoder.fills[1][0], seat.encoder.fills[1][-1] + 1
    options = {} if look is None else {"image_appearance": look}
    env = suction_debris_v8.batched_env(num_envs=worlds, autoreset_mode="disabled", **seat.image_options, **options)
    observations, _ = env.reset(seed=seed)
    seat.reset()
    truth, estimates = [], []
    done, success = np.zeros(worlds, bool), np.zeros(worlds, bool)
    while not done.all():
        seen = observations["suction"]
        truth.append(seen["observation"][~done, start:stop])
        estimates.append(seat.encoder(seat.encoder.image(seen)[~done]))
        observations, _, terminations, truncations, infos = env.step(
            {"suction": seat(seen), "grasper": partner(observations["grasper"]["observation"])})
        success |= ~done & infos["suction"]["is_success"]
        done |= terminations["suction"] | truncations["suction"]
    truth, error = np.concatenate(truth), np.concatenate(estimates) - np.concatenate(truth)
    near_empty = truth < 0.15
    return {"success_rate": float(success.mean()), "mean_error": float(error.mean()),
            "near_empty_mean_error": float(error[near_empty].mean()) if near_empty.any() else None}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pixel", required=True, help="a pixel seat's policy folder (image.fills)")
    parser.add_argument("--worlds", type=int, default=8)
    parser.add_argument("--looks", nargs="+", choices=list(FACTORS), default=list(FACTORS))
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    for name, appearance in FACTORS.items():
        if appearance is not None and name not in endoscope.APPEARANCES:
            endoscope.APPEARANCES[name] = appearance  # (this process only: a diagnosis's ranges)
    rows = []
    for name in args.looks:
        row = {"look": name, "worlds": args.worlds, **play(args.pixel, None if name == "scene" else name, args.worlds,
                                                           teams.EVAL_SEED)}
        rows.append(row)
        print(json.dumps(row), flush=True)
    if args.json:
        args.json.write_text(json.dumps({"pixel": str(args.pixel), "rows": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
