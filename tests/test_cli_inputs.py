"""Bad command-line input is named before anything runs: flags that do not apply, outputs that cannot be written,
addresses that do not resolve, files without the columns a command reads (nothing a run or a person did is lost to a
bad output path, since no episode starts)."""

import pytest

from dvrl_marl.cli import main


def _refused(argv, capsys) -> str:
    """The command's exit status is 2 and its message is returned (argparse's or the command's own)."""
    try:
        status = main(argv)
    except SystemExit as exit_:
        status = exit_.code
    assert status == 2, argv
    return capsys.readouterr().err


def test_a_tool_pick_cannot_use_is_named(capsys):
    assert "tool must be 'lnd'" in _refused(["evaluate", "pick-lnd", "--tool", "suction_irrigation",
                                             "--episodes", "1"], capsys)


@pytest.mark.parametrize("flags,named", [(["--tool", "lnd"], "--tool"), (["--env", "dvrl_marl/PSMReach-v1"], "--env"),
                                         (["--tool", "lnd", "--video", "x.mp4"], "--tool, --video")])
def test_flags_that_do_not_apply_to_a_seat_are_named(capsys, tmp_path, flags, named):
    flags = [str(tmp_path / f) if f.endswith(".mp4") else f for f in flags]
    message = _refused(["evaluate", "marl-grasper", "--episodes", "1", *flags], capsys)
    assert named in message and "not apply to marl-grasper" in message


@pytest.mark.parametrize("argv,named", [
    (["evaluate", "reach-lnd", "--video", "/proc/x.mp4"], "--video: '/proc/x.mp4' cannot be written"),
    (["evaluate-team", "--json", "{tmp}"], "--json: '{tmp}' is a folder"),
    (["render", "--out", "{tmp}"], "--out: '{tmp}' is a folder"),
    (["demo", "--record", "/proc/x.npz"], "--record: '/proc/x.npz' cannot be written"),
    (["demo", "--record", "{tmp}"], "--record: '{tmp}' is a folder"),
    (["demo", "--out", "{file}"], "--out: '{file}' is a file"),
    (["train", "suction_debris_mappo", "--out", "{file}"], "--out: '{file}' is a file"),
    (["demo", "--out", "/proc/run"], "--out: '/proc/run' cannot be made"),
    (["teleop", "--host", "256.1.1.1"], "--host: '256.1.1.1' is not an address"),
    (["plot", "{tmp}", "--out", "/proc/curves"], "--out: '/proc/curves.png' cannot be written"),
])
def test_outputs_and_addresses_are_checked_before_anything_runs(capsys, tmp_path, argv, named):
    (tmp_path / "taken").write_text("a file")
    fill = {"tmp": str(tmp_path), "file": str(tmp_path / "taken")}
    message = _refused([a.format(**fill) for a in argv], capsys)
    assert named.format(**fill) in message


def test_a_progress_file_without_its_columns_is_named(capsys, tmp_path):
    pytest.importorskip("matplotlib")  # (plot's extra)
    csv = tmp_path / "other.csv"
    csv.write_text("a,b\n1,2\n")
    assert "no column timesteps, success_rate" in _refused(["plot", str(csv), "--out", str(tmp_path / "c")], capsys)
    assert "no column steps, success_rate, blood_removed_ml" in _refused(
        ["plot", str(csv), "--team", "--out", str(tmp_path / "c")], capsys)
    assert "no progress.csv there" in _refused(["plot", str(tmp_path), "--out", str(tmp_path / "c")], capsys)


@pytest.mark.parametrize("argv,named", [
    (["train", "reach_lnd_ddpg_her", "--trainer", "jax"], "--trainer jax: {config} (ddpg_bc) is trained by sb3"),
    (["train", "reach_lnd_ddpg_her", "--device", "cuda"], "sb3: it does not take --device (jax does)"),
    (["train", "surgeon_bc", "--steps", "10"], "bc: it does not take --steps"),
    (["train", "suction_debris_mappo", "--trainer", "torchrl", "--device", "cuda"],
     "--trainer torchrl cannot train {config}: it does not take --device (jax does)"),
    (["train", "suction_debris_mappo", "--trainer", "torchrl", "--validators", "2"], "it does not take --validators"),
    (["train", "suction_debris_mappo", "--trainer", "jax", "--resume"],
     "--trainer jax cannot train {config}: it does not take --resume (sb3, torchrl do)"),
    (["train", "suction_debris_mappo", "--device", "cuda", "--ray-address", "local"],
     "no trainer can train {config}: jax: it does not take --ray-address (torchrl does); torchrl: it does not take "
     "--device (jax does)"),
    (["train", "suction_debris_mappo", "--trainer", "device"], "--trainer device was retired: the compiled JAX trainer"),
    (["train", "suction_debris_mappo", "--trainer", "record"], "--trainer record was retired: the TorchRL trainer"),
    (["train", "suction_debris_mappo", "--trainer", "compiled"], "--trainer compiled: {config} (mappo) is trained by "
     "jax, torchrl"),
])
def test_a_trainer_flag_that_does_not_apply_is_named(capsys, argv, named):
    from dvrl_marl.cli import resolve_config

    assert named.format(config=resolve_config(argv[1])) in _refused(argv, capsys)


def test_evaluate_team_checks_every_seat_before_any_pair_runs(capsys):
    message = _refused(["evaluate-team", "--suction", "scripted", "benchmark-suction", "--grasper", "scripted",
                        "benchmark-grasperr", "--episodes", "1"], capsys)
    assert "--grasper 'benchmark-grasperr': not a seat" in message and "benchmark-grasper," in message
    assert "was trained for the 'grasper' seat" in _refused(["evaluate-team", "--suction", "marl-grasper"], capsys)


def test_evaluate_team_plays_the_preset_its_seats_learnt_on(capsys):
    from dvrl_marl.cli import _team_preset

    assert _team_preset(["benchmark-suction"], ["benchmark-grasper"], None) == "benchmark"
    assert _team_preset(["scripted"], ["benchmark-grasper"], None) == "benchmark"
    assert _team_preset(["marl-suction"], ["scripted"], None) == "default"
    assert _team_preset(["benchmark-suction"], ["benchmark-grasper"], "default") == "default"
    assert "not the preset benchmark-suction learnt on (benchmark)" in capsys.readouterr().err
    assert "choose the scene with --preset" in _refused(["evaluate-team", "--suction", "benchmark-suction",
                                                         "--grasper", "marl-grasper"], capsys)


def test_a_seat_policy_that_does_not_name_its_seat_is_refused(capsys, tmp_path):
    import json
    import shutil

    from dvrl_marl import policies

    folder = tmp_path / "seat"
    shutil.copytree(policies.shipped_dir() / "marl-grasper", folder)
    spec = json.loads((folder / "policy.json").read_text())
    del spec["agent"]
    (folder / "policy.json").write_text(json.dumps(spec))
    assert "must say which seat it fills" in _refused(["evaluate", str(folder), "--episodes", "1"], capsys)


@pytest.mark.parametrize("argv,named", [
    (["render", "--out", "{tmp}/scene"], "has no image suffix"),
    (["render", "--out", "{tmp}/scene.xyz"], "has no image suffix"),
    (["train", "suction_debris_mappo", "--trainer", "jax", "--device", "tpu"], "'tpu' is not a device"),
    (["train", "suction_debris_mappo", "--trainer", "jax", "--device", "cpu:abc"], "'cpu:abc' is not a device"),
    (["train", "suction_debris_mappo", "--trainer", "jax", "--device", "cuda:x"], "'cuda:x' is not a device"),
    (["evaluate", "reach-lnd", "--env", "dvrl_marl/Nope-v1", "--episodes", "1"],
     "--env 'dvrl_marl/Nope-v1' is not a registered environment"),
])
def test_paths_that_once_ended_in_a_traceback_name_what_was_wrong(capsys, tmp_path, argv, named):
    message = _refused([part.replace("{tmp}", str(tmp_path)) for part in argv], capsys)
    assert named in message and "Traceback" not in message
    assert not list(tmp_path.iterdir())  # nothing written


def test_a_policy_of_an_unknown_env_is_named(capsys, tmp_path):
    import json
    import shutil

    from dvrl_marl import policies

    shutil.copytree(policies.shipped_dir() / "reach-lnd", tmp_path / "policy")
    spec = json.loads((tmp_path / "policy" / "policy.json").read_text())
    (tmp_path / "policy" / "policy.json").write_text(json.dumps({**spec, "env_id": "dvrl_marl/PSMReach-v0"}))
    message = _refused(["evaluate", str(tmp_path / "policy"), "--episodes", "1"], capsys)
    assert "env_id 'dvrl_marl/PSMReach-v0' is not a registered environment" in message


def test_a_render_past_what_the_opengl_draws_is_named(capsys, tmp_path):
    message = _refused(["render", "--width", "40000", "--height", "16", "--out", str(tmp_path / "wide.png")], capsys)
    assert "render size 40000 x 16" in message and not (tmp_path / "wide.png").exists()
