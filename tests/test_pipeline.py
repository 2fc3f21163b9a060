"""Pipelines: stage hand-over, re-centred frames, pipeline files, and the composed teams."""

import json

import gymnasium as gym
import imageio.v2 as imageio
import numpy as np
import pytest

from dvrl_marl import policies
from dvrl_marl.agents import ReachExpert
from dvrl_marl.cli import main as cli_main
from dvrl_marl.envs import suction_debris_v8
from dvrl_marl.pipeline import (ArmPipeline, RecentredFrame, StageSpec, available_pipelines, load_pipeline,
                                pipeline_policies)
from dvrl_marl.pipeline.core import ArmPlan


def run_team(pipeline, seed, **env_kwargs):
    env = suction_debris_v8.parallel_env(**env_kwargs)
    suction = ArmPipeline.from_file(pipeline, "suction", env)
    grasper = ArmPipeline.from_file(pipeline, "grasper", env)
    observations, _ = env.reset(seed=seed)
    while env.agents:
        observations, _, _, _, infos = env.step(
            {"suction": suction(observations["suction"]), "grasper": grasper(observations["grasper"])}
        )
    return infos["suction"], suction, grasper


def test_shipped_pipelines_parse():
    assert {"learned_team", "scripted_team"} <= set(available_pipelines())
    plans = load_pipeline("learned_team")
    assert plans["suction"].for_each == "cavity" and plans["grasper"].for_each == "debris"
    assert [s.type for s in plans["grasper"].stages] == ["reach", "reach", "pick", "reach", "release"]


def test_invalid_pipeline_files_raise(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('[grasper]\nstages = [ { type = "dance" } ]\n')
    with pytest.raises(ValueError, match="stage type"):
        load_pipeline(bad)
    bad.write_text('[camera]\nstages = []\n')
    with pytest.raises(ValueError, match="unknown arm"):
        load_pipeline(bad)
    bad.write_text('[grasper]\nstages = [ { type = "reach", target = "moon" } ]\n')
    with pytest.raises(ValueError, match="target"):
        load_pipeline(bad)
    bad.write_text('[grasper]\nstages = [ { type = "reach", target = "home", speed = 2 } ]\n')
    with pytest.raises(ValueError, match="unknown stage key"):
        load_pipeline(bad)
    with pytest.raises(FileNotFoundError):
        load_pipeline("no_such_pipeline")


def test_reach_stage_hands_over_once_the_tip_is_within_delta():
    env = suction_debris_v8.parallel_env()
    observations, _ = env.reset(seed=0)
    plan = ArmPlan("none", (), idle=(StageSpec("reach", target="home"), StageSpec("reach", target="park")))
    pipeline = ArmPipeline(plan, "grasper", env)
    arm = env.arms["grasper"]
    home = pipeline.base + np.array((-0.015, 0.02, -0.08))
    arm.set_tip(*arm.to_base(home).tolist())
    observations = {"grasper": env.seat_observation("grasper")}
    pipeline(observations["grasper"])
    assert pipeline.stage_index == 1  # already at home: straight on to the next stage
    assert any("end idle stage 0" in entry for _, entry in pipeline.log)


def test_stage_timeout_hands_over():
    env = suction_debris_v8.parallel_env()
    observations, _ = env.reset(seed=0)
    plan = ArmPlan("none", (), idle=(StageSpec("reach", target="park", timeout=3), StageSpec("reach", target="home")))
    pipeline = ArmPipeline(plan, "grasper", env)
    for _ in range(5):
        observations, *_ = env.step({"suction": np.zeros(4), "grasper": pipeline(observations["grasper"])})
    assert pipeline.timeouts == 1 and pipeline.stage_index == 1


def test_suction_pipeline_skips_clear_cavities_and_finishes_by_parking():
    env = suction_debris_v8.parallel_env()
    observations, _ = env.reset(seed=0, options={"blood_ml": [8.0, 0.0]})
    pipeline = ArmPipeline.from_file("scripted_team", "suction", env)
    pipeline(observations["suction"])
    assert pipeline.item == 0  # cavity 1 is empty although it is the one the plan would start with
    while env.agents and pipeline.mode != "final":
        observations, *_ = env.step({"suction": pipeline(observations["suction"]), "grasper": np.zeros(4)})
    assert env.blood.remaining_ml[0] < env.params.blood_threshold_ml
    assert pipeline.sequence[pipeline.stage_index].target == "park"


def test_recentred_frame_gives_the_same_behaviour_relative_to_the_goal():
    policy = policies.load("reach-lnd") if "reach-lnd" in policies.available() else ReachExpert()
    shift = np.array([0.012, -0.008, 0.004])
    runs = []
    for offset in (np.zeros(3), shift):
        env = gym.make("dvrl_marl/PSMReach-v1", workspace_centre=np.array([0.0, 0.0, -0.11]) + offset)
        start, goal = np.array([0.02, -0.01, -0.09]) + offset, np.array([-0.015, 0.02, -0.1]) + offset
        obs, _ = env.reset(seed=0, options={"start": start, "goal": goal})
        actions, tips = [], []
        for _ in range(60):
            action = policy(obs)
            obs, *_ = env.step(action)
            actions.append(action)
            tips.append(np.array(env.unwrapped.arm.tip) - offset)
        runs.append((np.array(actions), np.array(tips)))
    np.testing.assert_allclose(runs[0][0], runs[1][0], atol=1e-5)
    np.testing.assert_allclose(runs[0][1], runs[1][1], atol=1e-9)
    frame = RecentredFrame([0.1, 0.2, 0.3], 0.05)
    np.testing.assert_allclose(frame.normalise([0.15, 0.2, 0.25]), [1.0, 0.0, -1.0])


@pytest.mark.slow
def test_scripted_pipeline_team_completes_the_task():
    for seed in range(3):
        info, suction, grasper = run_team("scripted_team", seed)
        assert info["is_success"], (seed, suction.log[-5:], grasper.log[-5:])


@pytest.mark.slow
def test_a_pipeline_fills_the_surgeon_seat():
    probe = suction_debris_v8.parallel_env()
    surgeon = ArmPipeline.from_file("scripted_team", "grasper", probe)
    env = suction_debris_v8.parallel_env(surgeon=surgeon)
    suction = ArmPipeline.from_file("scripted_team", "suction", env)
    observations, _ = env.reset(seed=1)
    while env.agents:
        observations, _, _, _, infos = env.step({"suction": suction(observations["suction"])})
    assert infos["suction"]["is_success"]


@pytest.mark.skipif(not pipeline_policies("learned_team") <= set(policies.available()),
                    reason="the learned policies are not shipped")
@pytest.mark.slow
def test_learned_pipeline_team_completes_the_task():
    results = [run_team("learned_team", seed)[0]["is_success"] for seed in range(3)]
    assert sum(results) >= 2, results


@pytest.mark.slow
def test_demo_command_writes_a_playable_video_and_metrics(tmp_path, capsys):
    out = tmp_path / "demo"
    assert cli_main(["demo", "--surgeon", "scripted", "--max-cycles", "40", "--out", str(out), "--no-progress"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    for key in ("success", "blood_removed_ml", "debris_delivered", "steps", "instrument_contacts"):
        assert key in metrics
    assert metrics["steps"] == 40 and metrics["success"] is False and len(metrics["blood_removed_ml"]) == 2
    reader = imageio.get_reader(out / "demo.mp4")
    frames = [frame for frame in reader]
    assert len(frames) >= 10 and frames[0].shape == (480, 640, 3) and frames[-1].std() > 5
    assert "debris delivered" in capsys.readouterr().out


def test_reach_stages_lift_over_the_phantom_and_position_precisely():
    env = suction_debris_v8.parallel_env()
    observations, _ = env.reset(seed=0)
    name = "reach-lnd" if "reach-lnd" in policies.available() else "scripted"
    plan = ArmPlan("none", (), idle=(StageSpec("reach", policy=name, target="home"),
                                     StageSpec("reach", policy=name, target="park", precision=4, tolerance=0.001)))
    pipeline = ArmPipeline(plan, "grasper", env)
    arm = env.arms["grasper"]
    cavity = env.phantom.cavities[1]
    arm.set_tip(*arm.to_base((cavity.centre_x, cavity.centre_y, cavity.floor_z + 0.002)).tolist())  # start deep
    observations = {"grasper": env.seat_observation("grasper")}
    first_stage_heights = []
    while pipeline.stage_index < 2 and pipeline.steps < 800:
        action = pipeline(observations["grasper"])
        if pipeline.stage_index == 0:
            first_stage_heights.append(arm.tip_world()[2])
        observations, *_ = env.step({"suction": np.zeros(4), "grasper": action})
    assert pipeline.timeouts == 0 and pipeline.stage_index == 2
    safe = env.phantom.top_z + 0.01
    assert max(first_stage_heights) >= safe - 0.0015  # it climbed out of the cavity before travelling
    park = pipeline._target(StageSpec("reach", target="park"), pipeline._parse(observations["grasper"]))
    assert np.linalg.norm(np.array(arm.tip_world()) - park) <= 0.001  # finer than the policy's own 3 mm delta
