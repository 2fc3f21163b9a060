"""benchmarks/marl_benchmark.py: a run writes one record and never overwrites one; the table aggregates the records
(IQM with a bootstrap interval, frames to the target) into its JSON and plot."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import load_script

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "marl_benchmark.py"


marl_benchmark = load_script(SCRIPT)


def _shipped_options() -> dict:
    """The shipped task file's options (read from its YAML: needs PyYAML, as the script's runs do)."""
    pytest.importorskip("yaml")
    return marl_benchmark._task_options("easy")


def _shipped_task() -> str:
    """The scene the shipped task files run: the version and its scene options (tool_speed, the grasp's)."""
    return marl_benchmark._scene_of(_shipped_options())


def _record(results, library, level, seed, success, reached, task=None, options=None, diverged=None, settings=None):
    options = options or ({"task": task} if task else _shipped_options())
    task = marl_benchmark._scene_of(options)
    curve = [{"frames": 1000 * (i + 1), "wall_seconds": 10.0 * (i + 1), "success_rate": s}
             for i, s in enumerate([0.2, success])]
    out = {"library": library, "algorithm": "mappo", "level": level, "seed": seed, "frames": 2000,
           "wall_seconds": 20.0, "final": {"success_rate": success, **({"diverged": diverged} if diverged else {})},
           "curve": curve,
           "frames_to_target": 2000 if reached else None, "wall_to_target": 20.0 if reached else None,
           "env_options": options, "machine": {"cpus": 2, "python": "3.11.7"},
           **({"benchmarl_settings": settings} if settings else {})}
    path = marl_benchmark._record_path(results, library, "mappo", level, seed, options, settings)
    path.write_text(json.dumps(out))


def test_table_aggregates_iqm_intervals_and_frames_to_target(tmp_path):
    pytest.importorskip("rliable")
    for seed, success in enumerate([1.0, 0.95, 0.9, 0.2, 1.0]):
        _record(tmp_path, "dvrl-marl", "default", seed, success, success >= 0.9)
    for seed in range(3):
        _record(tmp_path, "benchmarl", "easy", seed, 0.0, False)
        _record(tmp_path, "benchmarl", "easy", seed, 1.0, True, task="suction_debris_v2")  # another scene's cell
    assert marl_benchmark.main(["table", "--results", str(tmp_path)]) == 0
    table = json.loads((tmp_path / "table.json").read_text())
    rows = {(r["library"], r["level"]): r for r in table["rows"] if r["task"] == _shipped_task()}
    assert [r["iqm_success"] for r in table["rows"] if r["task"] == "suction_debris_v2"] == [1.0]
    ours = rows["dvrl-marl", "default"]
    assert ours["machine"] == "2 cores, Python 3.11.7"
    assert ours["seeds"] == 5 and ours["reached_target"] == "4/5" and ours["frames_to_target"] == 2000
    assert ours["iqm_success"] == pytest.approx(0.95)  # the middle three of five: 0.9, 0.95, 1.0
    assert ours["ci95"][0] <= ours["iqm_success"] <= ours["ci95"][1]
    assert rows["benchmarl", "easy"]["iqm_success"] == 0.0 and rows["benchmarl", "easy"]["frames_to_target"] is None
    assert (tmp_path / "benchmark.png").stat().st_size > 1000


def test_a_diverged_seed_counts_as_one_that_did_not_learn_and_says_so(tmp_path, capsys):
    pytest.importorskip("rliable")
    for seed, success in enumerate([1.0, 1.0, 1.0, 1.0]):
        _record(tmp_path, "benchmarl", "default", seed, success, True)
    _record(tmp_path, "benchmarl", "default", 4, 0.0, False, diverged="at 2,600,000 frames: NaN actions")
    assert marl_benchmark.main(["table", "--results", str(tmp_path)]) == 0
    row = json.loads((tmp_path / "table.json").read_text())["rows"][0]
    assert row["seeds"] == 5 and row["seed_diverged"] == [False] * 4 + [True]
    assert "0.00 (diverged)" in capsys.readouterr().out


def test_runs_on_different_scenes_are_never_pooled(tmp_path):
    """The same version with and without a scene option (tool_speed) is two scenes: two cells, two record names."""
    pytest.importorskip("rliable")
    for seed in range(3):
        _record(tmp_path, "benchmarl", "default", seed, 0.0, False, options={"task": "suction_debris_v3"})
        _record(tmp_path, "benchmarl", "default", seed, 0.5, False,
                options={"task": "suction_debris_v3", "tool_speed": 0.1})
    assert sorted(p.name for p in tmp_path.glob("*seed0.json")) == [
        "benchmarl_mappo_suction_debris_v3_default_seed0.json",
        "benchmarl_mappo_suction_debris_v3_tool_speed0.1_default_seed0.json"]
    assert marl_benchmark.main(["table", "--results", str(tmp_path)]) == 0
    table = json.loads((tmp_path / "table.json").read_text())
    assert {row["task"]: row["iqm_success"] for row in table["rows"]} == {
        "suction_debris_v3": 0.0, "suction_debris_v3_tool_speed0.1": 0.5}


def test_the_grasp_options_name_their_own_scene():
    """A switch jaw and the hold are scene options: in the scene's name (a flag only when on), never pooled."""
    base = {"task": "suction_debris_v5", "tool_speed": 0.1}
    assert marl_benchmark._scene_of(base) == "suction_debris_v5_tool_speed0.1"
    assert marl_benchmark._scene_of({**base, "jaw_command": "switch", "hold_until_handoff": True}) == (
        "suction_debris_v5_tool_speed0.1_jaw_command-switch_hold_until_handoff")
    assert marl_benchmark._scene_of({**base, "jaw_command": "proportional", "hold_until_handoff": False}) == (
        "suction_debris_v5_tool_speed0.1_jaw_command-proportional")
    from dvrl_marl.suction_debris.presets import with_preset

    shipped = with_preset(_shipped_options())
    assert shipped["jaw_command"] == "switch" and shipped["hold_until_handoff"] is True


def test_a_run_never_overwrites_a_record(tmp_path, capsys):
    _record(tmp_path, "dvrl-marl", "easy", 0, 1.0, True)
    before = (tmp_path / f"dvrl-marl_mappo_{_shipped_task()}_easy_seed0.json").read_text()
    code = marl_benchmark.main(["run", "--library", "dvrl-marl", "--algorithm", "mappo", "--level", "easy",
                                "--seed", "0", "--results", str(tmp_path)])
    assert code == 2 and "exists" in capsys.readouterr().err
    assert (tmp_path / f"dvrl-marl_mappo_{_shipped_task()}_easy_seed0.json").read_text() == before


def test_bad_flags_are_named():
    result = subprocess.run([sys.executable, str(SCRIPT), "run", "--library", "dvrl-marl", "--algorithm", "mappo",
                             "--level", "easy", "--seed", "0", "--frames", "0"], capture_output=True, text=True)
    assert result.returncode == 2 and "--frames" in result.stderr


@pytest.mark.extended
@pytest.mark.parametrize("library", ["dvrl-marl", "benchmarl", "rllib"])
def test_a_tiny_run_writes_its_record(tmp_path, library):
    pytest.importorskip("torchrl")
    if library == "benchmarl":
        pytest.importorskip("benchmarl")
    elif library == "rllib":
        pytest.importorskip("ray.rllib", reason='RLlib\'s row needs the extra: pip install "dvrl-marl[rllib]"')
    else:
        pytest.importorskip("yaml")
    flags = {"benchmarl": ["--frames", "1200", "--worlds", "4", "--batch-frames", "600", "--eval-every", "600"],
             "dvrl-marl": ["--frames", "2048", "--eval-every", "8192", "--eval-episodes", "2"],
             "rllib": ["--frames", "1024", "--batch-frames", "1024", "--eval-every", "1024", "--eval-episodes",
                       "1"]}[library]
    test_episodes = 1 if library in ("rllib", "dvrl-marl") else 3  # (an untrained team's episodes run to the end)
    algorithm = "ippo" if library == "rllib" else "mappo"
    env = {**os.environ, "MUJOCO_GL": "egl"}
    result = subprocess.run([sys.executable, str(SCRIPT), "run", "--library", library, "--algorithm", algorithm,
                             "--level", "easy", "--seed", "0", "--test-episodes", str(test_episodes),
                             "--results", str(tmp_path),
                             *flags], capture_output=True, text=True, env=env, timeout=900)
    assert result.returncode == 0, result.stderr[-3000:]
    records = list(tmp_path.glob("*_seed0.json"))
    assert len(records) == 1
    record = json.loads(records[0].read_text())
    if library == "benchmarl":  # what it changed in BenchMARL's defaults, named in the record and its file name
        assert record["benchmarl_settings"]["algorithm"] == {"share_param_critic": False, "lmbda": 0.95,
                                                              "entropy_coef": 0.001}
        assert record["benchmarl_settings"]["model"] == {"num_cells": [64, 64]}
        assert record["benchmarl_settings"]["experiment"]["clip_grad_val"] == 1.0
        label = marl_benchmark._settings_label(record["benchmarl_settings"])
        assert records[0].name == f"benchmarl_mappo_{_shipped_task()}_easy_{label}_seed0.json"
    elif library == "rllib":  # the recipe's --guided PPO settings, named in the record and its file name
        recipe_settings = marl_benchmark._rllib_recipe().benchmark_ppo_settings()
        assert record["rllib_settings"]["ppo"]["lr"] == recipe_settings["lr"]
        assert record["rllib_settings"]["ppo"]["vf_clip_param"] == "inf"  # JSON-safe
        label = marl_benchmark._settings_label(record["rllib_settings"])
        assert records[0].name == f"rllib_ippo_{_shipped_task()}_easy_{label}_seed0.json"
        assert [point["frames"] for point in record["curve"]] == [1024]  # validated every --eval-every
        assert (tmp_path / "runs" / records[0].stem / "checkpoint").is_dir()
    else:
        assert records[0].name == f"dvrl-marl_mappo_{_shipped_task()}_easy_seed0.json"
    assert record["final"]["episodes"] == test_episodes and 0.0 <= record["final"]["success_rate"] <= 1.0
    assert 0.0 <= record["final"]["success_rate_sampled"] <= 1.0
    assert record["env_options"]["start_level"] == "easy" and record["frames"] >= 1024
    assert record["command"].startswith("python benchmarks/marl_benchmark.py run")
    if library == "rllib":
        return  # (mean_action_failures.py reads a BenchMARL run's folder)
    # the run's folder holds what benchmarks/mean_action_failures.py reads: its failures, classified
    failures = load_script(ROOT / "benchmarks" / "mean_action_failures.py")
    success, classes, examples = failures.classify(tmp_path / "runs" / records[0].stem, 3, 10)
    assert 0.0 <= success <= 1.0 and sum(classes.values()) == round(3 * (1.0 - success))
    assert set(examples) == set(classes)
    # ... and played on a changed scene (--option): the same policies, another rule
    again, changed, _ = failures.classify(tmp_path / "runs" / records[0].stem, 3, 10, {"blocked_moves": "climb"})
    assert 0.0 <= again <= 1.0 and sum(changed.values()) == round(3 * (1.0 - again))
    with pytest.raises(SystemExit):
        failures.main([str(tmp_path / "runs" / records[0].stem), "--episodes", "2", "--option", "tool_speed=fast"])
    if library == "benchmarl":  # ... and with a seat's slot sampled as in training (--sampled), named when unknown
        sampled, classes, _ = failures.classify(tmp_path / "runs" / records[0].stem, 3, 10, None,
                                                (("suction", "tool"),))
        assert 0.0 <= sampled <= 1.0 and sum(classes.values()) == round(3 * (1.0 - sampled))
        # only the named slot is drawn: the suction's valve varies from call to call, the rest is the mean action
        from dvrl_marl.envs import suction_debris_v8
        from dvrl_marl.suction_debris.layout import MOVE, TOOL

        options, mean_act = failures.team_of(tmp_path / "runs" / records[0].stem)
        _, sampled_act = failures.team_of(tmp_path / "runs" / records[0].stem, (("suction", "tool"),))
        observations, _ = suction_debris_v8.batched_env(num_envs=4, **options).reset(seed=0)
        mean, first, second = mean_act(observations), sampled_act(observations), sampled_act(observations)
        np.testing.assert_array_equal(first["suction"][:, MOVE], mean["suction"][:, MOVE])
        np.testing.assert_array_equal(first["grasper"], mean["grasper"])
        assert not np.array_equal(first["suction"][:, TOOL], second["suction"][:, TOOL])
        with pytest.raises(SystemExit):
            failures.main([str(tmp_path / "runs" / records[0].stem), "--episodes", "2", "--sampled", "suction:valve"])


def test_a_cells_interval_does_not_depend_on_the_other_cells():
    pytest.importorskip("rliable")
    records = [{"library": "dvrl-marl", "algorithm": "mappo", "level": "default", "frames": 2000, "wall_seconds": 20.0,
                "final": {"success_rate": s}, "frames_to_target": None, "wall_to_target": None,
                "env_options": {"task": "suction_debris_v3"}, "machine": {"cpus": 2, "python": "3.11.7"}}
               for s in (0.05, 0.52, 0.21, 0.93, 0.34, 0.77, 0.12, 0.66, 0.48, 0.29)]  # distinct: a resample shows
    other = [{**record, "library": "benchmarl", "final": {"success_rate": 1.0 - record["final"]["success_rate"]}}
             for record in records]
    alone = marl_benchmark.aggregate(records, reps=200)
    beside = [row for row in marl_benchmark.aggregate(other + records, reps=200) if row["library"] == "dvrl-marl"]
    assert alone[0]["ci95"] == beside[0]["ci95"]


def test_runs_of_different_benchmarl_settings_are_kept_apart(tmp_path):
    """Records of BenchMARL's own settings and of other settings are separate cells and separate files."""
    pytest.importorskip("rliable")
    options = _shipped_options()
    ours = {"algorithm": {"share_param_critic": False}, "model": {}, "experiment": {"lr": 0.0001}}
    label = marl_benchmark._settings_label(ours)
    assert label.startswith("settings") and marl_benchmark._settings_label({"algorithm": {}, "model": {}}) == ""
    assert marl_benchmark._settings_label({**ours, "model": {"num_cells": [8]}}) != label
    stock = marl_benchmark._record_path(tmp_path, "benchmarl", "mappo", "default", 0, options)
    tuned = marl_benchmark._record_path(tmp_path, "benchmarl", "mappo", "default", 0, options, ours)
    assert stock != tuned and label in tuned.name
    for seed in range(3):
        _record(tmp_path, "benchmarl", "default", seed, 0.0, False)  # BenchMARL's own settings
        _record(tmp_path, "benchmarl", "default", seed, 1.0, True, settings=ours)
    assert len(list(tmp_path.glob("*.json"))) == 6  # none written over another
    rows = {row["library"]: row for row in marl_benchmark.aggregate(
        [json.loads(p.read_text()) for p in sorted(tmp_path.glob("*.json"))], reps=100)}
    assert rows["benchmarl"]["iqm_success"] == 0.0 and rows["benchmarl"]["seeds"] == 3
    assert rows[f"benchmarl ({label})"]["iqm_success"] == 1.0 and rows[f"benchmarl ({label})"]["seeds"] == 3


def test_a_missing_settings_file_is_named(tmp_path):
    pytest.importorskip("benchmarl")
    result = subprocess.run([sys.executable, str(SCRIPT), "run", "--library", "benchmarl", "--algorithm", "mappo",
                             "--level", "easy", "--seed", "0", "--algorithm-file", str(tmp_path / "nope.yaml"),
                             "--results", str(tmp_path)], capture_output=True, text=True)
    assert result.returncode != 0 and "nope.yaml: no such settings file" in result.stderr
    assert not list(tmp_path.glob("*.json"))
