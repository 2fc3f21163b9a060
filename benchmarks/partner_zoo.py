"""Learned seats beside partners they never met: the held-out person-like zoo, against the scripted seat.

For each seat, the learned policy (its default call: the mean action, as a robot is driven) and the scripted
expert play beside the same partners: the scripted one, the Reach + Pick pipeline, the measured person
(:data:`dvrl_marl.agents.partners.PERSON`), each held-out kind (:data:`~dvrl_marl.agents.partners.HELD_OUT`:
late, slow, shaky, hesitant; drawn with ``ZOO_SEED``, never used in training) and, beside the suction, the held-out
surgeons that rest in its way (:data:`dvrl_marl.agents.in_the_way.HELD_OUT`). Test seeds (``teams.EVAL_SEED`` on),
``suction_debris_v8`` with a person's 6,000-step horizon. ``--preset irrigation``: the irrigation level, where the
zoo's suctions (the scripted expert and the person-like kinds made from it, the pipeline) irrigate clotted cavities;
no learned seat reads its observation yet, so ``--grasper scripted --seats grasper`` plays the scripted surgeon
beside them.

    python benchmarks/partner_zoo.py [--episodes 100] [--suction marl-suction] [--grasper marl-grasper]
                                     [--seats suction grasper] [--partners scripted in-the-way ...]
                                     [--noise] [--preset irrigation] [--json baselines/results/partner_zoo.json]

Prints, per seat and partner: success, median steps to success, instrument-contact steps, the seat's tip path (mm)
and its mean absolute action change between steps (smoothness), learned beside scripted. The gap is the figure
(the learned seat within 2 points of the scripted seat's success beside each partner).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from dvrl_marl.agents.partners import HELD_OUT, zoo_partner
from dvrl_marl.envs import suction_debris_v8
from dvrl_marl.training import teams

PARTNERS = ("scripted", "pipeline", "person", *sorted(HELD_OUT), "in-the-way")
#: Kinds that fill one seat only: the obstructing surgeons (dvrl_marl.agents.in_the_way) sit in the LND seat.
SEAT_OF = {"in-the-way": "grasper"}


def evaluate(seat: str, player: str, partner: str, episodes: int, noise: bool, **env_kwargs) -> dict:
    """One row: ``player`` in ``seat`` beside ``partner`` (``env_kwargs``: the evaluation env's options, such as
    ``image_appearance`` for a seat that sees the endoscope, or a ``preset``)."""
    other = other_seat(seat)
    scene = suction_debris_v8.parallel_env(**{k: v for k, v in env_kwargs.items() if k == "preset"})
    team = {seat: teams.seat(player, seat, scene,
                             noise_from=teams.EVAL_SEED if noise and player != "scripted" else None),
            other: partner_seat(partner, other, scene)}
    result = teams.evaluate_team_batched(team, episodes, max_cycles=6000, **env_kwargs)
    return {"seat": seat, "player": player, "partner": partner, "episodes": episodes,
            "success_rate": result["success_rate"], "median_steps_to_completion": result["median_steps_to_completion"],
            "mean_contact_steps": result["mean_contact_steps"], "tip_path_mm": result["mean_tip_path_mm"][seat],
            "action_change": result["mean_action_change"][seat],
            # per episode (test seed), in order: where the contact steps and the failures fall
            "success": result["success"], "contact_steps": result["contact_steps"]}


def partner_seat(partner: str, seat: str, scene=None):
    """The partner kind ``partner`` (one of :data:`PARTNERS`) filling ``seat`` of ``scene`` (the default scene's
    parallel env if None: the seats read its layout)."""
    scene = scene or suction_debris_v8.parallel_env()
    if partner in ("scripted", "pipeline"):
        return teams.seat(partner, seat, scene)
    return zoo_partner(partner, seat, scene)


def other_seat(seat: str) -> str:
    return "grasper" if seat == "suction" else "suction"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--episodes", type=int, default=100, help="test seeds per row")
    parser.add_argument("--suction", default="marl-suction", help="the learned suction seat")
    parser.add_argument("--grasper", default="marl-grasper", help="the learned grasper seat")
    parser.add_argument("--noise", action="store_true", help="learned seats act with their exploration noise")
    parser.add_argument("--seats", nargs="+", choices=("suction", "grasper"), default=["suction", "grasper"],
                        help="the seats to measure")
    parser.add_argument("--partners", nargs="+", choices=PARTNERS, default=list(PARTNERS), help="the partner kinds")
    parser.add_argument("--preset", choices=sorted(suction_debris_v8.PRESETS), default="default",
                        help="the scene's preset (irrigation: the zoo's suctions irrigate)")
    parser.add_argument("--json", type=Path, help="write the rows here")
    args = parser.parse_args()
    rows = []
    print(f"{'seat':8s} {'partner':10s} {'player':14s} {'success':>8s} {'median steps':>13s} {'contacts':>9s} "
          f"{'tip path mm':>12s} {'action change':>14s}")
    for seat in args.seats:
        learned = args.suction if seat == "suction" else args.grasper
        for partner in args.partners:
            if partner in SEAT_OF and SEAT_OF[partner] != other_seat(seat):
                continue
            for player in dict.fromkeys((learned, "scripted")):  # (once, where the learned seat is the script)
                row = evaluate(seat, player, partner, args.episodes, args.noise, preset=args.preset)
                rows.append(row)
                median = row["median_steps_to_completion"]
                print(f"{seat:8s} {partner:10s} {player:14s} {row['success_rate']:8.2f} "
                      f"{'-' if median is None else f'{median:.0f}':>13s} {row['mean_contact_steps']:9.1f} "
                      f"{row['tip_path_mm']:12.0f} {row['action_change']:14.3f}", flush=True)
    if args.json:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        import provenance

        record = {"command": "python benchmarks/partner_zoo.py " + " ".join(sys.argv[1:]), **provenance.code_state(),
                  "noise": args.noise, "preset": args.preset, "rows": rows}
        args.json.write_text(json.dumps(record, indent=2) + "\n")


if __name__ == "__main__":
    main()
