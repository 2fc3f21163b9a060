"""What the privileged suction seat reads: its success when parts of its observation are withheld or perturbed.

A seat that sees the endoscope must give its policy what the policy acts on. This measures it for the privileged
suction (``marl-suction``) by its default call: each row replaces part of the observation before the seat reads it
(a constant, zero, noise or a bias on the blood left) and plays the validation seeds beside the training partners
(the scripted surgeon, ``marl-grasper``, the person-like population; the task's 1,500-step limit), the seeds and
partners a pixel seat's DAgger rounds are validated on. ``--partners`` then plays the blind seat (its own tip and
valve, the blood left and the hand-off point; zero for the rest) and the full one beside each partner kind of
``benchmarks/partner_zoo.py`` on test seeds with a person's 6,000-step horizon.

    python benchmarks/privileged_inputs.py [--episodes 32] [--partners scripted pipeline ...] [--zoo-episodes 20]
                                           [--json FILE]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from partner_zoo import PARTNERS, zoo_partner

from dvrl_marl.envs import suction_debris_v8
from dvrl_marl.training import teams

TRAINING_PARTNERS = ["scripted", "marl-grasper", "person-like"]


def _rows(layout: dict, mean: np.ndarray) -> dict:
    """name -> (indices set to ``mean`` or to zero, blood noise, blood bias)."""
    debris = range(layout["debris"].start, layout["debris"].stop)
    flags = {name: [i for i in debris if (i - layout["debris"].start) % 6 == k]
             for k, name in ((3, "visible"), (4, "held"), (5, "delivered"))}
    positions = [i for i in debris if (i - layout["debris"].start) % 6 < 3]
    other = list(range(layout["other_tip"].start, layout["other_tip"].stop))
    kept = set(range(layout["own_tip"].start, layout["own_tool"].stop)) | set(range(layout["blood"].start,
                                                                                    layout["blood"].stop))
    kept |= set(range(layout["handoff"].start, layout["handoff"].stop))
    blind = [i for i in range(len(mean)) if i not in kept]
    return {"everything": ([], "mean", 0.0, 0.0), "the other tip at its mean": (other, "mean", 0.0, 0.0),
            "the pins' positions at their mean": (positions, "mean", 0.0, 0.0),
            "the pins' 'visible' at their mean": (flags["visible"], "mean", 0.0, 0.0),
            "the pins' 'visible' zero": (flags["visible"], "zero", 0.0, 0.0),
            "the pins' 'held' and 'delivered' at their mean": (flags["held"] + flags["delivered"], "mean", 0.0, 0.0),
            "blind: own tip and valve, blood, hand-off; zero else": (blind, "zero", 0.0, 0.0),
            **{f"blind, blood noise {s}": (blind, "zero", s, 0.0) for s in (0.01, 0.02, 0.05)},
            **{f"blind, blood {b:+}": (blind, "zero", 0.0, b) for b in (-0.01, 0.01, 0.03)}}


def _withholding(teacher, indices, how, mean, blood, noise, bias, seed=0):
    rng = np.random.default_rng(seed)

    def act(observation):
        seen = np.array(observation, dtype=np.float64, copy=True)
        seen[:, indices] = mean[indices] if how == "mean" else 0.0
        seen[:, blood] += bias + noise * rng.standard_normal(seen[:, blood].shape)
        return teacher(seen)

    return act


def _observed_mean(teacher, episodes: int = 16) -> np.ndarray:
    """The mean observation of the seat's own episodes beside the training partners (600 steps, seeds from 5)."""
    env = suction_debris_v8.batched_env(num_envs=episodes, autoreset_mode="disabled")
    partner = teams.partner(TRAINING_PARTNERS, "grasper")
    observations, _ = env.reset(seed=5)
    rows = []
    for _ in range(600):
        rows.append(observations["suction"])
        observations, *_ = env.step({"suction": teacher(observations["suction"]),
                                     "grasper": partner(observations["grasper"])})
    return np.concatenate(rows).mean(0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--episodes", type=int, default=32, help="validation seeds per row")
    parser.add_argument("--partners", nargs="*", default=[], choices=PARTNERS,
                        help="then the blind and the full seat beside these partner kinds")
    parser.add_argument("--zoo-episodes", type=int, default=20, help="test seeds per partner row")
    parser.add_argument("--json", type=Path, help="write the rows here")
    args = parser.parse_args()
    layout = suction_debris_v8.parallel_env().observation_layout
    teacher = teams.seat("marl-suction", "suction")
    mean = _observed_mean(teacher)
    blood = slice(layout["blood"].start, layout["blood"].stop)
    rows = []

    def keep(row):
        rows.append(row)
        print(f"{row.get('partner', 'training partners'):18s} {row['withheld']:55s} {row['success_rate']:6.2f} "
              f"{row['mean_contact_steps']:9.1f}", flush=True)
        if args.json:
            args.json.write_text(json.dumps({"episodes": args.episodes, "rows": rows}, indent=2) + "\n")

    print(f"{'partner':18s} {'withheld':55s} {'success':>6s} {'contacts':>9s}")
    specs = _rows(layout, mean)
    for name, (indices, how, noise, bias) in specs.items():
        seat = _withholding(teacher, indices, how, mean, blood, noise, bias)
        result = teams.evaluate_team_batched({"suction": seat, "grasper": teams.partner(TRAINING_PARTNERS, "grasper")},
                                             args.episodes, seed=teams.VALIDATION_SEED)
        keep({"withheld": name, "success_rate": result["success_rate"],
              "mean_contact_steps": result["mean_contact_steps"]})
    indices, how, _, _ = specs["blind: own tip and valve, blood, hand-off; zero else"]
    env = suction_debris_v8.parallel_env()
    for partner in args.partners:
        for name, seat in (("everything", teacher), ("blind", _withholding(teacher, indices, how, mean, blood, 0, 0))):
            filler = (zoo_partner(partner, "grasper", env) if partner not in ("scripted", "pipeline")
                      else teams.seat(partner, "grasper"))
            result = teams.evaluate_team_batched({"suction": seat, "grasper": filler}, args.zoo_episodes,
                                                 max_cycles=6000)
            keep({"partner": partner, "withheld": name, "success_rate": result["success_rate"],
                  "mean_contact_steps": result["mean_contact_steps"]})


if __name__ == "__main__":
    main()
