"""Damaged or hand-edited data files give a ValueError naming the file and the field, never a bare decoder error
and never a silently wrong policy."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from dvrl_marl import policies
from dvrl_marl.pipeline import load_pipeline
from dvrl_marl.task import load_task


@pytest.fixture
def reach_copy(tmp_path):
    folder = tmp_path / "reach"
    shutil.copytree(policies.shipped_dir() / "reach-lnd", folder)
    return folder


def _edit_npz(folder, change):
    with np.load(folder / "policy.npz") as archive:
        arrays = {k: archive[k] for k in archive.files}
    change(arrays)
    with (folder / "policy.npz").open("wb") as handle:
        np.savez(handle, **arrays)


def _edit_json(folder, change):
    spec = json.loads((folder / "policy.json").read_text())
    change(spec)
    (folder / "policy.json").write_text(json.dumps(spec))


@pytest.mark.parametrize("damage, file, message", [
    (lambda f: _edit_npz(f, lambda a: a.update(b3=a["b3"][:1])), "policy.npz", "array 'b3' has shape (1,)"),
    (lambda f: _edit_npz(f, lambda a: a.update(W1=a["W1"][:, :10])), "policy.npz", "array 'W1' has shape"),
    (lambda f: _edit_npz(f, lambda a: a.pop("W2")), "policy.npz", "missing array 'W2'"),
    (lambda f: _edit_npz(f, lambda a: a["W0"].__setitem__((0, 0), np.nan)), "policy.npz", "array 'W0' must hold finite"),
    (lambda f: (f / "policy.npz").write_bytes((f / "policy.npz").read_bytes()[:500]), "policy.npz", "not a readable .npz"),
    (lambda f: (f / "policy.json").write_text((f / "policy.json").read_text()[:40]), "policy.json", "not valid JSON"),
    (lambda f: (f / "policy.json").write_text("{}"), "policy.json", "format: missing"),
    (lambda f: _edit_json(f, lambda s: s.pop("activations")), "policy.json", "activations: missing"),
    (lambda f: _edit_json(f, lambda s: s.update(format="v0")), "policy.json", "field 'format' is 'v0'"),
    (lambda f: _edit_json(f, lambda s: s.update(activations=["relu", "relu", "gelu", "tanh"])), "policy.json",
     "activations[2]"),
    (lambda f: _edit_json(f, lambda s: s.update(layer_sizes=[9, 256, 3])), "policy.json", "layer_sizes"),
    (lambda f: _edit_json(f, lambda s: s.update(action_low=[-1.0])), "policy.json", "action_low needs 3 values"),
    (lambda f: _edit_json(f, lambda s: s.update(action_low=s["action_high"], action_high=s["action_low"])),
     "policy.json", "action_low[0] = 1.0 must be below action_high[0] = -1.0"),
    (lambda f: _edit_json(f, lambda s: s.update(action_high=[1.0, "1", 1.0])), "policy.json", "action_high[1]"),
])
def test_damaged_policy_names_file_and_field(reach_copy, damage, file, message):
    damage(reach_copy)
    with pytest.raises(ValueError) as error:
        policies.load(reach_copy)
    assert str(reach_copy / file) in str(error.value)
    assert message in str(error.value)


def test_intact_copy_still_loads_and_acts(reach_copy):
    policy = policies.load(reach_copy)
    observation = {"observation": np.zeros(3), "achieved_goal": np.zeros(3), "desired_goal": np.full(3, 0.5)}
    assert policy(observation).shape == (3,)


def test_damaged_task_and_pipeline_files(tmp_path):
    task = tmp_path / "broken_task.toml"
    task.write_text("[task\nworkspace_range = 0.05\n")
    with pytest.raises(ValueError, match="broken_task.toml: not valid TOML"):
        load_task(task)
    task.write_text("[other]\nx = 1\n")
    with pytest.raises(ValueError, match="broken_task.toml: missing field 'task'"):
        load_task(task)
    pipeline = tmp_path / "broken_pipeline.toml"
    pipeline.write_text("[suction\nstages = []\n")
    with pytest.raises(ValueError, match="broken_pipeline.toml: not valid TOML"):
        load_pipeline(pipeline)


def test_damaged_demonstration_files(tmp_path):
    from dvrl_marl.teleop import load_demonstration
    from dvrl_marl.training.demonstrations import load_demonstrations

    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(b"PK\x03\x04 not really a zip")
    for loader in (load_demonstration, load_demonstrations):
        with pytest.raises(ValueError, match="truncated.npz: not a readable .npz"):
            loader(truncated)
    wrong = tmp_path / "wrong.npz"
    np.savez(wrong, observations=np.zeros((3, 30)), actions=np.zeros((2, 4)),
             metadata=np.array(json.dumps({"format": "x"})))
    with pytest.raises(ValueError, match="wrong.npz: field 'metadata.format' is 'x'"):
        load_demonstration(wrong)
    no_meta = tmp_path / "no_meta.npz"
    np.savez(no_meta, observations=np.zeros((3, 30)))
    with pytest.raises(ValueError, match="no_meta.npz: missing array 'metadata'"):
        load_demonstrations(no_meta)


def test_policy_meeting_the_wrong_env_names_itself():
    policy = policies.load("reach-lnd")
    with pytest.raises(ValueError, match="'reach-lnd'.*reads 9 observation features, got 13"):
        policy(np.zeros(13))
    with pytest.raises(ValueError, match="absent from this env's observation"):
        policy({"observation": np.zeros(3)})


def test_damaged_run_configuration(tmp_path):
    from dvrl_marl.training.runner import load_config

    path = tmp_path / "run.toml"
    path.write_text("[run\nenv_id = 'x'\n")
    with pytest.raises(ValueError, match="run.toml: not valid TOML"):
        load_config(path)


@pytest.mark.parametrize("files", [{"a": "a"}, {"a": "b", "b": "a"}, {"a": "b", "b": "c", "c": "b"}])
def test_a_task_file_that_extends_itself_through_others_is_named(tmp_path, monkeypatch, files):
    """A chain of ``extends`` that comes back to one of its files is an error naming the chain (it was a
    RecursionError)."""
    from dvrl_marl import task

    for name, base in files.items():
        (tmp_path / f"{name}.toml").write_text(f'[task]\nextends = "{base}"\n')
    monkeypatch.setattr(task, "tasks_dir", lambda: tmp_path)
    with pytest.raises(ValueError, match=r"a\.toml|b\.toml|c\.toml") as error:
        task.load_task_table("a")
    assert "cannot extend itself" in str(error.value) and "->" in str(error.value) or files == {"a": "a"}


def _seat_copy(tmp_path, name):
    folder = tmp_path / name
    shutil.copytree(policies.shipped_dir() / name, folder)
    return folder


def _felt(spec, **changes):
    from dvrl_marl.suction_debris.scripted_team import felt_contact_rule

    spec["felt_contact"] = {**felt_contact_rule(0.08, 30.0, 2.0, 100, 0.3), **changes}


@pytest.mark.parametrize("name, change, message", [
    ("marl-grasper", lambda s: s["features"]["cavity_centres"][0].__setitem__(0, float("nan")),
     "cavity_centres must be finite numbers of shape (2, 2)"),
    ("marl-grasper", lambda s: s["features"].update(cavities=3), "cavity_centres must be finite numbers of shape (3, 2)"),
    ("marl-grasper", lambda s: s["features"].update(debris=2), "its features read an observation of 24 values"),
    ("marl-grasper", lambda s: s["features"].update(zoom=1.0), "unknown ['zoom']"),
    ("marl-grasper", lambda s: s["features"].pop("rim_z"), "missing ['rim_z']"),
    ("marl-grasper", lambda s: s.update(agent="scalpel"), "agent"),
    ("marl-grasper", lambda s: s.update(preset="fast"), "preset 'fast' is not a preset"),
    ("marl-suction-pixels", lambda s: s["keep_clear"].update(keep_mm=1e6, keep=1e6 / 80), "wider than the workspace"),
    ("marl-suction-pixels", lambda s: _felt(s, near_mm=30.0, near=30.0 / 40), "the _mm values and their observation units"),
    ("marl-suction-pixels", lambda s: _felt(s, retreat_mm=40.0, retreat=0.5), "retreat_mm 40.0 must be below near_mm"),
    ("marl-suction-pixels", lambda s: _felt(s, hold_steps=10**7), "hold_steps"),
    ("marl-suction-pixels", lambda s: (s["keep_clear"].update(keep_mm=14.0, keep=14.0 / 40), _felt(s)),
     "keep_clear reads 40 mm per observation unit, felt_contact 80"),
])
def test_every_table_of_a_seat_is_checked_at_load(tmp_path, name, change, message):
    """A seat's features, keep_clear and felt_contact, its seat and preset: checked when the file is read, the file
    named (a NaN centre once gave NaN actions; wrong counts numpy's own errors at the first step)."""
    folder = _seat_copy(tmp_path, name)
    _edit_json(folder, change)
    with pytest.raises(ValueError) as error:
        policies.load(folder)
    assert str(folder / "policy.json") in str(error.value) and message in str(error.value), str(error.value)


@pytest.fixture(scope="module")
def pixel_observation():
    from dvrl_marl.envs import suction_debris_v8

    policy = policies.load("marl-suction-pixels")
    env = suction_debris_v8.batched_env(num_envs=2, **policy.image_options)
    observations, _ = env.reset(seed=0)
    return policy, observations["suction"]


@pytest.mark.parametrize("change, message", [
    (lambda o: o.update(image=o["image"] / 255.0), "uint8 RGB in 0..255, got float64"),
    (lambda o: o.update(image=o["image"].astype(np.uint16) * 257), "got uint16"),
    (lambda o: o.update(image_right=o["image_right"][:, :32, :32]), "'image_right' as 64 x 64 RGB images"),
    (lambda o: o.update(image_right=o["image_right"][:1]), "one per world as the other eye's"),
    (lambda o: o.update(observation=o["observation"][:, :-1]), "reads 'observation' as 30 values per world"),
    (lambda o: o["observation"].__setitem__((0, 0), np.nan), "its 'observation' holds NaN or inf"),
    (lambda o: o.pop("image_right"), "sees the endoscope"),
])
def test_what_a_pixel_seat_reads_is_checked(pixel_observation, change, message):
    """Images of another kind (floats in 0..1, uint16), an eye of another size or count, an observation of another
    width, NaN: each refused by name, where they once gave other actions silently or numpy's own errors."""
    policy, observation = pixel_observation
    given = {key: np.array(value) for key, value in observation.items()}
    change(given)
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)").replace(".", r"\.")):
        policy(given)
    assert np.all(np.isfinite(policy({key: np.array(value) for key, value in observation.items()})))
