"""The collaborative teams on the irrigation level (``preset="irrigation"``: half of each cavity's blood clotted,
the Suction & Irrigation valve signed), with the figures CRESSim reports for its irrigation and suction agents.

    python benchmarks/irrigation_field.py [--episodes 100] [--learned runs/<run> ...]
        [--out benchmarks/results/irrigation_field_<date>.json]

Teams: the scripted irrigating team (``ScriptedSuction`` irrigates where the scene irrigates and a cavity holds a
clot; the scripted surgeon as ever), the learned pipeline team (the shipped Reach and Pick policies composed,
``pipeline/specs/learned_team.toml``: its suck stage irrigates in the same bursts), the scripted team of the level without irrigation (the same suction with
``irrigate=False``: today's plan) and the keep-clear scripted team (the bleeding field's experts, suction only).
Held-out seeds (``teams.EVAL_SEED``), all worlds batched. Prints one row per team: success, median steps, blood left
(ml and share of the start), clot left, saline used and wasted (ml), episodes with an overflow, overflow time, contact
steps. ``--learned``: runs of the compiled MAPPO trainer on the level (``suction_debris_mappo_irrigation.toml``,
one seed each), each run's team (its ``policies/``: the last validated, by their mean action) a row, and over them
the IQM of the success with a 95 % stratified-bootstrap interval (``rliable``, as the benchmark table). ``--out``
writes them as a JSON record with the command and the commit (``docs/build_results.py`` makes the
results page's table from it).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import provenance  # noqa: E402

from dvrl_marl.agents.collaborative import ScriptedSuction  # noqa: E402
from dvrl_marl.envs import suction_debris  # noqa: E402
from dvrl_marl.training import teams  # noqa: E402

LEVEL = "irrigation"


def lineup(scene) -> dict:
    """The teams, each ``{agent: seat}``, made for ``scene`` (their scripts read its layout)."""
    return {
        "scripted irrigating team": teams.seats("scripted", "scripted", env=scene),
        "learned pipeline team": teams.seats("pipeline", "pipeline", env=scene),
        "scripted team, suction only": {"suction": ScriptedSuction(*_scripted_args(scene), irrigate=False),
                                        "grasper": teams.seat("scripted", "grasper", scene)},
        "keep-clear scripted team": teams.seats("keep-clear", "keep-clear", env=scene),
    }


def learned_summary(rows: list[dict], reps: int = 2000) -> dict:
    """The learned runs' test success over seeds: IQM with a 95 % stratified-bootstrap interval (rliable; its
    resampling seeded, as the benchmark table's)."""
    import numpy as np
    from rliable import library as rly
    from rliable import metrics

    np.random.seed(0)
    scores = np.array([[row["success_rate"]] for row in rows])  # (seeds, 1 task)
    point, interval = rly.get_interval_estimates({"x": scores}, lambda s: np.array([metrics.aggregate_iqm(s)]),
                                                 reps=reps)
    return {"seeds": len(rows), "iqm_success": float(point["x"][0]),
            "ci95": [float(interval["x"][0][0]), float(interval["x"][1][0])],
            "seed_success": [row["success_rate"] for row in rows]}


def _scripted_args(scene):
    unwrapped = getattr(scene, "unwrapped", scene)
    return unwrapped.layout(), unwrapped.observation_layout, unwrapped.workspace_range


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--learned", nargs="+", type=Path, default=[],
                        help="run folders of the level's MAPPO runs (each with policies/marl-suction, marl-grasper)")
    parser.add_argument("--out", help="write the figures to this JSON file")
    args = parser.parse_args()
    if args.episodes < 1:
        parser.error(f"--episodes must be at least 1, got {args.episodes}")
    for run in args.learned:
        if not all((run / "policies" / f"marl-{agent}" / "policy.json").is_file() for agent in ("suction", "grasper")):
            parser.error(f"--learned {run}: no policies/marl-suction and policies/marl-grasper there")
    scene = suction_debris.parallel_env(preset=LEVEL)
    teams_ = lineup(scene)
    for run in args.learned:
        teams_[f"MAPPO team ({run.name})"] = teams.seats(str(run / "policies" / "marl-suction"),
                                                         str(run / "policies" / "marl-grasper"), env=scene)
    rows = []
    print(f"{'team':30s} {'success':>8s} {'steps':>6s} {'blood left':>11s} {'share':>6s} {'clot':>5s} "
          f"{'saline':>7s} {'wasted':>7s} {'overflowed':>10s} {'overflow s':>10s} {'contacts':>8s}")
    for team, seats in teams_.items():
        began = time.perf_counter()
        result = teams.evaluate_team_batched(seats, args.episodes, preset=LEVEL)
        wall = time.perf_counter() - began
        median = result["median_steps_to_completion"]
        print(f"{team:30s} {result['success_rate']:8.0%} {median if median is not None else '-':>6} "
              f"{result['mean_blood_left_ml']:8.2f} ml {result['mean_blood_left_share']:6.1%} "
              f"{result['mean_clot_left_ml']:5.2f} {result['mean_saline_used_ml']:7.2f} "
              f"{result['mean_saline_wasted_ml']:7.2f} {result['overflowed_episodes']:10.0%} "
              f"{result['mean_overflow_s']:10.2f} {result['mean_contact_steps']:8.1f}")
        rows.append({"level": LEVEL, "team": team, "wall_s": round(wall, 1),
                     **{k: v for k, v in result.items() if k not in ("success", "steps", "contact_steps",
                                                                    "saline_used_ml")}})
    learned = [row for row in rows if row["team"].startswith("MAPPO team")]
    summary = None
    if learned:
        summary = learned_summary(learned)
        print(f"MAPPO (compiled trainer), {summary['seeds']} seeds: IQM success {summary['iqm_success']:.2f} "
              f"[{summary['ci95'][0]:.2f}, {summary['ci95'][1]:.2f}]")
    if args.out:
        record = {"command": "python benchmarks/" + Path(__file__).name + " " + " ".join(sys.argv[1:]),
                  **provenance.code_state(), "episodes": args.episodes, "rows": rows,
                  **({"learned": summary} if summary else {})}
        Path(args.out).write_text(json.dumps(record, indent=1) + "\n")
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
