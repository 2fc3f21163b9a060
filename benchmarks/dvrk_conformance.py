"""The robot seat against the dVRK's own software: ``reach-lnd`` on the dVRK's kinematically simulated PSM1 (Large
Needle Driver), through its socket streamer, for seeded goals; then the stale-measurement hold, timed with the dVRK's
process stopped mid-run.

Needs the dVRK's system program built with the socket streamer (release 2.4.0; the project does not build it:
``docs/robot.md``). Each episode is the env's: ``PSMReach-v1`` reset with the seed gives the start and the goal; the
arm goes to the start by the dVRK's own trajectory (``move_cp``), then the seat runs at most 100 steps. Every datagram
both ways is logged (``--logs``), and the figures go to a JSON record:

    python benchmarks/dvrk_conformance.py --system /path/to/sawIntuitiveResearchKitSystem \\
        --share /path/to/sawIntuitiveResearchKit/share --library-path /path/to/lib:/path/to/other/lib \\
        --episodes 20 --json benchmarks/results/dvrk_conformance_2026-12-01.json --logs tests/dvrk_recordings
"""

from __future__ import annotations

import argparse
import gzip
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import provenance  # noqa: E402

ARM_PORT, SYSTEM_PORT = 10002, 10004


def start_system(system: str, share: Path, folder: Path, library_path: str):
    """The dVRK's system program with PSM1 in kinematic simulation and the streamers, text only. Its standard input
    is a pipe from ``sleep`` that stays open and silent (given this process's own pipe, its key loop spun and the
    arm's homing never ended, here)."""
    environment = {**os.environ, "LD_LIBRARY_PATH": library_path + ":" + os.environ.get("LD_LIBRARY_PATH", "")}
    command = [system, "-t", "-j", str(share / "system" / "system-PSM1_Classic_KIN_SIMULATED.json"),
               "-m", "manager-PSM1.json"]
    silence = subprocess.Popen(["sleep", "infinity"], stdout=subprocess.PIPE)
    process = subprocess.Popen(command, cwd=folder, env=environment, stdin=silence.stdout,
                               stdout=open(folder / "system.out", "w"), stderr=subprocess.STDOUT)
    silence.stdout.close()
    return process, silence


def wait_for(predicate, arm, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        arm.update()
        if predicate():
            return
        time.sleep(0.01)
    raise RuntimeError(f"timed out waiting for {what}; operating_state: {arm.operating_state}")


def go_to(arm, pose, timeout_s: float = 10.0) -> float:
    """The dVRK's own trajectory to ``pose`` (``move_cp``); returns how far (mm) the measured tip ended from it."""
    arm.move_cp(pose)
    time.sleep(0.1)
    wait_for(lambda: arm.operating_state and not arm.operating_state.get("IsBusy", False), arm, timeout_s,
             "the move to the start")
    time.sleep(0.2)
    arm.update()
    return 1000.0 * float(np.linalg.norm(arm.measured_cp().position - pose[:3, 3]))


class _Done(Exception):
    """The episodes are done and no stale-measurement run was asked for."""


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--system", required=True, help="the dVRK's sawIntuitiveResearchKitSystem")
    parser.add_argument("--share", type=Path, required=True, help="sawIntuitiveResearchKit's share folder")
    parser.add_argument("--library-path", default="", help="folders of the dVRK's and the streamer's libraries")
    parser.add_argument("--version", default="2.4.0", help="the dVRK's release, as the record names it")
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--policy", default="reach-lnd", help="reach-lnd, or pick-lnd (the object modelled by the env)")
    parser.add_argument("--no-stale", action="store_true", help="skip the stale-measurement run")
    parser.add_argument("--json", help="write the record here")
    parser.add_argument("--logs", type=Path, help="keep each episode's datagram log here (gzipped JSON lines)")
    args = parser.parse_args()
    code = provenance.code_state()
    import gymnasium as gym

    import dvrl_marl  # noqa: F401
    from dvrl_marl import frames, policies
    from dvrl_marl.dvrk import ArmLink, DatagramLog, RobotSeat, SceneRobotSeat, StreamerLink, SystemLink
    from dvrl_marl.dvrk.configs import write_configs

    folder = Path(tempfile.mkdtemp(prefix="dvrk-seat-"))
    write_configs(folder, arm="PSM1", arm_port=ARM_PORT, system_port=SYSTEM_PORT)
    log_folder = Path(tempfile.mkdtemp(prefix="dvrk-logs-"))
    setup_log = DatagramLog(log_folder / "setup.jsonl")
    policy = policies.load(args.policy)
    env_id = policy.spec["env_id"]
    scene = policy.spec.get("agent") is not None  # (a seat of the collaborative scene: the rest of it modelled)
    for attempt in range(3):  # (a start whose streamers stay silent, seen now and then here, is tried again)
        process, silence = start_system(args.system, args.share, folder, args.library_path)
        arm_link = StreamerLink("PSM1", ARM_PORT, host="127.0.0.1", log=setup_log)
        system_link = StreamerLink("system", SYSTEM_PORT, host="127.0.0.1", log=setup_log)
        arm, system = ArmLink("PSM1", arm_link), SystemLink(system_link)
        try:
            system.wait_heard(timeout_s=10.0)
            break
        except RuntimeError:
            print(f"start {attempt + 1}: the streamers stayed silent; starting the dVRK again", file=sys.stderr)
            for link in (arm_link, system_link):
                link.close()
            process.kill()
            silence.kill()
            process.wait()
            time.sleep(1.0)
    rows, stale, periods = [], None, []
    try:
        system.wait_heard(timeout_s=10.0)
        wait_for(lambda: arm.operating_state is not None and arm.measured_cp() is not None, arm, 30.0,
                 "the arm's streamer")
        time.sleep(3.0)  # (homing asked within a second of the start stayed HOMING for good, here: let it settle)
        arm.update()
        system.power_on()
        wait_for(lambda: arm.operating_state.get("State") == "ENABLED", arm, 30.0, "the arm to be enabled")
        system.home()
        wait_for(lambda: arm.operating_state.get("IsHomed") and not arm.operating_state.get("IsBusy"), arm, 60.0,
                 "the arm to be homed")
        for seed in range(args.episodes):
            if scene:
                pose = SceneRobotSeat.start_pose(policy, seed=seed)
                start, goal = pose[:3, 3], None
                start_error = go_to(arm, pose)
                log = DatagramLog(log_folder / f"episode-{seed:02d}.jsonl")
                arm_link.log = log
                summary = SceneRobotSeat(arm, policy, seed=seed, log=log).run(1500)
            else:
                env = gym.make(env_id)
                env.reset(seed=seed)
                start, goal = np.array(env.unwrapped.arm.tip), env.unwrapped.goal.copy()
                start_error = go_to(arm, frames.servo_cp_goal(start))
                log = DatagramLog(log_folder / f"episode-{seed:02d}.jsonl")
                arm_link.log = log
                summary = RobotSeat(arm, policy, goal=goal, log=log).run(100)
            arm_link.log = setup_log
            log.close()
            periods += summary.periods_ms
            rows.append({"seed": seed, "start": start.tolist(), "goal": None if goal is None else goal.tolist(),
                         "start_error_mm": round(start_error, 4), **summary.figures()})
            print(json.dumps(rows[-1]))
        if args.no_stale:
            raise _Done
        # the stale-measurement hold: the dVRK's process stopped mid-run (no datagram comes), then let go on
        env = gym.make("dvrl_marl/PSMReach-v1")
        env.reset(seed=1000)
        go_to(arm, frames.servo_cp_goal(np.array(env.unwrapped.arm.tip)))
        log = DatagramLog(log_folder / "stale.jsonl")
        arm_link.log = log
        seat = RobotSeat(arm, policy, goal=env.unwrapped.goal.copy(), log=log)
        calls = {"n": 0}
        inner = seat.policy

        def stop_the_dvrk_at_step_10(observation):
            calls["n"] += 1
            if calls["n"] == 10:
                os.kill(process.pid, signal.SIGSTOP)
            return inner(observation)

        seat.policy = stop_the_dvrk_at_step_10
        summary = seat.run(100)
        os.kill(process.pid, signal.SIGCONT)
        log.close()
        arm_link.log = setup_log
        lines = [json.loads(text) for text in (log_folder / "stale.jsonl").read_text().splitlines()]
        last_in = max(line["t"] for line in lines if line["dir"] == "in")
        holds = [line["t"] for line in lines if line["dir"] == "out" and line["data"] == {"hold": ""}]
        stale = {"stopped": summary.stopped, "steps_before": summary.steps,
                 "hold_after_last_measurement_ms": round(1000.0 * (min(holds) - last_in), 2) if holds else None}
        print(json.dumps(stale))
    except _Done:
        pass
    finally:
        for link in (arm_link, system_link):
            link.close()
        setup_log.close()
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
        silence.kill()
    successes = sum(row["success"] for row in rows)
    tracking = [row["tracking_error_mm"] for row in rows if row["tracking_error_mm"] is not None]
    p99s = [row["period_ms_p99"] for row in rows if row["period_ms_p99"] is not None]
    record = {"what": f"{args.policy} on the dVRK's kinematically simulated PSM1 (LND) through its socket streamer"
              + (" (the object modelled by the env)" if "Pick" in env_id else "")
              + (" (the rest of the scene modelled, the scripted partner in the other seat)" if scene else ""),
              "policy": args.policy, "dvrk_version": args.version, "episodes": len(rows), "successes": successes,
              "largest_tracking_error_mm": max(tracking) if tracking else None,
              "largest_period_ms_p99": max(p99s) if p99s else None, "stale_hold": stale, "rows": rows,
              "periods": len(periods), "period_ms_median_all": round(float(np.median(periods)), 3) if periods else None,
              "period_ms_p99_all": round(float(np.percentile(periods, 99)), 3) if periods else None,
              "period_ms_max_all": round(float(np.max(periods)), 3) if periods else None,
              "command": "python benchmarks/dvrk_conformance.py " + " ".join(sys.argv[1:]), "code": code}
    print(json.dumps({key: value for key, value in record.items() if key not in ("rows", "code")}, indent=1))
    if args.json:
        Path(args.json).write_text(json.dumps(record, indent=1) + "\n")
    if args.logs:
        args.logs.mkdir(parents=True, exist_ok=True)
        for path in sorted(log_folder.glob("*.jsonl")):
            with path.open("rb") as source, gzip.open(args.logs / (path.name + ".gz"), "wb") as target:
                shutil.copyfileobj(source, target)
    return 0 if successes >= 0.95 * len(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
