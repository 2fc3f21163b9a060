"""Every kind of file and flag the library reads, broken the ways a careless or hostile user breaks them (typos, wrong
types, values out of range, truncated or crafted files): each must be a clear error naming the file (or flag), the
table and the field, and nothing may be written or overwritten."""

from __future__ import annotations

import math
import os
import pickle
import subprocess
import sys
import tomllib
from dataclasses import fields
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import dvrl_marl  # noqa: F401  (registration)
from dvrl_marl.assets import tasks_dir
from dvrl_marl.envs.suction_debris import SuctionDebrisParams
from dvrl_marl.schemas import SingleArmTask
from dvrl_marl.suction_debris.task import task_schema
from dvrl_marl.task import load_task

ROOT = Path(__file__).resolve().parents[1]
FUZZ = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and math.isnan(value):
        return "nan"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + " }"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return repr(value)


def _write_toml(path: Path, tables: dict) -> Path:
    lines = []
    for name, table in tables.items():
        lines.append(f"[{name}]")
        lines += [f"{key} = {_toml_value(value)}" for key, value in table.items()]
    path.write_text("\n".join(lines) + "\n")
    return path


def _files(folder: Path) -> set:
    return {p.relative_to(folder) for p in folder.rglob("*")}


#: Values that no field of a declared schema accepts in place of a number (or a flag): a string that looks like a
#: number, a table, a list of tables.
NOT_A_NUMBER = ["0.5", {"nonsense": 1}, [{"nonsense": 1}]]


def _assert_named(error: ValueError, path: Path, field: str) -> None:
    message = str(error)
    assert str(path) in message, message
    assert field in message, message


# --- task files ---------------------------------------------------------------------------------------------------
def _task_table(name: str) -> dict:
    with (tasks_dir() / f"{name}.toml").open("rb") as handle:
        return tomllib.load(handle)["task"]


@pytest.mark.parametrize("task, loader, schema", [
    ("suction_debris_v8", SuctionDebrisParams.from_task, task_schema()), ("psm_reach", load_task, SingleArmTask),
    ("psm_pick", load_task, SingleArmTask)])
@FUZZ
@given(data=st.data())
def test_a_broken_task_file_names_file_table_and_field(tmp_path, task, loader, schema, data):
    table = _task_table(task)
    numeric = [key for key, value in table.items() if isinstance(value, (int, float)) and not isinstance(value, bool)]
    required = [key for key in numeric if schema.model_fields[key].is_required()]
    kind = data.draw(st.sampled_from(["typo", "wrong type", "negative", "nan", "missing"]))
    key = data.draw(st.sampled_from(sorted(table) if kind == "typo" else required if kind == "missing" else numeric))
    broken = dict(table)
    if kind == "typo":
        broken[key + "_"] = broken.pop(key)
    elif kind == "wrong type":
        broken[key] = data.draw(st.sampled_from(NOT_A_NUMBER))
    elif kind == "negative":  # (every number of a task is a size, a time, a count or a threshold)
        broken[key] = -abs(broken[key]) - 1
    elif kind == "nan":
        broken[key] = math.nan
    else:
        del broken[key]
    path = _write_toml(tmp_path / f"{task}_broken.toml", {"task": broken})
    before = _files(tmp_path)
    with pytest.raises(ValueError) as error:
        loader(path)
    _assert_named(error.value, path, key + "_" if kind == "typo" else key)
    assert "[task]" in str(error.value)
    assert _files(tmp_path) == before


def test_a_misspelt_key_in_a_task_file_no_longer_gives_another_physics(tmp_path):
    table = {**_task_table("suction_debris_v8"), "pins_fal": True}  # (pins_fall, misspelt)
    path = _write_toml(tmp_path / "typo.toml", {"task": table})
    with pytest.raises(ValueError, match=r"\[task\] pins_fal: unknown key"):
        SuctionDebrisParams.from_task(path)
    with pytest.raises(ValueError, match="not valid TOML"):
        (tmp_path / "cut.toml").write_text("[task]\nworkspace_range = ")
        load_task(tmp_path / "cut.toml")


# --- training configurations ----------------------------------------------------------------------------------------
torch = pytest.importorskip("torch")
pytest.importorskip("torchrl")
from dvrl_marl.training import mappo  # noqa: E402
from dvrl_marl.training import clone as clone_training  # noqa: E402
from dvrl_marl.training import runner  # noqa: E402

_MAPPO_NUMBERS = sorted(f.name for f in fields(mappo.MappoConfig)
                        if f.name not in ("name", "env", "surgeon", "initial_tool_logit",
                                          "observation_features", "device", "hidden", "algorithm", "surgeon_seat",
                                          "tool_head", "critic_input", "bc_expert"))


@FUZZ
@given(key=st.sampled_from(_MAPPO_NUMBERS), kind=st.sampled_from(["wrong type", "nan", "negative", "typo"]),
       data=st.data())
def test_a_broken_mappo_configuration_names_file_table_and_field(tmp_path, key, kind, data):
    default = getattr(mappo.MappoConfig(), key)
    table = next((name for name, keys in mappo.TABLE_KEYS.items() if keys and key in keys), "run")
    if kind == "wrong type":
        value = data.draw(st.sampled_from(NOT_A_NUMBER))
    elif kind == "nan":
        value = math.nan
    elif kind == "negative":
        value = -1 if isinstance(default, int) and not isinstance(default, bool) else -0.5
    else:
        value = default if default is not None else 1.0
    if kind in ("nan", "negative") and isinstance(default, bool):
        value = 2  # a flag given a number
    path = _write_toml(tmp_path / "broken.toml", {"run": {"algorithm": "mappo"},
                                                   table: {key + ("x" if kind == "typo" else ""): value}})
    before = _files(tmp_path)
    with pytest.raises(ValueError) as error:
        mappo.load_config(path)
    _assert_named(error.value, path, key)
    assert f"[{table}]" in str(error.value)
    assert _files(tmp_path) == before


@pytest.mark.parametrize("tables, field", [
    ({"run": {"env_id": "dvrl_marl/PSMReach-v1", "algorithm": "ddpg", "total_timesteps": "100"}}, "total_timesteps"),
    ({"run": {"env_id": "dvrl_marl/PSMReach-v1", "algorithm": "ddpg", "total_timesteps": 100, "eval_evry": 5}},
     "eval_evry"),
    ({"run": {"env_id": "dvrl_marl/PSMReach-v1", "algorithm": "ddpg", "total_timesteps": 100,
              "action_noise": -0.2}}, "action_noise"),
    ({"run": {"env_id": "dvrl_marl/PSMReach-v1", "algorithm": "ddpg", "total_timesteps": 100}, "hre": {}}, "[hre]"),
    ({"run": {"env_id": "dvrl_marl/PSMReach-v1", "algorithm": "dpg", "total_timesteps": 100}}, "algorithm"),
])
def test_a_broken_goal_env_configuration_is_named(tmp_path, tables, field):
    path = _write_toml(tmp_path / "goal.toml", tables)
    with pytest.raises(ValueError) as error:
        runner.load_config(path)
    _assert_named(error.value, path, field)


@pytest.mark.parametrize("tables, field", [
    ({"run": {"algorithm": "bc"}}, "dataset"),
    ({"run": {"algorithm": "bc", "dataset": "dvrl_marl/x-v1"}, "bc": {"epochs": 0}}, "epochs"),
    ({"run": {"algorithm": "bc", "dataset": "dvrl_marl/x-v1"}, "bc": {"hidden": [32, "64"]}}, "hidden[1]"),
    ({"run": {"algorithm": "bc", "dataset": "dvrl_marl/x-v1"}, "bc": {"learning_rate": math.nan}}, "learning_rate"),
    ({"run": {"algorithm": "bc", "dataset": "dvrl_marl/x-v1"}, "evaluate": {"episodes": -3}}, "episodes"),
    ({"run": {"algorithm": "bc", "dataset": "dvrl_marl/x-v1"}, "record": {"policy": "scripted", "episodes": 5,
                                                                          "seed": -1}}, "seed"),
    ({"run": {"algorithm": "bc", "dataset": "dvrl_marl/x-v1"}, "clone": {}}, "[clone]"),
])
def test_a_broken_cloning_configuration_is_named(tmp_path, tables, field):
    path = _write_toml(tmp_path / "bc.toml", tables)
    with pytest.raises(ValueError) as error:
        clone_training.load_config(path)
    _assert_named(error.value, path, field)


def test_a_broken_sb3_ppo_configuration_is_named_before_training(tmp_path):
    from dvrl_marl.training.marl import train_ppo

    for tables, field in (({"run": {"n_envs": 0}}, "n_envs"), ({"run": {"surgeon": "human"}}, "surgeon"),
                          ({"env": {"reward_typ": "dense"}}, "reward_typ"), ({"algo": {}}, "[algo]")):
        path = _write_toml(tmp_path / "ppo.toml", tables)
        with pytest.raises(ValueError) as error:
            train_ppo(path, 0, tmp_path / "out")
        _assert_named(error.value, path, field)
        assert not (tmp_path / "out").exists()


# --- pipeline specs -------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("stage, field", [
    ('{ type = "reach", target = "home", height = nan }', "height"),
    ('{ type = "reach", target = "home", tolerance = -0.001 }', "tolerance"),
    ('{ type = "reach", target = "home", timeout = "400" }', "timeout"),
    ('{ type = "reach", target = "home", hieght = 0.01 }', "hieght"),
    ('{ type = "pick", lift = -0.01 }', "lift"),
])
def test_a_broken_pipeline_stage_is_named(tmp_path, stage, field):
    from dvrl_marl.pipeline import load_pipeline

    path = tmp_path / "spec.toml"
    path.write_text(f'[grasper]\nfor_each = "debris"\nstages = [ {stage} ]\n')
    with pytest.raises(ValueError) as error:
        load_pipeline(path)
    _assert_named(error.value, path, field)
    assert "grasper.stages[0]" in str(error.value)


# --- checkpoints and resumed runs -----------------------------------------------------------------------------------
TINY = {"run": {"algorithm": "mappo", "total_steps": 1024, "num_envs": 16, "rollout_steps": 16, "eval_every": 1024,
                "eval_episodes": 2, "checkpoint_every": 1024}, "env": {"reward_type": "dense", "max_cycles": 30},
        "ppo": {"epochs": 1, "minibatches": 1}, "model": {"hidden": [8]}}


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("finished")
    config = mappo.load_config(_write_toml(folder / "tiny.toml", TINY))
    mappo.train(config, 0, folder / "run", progress=False, tensorboard=False, log=lambda *_: None)
    return config, folder / "run"


def _snapshot(folder: Path) -> dict:
    return {path: path.read_bytes() for path in folder.rglob("*") if path.is_file()}


def test_resuming_a_finished_run_says_so_and_changes_nothing(finished_run):
    config, run = finished_run
    before = _snapshot(run)
    said = []
    for steps in (None, 512):  # as configured, or fewer steps than done
        result = mappo.train(config, 0, run, total_steps=steps, resume=True, progress=False, tensorboard=False,
                             log=said.append)
        assert "success_rate" in result and result["steps"] == 1024
    assert _snapshot(run) == before
    assert all("finished" in line for line in said)


def test_a_new_run_never_overwrites_a_record_and_a_resume_needs_its_checkpoint(finished_run, tmp_path):
    config, run = finished_run
    before = _snapshot(run)
    with pytest.raises(ValueError, match="holds a run already"):
        mappo.train(config, 0, run, progress=False, tensorboard=False, log=lambda *_: None)
    assert _snapshot(run) == before
    with pytest.raises(ValueError, match="no checkpoint to resume from"):  # a mistyped --out
        mappo.train(config, 0, tmp_path / "rnu", resume=True, progress=False, tensorboard=False, log=lambda *_: None)
    assert not (tmp_path / "rnu").exists()


class _Payload:
    """A pickle that runs a command when loaded (what a crafted checkpoint does)."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def test_a_crafted_or_damaged_checkpoint_is_refused_by_name_and_runs_nothing(finished_run, tmp_path):
    config, run = finished_run
    crafted = tmp_path / "crafted"
    crafted.mkdir()
    marker = tmp_path / "pwned"
    with (crafted / "checkpoint.pt").open("wb") as handle:
        pickle.dump({"loss_module": _Payload(marker)}, handle)
    with pytest.raises(ValueError, match=r"crafted/checkpoint.pt: not a checkpoint this trainer can read"):
        mappo.train(config, 0, crafted, resume=True, progress=False, tensorboard=False, log=lambda *_: None)
    assert not marker.exists()
    damaged = tmp_path / "damaged"
    damaged.mkdir()
    (damaged / "checkpoint.pt").write_bytes((run / "checkpoint.pt").read_bytes()[:300])
    with pytest.raises(ValueError, match=r"damaged/checkpoint.pt: not a checkpoint"):
        mappo.load_checkpoint(damaged / "checkpoint.pt")
    (damaged / "checkpoint.pt").write_bytes(torch_save_bytes({"steps": 3}))
    with pytest.raises(ValueError, match=r"not a dvrl-marl MAPPO checkpoint \(missing \['loss_module'"):
        mappo.load_checkpoint(damaged / "checkpoint.pt")


def torch_save_bytes(value) -> bytes:
    import io

    buffer = io.BytesIO()
    torch.save(value, buffer)
    return buffer.getvalue()


# --- the command line ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("arguments, flag", [
    (["train", "baselines/configs/suction_debris_mappo.toml", "--steps", "0"], "--steps"),
    (["train", "baselines/configs/suction_debris_mappo.toml", "--num-collectors", "-1"], "--num-collectors"),
    (["train", "baselines/configs/suction_debris_mappo.toml", "--seed", "1e3"], "--seed"),
    (["teleop", "--max-cycles", "0"], "--max-cycles"),
    (["teleop", "--port", "70000"], "--port"),
    (["teleop", "--seed", "-3"], "--seed"),
    (["evaluate", "reach-lnd", "--episodes", "0"], "--episodes"),
    (["render", "--width", "abc"], "--width"),
])
@pytest.mark.slow
def test_a_bad_flag_is_named_and_nothing_runs(tmp_path, arguments, flag):
    result = subprocess.run([sys.executable, "-m", "dvrl_marl.cli", *arguments], capture_output=True, text=True,
                            timeout=120, cwd=tmp_path if arguments[0] != "train" else ROOT)
    assert result.returncode == 2 and f"argument {flag}" in result.stderr, result.stderr
    assert not list(tmp_path.iterdir())


def test_a_mistyped_algorithm_is_refused_not_trained_as_something_else(tmp_path):
    path = _write_toml(tmp_path / "typo.toml", {"run": {"algorithm": "mapo", "total_steps": 1000}})
    result = subprocess.run([sys.executable, "-m", "dvrl_marl.cli", "train", str(path), "--out", str(tmp_path / "r")],
                            capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert result.returncode == 2 and "[run] algorithm: must be one of" in result.stderr, result.stderr
    assert "'mapo'" in result.stderr and not (tmp_path / "r").exists()
