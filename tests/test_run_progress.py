"""A compiled trainer's run (dvrl_marl.training.run_progress): validations beside the learner that are still scoring
when the run stops are stopped, not waited for, and leave no worker behind."""

import multiprocessing
import time

import numpy as np

from dvrl_marl.training.mappo_config import MappoConfig
from dvrl_marl.training.run_progress import Progress, Validations, new_run_folder

TINY = MappoConfig(num_envs=8, eval_episodes=2, env={"preset": "benchmark", "max_cycles": 40})


def test_validations_still_scoring_when_a_run_stops_are_stopped_not_waited_for(tmp_path):
    before = set(multiprocessing.active_children())
    validations = Validations(tmp_path, TINY, 0, beside=True, workers=1)
    validations.pending.append((0, 0.0, tmp_path / "validating" / "0", validations.pool.apply_async(time.sleep, (60,))))
    began = time.perf_counter()
    validations.close()
    assert time.perf_counter() - began < 20.0  # (its worker's start included; the 60 s job was not waited for)
    assert not set(multiprocessing.active_children()) - before  # (no worker left behind)


def test_progress_writes_a_row_per_validation_and_says_when_the_run_stops(tmp_path):
    out = new_run_folder(tmp_path / "run")
    lines = []
    progress = Progress(out, TINY, 0, time.perf_counter(), stop_at=0.5, log=lines.append)
    progress.count(3, 4)
    result = {"success_rate": 0.25, "mean_blood_removed_ml": 10.0, "mean_contact_steps": 1.0}
    assert progress.report(512, 2.0, result) is False
    assert progress.report(1024, 4.0, {**result, "success_rate": 0.5}) is True
    rows = (out / "progress.csv").read_text().splitlines()
    assert rows[0].split(",") == list(Progress.COLUMNS) and len(rows) == 3
    assert rows[1].split(",")[4] == "0.75" and rows[2].split(",")[4] == "0.0"  # (train success since the last row)
    assert len(lines) == 2 and "validation 0.50" in lines[1]


def test_a_training_record_is_made_from_the_run_folders_progress(tmp_path):
    """benchmarks/training_record.py: a run's row says its last validation and when it first reached the target, from
    the folder the trainer wrote; a folder that is not a finished run is refused by name."""
    import json
    from pathlib import Path

    import pytest
    from conftest import load_script

    record = load_script(Path(__file__).resolve().parents[1] / "benchmarks" / "training_record.py")
    out = new_run_folder(tmp_path / "run-seed3")
    progress = Progress(out, TINY, 3, time.perf_counter(), log=lambda line: None)
    result = {"success_rate": 0.25, "mean_blood_removed_ml": 10.0, "mean_contact_steps": 1.0}
    for steps, success in ((512, 0.25), (1024, 0.92), (1536, 0.88)):
        progress.report(steps, steps / 100.0, {**result, "success_rate": success})
    progress.finish(device="cpu:0", backend="jax")
    target = tmp_path / "record.jsonl"
    assert record.main([str(out), "--target", "0.9", "--commit", "abc1234", "--command",
                        "train --out {out} --seed {seed}", "--out", str(target)]) == 0
    (row,) = [json.loads(line) for line in target.read_text().splitlines()]
    assert (row["seed"], row["validation_success"], row["steps"]) == (3, 0.88, 1536)
    assert (row["reached_target"], row["steps_to_target"]) == (True, 1024)
    assert row["seconds_to_target"] == row["curve"][1]["wall_seconds"]  # (the first validation at 0.9 or above)
    assert row["command"] == f"train --out {out.as_posix()} --seed 3" and len(row["curve"]) == 3
    with pytest.raises(SystemExit):
        record.main([str(tmp_path / "nothing"), "--commit", "x", "--command", "{seed}", "--out", str(target)])


def test_an_export_records_the_preset_its_configuration_file_names(tmp_path):
    """A configuration file's ``[env] preset`` is expanded into the scene's options and its name kept, so that the
    policies exported record the scene they learnt on (evaluations make it)."""
    from dvrl_marl import policies
    from dvrl_marl.envs import suction_debris_v8
    from dvrl_marl.training.jax_mappo import actors  # (numpy in, numpy out: no JAX)
    from dvrl_marl.training.mappo_config import load_config, scene_metadata
    from dvrl_marl.training.run_progress import export

    config = tmp_path / "irrigation.toml"
    config.write_text('[run]\nalgorithm = "mappo"\n[env]\npreset = "irrigation"\n[model]\ntool_head = "gaussian"\n')
    loaded = load_config(config)
    assert loaded.env["preset"] == "irrigation" and loaded.env["irrigation_ml_s"] == 1.0
    assert scene_metadata(loaded) == {"preset": "irrigation"}
    default = tmp_path / "default.toml"
    default.write_text('[run]\nalgorithm = "mappo"\n')
    assert scene_metadata(load_config(default)) == {}
    env = suction_debris_v8.batched_env(num_envs=1, **loaded.env)
    width = env.observation_space("suction").shape[0]
    layer = {"weight": np.zeros((4, width), np.float32), "bias": np.zeros(4, np.float32)}
    params = {"actors": [[layer], [layer]], "log_std": np.zeros((2, 4), np.float32)}
    norms = {"observation": {"mean": np.zeros(width), "var": np.ones(width)}}
    folders = export(actors(params, norms, env.possible_agents), loaded, tmp_path / "out", 0, 0, env)
    assert policies.load(folders["suction"]).spec["preset"] == "irrigation"
