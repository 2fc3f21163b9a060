"""The pages generated from records cannot silently go empty: each holds a row per cell of its records, and says how
many records it aggregates, which must be every record there is (a page regenerated from fewer, or records added
without regenerating it, fails here)."""

import collections
import json
import re
from pathlib import Path

from conftest import load_script

ROOT = Path(__file__).resolve().parents[1]


marl_benchmark = load_script(ROOT / "benchmarks" / "marl_benchmark.py")


def _page_rows(page: Path) -> list[list[str]]:
    lines = [line for line in page.read_text().splitlines() if line.startswith("|")]
    assert len(lines) >= 2, f"{page}: no table"
    return [[cell.strip() for cell in line.strip("|").split("|")] for line in lines[2:]]


def test_the_benchmark_page_holds_a_row_per_cell_of_the_current_scenes_records():
    records = [json.loads(path.read_text()) for path in sorted(marl_benchmark.RESULTS.glob("*_seed*.json"))]
    scene = marl_benchmark.current_scene()
    cells = collections.Counter((marl_benchmark._library_of(r), r["algorithm"].upper(), r["level"])
                                for r in records if marl_benchmark._task_of(r) == scene)
    assert cells, f"no record of the benchmark's scene {scene} in {marl_benchmark.RESULTS}"
    page = marl_benchmark.DOCS_PAGE
    rows = _page_rows(page)
    assert rows, f"{page} has a table without rows: regenerate it (python benchmarks/marl_benchmark.py table)"
    on_page = {(row[0], row[1], row[2]): int(row[3]) for row in rows}
    assert on_page == dict(cells), (f"{page} is not the table of the records: regenerate it "
                                    "(python benchmarks/marl_benchmark.py table)")
    assert marl_benchmark.records_on_page(page) == sum(cells.values())
    assert f"`{scene}`" in page.read_text()
    assert re.search(r"!\[.*\]\(benchmark\.png\)", page.read_text())
    assert (page.with_suffix(".png")).stat().st_size > 30_000  # bars, not empty axes (17.5 kB)


def test_a_regeneration_from_fewer_records_leaves_the_page_as_it_was(tmp_path, capsys):
    page = tmp_path / "benchmark.md"
    page.write_text(marl_benchmark.DOCS_PAGE.read_text())
    before = page.read_text()
    results = tmp_path / "records"
    results.mkdir()
    one = sorted(path for path in marl_benchmark.RESULTS.glob("*_seed*.json")
                 if marl_benchmark._task_of(json.loads(path.read_text())) == marl_benchmark.current_scene())[0]
    (results / one.name).write_text(one.read_text())
    assert marl_benchmark.main(["table", "--results", str(results), "--docs", str(page)]) == 2
    assert "left as it was" in capsys.readouterr().err and page.read_text() == before
    (results / one.name).unlink()
    other = next(marl_benchmark.RESULTS.glob("*_v3_*_seed*.json"))  # an earlier scene's record only
    (results / other.name).write_text(other.read_text())
    assert marl_benchmark.main(["table", "--results", str(results), "--docs", str(page)]) == 2
    assert "no record of the current scene" in capsys.readouterr().err and page.read_text() == before


def test_the_marl_eval_export_is_the_records_in_marl_evals_form():
    """baselines/results/benchmark/marl_eval_<level>.json: regenerated with the table, from the records alone, and in
    the form marl-eval's checks ask (per scene: one task, every algorithm in it, the same number of steps in every
    run, the steps' metrics in the absolute metrics)."""
    records = [json.loads(path.read_text()) for path in sorted(marl_benchmark.RESULTS.glob("*_seed*.json"))]
    exported = marl_benchmark.marl_eval_json(records)
    assert set(marl_benchmark.LEVELS) <= set(exported) <= set(marl_benchmark.RUN_LEVELS)  # (the table's, and any run)
    for level, data in exported.items():
        path = marl_benchmark.RESULTS / marl_benchmark.MARL_EVAL.format(level)
        assert json.loads(path.read_text()) == data, f"{path} is stale: python benchmarks/marl_benchmark.py table"
        for scene, tasks in data.items():
            assert list(tasks) == [level]
            runs = [run for algorithm in tasks[level].values() for run in algorithm.values()]
            assert len({len(run) for run in runs}) == 1, scene
            for run in runs:
                steps = [value for key, value in run.items() if key.startswith("step_")]
                assert all(set(step) == {"step_count", "success_rate"} for step in steps)
                assert set(run["absolute_metrics"]) == {"success_rate"}
    current = exported["default"][marl_benchmark.current_scene()]["default"]
    assert {len(runs) for runs in current.values()} == {5} and "dvrl-marl MAPPO" in current


build_results = load_script(ROOT / "docs" / "build_results.py")


def test_the_results_and_the_policies_tables_are_what_the_records_give():
    assert build_results.main(["--check"]) == 0, "python docs/build_results.py"
    page = build_results.RESULTS_PAGE.read_text()
    assert len(page.splitlines()) <= 600
    for title, _, make in build_results.SECTIONS:  # every table has rows, and names its record, command and commit
        section = page.split(f"## {title}\n", 1)[1].split("\n## ", 1)[0]
        assert section.count("\n| ") >= 2 and "Record `" in section and " at " in section, title


def test_a_missing_record_or_a_table_without_rows_writes_no_page(tmp_path, monkeypatch, capsys):
    page = tmp_path / "results.md"
    page.write_text("the page as it was\n")
    monkeypatch.setattr(build_results, "RESULTS_PAGE", page)
    monkeypatch.setattr(build_results, "POLICIES_PAGE", tmp_path / "policies.md")
    (tmp_path / "policies.md").write_text("no generated tables\n")
    monkeypatch.setattr(build_results, "POLICY_TABLES", {})

    def from_a_lost_record():
        build_results._read("baselines/results/a_lost_record.json")

    def without_rows():
        return build_results.Table(["a", "b"])

    for make in (from_a_lost_record, without_rows):
        monkeypatch.setattr(build_results, "SECTIONS", (("A capability", "What it shows.", make),))
        assert build_results.main([]) == 2
        assert "no page was written" in capsys.readouterr().err
        assert page.read_text() == "the page as it was\n"


def test_the_environments_page_lists_every_task_parameter_with_its_range():
    """The collaborative task's parameter table is generated from SuctionDebrisParams: a row per field, none empty."""
    from dataclasses import fields

    from dvrl_marl.suction_debris.task import SuctionDebrisParams

    page = (ROOT / "docs" / "environments.md").read_text()
    table = page.split("### Parameters", 1)[1].split("\n## ", 1)[0].split("\n### ", 1)[0]
    rows = [line for line in table.splitlines() if line.startswith("| `")]
    assert [row.split("`")[1] for row in rows] == [f.name for f in fields(SuctionDebrisParams)]
    assert all(cell.strip() for row in rows for cell in row.strip("|").split("|"))
    assert "| `clotting_ml_s` | finite number >= 0 | `0.0` |" in table


def test_the_environments_page_lists_each_forms_keywords():
    """The keywords table is generated from the forms' signatures: a row per keyword, each form taking some."""
    import inspect

    from dvrl_marl.envs import suction_debris_v8

    page = (ROOT / "docs" / "environments.md").read_text()
    table = page.split("### Keywords, form by form", 1)[1].split("\n## ", 1)[0]
    rows = [line.strip("|").split("|") for line in table.splitlines() if line.startswith("| `")]
    assert {row[0].strip().strip("`") for row in rows} >= {"reward_type", "preset", "num_envs", "image_size"}
    for column, form in ((2, suction_debris_v8.parallel_env), (3, suction_debris_v8.batched_env),
                         (4, suction_debris_v8.jax_env)):
        taken = {row[0].strip().strip("`") for row in rows if row[column].strip() == "yes"}
        assert taken and taken <= set(inspect.signature(form).parameters)
