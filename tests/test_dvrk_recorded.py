"""The robot seat held to its runs against the dVRK's own software (release 2.4.0, PSM1 with a Large Needle Driver in the
dVRK's kinematic simulation, through its socket streamer; ``benchmarks/dvrk_conformance.py``, whose record is
``benchmarks/results/dvrk_conformance_2026-12-01.json``). The datagrams both ways of those runs are in
``tests/dvrk_recordings``: every episode, the stale-measurement run, and the start of the setup (power, homing, the
first move; the rest of it is the dVRK's stream while the arm moved to each start). No robot is needed here."""

import gzip
import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import dvrl_marl  # noqa: F401
from conftest import DrivenClock as Clock
from dvrl_marl import frames, policies
from dvrl_marl.dvrk import ArmLink, ReplayLink, RobotSeat
from dvrl_marl.dvrk.link import encode

ROOT = Path(__file__).resolve().parents[1]
RECORDINGS = ROOT / "tests" / "dvrk_recordings"
RECORD = json.loads((ROOT / "benchmarks" / "results" / "dvrk_conformance_2026-12-01.json").read_text())
EPISODES = sorted(RECORDINGS.glob("episode-*.jsonl.gz"))


def _lines(path):
    with gzip.open(path, "rt") as handle:
        return [json.loads(line) for line in handle]


def test_the_record_and_its_recordings_are_all_there():
    assert RECORD["dvrk_version"] == "2.4.0" and RECORD["episodes"] == len(EPISODES) == 20
    assert RECORD["successes"] >= 19  # (the target: 19 of 20 seeded goals)
    assert RECORD["period_ms_p99_all"] <= 22.0 and RECORD["stale_hold"]["hold_after_last_measurement_ms"] <= 100.0


@pytest.mark.parametrize("path", EPISODES, ids=lambda path: path.name.split(".")[0])
def test_each_command_sent_is_what_the_seat_makes_of_the_measurement_before_it(path):
    row = RECORD["rows"][int(path.name.split("-")[1].split(".")[0])]
    seat = RobotSeat(ArmLink("PSM1", ReplayLink("PSM1", [], clock=Clock())), policies.load("reach-lnd"),
                     goal=row["goal"])
    # Before the episode's first measurement in its file (one that came while the log was the setup's): the start,
    # where the dVRK's trajectory left the arm (the record's start error: none).
    assert row["start_error_mm"] < 1e-3
    measured, commands = np.asarray(row["start"]), 0
    for line in _lines(path):
        if line["dir"] == "in" and "measured_cp" in line["data"]:
            measured = np.asarray(line["data"]["measured_cp"]["Position"]["Translation"])
        elif line["dir"] == "out":
            encode(line["data"], "PSM1")  # (every datagram sent fits the streamer's buffer)
            if "servo_cp" not in line["data"]:
                continue
            commands += 1
            tip = frames.dvrk_to_env(measured)
            target, _ = seat.target(tip, seat.policy(seat.observation(tip)))
            np.testing.assert_allclose(line["data"]["servo_cp"]["Goal"]["Translation"], target, rtol=0, atol=2e-9,
                                       err_msg=f"{path.name}: command {commands}")
            np.testing.assert_allclose(line["data"]["servo_cp"]["Goal"]["Rotation"],
                                       frames.servo_cp_goal(target)[:3, :3], atol=1e-9)
    assert commands == row["steps"]


def test_the_observation_of_a_recorded_pose_is_the_envs_for_that_pose():
    row = RECORD["rows"][0]
    first = next(line for line in _lines(EPISODES[0]) if line["dir"] == "in" and "measured_cp" in line["data"])
    pose = np.asarray(first["data"]["measured_cp"]["Position"]["Translation"])
    np.testing.assert_allclose(pose, row["start"], atol=1e-6)  # (the dVRK's trajectory took the arm to the start)
    env = gym.make("dvrl_marl/PSMReach-v1")
    observation, _ = env.reset(options={"start": pose, "goal": np.asarray(row["goal"])})
    seat = RobotSeat(ArmLink("PSM1", ReplayLink("PSM1", [], clock=Clock())), policies.load("reach-lnd"),
                     goal=row["goal"])
    for key, value in seat.observation(frames.dvrk_to_env(pose)).items():
        np.testing.assert_allclose(value, observation[key], rtol=0, atol=1e-12, err_msg=key)


def test_the_commands_went_out_at_the_envs_50_hz():
    periods = []
    for path in EPISODES:
        times = [line["t"] for line in _lines(path) if line["dir"] == "out" and "servo_cp" in line["data"]]
        periods += np.diff(times).tolist()
    periods = 1000.0 * np.asarray(periods)
    assert abs(np.median(periods) - 20.0) < 0.5 and np.percentile(periods, 99) <= 22.0


def test_the_arm_was_powered_and_homed_before_it_was_moved():
    lines = _lines(RECORDINGS / "setup-head.jsonl.gz")
    sent = [(index, line["data"]) for index, line in enumerate(lines) if line["dir"] == "out"]
    assert [list(data)[0] for _, data in sent] == ["power_on", "home", "move_cp"]
    homed = next(index for index, line in enumerate(lines) if line["dir"] == "in" and "operating_state" in line["data"]
                 and line["data"]["operating_state"]["IsHomed"] and not line["data"]["operating_state"]["IsBusy"]
                 and line["data"]["operating_state"]["State"] == "ENABLED")
    assert homed < sent[2][0]


def test_the_stale_measurement_hold_came_within_100_ms():
    lines = _lines(RECORDINGS / "stale.jsonl.gz")
    last_in = max(line["t"] for line in lines if line["dir"] == "in")
    hold = [line["t"] for line in lines if line["dir"] == "out" and line["data"] == {"hold": ""}]
    assert len(hold) == 1 and 0.0 < hold[0] - last_in <= 0.1
    assert not [line for line in lines if line["dir"] == "out" and line["t"] > hold[0]]  # (nothing sent after it)


def test_a_replayed_run_reaches_the_goal_where_the_recorded_one_did():
    row = RECORD["rows"][0]
    clock = Clock()
    link = ReplayLink("PSM1", _lines(EPISODES[0]), clock=clock)
    link.latest["operating_state"] = (0.0, {"State": "ENABLED", "IsHomed": True, "IsBusy": False})
    summary = RobotSeat(ArmLink("PSM1", link), policies.load("reach-lnd"), goal=row["goal"], clock=clock,
                        sleep=clock.sleep).run(100, settle_s=0.0)
    assert summary.success and abs(summary.success_step - row["success_step"]) <= 2


PICK_RECORD = json.loads((ROOT / "benchmarks" / "results" / "dvrk_conformance_pick_2026-12-01.json").read_text())
PICK_EPISODES = sorted((RECORDINGS / "pick").glob("episode-*.jsonl.gz"))


def _replay_in_turn(seat, lines, name: str) -> int:
    """Every recorded command (``servo_cp``, the jaw's) against what ``seat`` makes of the measurement before it,
    measurement by measurement from the run's recorded start (the seat's model carries over: Pick's object, the
    scene). Returns how many periods were replayed."""
    start = next(line["data"] for line in lines if line["dir"] == "note" and line["data"]["what"] == "start")
    measured = np.asarray(start["measured"])
    seat.start(seat.from_dvrk(measured))  # (Pick: the modelled object, on the table below where the run began)
    servo = jaws = 0
    for line in lines:
        if line["dir"] == "in" and "measured_cp" in line["data"]:
            measured = np.asarray(line["data"]["measured_cp"]["Position"]["Translation"])
        elif line["dir"] == "out" and "servo_cp" in line["data"]:
            servo += 1
            tip = seat.from_dvrk(measured)
            target, _ = seat.target(tip, seat.policy(seat.observation(tip)))
            np.testing.assert_allclose(line["data"]["servo_cp"]["Goal"]["Translation"], seat.to_dvrk(target)[:3, 3],
                                       rtol=0, atol=2e-9, err_msg=f"{name}: command {servo}")
        elif line["dir"] == "out" and "jaw/servo_jp" in line["data"]:
            jaws += 1
            assert line["data"]["jaw/servo_jp"]["Goal"][0] == pytest.approx(seat.tool_command(), abs=2e-9)
    assert servo == jaws
    return servo


def test_pick_on_the_dvrk_sent_what_the_env_makes_of_each_measurement_in_turn():
    """pick-lnd on the dVRK's simulated PSM1, the object the env's model of it: replayed measurement by measurement,
    the seat sends the recorded commands (servo_cp and the jaw), and its modelled object reaches the goal."""
    assert PICK_RECORD["policy"] == "pick-lnd" and PICK_RECORD["episodes"] == len(PICK_EPISODES) >= 5
    for path in PICK_EPISODES:
        row = PICK_RECORD["rows"][int(path.name.split("-")[1].split(".")[0])]
        seat = RobotSeat(ArmLink("PSM1", ReplayLink("PSM1", [], clock=Clock())), policies.load("pick-lnd"),
                         goal=row["goal"])
        assert _replay_in_turn(seat, _lines(path), path.name) == row["steps"]
        assert seat.reached(None)[0] == row["success"]  # (the modelled object, after them)


def test_a_scene_seat_on_the_dvrk_sent_what_the_modelled_scene_makes_of_each_measurement_in_turn():
    """marl-grasper on the dVRK's simulated PSM1, the rest of the scene (the scripted suction, the blood, the pins)
    the env's model: replayed measurement by measurement, the same commands, and the modelled scene cleared."""
    from dvrl_marl.dvrk import SceneRobotSeat

    record = json.loads((ROOT / "benchmarks" / "results" / "dvrk_conformance_scene_2026-12-01.json").read_text())
    assert record["policy"] == "marl-grasper" and record["successes"] == record["episodes"] >= 3
    row = record["rows"][0]
    seat = SceneRobotSeat(ArmLink("PSM1", ReplayLink("PSM1", [], clock=Clock())), policies.load("marl-grasper"),
                          seed=row["seed"])
    assert _replay_in_turn(seat, _lines(RECORDINGS / "scene" / "episode-00.jsonl.gz"), "scene") == row["steps"]
    assert seat.reached(None)[0]
