"""Write docs/results.md, and the tables of docs/policies.md, from the records alone.

    python docs/build_results.py            # rewrite
    python docs/build_results.py --check    # exit 1 if a page is stale

Every figure on these pages is read from a record (a JSON file under baselines/ or benchmarks/results/); every table
says which record, the command that wrote it and the commit it was made at. A record that is missing, or a table
that finds no rows in its record, stops the generator: a page never goes empty without a word. Where a record does
not carry its command or commit (the older ones), :data:`MADE_BY` says them, here and nowhere else.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS_PAGE = ROOT / "docs" / "results.md"
POLICIES_PAGE = ROOT / "docs" / "policies.md"

#: The command and commit of the records that do not say them themselves (the commit: the one that wrote the record).
MADE_BY = {
    "baselines/policies/reach-lnd/policy.json": ("dvrl-marl evaluate reach-lnd --episodes 50", "cf2ebaf"),
    "baselines/policies/reach-suction-irrigation/policy.json": (
        "dvrl-marl evaluate reach-suction-irrigation --episodes 50 --tool suction_irrigation", "cf2ebaf"),
    "baselines/policies/pick-lnd/policy.json": ("dvrl-marl evaluate pick-lnd --episodes 50", "cf2ebaf"),
    "baselines/policies/pick-lnd-scratch/policy.json": ("dvrl-marl evaluate pick-lnd-scratch --episodes 50", "e6805a2"),
    "baselines/results/partner_zoo_v8.json": (
        "python benchmarks/partner_zoo.py --episodes 100 --json baselines/results/partner_zoo_v8.json", "789969e"),
    "baselines/results/partner_zoo_yielding.json": (
        "python benchmarks/partner_zoo.py --seats suction --suction marl-suction-yielding --episodes 100 --json "
        "baselines/results/partner_zoo_yielding.json", "4f237ee"),
    "baselines/results/reference_team/cross_play.json": (
        "dvrl-marl evaluate-team --suction benchmark-suction scripted person-like --grasper benchmark-grasper scripted "
        "person-like --preset benchmark --episodes 100 --json baselines/results/reference_team/cross_play.json",
        "66992d7"),
    "baselines/results/bleeding_field_v8.json": (
        "python benchmarks/bleeding_field.py --episodes 100 --out baselines/results/bleeding_field_v8.json", "17c9108"),
    "baselines/results/bleeding_field_sweeping.json": (
        'python benchmarks/bleeding_field.py --episodes 100 --teams "keep-clear scripted team" "sweeping scripted '
        'team" "learned bleeding team" --out baselines/results/bleeding_field_sweeping.json', "4b29644"),
    "baselines/results/pixel_seat_stereo_v8.json": (None, "22b9a81"),
}


class MissingRecord(RuntimeError):
    """A record a table reads is missing, or holds none of the rows the table shows."""


def _read(path: str):
    file = ROOT / path
    if not file.is_file():
        raise MissingRecord(f"{path}: no such record (a table of the results reads it)")
    if path.endswith(".jsonl"):
        return [json.loads(line) for line in file.read_text().splitlines() if line.strip()]
    return json.loads(file.read_text())


@dataclass
class Table:
    """One table: its rows (lists of cells) under ``header``, and each record it read with the record's command and
    commit."""

    header: list[str]
    rows: list[list[str]] = field(default_factory=list)
    sources: list[tuple[str, str, str]] = field(default_factory=list)

    def source(self, path: str, command: str | None = None, commit: str | None = None) -> None:
        made = MADE_BY.get(path, (None, None))
        command, commit = command or made[0], commit or made[1]
        if not command or not commit:
            raise MissingRecord(f"{path}: the record says neither its command nor its commit, and MADE_BY lacks them")
        if (path, command, commit) not in self.sources:
            self.sources.append((path, command, commit))

    def sources_of_rows(self, path: str, rows: list[dict]) -> None:
        """A record whose rows each name their command and commit: one line per command and commit."""
        for row in rows:
            self.source(path, row["command"], row["commit"])

    def markdown(self, name: str) -> list[str]:
        if not self.rows:
            raise MissingRecord(f"table {name!r}: no rows in {[path for path, _, _ in self.sources]}")
        lines = ["| " + " | ".join(self.header) + " |", "|" + "---|" * len(self.header)]
        lines += ["| " + " | ".join(row) + " |" for row in self.rows]
        lines.append("")
        for path, command, commit in self.sources:
            made = command if command.startswith("from ") else f"by `{command}`"
            lines.append(f"Record `{path}`, made {made} at {commit}.  ")
        lines[-1] = lines[-1].rstrip()
        return lines


def _percent(value) -> str:
    return f"{100 * float(value):.0f} %"


def _share(value) -> str:
    return "-" if value is None else f"{float(value):.2f}"


def _count(value) -> str:
    return "-" if value is None else f"{float(value):,.0f}"


# --- the tables -------------------------------------------------------------------------------------------------
def single_arm() -> Table:
    table = Table(["policy", "env", "success", "episodes", "mean final distance"])
    for name, env in (("reach-lnd", "`PSMReach-v1`"), ("reach-suction-irrigation", '`PSMReach-v1`, `tool="suction_irrigation"`'),
                      ("pick-lnd", "`PSMPick-v1`"), ("pick-lnd-scratch", "`PSMPick-v1`")):
        path = f"baselines/policies/{name}/policy.json"
        evaluation = _read(path)["evaluation"]
        table.rows.append([f"`{name}`", env, _percent(evaluation["success_rate"]), str(evaluation["episodes"]),
                           f"{1000 * evaluation['mean_final_distance']:.1f} mm"])
        table.source(path, evaluation.get("command"))
    return table


def pick_without_demonstrations() -> Table:
    path = "baselines/results/pick_lnd_ppo_scratch_held_out.json"
    record = _read(path)
    table = Table(["seed", "success", "held-out episodes", "mean final distance", "training steps", "training minutes"])
    for seed in record["seeds"]:
        table.rows.append([str(seed["seed"]), _percent(seed["success_rate"]), str(seed["episodes"]),
                           f"{1000 * seed['mean_final_distance']:.1f} mm", _count(seed["training_steps"]),
                           f"{seed['training_wall_seconds'] / 60:.0f}"])
    table.source(path, record.get("command"), record.get("commit"))
    return table


def teams() -> Table:
    path = "baselines/results/collaborative_teams_v8.json"
    record = _read(path)
    names = {"scripted team": "the scripted experts",
             "pipeline scripted_team": "the pipeline of scripted stages (`scripted_team.toml`)",
             "pipeline learned_team": "the pipeline of learned Reach and Pick policies (`learned_team.toml`)"}
    table = Table(["team", "success", "mean steps", "blood removed", "contact steps"])
    for label, result in record["teams"].items():
        table.rows.append([names.get(label, label), _percent(result["success_rate"]), _count(result["mean_steps"]),
                           f"{result['mean_blood_removed_ml']:.2f} ml", f"{result['mean_contacts']:.2f}"])
    table.source(path, record.get("command"), record["code"]["commit"])
    return table


def _zoo(path: str, seats: tuple[str, ...]) -> Table:
    record = _read(path)
    rows = record["rows"]
    table = Table(["seat", "partner", "learned: success", "contact steps", "scripted: success", "contact steps",
                   "median steps (learned)"])
    for seat in seats:
        learned = [row for row in rows if row["seat"] == seat and row["player"] != "scripted"]
        scripted = {row["partner"]: row for row in rows if row["seat"] == seat and row["player"] == "scripted"}
        for index, row in enumerate(learned):
            other = scripted.get(row["partner"], {})
            table.rows.append([f"{seat} (`{row['player']}`)" if index == 0 else "", row["partner"],
                               _share(row["success_rate"]), f"{row['mean_contact_steps']:.1f}",
                               _share(other.get("success_rate")),
                               "-" if not other else f"{other['mean_contact_steps']:.1f}",
                               _count(row["median_steps_to_completion"])])
    table.source(path)
    return table


def partner_zoo() -> Table:
    return _zoo("baselines/results/partner_zoo_v8.json", ("suction", "grasper"))


def yielding_zoo() -> Table:
    return _zoo("baselines/results/partner_zoo_yielding.json", ("suction",))


def benchmark_cells() -> Table:
    import importlib.util

    spec = importlib.util.spec_from_file_location("marl_benchmark", ROOT / "benchmarks" / "marl_benchmark.py")
    marl_benchmark = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(marl_benchmark)
    path = "baselines/results/benchmark/table.json"
    scene = marl_benchmark.current_scene()
    table = Table(["library", "algorithm", "level", "seeds", "IQM success, mean action [95 % CI]", "IQM, sampled"])
    for row in _read(path)["rows"]:
        if row["task"] != scene:
            continue
        low, high = row["ci95"]
        table.rows.append([row["library"], row["algorithm"].upper(), row["level"], str(row["seeds"]),
                           f"{row['iqm_success']:.2f} [{low:.2f}, {high:.2f}]", _share(row["iqm_success_sampled"])])
    table.source(path, "from the runs' records (`baselines/results/benchmark/*_seed*.json`, each naming its command "
                       "and machine) by `python benchmarks/marl_benchmark.py table`",
                 "each run's commit (named by the records from 2026-12-01 on)")
    return table


def cross_play() -> Table:
    path = "baselines/results/reference_team/cross_play.json"
    table = Table(["suction", "grasper", "success", "debris delivered (of 3)", "median steps", "contact steps"])
    for row in _read(path):
        table.rows.append([row["suction"], row["grasper"], _share(row["success_rate"]),
                           f"{row['mean_debris_delivered']:.2f}", _count(row["median_steps_to_completion"]),
                           f"{row['mean_contact_steps']:.1f}"])
    table.source(path)
    return table


def bleeding_field() -> Table:
    table = Table(["variant", "team", "success", "blood left", "median steps", "contact steps"])
    seen = set()
    for path in ("baselines/results/bleeding_field_sweeping.json", "baselines/results/bleeding_field_v8.json"):
        for row in _read(path):
            if (row["variant"], row["team"]) in seen:  # (the keep-clear team in both records: the newer one's)
                continue
            seen.add((row["variant"], row["team"]))
            table.rows.append([row["variant"], row["team"], _percent(row["success_rate"]),
                               f"{row['mean_blood_left_ml']:.2f} ml", _count(row["median_steps_to_completion"]),
                               f"{row['mean_contact_steps']:.2f}"])
        table.source(path)
    table.rows.sort(key=lambda row: (["no bleeding", "bleeding 0.1 ml/s", "bleeding 0.3 ml/s"].index(row[0])
                                     if row[0] in ("no bleeding", "bleeding 0.1 ml/s", "bleeding 0.3 ml/s") else 9))
    return table


def irrigation_field(path: str = "benchmarks/results/irrigation_field_2026-12-02.json", learned_only: bool = False,
                     speed: bool = True) -> Table:
    record = _read(path)
    table = Table(["team", "success", "median steps", "blood left", "of the start", "clot left", "saline used",
                   "saline wasted", "episodes overflowing", "overflow time", "contact steps"])
    for row in record["rows"]:
        if learned_only and not row["team"].startswith("MAPPO"):
            continue
        table.rows.append([row["team"], _percent(row["success_rate"]), _count(row["median_steps_to_completion"]),
                           f"{row['mean_blood_left_ml']:.2f} ml", _percent(row["mean_blood_left_share"]),
                           f"{row['mean_clot_left_ml']:.2f} ml", f"{row['mean_saline_used_ml']:.2f} ml",
                           f"{row['mean_saline_wasted_ml']:.2f} ml", _percent(row["overflowed_episodes"]),
                           f"{row['mean_overflow_s']:.2f} s", f"{row['mean_contact_steps']:.1f}"])
    learned = record.get("learned")
    if learned:
        low, high = learned["ci95"]
        table.rows.append([f"MAPPO (the compiled trainer), IQM over {learned['seeds']} seeds", f"{learned['iqm_success']:.2f} "
                           f"[{low:.2f}, {high:.2f}]", *["-"] * 9])
    table.source(path, record["command"], record["commit"])
    if not speed:
        return table
    path = "benchmarks/results/irrigation_speed_2026-12-02.jsonl"
    for row in _read(path):
        table.rows.append([f"the batched step, N = {row['worlds']:,}, one core: irrigation on", "-", "-", "-", "-",
                           "-", "-", "-", "-", "-", f"{row['ratio']:.2f}x the step without it "
                           f"({_count(row['irrigation_steps_s'])} vs {_count(row['benchmark_steps_s'])} steps/s)"])
        table.source(path, row["command"], row["commit"])
    return table


def irrigation_training(path: str = "benchmarks/results/irrigation_training_2026-12-02.jsonl") -> Table:
    table = Table(["seed", "validation success (last)", "steps to 0.9 validation", "seconds to it", "env-steps/s"])
    for row in _read(path):
        table.rows.append([str(row["seed"]), _share(row["validation_success"]), _count(row["steps_to_target"]),
                           _count(row["seconds_to_target"]), _count(row["env_steps_per_s"])])
        table.source(path, row["command"].replace(f"seed{row['seed']} --seed {row['seed']}", "seedN --seed N"),
                     row["commit"])
    return table


def _learned_irrigation(variant: str, record: str):
    """The tables of one configuration's five irrigation runs: their teams on the level (``irrigation_field_<variant>``)
    and their training (``irrigation_training_<variant>``), from ``benchmarks/results/irrigation_*_<record>.json(l)``."""
    def field() -> Table:
        return irrigation_field(f"benchmarks/results/irrigation_field_{record}.json", learned_only=True, speed=False)

    def training() -> Table:
        return irrigation_training(f"benchmarks/results/irrigation_training_{record}.jsonl")

    field.__name__, training.__name__ = f"irrigation_field_{variant}", f"irrigation_training_{variant}"
    return field, training


irrigation_field_frugal, irrigation_training_frugal = _learned_irrigation("frugal", "waste_2026-12-02")
irrigation_field_frugal_quarter, irrigation_training_frugal_quarter = _learned_irrigation(
    "frugal_quarter", "waste_quarter_2026-12-02")
irrigation_field_entropy, irrigation_training_entropy = _learned_irrigation("entropy", "entropy_2026-12-02")
irrigation_field_entropy_frugal, irrigation_training_entropy_frugal = _learned_irrigation(
    "entropy_frugal", "entropy_frugal_2026-12-02")
irrigation_field_entropy_frugal_to98, irrigation_training_entropy_frugal_to98 = _learned_irrigation(
    "entropy_frugal_to98", "entropy_frugal_to98_2026-12-02")

#: The irrigation level's learning configurations, each with its records' suffix (benchmarks/results/irrigation_*_<suffix>).
#: (the configuration as the table names it, its records' suffix): runs stopped at 0.9 validation unless said.
IRRIGATION_CONFIGURATIONS = (("`suction_debris_mappo_irrigation`", "2026-12-02"),
                             ("`suction_debris_mappo_irrigation_frugal`", "waste_2026-12-02"),
                             ("`suction_debris_mappo_irrigation_frugal_quarter`", "waste_quarter_2026-12-02"),
                             ("`suction_debris_mappo_irrigation_entropy`", "entropy_2026-12-02"),
                             ("`suction_debris_mappo_irrigation_entropy_frugal`", "entropy_frugal_2026-12-02"),
                             ("`suction_debris_mappo_irrigation_entropy_frugal`, to 0.98 validation",
                              "entropy_frugal_to98_2026-12-02"))


def _team_outcome(row: dict) -> str:
    """A team's row of an irrigation record in brief: its run, success, median steps, saline and contact steps."""
    return (f"{row['team'].removeprefix('MAPPO team (').rstrip(')')}: {_percent(row['success_rate'])}, "
            f"{_count(row['median_steps_to_completion'])} steps, {row['mean_saline_used_ml']:.2f} ml, "
            f"{row['mean_contact_steps']:.1f} contact steps")


def irrigation_configurations() -> Table:
    """Issue 78's learning target, configuration by configuration: the IQM over five seeds, and which teams went
    beyond the script (less saline and fewer steps than the scripted irrigating team, on the same episodes)."""
    table = Table(["configuration", "seeds to 0.9 validation", "IQM success [95 % CI]", "best seed by success",
                   "teams with less saline and fewer steps than the script"])
    for config, suffix in IRRIGATION_CONFIGURATIONS:
        path = f"benchmarks/results/irrigation_field_{suffix}.json"
        record = _read(path)
        script = next(row for row in record["rows"] if row["team"] == "scripted irrigating team")
        learned = [row for row in record["rows"] if row["team"].startswith("MAPPO")]
        best = max(learned, key=lambda row: row["success_rate"])
        beyond = [row for row in learned if row["success_rate"] > 0
                  and row["mean_saline_used_ml"] < script["mean_saline_used_ml"]
                  and row["median_steps_to_completion"] < script["median_steps_to_completion"]]
        training = f"benchmarks/results/irrigation_training_{suffix}.jsonl"
        reached = sum(bool(row["reached_target"]) for row in _read(training))
        low, high = record["learned"]["ci95"]
        table.rows.append([config, f"{reached} of {len(learned)}",
                           f"{record['learned']['iqm_success']:.2f} [{low:.2f}, {high:.2f}]", _team_outcome(best),
                           "; ".join(_team_outcome(row) for row in beyond) or "none"])
        table.source(path, record["command"], record["commit"])
    script_text = _team_outcome({**script, "team": "the script"})
    table.rows.append(["(scripted irrigating team)", "-", "-", script_text, "-"])
    return table


def irrigation_zoo() -> Table:
    path = "benchmarks/results/partner_zoo_irrigation_2026-12-02.json"
    record = _read(path)
    table = Table(["the suction seat (it irrigates)", "the grasper seat", "success", "median steps", "contact steps"])
    for row in record["rows"]:
        table.rows.append([row["partner"], row["player"], _percent(row["success_rate"]),
                           _count(row["median_steps_to_completion"]), f"{row['mean_contact_steps']:.1f}"])
    table.source(path, record["command"], record["commit"])
    return table


def pixel_seat() -> Table:
    path = "baselines/results/pixel_seat_stereo_v8.json"
    record = _read(path)
    looks = {None: "`marl-suction-yielding` (no image)", "train": "pixels, training looks",
             "scene": "pixels, the scene's own look", "held_out": "pixels, held-out looks"}
    cells: dict = {}
    for row in record["rows"]:
        failed = [str(world) for world, success in enumerate(row["success"]) if not success]
        cells.setdefault(row["partner"], {})[row["look"]] = (
            f"{row['success_rate']:.2f}, {row['mean_contact_steps']:.1f}"
            + (f" (fails {', '.join(failed)})" if failed else ""))
    table = Table(["partner", *looks.values()])
    order = ["scripted", "pipeline", "person", "hesitant", "late", "shaky", "slow", "in-the-way"]
    for partner, by_look in sorted(cells.items(), key=lambda item: order.index(item[0]) if item[0] in order else 99):
        table.rows.append([{"in-the-way": "surgeons in its way"}.get(partner, partner),
                           *(by_look.get(look, "-") for look in looks)])
    for command in record["commands"]:
        table.source(path, command.replace("<the seat>", "<the seat's run folder>"), record["code"].split(" ")[0]
                     + " (the seat's training) to " + MADE_BY[path][1] + " (the evaluations)")
    return table


def pixel_seat_without_reset() -> Table:
    path = "baselines/results/pixel_seat_without_reset_v8.json"
    table = Table(["the seat", "second episodes completed", "seconds"])
    for row in _read(path)["rows"]:
        table.rows.append([f"`{row['policy']}`, " + ("a new episode seen where its tip jumps" if row["new_episodes_seen"]
                                                     else "as it was: no new episode seen"),
                           f"{row['second_episodes_completed']} of {row['worlds']}", f"{row['seconds']:.0f}"])
        table.source(path, row["command"], row["code"]["commit"]
                     + (" (with " + ", ".join(row["code"]["modified"]) + " changed)" if row["code"]["modified"] else ""))
    return table


def bad_input_round() -> Table:
    path = "baselines/results/bad_input_round_4.json"
    record = _read(path)
    table = Table(["kind of case", "cases"])
    table.rows = [[kind, str(count)] for kind, count in record["kinds"].items()]
    table.rows.append([f"**all** (taken {record['taken']}, refused by name {record['refused']})",
                       f"**{record['cases']}: {record['defect']} defects**"])
    table.source(path, record["command"], record["code"]["commit"])
    return table


def jax_env_scale() -> Table:
    path = "benchmarks/results/jax_env_cpu_2026-12-01.jsonl"
    table = Table(["worlds", "steps", "finite", "the same for the same key", "worlds compared with numpy",
                   "largest difference", "state bytes a world (float32)", "one step's bytes a world (XLA, at N)",
                   "a million worlds' step", "env-steps/s", "compile and first run (s)"])
    rows = _read(path)[-1:]  # (the latest run: the code as it is; the record keeps the earlier ones)
    for row in rows:
        float32 = row.get("state_bytes_per_world_float32")
        step = "-" if "step_bytes_per_world" not in row else \
            f"{row['step_bytes_per_world']:,.0f} (N = {_count(row['memory_worlds'])})"
        table.rows.append([_count(row["worlds"]), _count(row["steps"]), "yes" if row["finite"] else "**no**",
                           "yes" if row["same_for_the_same_key"] else "**no**", str(row["worlds_compared"]),
                           f"{row['max_difference_from_numpy']:.1e}",
                           str(row["state_bytes_per_world"]) + ("" if float32 is None else f" ({float32})"), step,
                           "-" if "million_worlds_step_gb" not in row else f"{row['million_worlds_step_gb']:.1f} GB",
                           _count(row["env_steps_per_s"]), f"{row['compile_and_first_run_seconds']:.0f}"])
        table.source(path, row["command"], row["code"]["commit"]
                     + (" (with " + ", ".join(row["code"]["modified"]) + " changed)" if row["code"]["modified"] else ""))
    return table


def speed_side_by_side() -> Table:
    path = "benchmarks/results/versus_commit_2026-12-02_one_world.jsonl"
    table = Table(["form", "setting", "checkout", "scene's version", "steps/s (median)", "its steps/s over here's"])
    rows = _read(path)
    for row in rows:
        here = row["checkout"] == "here"
        checkout = f"here ({row['commit']})" if here else row["commit"]
        table.rows.append([row["form"], row["setting"], checkout, row["scene"].rsplit("_", 1)[-1], _count(row["steps_per_s"]),
                           "-" if row["versus_here"] is None else f"{row['versus_here']:.2f}"])
    if rows:
        code = rows[0]["code"]
        table.source(path, rows[0]["command"], code["commit"]
                     + (" (with " + ", ".join(code["modified"]) + " changed)" if code["modified"] else ""))
    return table


def dvrk_conformance() -> Table:
    table = Table(["dVRK", "arm", "policy", "episodes done", "steps (median)", "loop period: median / p99 / max",
                   "tracking error once settled", "stale-measurement hold after the last measurement"])
    for path, what in (("benchmarks/results/dvrk_conformance_2026-12-01.json", ""),
                       ("benchmarks/results/dvrk_conformance_pick_2026-12-01.json", " (the object modelled by the env)"),
                       ("benchmarks/results/dvrk_conformance_scene_2026-12-01.json",
                        " (the rest of the scene modelled, the scripted suction beside it)")):
        record = _read(path)
        steps = [row["success_step"] for row in record["rows"] if row["success"]]
        stale = record["stale_hold"]
        table.rows.append([record["dvrk_version"], "PSM1, LND, kinematic simulation", f"`{record['policy']}`{what}",
                           f"**{record['successes']} of {record['episodes']}**",
                           "-" if not steps else f"{float(np.median(steps)):.0f}",
                           f"{record['period_ms_median_all']:.1f} / {record['period_ms_p99_all']:.1f} / "
                           f"{record['period_ms_max_all']:.1f} ms ({_count(record['periods'])} commands)",
                           f"{record['largest_tracking_error_mm']:.2f} mm (worst episode)",
                           "-" if stale is None else f"{stale['hold_after_last_measurement_ms']:.0f} ms"])
        table.source(path, record["command"].split(" --system")[0] + " --system ... (the dVRK's build)",
                     record["code"]["commit"])
    return table


def endoscope_speed() -> Table:
    table = Table(["machine", "what", "size", "worlds", "GL contexts", "frames/s", "x the bare renderer", "record",
                   "commit"])
    for path, machine in (("benchmarks/results/endoscope_stereo_cpu_2026-11-30.jsonl", "2-core CPU"),
                          ("benchmarks/results/device_h200_endoscope_2026-11-29.jsonl", "NVIDIA H200")):
        rows = [row for row in _read(path) if "frames_per_second" in row
                and not row["what"].startswith("batched env step + image observations (layers")]
        if machine == "NVIDIA H200":  # the renderer of record there (fc6387e's tiles), and its bare renderer
            rows = [row for row in rows if row["commit"] == "fc6387e"]
        for row in rows:
            table.rows.append([machine, row["what"], str(row["size"]), _count(row["worlds"]),
                               str(row.get("contexts", 1)), _count(row["frames_per_second"]),
                               "-" if "versus_bare" not in row else f"{row['versus_bare']:.2f}",
                               f"`{Path(path).name}`", row["commit"]])
        table.sources_of_rows(path, rows)
    return table


def trainer_to_target() -> Table:
    table = Table(["machine", "seed", "worlds", "validation at the target", "held-out test", "seconds from the start",
                   "env-steps/s", "record", "commit"])
    for path, machine in (("benchmarks/results/jax_trainer_cpu_2026-11-28.jsonl", "2-core CPU"),
                          ("benchmarks/results/device_h200_jax_trainer_2026-11-28.jsonl", "NVIDIA H200")):
        rows = [row for row in _read(path) if row["what"] == "jax_trainer"]
        for row in rows:
            table.rows.append([machine, str(row["seed"]), _count(row["worlds"]), _share(row["validation_success"]),
                               _share(row.get("test_success")), f"{row['seconds_from_process_start']:.0f}",
                               _count(row["env_steps_per_s"]), f"`{Path(path).name}`", row["commit"]])
        table.sources_of_rows(path, rows)
    return table


#: The results page: (section title, what it shows, the table). One table per capability.
SECTIONS = (
    ("Single-arm policies", "The shipped Reach and Pick policies on the paper's tasks, by their mean action, "
     "held-out seeds (from 1,000,000).", single_arm),
    ("PSM Pick without demonstrations", "`pick_lnd_ppo_scratch.toml` (PPO through the env's learning options), three "
     "seeds, each on 100 held-out episodes; seed 0 ships as `pick-lnd-scratch`.", pick_without_demonstrations),
    ("Teams of the collaborative scene", "The scripted experts and the pipelines that compose the single-arm "
     "policies into the collaborative task (`suction_debris_v8`, default preset), 50 seeded episodes.", teams),
    ("Deployable seats beside partners they never met", "`marl-suction` and `marl-grasper` beside the held-out "
     "partner zoo, against the scripted seat in the same place; 100 test episodes per row, a person's 6,000-step "
     "horizon, the default preset.", partner_zoo),
    ("The yielding suction", "`marl-suction-yielding` beside every partner kind, the surgeons in its way "
     "(`in-the-way`) among them, against the scripted suction; 100 episodes per row.", yielding_zoo),
    ("The benchmark", "Both arms learnt from scratch on `suction_debris_v8` with `preset=\"benchmark\"`, per cell the "
     "interquartile mean over seeds of the success on 100 held-out test episodes; the whole table, its plot and "
     "each run's figures: [benchmark](benchmark.md).", benchmark_cells),
    ("The benchmark's reference team beside other partners", "`benchmark-suction` and `benchmark-grasper` with the "
     "scripted and person-like seats, the benchmark's scene and 1,500-step limit, 100 held-out episodes each.",
     cross_play),
    ("The bleeding field", "Teams on the field that bleeds (`bleeding_ml_s`), 100 held-out episodes per row, the "
     "task's 1,500 steps, by the policies' mean action.", bleeding_field),
    ("The irrigation level", "Teams on `preset=\"irrigation\"` (half of each cavity's blood clotted; the "
     "Suction & Irrigation valve signed), 100 held-out episodes per row, the level's 2,500 steps, with the figures "
     "CRESSim reports for its irrigation agents: blood left (ml, and as a share of the start), clot left, saline used "
     "and wasted (irrigated anywhere but into a cavity), the episodes in which a cavity overflowed and the time it "
     "did. The last row: the step's cost, side by side (`benchmarks/irrigation_speed.py`).", irrigation_field),
    ("Learning the irrigation level", "The compiled MAPPO trainer from scratch on the level "
     "(`suction_debris_mappo_irrigation.toml`), five seeds on this 2-core CPU machine, each stopped at 0.9 validation "
     "success by the mean action (or at 40M steps); the test figures of their teams are in the table above.",
     irrigation_training),
    ("Learning the irrigation level with a cost on wasted saline", "The same from scratch with `waste_penalty = 0.5` "
     "(`suction_debris_mappo_irrigation_frugal.toml`: each ml of saline irrigated into no cavity costs every agent "
     "0.5), five seeds, each stopped at 0.9 validation or at its first validation after 660 s; run at 45c5111, where "
     "the level's preset carried the cost. Its teams on the level's 100 held-out episodes (the scripted teams: the "
     "table above; the shipped `marl-*-irrigation` are seed 3):",
     irrigation_field_frugal),
    ("Training with a cost on wasted saline", "The runs above: validation success by the mean action.",
     irrigation_training_frugal),
    ("Learning the irrigation level with a lighter cost on wasted saline", "The same with half the cost, "
     "`waste_penalty = 0.25` (`suction_debris_mappo_irrigation_frugal_quarter.toml`), five seeds, each stopped at 0.9 "
     "validation or at its first validation after 660 s. Its teams on the level's 100 held-out episodes:",
     irrigation_field_frugal_quarter),
    ("Training with the lighter cost", "The runs above: validation success by the mean action.",
     irrigation_training_frugal_quarter),
    ("Learning the irrigation level with an entropy bonus", "The level's own configuration with PPO's entropy bonus "
     "(`[ppo] entropy_coef = 0.01`: `suction_debris_mappo_irrigation_entropy.toml`), no cost on saline, five seeds, "
     "each stopped at 0.9 validation or at its first validation after 660 s. Its teams on the level's 100 held-out "
     "episodes:", irrigation_field_entropy),
    ("Training with the entropy bonus", "The runs above: validation success by the mean action.",
     irrigation_training_entropy),
    ("Learning the irrigation level with the entropy bonus and a light cost on wasted saline", "Both together "
     "(`suction_debris_mappo_irrigation_entropy_frugal.toml`: `entropy_coef = 0.01`, `waste_penalty = 0.25`), five "
     "seeds, each stopped at 0.9 validation or at its first validation after 660 s. Its teams on the level's 100 "
     "held-out episodes:", irrigation_field_entropy_frugal),
    ("Training with the entropy bonus and the light cost", "The runs above: validation success by the mean action.",
     irrigation_training_entropy_frugal),
    ("Trained on to 0.98 validation", "The same configuration, five seeds, each stopped at 0.98 validation or at its "
     "first validation after 600 s rather than at 0.9 (`--stop-at 0.98 --max-seconds 600`): the policies exported "
     "are those last validated. Its teams on the level's 100 held-out episodes:", irrigation_field_entropy_frugal_to98),
    ("Training on to 0.98 validation", "The runs above: validation success by the mean action.",
     irrigation_training_entropy_frugal_to98),
    ("The irrigation level's learning configurations side by side", "Each configuration's five seeds on the level's "
     "100 held-out episodes (the tables above), against the target of learning beyond the script: an IQM of at least "
     "0.85 and a team with less saline in fewer steps than the scripted irrigating team. Median steps are over the "
     "episodes a team finished. BenchMARL's MAPPO on the level, three seeds of 15.7M frames each (the benchmark "
     "table's irrigation rows): with the entropy bonus of these configurations (0.01, "
     "`baselines/configs/benchmarl_mappo_irrigation.yaml`) its teams finish every test episode sampling their actions "
     "as in training (IQM 1.00) and few by their mean action (0.00, 0.02, 0.13): their mean valve irrigates (it sucks "
     "only through its noise), and with the suction's valve alone sampled they finish 0.99, 0.96 and 0.96 "
     "(`benchmarks/mean_action_failures.py <run> --sampled suction:tool`). With BenchMARL's MAPPO as this project ships "
     "it (entropy bonus 0.001) the mean action carries more: 0.56, 0.59 and 0.38 (IQM 0.51 [0.38, 0.59]; sampled 0.92), "
     "the failed episodes' suction pressing at a cavity's floor, its valve irrigating or shut, blood left.",
     irrigation_configurations),
    ("The irrigation level beside the partner zoo's suctions", "The zoo's suctions on the irrigation level (the "
     "scripted one, the Reach + Pick pipeline, the measured person and the held-out person-like kinds made from the "
     "scripted suction, all irrigating clotted cavities) beside the scripted surgeon, 100 test episodes each, a "
     "person's 6,000-step horizon (`benchmarks/partner_zoo.py --preset irrigation`).", irrigation_zoo),
    ("The suction seat from the stereo endoscope", "`marl-suction-pixels` by its default call beside every partner "
     "kind, in the looks it trained on, the scene's own and held-out ones, against its teacher with no image; 20 test "
     "episodes per cell, success and contact steps (the worlds that failed).", pixel_seat),
    ("A seat that keeps state per world, never reset", "`marl-suction-pixels` called across episodes without "
     "`reset()`, beside the scripted surgeon: each of 20 worlds plays two episodes; the second ones count.",
     pixel_seat_without_reset),
    ("Bad input", "A round of bad input as a careless user gives it (`benchmarks/bad_input_round.py`, seeded): each "
     "case taken and then well behaved, or refused by a `ValueError` (argparse's exit 2) naming the value; a defect is "
     "any other exception, a traceback, a refusal that changed a world, or NaN out. The device env's cases ran on the "
     "CPU through JAX.", bad_input_round),
    ("The scene in JaxMARL's form, at scale", "`jax.jit(jax.vmap(env.step))` of `suction_debris_v8.jax_env()` inside "
     "one `lax.scan` on this 2-core CPU (beside other work): every observation and reward finite, the run the same "
     "twice from one key, and the compared worlds equal to the numpy env's seeded `seed_of(key)`, step by step. The "
     "state's bytes are one world's `EnvState` (float64; in brackets, were its floats float32); one step's bytes are "
     "XLA's figures for a compiled `jit(vmap(step))` over N worlds (state in and out, actions and temporaries) per "
     "world, and a million worlds scaled from them.",
     jax_env_scale),
    ("A policy on the dVRK's own software", "`benchmarks/dvrk_conformance.py`: `reach-lnd` through the robot seat "
     "(`dvrl_marl.dvrk`) on the dVRK's system program (built from its public sources) with PSM1 in the dVRK's kinematic "
     "simulation, through its socket streamer: seeded episodes of `PSMReach-v1` and `PSMPick-v1` (100 steps at most) and "
     "of the collaborative scene's grasper seat (1,500), the arm taken to each start by the dVRK's `move_cp`; then, for "
     "Reach, the dVRK's process stopped mid-run for the stale-measurement hold. An episode is done when the env's goal "
     "is met (Pick: by its modelled object; the scene: cleared). In "
     "kinematic simulation the arm is where it was commanded, so the tracking error says nothing of a real arm's.",
     dvrk_conformance),
    ("The collaborative step against earlier commits, side by side", "Env-steps per second of this checkout and "
     "earlier ones (`benchmarks/versus_commit.py`: each measurement a fresh process pinned to one core, checkouts "
     "alternating, the median of the repeats, random actions); the parallel env is one world with its resets, N = "
     "4,096 the numpy batched env. 52f9c21 is the commit before one world's moves took their common case in floats "
     "(`suction_debris/lean_move.py`); 36a42a0 the last commit with the scalar-path versions (v7, and v2 before the sliding "
     "rules).", speed_side_by_side),
    ("Images: the endoscope's speed", "Frames per second of image observations (the batched env's step with its "
     "images) against a bare `mujoco.Renderer` drawing one world at a time, in one run each.", endoscope_speed),
    ("Training to the target: the compiled trainer", "`dvrl-marl train suction_debris_mappo_large_batch --trainer jax` "
     "to 0.9 validation success by the mean action, the seconds from the process's start.", trainer_to_target),
)

#: The tables of docs/policies.md, each between ``<!-- generated: NAME -->`` and ``<!-- end: NAME -->``.
POLICY_TABLES = {"teams": teams, "partner_zoo": partner_zoo, "pixel_seat": pixel_seat, "cross_play": cross_play}


def results_page() -> str:
    lines = ["# Results", "",
             "The current figures, one table per capability, each read from its record by `python docs/build_results.py`",
             "(do not edit: change a record, then regenerate). Every record names the command that made it and the",
             "commit it was made at. How each figure was reached, run by run: [history](history.md).", "",
             "## Reproducing a figure", "",
             "- **Evaluations** of a shipped policy or a scripted team are functions of their seeds: the command under",
             "  a table gives its figures again on any machine with the same library versions.",
             "- **Training runs** of the trainers of record (this project's MAPPO on TorchRL, the compiled JAX trainer,",
             "  SB3's DDPG/SAC/TQC + HER and PPO) are deterministic for a seed on one machine with one set of library",
             "  versions and thread settings (for the compiled trainer on a CPU, an otherwise idle machine too: two",
             "  runs of one seed alone gave the same policies bit for bit, a third beside a busy process other ones",
             "  within 2M steps, 2026-12-02): the tests train twice and compare the exported policies bit for bit",
             "  (`tests/test_mappo.py`, `tests/test_jax_mappo.py`, `tests/test_training.py`). Across machines, CPU",
             "  kinds, thread counts (`torch_threads`), library versions or a GPU they are not: the order of floating-",
             "  point sums differs, and a policy that differs in its last bits can take another path through an",
             "  episode. A training figure is therefore given over seeds (the benchmark's IQM and interval), and a",
             "  record names the commit, the tracked files that differed from it and the libraries' versions",
             "  (`benchmarks/provenance.py`; records before 2026-12-01 name their command and machine only: one such",
             "  benchmark seed (3), 0.98 when recorded, gave 0.70 when rerun on a later commit, and 0.92 at 84d0f03 on",
             "  this machine kind: `baselines/results/benchmark_rerun_seed3_2026-12-01.json`).",
             "- **Speed** figures are of the machine they name, measured side by side where they are ratios.",
             ""]
    for title, about, make in SECTIONS:
        lines += [f"## {title}", "", about, "", *make().markdown(make.__name__), ""]
    return "\n".join(lines).rstrip() + "\n"


def policies_page(text: str) -> str:
    """docs/policies.md with each generated table written anew (the prose around them is the page's own)."""
    for name, make in POLICY_TABLES.items():
        pattern = re.compile(rf"(<!-- generated: {name} -->\n).*?(<!-- end: {name} -->)", re.S)
        if not pattern.search(text):
            raise MissingRecord(f"{POLICIES_PAGE.name}: no place for the table {name!r} "
                                f"(<!-- generated: {name} --> ... <!-- end: {name} -->)")
        table = "\n".join(make().markdown(name))
        text = pattern.sub(lambda match: match.group(1) + table + "\n" + match.group(2), text)
    return text


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if a page is not what the records give")
    args = parser.parse_args(argv)
    try:
        pages = {RESULTS_PAGE: results_page(), POLICIES_PAGE: policies_page(POLICIES_PAGE.read_text())}
    except MissingRecord as error:
        print(f"build_results: {error}; no page was written", file=sys.stderr)
        return 2
    stale = [page for page, text in pages.items() if not page.is_file() or page.read_text() != text]
    if args.check:
        for page in stale:
            print(f"{page.relative_to(ROOT)} is not what the records give: python docs/build_results.py", file=sys.stderr)
        return 1 if stale else 0
    for page in stale:
        page.write_text(pages[page])
        print(f"wrote {page.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
