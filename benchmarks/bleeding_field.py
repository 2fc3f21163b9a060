"""The collaborative teams on suction_debris_v8 without and with a bleeding field.

    python benchmarks/bleeding_field.py [--episodes 100] [--bleeding 0.1 0.3] [--no-plain] [--teams "MAPPO team"]
        [--marl-suction runs/<run>/policies_best/marl-suction] [--marl-team runs/<run>/policies_best]

Teams: the scripted team, the learned pipeline team (learned_team.toml), the keep-clear and the sweeping scripted teams (the
cooperative experts for a bleeding field), the learned bleeding team (marl-suction-bleeding, marl-grasper-bleeding:
the sweeping experts cloned), and, when given, a multi-agent PPO
suction beside the scripted surgeon and a MAPPO team (both seats). Held-out seeds (teams.EVAL_SEED), all worlds
batched. Prints one row per (variant, team) and writes the figures as JSON next to the table when --out is given.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from dvrl_marl.training import teams


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--bleeding", type=float, nargs="+", default=[0.1, 0.3],
                        help="bleeding_ml_s of the bleeding variants")
    parser.add_argument("--marl-suction", help="a multi-agent PPO suction policy folder (trained beside the scripted surgeon)")
    parser.add_argument("--marl-team", help="a folder with marl-suction/ and marl-grasper/ (trained together)")
    parser.add_argument("--out", help="write the figures to this JSON file")
    parser.add_argument("--teams", nargs="+", help="only these teams (their names as printed, e.g. \"MAPPO team\")")
    parser.add_argument("--no-plain", action="store_true", help="leave out the variant without bleeding")
    args = parser.parse_args()
    variants = {} if args.no_plain else {"no bleeding": {}}
    for rate in args.bleeding:
        variants[f"bleeding {rate} ml/s"] = {"bleeding_ml_s": rate}
    lineup = {"scripted team": ("scripted", "scripted"), "learned pipeline team": ("pipeline", "pipeline"),
              "keep-clear scripted team": ("keep-clear", "keep-clear"),
              "sweeping scripted team": ("sweeping", "sweeping"),
              "learned bleeding team": ("marl-suction-bleeding", "marl-grasper-bleeding")}
    if args.marl_suction:
        lineup["MAPPO suction + scripted surgeon"] = (args.marl_suction, "scripted")
    if args.marl_team:
        lineup["MAPPO team"] = (str(Path(args.marl_team) / "marl-suction"), str(Path(args.marl_team) / "marl-grasper"))
    if args.teams:
        unknown = sorted(set(args.teams) - set(lineup))
        if unknown:
            parser.error(f"--teams: unknown {unknown}; the teams are {sorted(lineup)}")
        lineup = {name: seats for name, seats in lineup.items() if name in args.teams}
    rows = []
    print(f"{'variant':28s} {'team':34s} {'success':>8s} {'median steps':>13s} {'blood left':>11s} "
          f"{'debris':>7s} {'contacts':>9s} {'wall s':>7s}")
    for variant, env_kwargs in variants.items():
        for team, (suction, grasper) in lineup.items():
            began = time.perf_counter()
            result = teams.evaluate_team_batched(teams.seats(suction, grasper), args.episodes, **env_kwargs)
            wall = time.perf_counter() - began
            median = result["median_steps_to_completion"]
            print(f"{variant:28s} {team:34s} {result['success_rate']:8.0%} {median if median is not None else '-':>13} "
                  f"{result['mean_blood_left_ml']:11.2f} {result['mean_debris_delivered']:7.2f} "
                  f"{result['mean_contact_steps']:9.2f} {wall:7.1f}", flush=True)
            rows.append({"variant": variant, "team": team, "suction": str(suction), "grasper": str(grasper),
                         **{k: v for k, v in result.items() if k not in ("success", "steps")}})
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
