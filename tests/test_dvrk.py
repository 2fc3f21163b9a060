"""The dVRK bridge without a robot: the wire's rules (datagram size, JSON both ways over a real UDP socket), the
robot seat's safety stops (not ready, a stale or invalid measurement, Ctrl-C / SIGTERM, a clamped move), the
observation and the commands it builds against the environment's own, and the command line's dry run. The recorded
runs against the dVRK's own software are replayed in ``test_dvrk_recorded.py``."""

import json
import signal
import socket
import time

import gymnasium as gym
import numpy as np
import pytest

import dvrl_marl  # noqa: F401
from conftest import DrivenClock as Clock
from dvrl_marl import frames, policies
from dvrl_marl.cli import main
from dvrl_marl.dvrk import MAX_DATAGRAM, ArmLink, DatagramLog, EchoLink, ReplayLink, RobotSeat, StreamerLink, read_log
from dvrl_marl.dvrk.link import encode
from dvrl_marl.dvrk.seat import jaw_angle


def _episode(seed=3):
    env = gym.make("dvrl_marl/PSMReach-v1")
    observation, _ = env.reset(seed=seed)
    return env, observation, np.array(env.unwrapped.arm.tip), env.unwrapped.goal.copy()


def test_a_datagram_the_streamer_would_cut_is_refused_by_name():
    goal = frames.servo_cp_goal(np.array([0.01, -0.02, -0.1]))
    from dvrl_marl.dvrk.arm import cartesian_goal

    assert len(encode({"servo_cp": {"Goal": cartesian_goal(goal)}}, "PSM1")) <= MAX_DATAGRAM
    with pytest.raises(ValueError, match=r"PSM1: the datagram for \['servo_cp'\] is \d+ bytes; the streamer reads at "
                                         r"most 1023"):
        encode({"servo_cp": {"Goal": "x" * 2000}}, "PSM1")
    with pytest.raises(ValueError, match="Out of range float values are not JSON compliant"):
        encode({"jaw/servo_jp": {"Goal": [float("nan")]}}, "PSM1")
    with pytest.raises(ValueError, match="a finite 4x4 pose"):
        cartesian_goal(np.eye(3))


def test_the_link_talks_json_over_udp_and_logs_both_ways(tmp_path):
    streamer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    streamer.bind(("127.0.0.1", 0))
    streamer.settimeout(2.0)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        local_port = probe.getsockname()[1]
    log = DatagramLog(tmp_path / "run.jsonl")
    link = StreamerLink("PSM1", local_port, host="127.0.0.1", log=log)
    try:
        with pytest.raises(RuntimeError, match="nothing heard from its streamer yet"):
            link.send({"hold": ""})  # (its address comes with its datagrams)
        measured = {"measured_cp": {"Position": {"Translation": [0.0, 0.0, -0.1], "Rotation": np.eye(3).tolist()},
                                    "Valid": True, "Timestamp": 1.5}}
        streamer.sendto(json.dumps(measured).encode(), ("127.0.0.1", local_port))
        streamer.sendto(b"not json", ("127.0.0.1", local_port))
        for _ in range(200):
            link.receive()
            if link.received and link.unreadable:
                break
            time.sleep(0.005)
        arm = ArmLink("PSM1", link)
        assert arm.measured_cp().timestamp == 1.5 and link.unreadable == 1
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as other:  # a second streamer: never mixed in
            other.sendto(json.dumps({"measured_cp": {"Valid": False}}).encode(), ("127.0.0.1", local_port))
            for _ in range(200):
                link.receive()
                if link.ignored:
                    break
                time.sleep(0.005)
        assert link.ignored == 1 and arm.measured_cp().timestamp == 1.5
        arm.servo_cp(frames.servo_cp_goal(np.array([0.0, 0.0, -0.1])))
        data, sender = streamer.recvfrom(2048)
        assert sender[1] == local_port  # (sent from the port the streamer sends to, to the port it sends from)
        assert json.loads(data)["servo_cp"]["Goal"]["Translation"] == [0.0, 0.0, -0.1]
    finally:
        link.close()
        streamer.close()
        log.close()
    lines = read_log(tmp_path / "run.jsonl")
    assert [line["dir"] for line in lines] == ["in", "in", "note", "out"] and lines[1]["data"] == {"unreadable": "not json"}
    assert lines[2]["data"]["what"] == "ignored"
    with pytest.raises(ValueError, match="cannot listen on UDP port"):
        StreamerLink("PSM1", _busy_port(), log=log)
    with pytest.raises(ValueError, match="local_port must be a UDP port"):
        StreamerLink("PSM1", 70000)


def _busy_port():
    held = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    held.bind(("", 0))
    _busy_port.held = held  # (kept open while the test asks for it)
    return held.getsockname()[1]


def test_the_dry_run_sends_what_the_env_does_from_the_same_tip():
    env, observation, start, goal = _episode()
    policy = policies.load("reach-lnd")
    clock = Clock(100.0)
    link = EchoLink("PSM1", frames.servo_cp_goal(start), clock=clock)
    seat = RobotSeat(ArmLink("PSM1", link), policy, goal=goal, clock=clock, sleep=clock.sleep)
    np.testing.assert_allclose(seat.observation(start)["observation"], observation["observation"], atol=1e-12)
    np.testing.assert_allclose(seat.observation(start)["desired_goal"], observation["desired_goal"], atol=1e-12)
    summary = seat.run(100)
    for index, (_, payload) in enumerate(link.outbox):
        observation, _, _, _, info = env.step(policy(observation))
        np.testing.assert_allclose(payload["servo_cp"]["Goal"]["Translation"], env.unwrapped.arm.tip, atol=1e-8,
                                   err_msg=f"command {index}")  # (goals go out to the nanometre)
    assert summary.success and info["is_success"] and summary.stopped == "goal reached"
    assert summary.figures()["period_ms_p99"] == pytest.approx(20.0)


def _replay(lines, clock):
    return ReplayLink("PSM1", lines, clock=clock)


def _measured(t, position, valid=True):
    return {"t": t, "link": "PSM1", "dir": "in",
            "data": {"measured_cp": {"Position": {"Translation": list(position), "Rotation": np.eye(3).tolist()},
                                     "Valid": valid, "Timestamp": t}}}


def _state(t, state="ENABLED", homed=True):
    return {"t": t, "link": "PSM1", "dir": "in", "data": {"operating_state": {"State": state, "IsHomed": homed}}}


@pytest.mark.parametrize("state, homed, why", [("DISABLED", True, "operating state is 'DISABLED'"),
                                               ("ENABLED", False, "not homed"), (None, None, "no operating_state")])
def test_an_arm_that_is_not_enabled_and_homed_is_never_moved(state, homed, why):
    _, _, start, goal = _episode()
    clock = Clock(100.0)
    lines = [_measured(0.0, start)] + ([] if state is None else [_state(0.0, state, homed)])
    link = _replay(lines, clock)
    summary = RobotSeat(ArmLink("PSM1", link), policies.load("reach-lnd"), goal=goal, clock=clock,
                        sleep=clock.sleep).run(100)
    assert summary.stopped.startswith("refused") and why in summary.stopped
    assert link.outbox == [] and summary.steps == 0


def test_a_stale_measurement_holds_the_arm_within_100_ms():
    _, _, start, goal = _episode()
    clock = Clock(100.0)
    link = _replay([_state(0.0), _measured(0.0, start)], clock)  # one measurement, then the streamer falls silent
    summary = RobotSeat(ArmLink("PSM1", link), policies.load("reach-lnd"), goal=goal, clock=clock,
                        sleep=clock.sleep).run(100)
    sent = [payload for _, payload in link.outbox]
    assert summary.stopped.startswith("stale measurement: measured_cp") and sent[-1] == {"hold": ""}
    hold_time = link.outbox[-1][0]
    assert 0.08 - 1e-9 <= hold_time - 100.0 <= 0.1 + 1e-9  # (within 100 ms of the last measurement)
    assert all("servo_cp" in payload for payload in sent[:-1]) and len(sent) - 1 == summary.steps == 5


def test_an_invalid_measurement_holds_the_arm():
    _, _, start, goal = _episode()
    clock = Clock(100.0)
    link = _replay([_state(0.0), _measured(0.0, start, valid=False)], clock)
    summary = RobotSeat(ArmLink("PSM1", link), policies.load("reach-lnd"), goal=goal, clock=clock,
                        sleep=clock.sleep).run(10)
    assert summary.stopped == "stale measurement: measured_cp invalid"
    assert [payload for _, payload in link.outbox] == [{"hold": ""}]


class Interrupted:
    """A policy that is interrupted (Ctrl-C, or SIGTERM raised as one) at its ``at``-th call."""

    def __init__(self, at, signum=None):
        self.calls, self.at, self.signum = 0, at, signum
        self.policy = policies.load("reach-lnd")

    def __call__(self, observation):
        self.calls += 1
        if self.calls == self.at:
            if self.signum is None:
                raise KeyboardInterrupt
            signal.raise_signal(self.signum)
        return self.policy(observation)


@pytest.mark.parametrize("signum", [None, signal.SIGTERM])
def test_ctrl_c_or_sigterm_holds_the_arm_and_keeps_the_log(tmp_path, signum):
    _, _, start, goal = _episode()
    clock = Clock(100.0)
    log = DatagramLog(tmp_path / "run.jsonl")
    link = EchoLink("PSM1", frames.servo_cp_goal(start), clock=clock, log=log)
    before = signal.getsignal(signal.SIGTERM)
    summary = RobotSeat(ArmLink("PSM1", link), Interrupted(5, signum), goal=goal, clock=clock,
                        sleep=clock.sleep, log=log).run(100)
    log.close()
    assert summary.stopped == "interrupted (Ctrl-C or SIGTERM)" and link.outbox[-1][1] == {"hold": ""}
    assert summary.steps == 4 and signal.getsignal(signal.SIGTERM) is before
    notes = [line["data"]["what"] for line in read_log(tmp_path / "run.jsonl") if line["dir"] == "note"]
    assert notes == ["start", "hold", "end"]


def test_a_move_the_workspace_box_clamps_is_clamped_and_logged(tmp_path):
    env = gym.make("dvrl_marl/PSMReach-v1").unwrapped
    env.reset(seed=0)
    corner = np.array(env.tip_high)  # (the box's corner: every outward move is clamped)
    clock = Clock(100.0)
    log = DatagramLog(tmp_path / "run.jsonl")
    link = EchoLink("PSM1", frames.servo_cp_goal(corner), clock=clock, log=log)
    outward = lambda observation: np.ones(3, dtype=np.float32)  # noqa: E731
    summary = RobotSeat(ArmLink("PSM1", link), outward, goal=env.goal, clock=clock, sleep=clock.sleep,
                        log=log).run(5)
    log.close()
    assert summary.clamped == 5 and summary.steps == 5
    for _, payload in link.outbox:
        assert np.all(np.asarray(payload["servo_cp"]["Goal"]["Translation"]) <= corner + 1e-12)
    assert sum(line["data"].get("what") == "clamped" for line in read_log(tmp_path / "run.jsonl")) == 5


def test_the_command_line_dry_run_and_its_refusals(tmp_path, capsys):
    _, _, start, goal = _episode()
    log = tmp_path / "dry.jsonl"
    assert main(["robot", "--dry-run", "--goal", *map(str, goal), "--start", *map(str, start), "--log",
                 str(log)]) == 0
    out = capsys.readouterr().out
    assert "PSM1 (dry run: nothing sent): goal reached" in out and out.count("servo_cp [") == 5
    assert len([line for line in read_log(log) if line["dir"] == "out"]) > 10
    assert main(["robot", "--dry-run", "--goal", "0.5", "0", "-0.1"]) == 2  # outside the workspace: said, no traceback
    assert "goal" in capsys.readouterr().err
    assert main(["robot", "--dry-run", "--policy", "marl-suction-pixels"]) == 2
    assert "sees the endoscope's images" in capsys.readouterr().err
    assert main(["robot", "--dry-run", "--policy", "marl-grasper", "--goal", "0", "0", "-0.1"]) == 2
    assert "--goal is for a single-arm policy" in capsys.readouterr().err
    assert main(["robot", "--dry-run", "--partner", "marl-suction", "--goal", "0", "0", "-0.1"]) == 2
    assert "--partner and --preset are for a seat of the collaborative scene" in capsys.readouterr().err
    assert main(["robot", "--dry-run", "--object", "0", "0", "-0.11", "--goal", "0", "0", "-0.1"]) == 2
    assert "--object is for a Pick policy" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["robot", "--goal", "0", "0", "nan"])


def test_the_streamers_files_carry_what_the_seat_reads_and_sends(tmp_path, capsys):
    assert main(["robot", "--write-configs", str(tmp_path / "seat"), "--arm", "PSM2", "--local-port", "12000",
                 "--system-local-port", "12001"]) == 0
    assert "-m manager-PSM2.json" in capsys.readouterr().out
    arm = json.loads((tmp_path / "seat" / "streamer-PSM2.json").read_text())
    system = json.loads((tmp_path / "seat" / "streamer-system.json").read_text())
    manager = json.loads((tmp_path / "seat" / "manager-PSM2.json").read_text())
    assert (arm["ip"], arm["port"], system["port"]) == ("127.0.0.1", "12000", "12001")
    assert {"measured_cp", "operating_state"} <= {c["name"] for c in arm["read-commands"]}
    assert {c["name"] for c in arm["write-commands"]} == {"servo_cp", "move_cp", "jaw/servo_jp"}
    assert "hold" in arm["void-commands"]
    assert {"power_on", "home"} <= set(system["void-commands"]) and system["read-commands"]
    assert [c["configure-parameter"] for c in manager["components"]] == ["streamer-PSM2.json", "streamer-system.json"]
    assert [c["provided"] for c in manager["connections"]] == [{"component": "PSM2", "interface": "Arm"},
                                                               {"component": "system", "interface": "Main"}]
    assert main(["robot"]) == 2 and "--goal X Y Z is needed" in capsys.readouterr().err


def test_the_command_line_says_when_no_arm_answers(tmp_path, capsys):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    code = main(["robot", "--goal", "0", "0", "-0.1", "--local-port", str(port), "--log", str(tmp_path / "r.jsonl")])
    out = capsys.readouterr().out
    assert code == 1 and "refused: PSM1: no operating_state received" in out and "0 commands" in out
    assert [line["data"]["what"] for line in read_log(tmp_path / "r.jsonl")] == ["refused", "end"]


def test_a_pick_dry_run_sends_what_the_env_does_with_its_modelled_object():
    env = gym.make("dvrl_marl/PSMPick-v1")
    observation, _ = env.reset(seed=3)
    start, goal = np.array(env.unwrapped.arm.tip), env.unwrapped.goal.copy()
    policy = policies.load("pick-lnd")
    clock = Clock(100.0)
    link = EchoLink("PSM1", frames.servo_cp_goal(start), clock=clock)
    seat = RobotSeat(ArmLink("PSM1", link), policy, goal=goal, clock=clock, sleep=clock.sleep)
    summary = seat.run(100)
    sent = [payload for _, payload in link.outbox]
    assert len(sent) == 2 * summary.steps  # (each period: servo_cp, then jaw/servo_jp)
    for index in range(summary.steps):
        observation, _, _, _, info = env.step(policy(observation))
        np.testing.assert_allclose(sent[2 * index]["servo_cp"]["Goal"]["Translation"], env.unwrapped.arm.tip,
                                   atol=1e-8, err_msg=f"command {index}")  # (goals go out to the nanometre)
        assert sent[2 * index + 1]["jaw/servo_jp"]["Goal"][0] == pytest.approx(
            jaw_angle(env.unwrapped.arm.jaw), abs=1e-6)
    assert summary.success and info["is_success"] and info["grasped"]
    with pytest.raises(ValueError, match="object_position is for a Pick policy"):
        RobotSeat(ArmLink("PSM1", link), policies.load("reach-lnd"), goal=goal, object_position=[0, 0, -0.11])


def test_a_seat_of_the_scene_on_an_arm_works_the_modelled_scene_as_the_env_does():
    from dvrl_marl.dvrk import SceneRobotSeat
    from dvrl_marl.envs import suction_debris

    policy = policies.load("marl-grasper")
    clock = Clock(100.0)
    link = EchoLink("PSM2", SceneRobotSeat.start_pose(policy, seed=0), clock=clock)
    seat = SceneRobotSeat(ArmLink("PSM2", link), policy, seed=0, clock=clock, sleep=clock.sleep)
    summary = seat.run(1500)
    env = suction_debris.batched_env(num_envs=1, autoreset_mode="disabled", surgeon="scripted", surgeon_seat="suction")
    observations, _ = env.reset(seed=0)
    servo = [payload["servo_cp"]["Goal"]["Translation"] for _, payload in link.outbox if "servo_cp" in payload]
    base = env.core.arms["grasper"].base_position
    for step in range(summary.steps):
        observations, _, terminated, _, info = env.step({"grasper": policy(observations["grasper"])})
        expected = frames.env_to_dvrk(env.core.arms["grasper"].tip_world()[0], frames.BasePose(tuple(base.tolist())),
                                      tool="lnd", env_tip_frame="tool_point")
        np.testing.assert_allclose(servo[step], expected, atol=1e-8, err_msg=f"command {step}")
    assert summary.success and bool(terminated["grasper"][0]) and int(info["grasper"]["debris_delivered"][0]) == 3
    assert len([payload for _, payload in link.outbox if "jaw/servo_jp" in payload]) == summary.steps
    with pytest.raises(ValueError, match="needs a seat of the collaborative scene"):
        SceneRobotSeat(ArmLink("PSM2", link), policies.load("reach-lnd"))
    assert main(["robot", "--dry-run", "--policy", "marl-grasper", "--goal", "0", "0", "-0.1"]) == 2
