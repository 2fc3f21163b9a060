"""The ``dvrl-marl`` command line."""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import tempfile
from pathlib import Path

from dvrl_marl.schemas import cli_number
from dvrl_marl.suction_debris.presets import PRESETS, evaluation_options
from dvrl_marl.suction_debris.task import TASK

__all__ = ["main"]


def _render(args) -> int:
    import imageio.v3 as iio

    from dvrl_marl.preview import render_scene, scene_summary

    image = render_scene(args.scene, width=args.width, height=args.height)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(out, image)
    print(scene_summary(args.scene))
    print(f"wrote {out} ({image.shape[1]}x{image.shape[0]}, camera 'endoscope')")
    return 0


def _train(args) -> int:
    from dvrl_marl.files import read_extended_toml
    # each trainer's module registers it on import (dvrl_marl.training.trainers)
    from dvrl_marl.training import clone, jax_mappo, mappo, marl, pixel_seat, runner, trainers  # noqa: F401

    args.config = resolve_config(args.config)
    run_table = read_extended_toml(args.config).get("run", {})  # (a file that extends another: the chain's [run])
    if not isinstance(run_table, dict):
        raise ValueError(f"{args.config}: [run] must be a table")
    request = trainers.TrainRequest(
        config=Path(args.config), seed=args.seed, out=args.out, progress=not args.no_progress, steps=args.steps,
        export=args.export, resume=args.resume, tensorboard=args.tensorboard, ray_address=args.ray_address,
        num_collectors=args.num_collectors, device=args.device, validators=args.validators)
    trainer, note = trainers.choose(request, run_table, asked=args.trainer)
    if note:
        print(note)
    return trainer.run(request, run_table)


def resolve_config(name: str) -> str:
    """A configuration file: the path given, or a shipped configuration's name (``suction_debris_mappo``), which
    works from an installed wheel as well as from a clone."""
    if Path(name).is_file():
        return name
    from dvrl_marl.assets import configs_dir

    shipped = configs_dir() / (name if name.endswith(".toml") else f"{name}.toml")
    if Path(name).name == str(name) and shipped.is_file():
        return str(shipped)
    names = sorted(path.stem for path in configs_dir().glob("*.toml"))
    raise FileNotFoundError(f"no configuration file {name}; shipped configurations: {', '.join(names)}")


#: The env ids a seat policy of the collaborative scene names (the seat env's, or the scene's it learnt on).
_SEAT_ENV_IDS = ("dvrl_marl/SurgeonSeat-v8", TASK)


def _evaluate(args) -> int:
    import json

    from dvrl_marl import policies
    from dvrl_marl.training.runner import evaluate_policy

    policy = policies.load(args.policy)
    env_id = args.env or policy.spec["env_id"]
    if env_id in _SEAT_ENV_IDS or policy.spec.get("agent"):  # a seat of the collaborative scene: its team
        from dvrl_marl.training import teams

        given = [flag for flag, value in (("--env", args.env), ("--tool", args.tool), ("--video", args.video))
                 if value is not None and not (flag == "--env" and value in _SEAT_ENV_IDS)]
        if given:
            raise ValueError(f"evaluate: {', '.join(given)} {'does' if len(given) == 1 else 'do'} not apply to "
                             f"{args.policy}, a seat of the "
                             f"collaborative scene (it is evaluated beside the pipeline partner on {TASK}); "
                             "dvrl-marl evaluate-team pairs it with other partners")

        agent = policy.spec.get("agent")
        if agent not in ("suction", "grasper"):  # (once seated as the grasper without a word)
            raise ValueError(f"{args.policy}: a policy of {env_id} must say which seat it fills (policy.json's "
                             f"'agent': 'suction' or 'grasper'), got {agent!r}")
        partner = "suction" if agent == "grasper" else "grasper"
        seed = teams.EVAL_SEED if args.seed == 1_000_000 else args.seed
        preset = policy.spec.get("preset", "default")  # the scene the seat learnt on (its manifest says)
        from dvrl_marl.envs import suction_debris

        # (the pipeline reads its layout: it irrigates there)
        scene = suction_debris.parallel_env(**evaluation_options(preset))
        result = teams.evaluate_team_batched({agent: policy, partner: teams.seat("pipeline", partner, scene)},
                                             args.episodes, seed=seed, **evaluation_options(preset))
        result = {k: v for k, v in result.items() if k not in ("success", "steps")}
        print(json.dumps({"policy": str(args.policy), "env_id": env_id, "preset": preset, "seat": agent,
                          "partner": "pipeline (learned_team)", **result}, indent=2))
        return 0
    _check_env_id(env_id, "--env" if args.env else f"{args.policy}'s env_id")
    env_kwargs = {"tool": args.tool} if args.tool else {}
    result = evaluate_policy(policy, env_id, args.episodes, seed=args.seed, env_kwargs=env_kwargs, video_path=args.video)
    result.update({"policy": str(args.policy), "env_id": env_id, **env_kwargs})
    print(json.dumps(result, indent=2))
    return 0


def _check_env_id(env_id: str, what: str) -> None:
    """An env id Gymnasium knows, or an error naming what gave it and the library's own ids."""
    import gymnasium as gym

    if env_id not in gym.registry:
        ours = sorted(name for name in gym.registry if name.startswith("dvrl_marl/"))
        raise ValueError(f"{what} {env_id!r} is not a registered environment; this library's: {', '.join(ours)}")


def _evaluate_team(args) -> int:
    import json

    from dvrl_marl.training import teams

    seed = teams.EVAL_SEED if args.seed is None else args.seed
    preset = _team_preset(args.suction, args.grasper, args.preset)  # every seat checked before any pair runs
    rows = teams.cross_play(args.suction, args.grasper, episodes=args.episodes, seed=seed, noise=args.noise,
                            **evaluation_options(preset))
    width = max(12, *(len(row["suction"]) for row in rows), *(len(row["grasper"]) for row in rows))
    print(f"{'suction':<{width}} {'grasper':<{width}} {'success':>8} {'blood ml':>9} {'debris':>7} "
          f"{'median steps':>13} {'contacts':>9}")
    for row in rows:
        median = "-" if row["median_steps_to_completion"] is None else f"{row['median_steps_to_completion']:.0f}"
        print(f"{row['suction']:<{width}} {row['grasper']:<{width}} {row['success_rate']:>8.2f} "
              f"{row['mean_blood_removed_ml']:>9.2f} {row['mean_debris_delivered']:>7.2f} {median:>13} "
              f"{row['mean_contact_steps']:>9.1f}")
    print(f"({args.episodes} episodes each on preset {preset!r}, seeds {seed}..{seed + args.episodes - 1}"
          f"{'; learned seats acting with their exploration noise' if args.noise else ''})")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2) + "\n")
    return 0


#: The seats ``evaluate-team`` builds by name rather than from a policy file (dvrl_marl.training.teams.seat).
_NAMED_SEATS = ("scripted", "keep-clear", "sweeping", "yielding", "person-like", "in-the-way", "pipeline")


def _team_preset(suctions, graspers, given) -> str:
    """The preset every pair of ``evaluate-team`` runs on, after checking every seat it names: the one the learned
    seats record (a policy without one learnt on the default scene), or ``--preset``; a learned seat beside another
    of a different preset needs ``--preset``, and a ``--preset`` other than a seat's own is said."""
    from dvrl_marl import policies

    recorded = {}
    for flag, agent, names in (("--suction", "suction", suctions), ("--grasper", "grasper", graspers)):
        for name in names:
            if name in _NAMED_SEATS:
                if name == "yielding" and agent != "suction":
                    raise ValueError(f"{flag} yielding: 'yielding' is a suction seat")
                continue
            try:
                policy = policies.load_seat(name, agent, who=flag)
            except FileNotFoundError:
                raise ValueError(f"{flag} {name!r}: not a seat ({', '.join(_NAMED_SEATS)}), a shipped policy "
                                 f"({', '.join(policies.available())}) nor a policy folder") from None
            recorded[name] = policy.spec.get("preset", "default")
    presets = sorted(set(recorded.values()))
    if given is None:
        if len(presets) > 1:
            raise ValueError("the learned seats learnt on different presets ("
                             + ", ".join(f"{name}: {preset}" for name, preset in recorded.items())
                             + "); choose the scene with --preset")
        return presets[0] if presets else "default"
    other = {name: preset for name, preset in recorded.items() if preset != given}
    if other:
        print("dvrl-marl: note: --preset " + given + " is not the preset "
              + ", ".join(f"{name} learnt on ({preset})" for name, preset in other.items()), file=sys.stderr)
    return given


def _plot(args) -> int:
    from dvrl_marl.training.plots import plot_learning_curves, plot_team_curves

    png, csv_path = (plot_team_curves if args.team else plot_learning_curves)(args.runs, args.out)
    print(f"wrote {png} and {csv_path}")
    return 0


def _demo(args) -> int:
    from dvrl_marl.demo import format_summary, run_demo

    if args.surgeon == "keyboard" and not os.environ.get("DISPLAY"):
        raise ValueError("--surgeon keyboard needs a display (the scene's window takes the keys); on a headless "
                         "machine run it under xvfb-run")
    with _sigterm_as_interrupt():  # `kill` ends the episode as Ctrl-C does: metrics and recording are written
        metrics = run_demo(surgeon=args.surgeon, out=args.out, seed=args.seed, max_cycles=args.max_cycles,
                           video=not args.no_video, progress=not args.no_progress, pipeline=args.pipeline,
                           team=args.team, record=args.record)
    print(format_summary(metrics))
    return 0


@contextlib.contextmanager
def _sigterm_as_interrupt():
    """SIGTERM raises KeyboardInterrupt while the block runs, so a session stopped with ``kill`` (or by a service
    manager) takes the same path as Ctrl-C and writes what a person recorded before the process ends."""
    def interrupt(signum, frame):
        raise KeyboardInterrupt(f"signal {signum}")

    try:
        previous = signal.signal(signal.SIGTERM, interrupt)
    except ValueError:  # not the main thread (an embedding program): leave its signals alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _teleop(args) -> int:
    from dvrl_marl.teleop.session import TeleopSession
    from dvrl_marl.teleop.web import TeleopServer

    session = TeleopSession(seat=args.seat, partner=args.partner, seed=args.seed, record=not args.no_record,
                            dataset_id=args.dataset, max_cycles=args.max_cycles,
                            **({"preset": args.preset} if args.preset != "default" else {}))
    server = TeleopServer(session, args.host, args.port, allow_remote=args.allow_remote, token=args.token)
    print(f"dvrl-marl teleop: the {args.seat} seat beside the {args.partner} partner; open this URL in a browser "
          f"(Ctrl-C to stop):\n  {server.url}", flush=True)
    if not args.no_record:
        print(f"every episode is recorded; the Minari dataset {session.dataset_id} (or its next free version) is "
              "written when you stop recording or the server stops", flush=True)
    with _sigterm_as_interrupt():  # `kill` stops the server as Ctrl-C does: the recording is written first
        saved = server.run()
    for dataset in saved:
        if dataset.get("id"):
            print(f"saved Minari dataset {dataset['id']}: {dataset['episodes']} episodes "
                  f"({dataset['successes']} succeeded) in {dataset['path']}")
        else:
            print(f"dvrl-marl teleop: could not save {dataset['episodes']} episodes: {dataset['error']}",
                  file=sys.stderr)
    return 0


# The command line's numbers, declared once (dvrl_marl.schemas.cli_number): a count is >= 1 (0 once meant "the
# config's value", -1 "one"), a seed >= 0, a port a TCP port. argparse names the flag in the error.
COUNT = cli_number(int, low=1, name="count (>= 1)")


def output_file(text: str) -> str:
    """A file this command will write, checked before it runs (so that no episode, and nothing a person did, is
    lost to a path that cannot be written): not a folder, in a folder that exists or can be made, writable."""
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r} is a folder; give a file path")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        existed = path.exists()
        with open(path, "ab"):
            pass
        if not existed:
            path.unlink()
    except OSError as error:
        raise argparse.ArgumentTypeError(f"{text!r} cannot be written ({error.strerror or error})") from None
    return text


def output_folder(text: str) -> str:
    """A run folder this command will write into: not a file, and makeable."""
    path = Path(text).absolute()
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r} is a file; give a folder for the run")
    existing = next(folder for folder in (path, *path.parents) if folder.exists())  # made by the run, not here
    try:
        if not existing.is_dir():
            raise NotADirectoryError(f"{existing} is not a folder")
        os.rmdir(tempfile.mkdtemp(dir=existing))  # a folder can be made there
    except OSError as error:
        raise argparse.ArgumentTypeError(f"{text!r} cannot be made ({error.strerror or error})") from None
    return text


#: The image files ``render`` writes (what imageio's Pillow plugin writes).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


def image_file(text: str) -> str:
    """An image file to write: :func:`output_file`, with a suffix that names an image format."""
    if Path(text).is_dir() or Path(text).suffix.lower() in IMAGE_SUFFIXES:
        return output_file(text)  # (a folder is named as one)
    raise argparse.ArgumentTypeError(f"{text!r} has no image suffix; give one of {', '.join(IMAGE_SUFFIXES)}")


def device_name(text: str) -> str:
    """A device of the compiled trainers: ``cpu``, ``cuda`` or ``cuda:<index>`` (what is there is checked when the
    run starts, before any work)."""
    kind, colon, index = text.partition(":")
    if kind not in ("cpu", "cuda") or (colon and (kind == "cpu" or not index.isdigit())):
        raise argparse.ArgumentTypeError(f"{text!r} is not a device; give cpu, cuda or cuda:<index>")
    return text


def host_address(text: str) -> str:
    """An interface to serve on: an IP address or a name this machine resolves."""
    import socket

    try:
        socket.getaddrinfo(text, None)
    except (socket.gaierror, UnicodeError) as error:
        raise argparse.ArgumentTypeError(f"{text!r} is not an address this machine can serve on ({error})") from None
    return text
SEED = cli_number(int, low=0, name="seed (>= 0)")
PORT = cli_number(int, low=0, high=65535, name="port (0-65535)")
METRES = cli_number(float, low=-1.0, high=1.0, name="position in metres (-1..1)")
SECONDS = cli_number(float, low=0.0, high=600.0, name="seconds (0-600)")


def _robot(args) -> int:
    """A shipped single-arm policy on a dVRK arm through its socket streamer (dvrl_marl.dvrk), or a dry run."""
    import time

    import numpy as np

    from dvrl_marl import frames, policies
    from dvrl_marl.dvrk import ArmLink, DatagramLog, EchoLink, RobotSeat, SceneRobotSeat, StreamerLink, SystemLink

    if args.write_configs:
        from dvrl_marl.dvrk.configs import write_configs

        manager = write_configs(args.write_configs, arm=args.arm, ip=args.seat_ip, arm_port=args.local_port,
                                system_port=args.system_local_port)
        print(f"wrote the streamers' files in {manager.parent}; start the dVRK's system program there with "
              f"-m {manager.name} (docs/robot.md)")
        return 0
    policy = policies.load(args.policy)
    if policy.image_options is not None:
        raise ValueError(f"--policy {args.policy}: it sees the endoscope's images, which the robot seat does not draw")
    scene = policy.spec.get("agent") is not None  # (a seat of the collaborative scene)
    task = policy.spec.get("env_id", "").split("/")[-1].split("-")[0]
    if not scene and task not in ("PSMReach", "PSMReachDense", "PSMPick", "PSMPickDense"):
        raise ValueError(f"--policy {args.policy}: the robot seat runs single-arm policies (reach-lnd, "
                         f"reach-suction-irrigation, pick-lnd) and seats of the collaborative scene (marl-grasper, "
                         f"...); this one is for {policy.spec.get('env_id')!r}")
    if args.object is not None and not task.startswith("PSMPick"):
        raise ValueError("--object is for a Pick policy (the object the env models; Reach has none)")
    if scene and args.goal is not None:
        raise ValueError(f"--goal is for a single-arm policy; {args.policy} works the collaborative scene's seat "
                         "(its goals are the scene's)")
    if not scene and args.goal is None:
        raise ValueError("robot: --goal X Y Z is needed (metres, the arm's base frame)")
    if not scene and (args.partner != "scripted" or args.preset != "default"):
        raise ValueError("--partner and --preset are for a seat of the collaborative scene")
    tool = (policy.spec.get("env_kwargs") or {}).get("tool", "lnd")
    log_path = Path(args.log or Path("runs") / f"robot-{time.strftime('%Y%m%d-%H%M%S')}.jsonl")
    log = DatagramLog(log_path)
    links = []
    try:
        if args.dry_run:
            if scene:  # (where the scene's model starts the seat's arm)
                link = EchoLink(args.arm, SceneRobotSeat.start_pose(policy, args.preset, args.seed), log=log)
            else:
                start = np.asarray(args.start if args.start else (0.0, 0.0, -0.11))
                link = EchoLink(args.arm, frames.servo_cp_goal(start, tool=tool), log=log)
        else:
            link = StreamerLink(args.arm, args.local_port, host=args.host, log=log)
            links.append(link)
            if args.power_on or args.home:
                system = StreamerLink("system", args.system_local_port, host=args.host, log=log)
                links.append(system)
                system_link = SystemLink(system)
                system_link.wait_heard(timeout_s=5.0)
                if args.power_on:
                    system_link.power_on()
                    time.sleep(args.home_wait / 2)
                if args.home:
                    system_link.home()
                    time.sleep(args.home_wait)
        if scene:
            seat = SceneRobotSeat(ArmLink(args.arm, link), policy, partner=args.partner, preset=args.preset,
                                  seed=args.seed, log=log)
        else:
            seat = RobotSeat(ArmLink(args.arm, link), policy, goal=args.goal, tool=tool, log=log,
                             object_position=args.object)
        summary = seat.run(args.steps)
    finally:
        for link in links:
            link.close()
        log.close()
    figures = summary.figures()
    distance = "-" if figures["final_distance_mm"] is None else f"{figures['final_distance_mm']:.1f}"
    print(f"{args.arm}{' (dry run: nothing sent)' if args.dry_run else ''}: {summary.stopped}; "
          f"{figures['steps']} commands, goal {'reached at step ' + str(summary.success_step) if summary.success else 'not reached'}"
          f" (distance {distance} mm), period median {figures['period_ms_median']} ms, "
          f"p99 {figures['period_ms_p99']} ms, tracking error {figures['tracking_error_mm']} mm; log {log_path}")
    if args.dry_run:
        for command in summary.commands[: args.show]:
            print("servo_cp", [round(v, 6) for v in command])
    return 0 if summary.success or args.dry_run else 1


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="dvrl-marl", description="dVRK reinforcement-learning environments on MuJoCo")
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="run the collaborative suction + debris episode end to end (MP4 + metrics)")
    demo.add_argument("--surgeon", choices=["learned", "scripted", "keyboard"], default="learned",
                      help="who works the LND (default: the learned Reach + Pick pipeline)")
    demo.add_argument("--out", type=output_folder, help="run folder (default runs/demo-<timestamp>)")
    demo.add_argument("--seed", type=SEED, default=0)
    demo.add_argument("--max-cycles", type=COUNT, help="truncate the episode after this many steps (default: the "
                      "task's 1500; 6000, two minutes, for --surgeon keyboard)")
    demo.add_argument("--pipeline", help="pipeline name or TOML file (default: learned_team)")
    demo.add_argument("--team", choices=["pipeline", "marl"], default="pipeline",
                      help="pipeline: composed single-arm policies (default); marl: the suction learned by MAPPO "
                      "(with --surgeon learned, the learned grasper too)")
    demo.add_argument("--record", metavar="FILE", type=output_file, help="save what the surgeon seat did as a demonstration (.npz) "
                      "that ReplayDevice plays back and behaviour cloning learns from")
    demo.add_argument("--no-video", action="store_true", help="skip rendering")
    demo.add_argument("--no-progress", action="store_true", help="no progress bar")
    demo.set_defaults(func=_demo)
    teleop = sub.add_parser("teleop", help="a person in the surgeon seat, in a web browser (prints the URL to open)")
    teleop.add_argument("--seat", choices=["grasper", "suction"], default="grasper",
                        help="the arm the person works (default: grasper, the LND)")
    teleop.add_argument("--partner", default="scripted", help="who works the other arm: scripted (default), learned "
                        "(the learned seat: marl-suction-yielding or marl-grasper), pipeline (the Reach + Pick "
                        "pipeline), or a shipped policy name or folder")
    teleop.add_argument("--port", type=PORT, default=8000, help="port (default 8000; 0: any free port)")
    teleop.add_argument("--host", type=host_address, default="127.0.0.1", help="interface to serve on (default 127.0.0.1: this "
                        "machine only; another needs --allow-remote)")
    teleop.add_argument("--allow-remote", action="store_true", help="allow --host to be reachable from other "
                        "machines (the access token in the URL is still checked on every connection)")
    teleop.add_argument("--token", help="access token (default: a new random one, printed in the URL)")
    teleop.add_argument("--seed", type=SEED, default=0, help="episode k runs seed SEED + k")
    teleop.add_argument("--max-cycles", type=COUNT, help="steps before an episode is cut (default 6000: 2 minutes)")
    teleop.add_argument("--dataset", default="dvrl_marl/surgeon-teleop-v1",
                        help="Minari dataset id to record into (the next free version when taken)")
    teleop.add_argument("--no-record", action="store_true", help="do not record episodes")
    teleop.add_argument("--preset", choices=sorted(PRESETS), default="default", help="the scene's preset (irrigation: "
                        "a clotted field; in the suction seat, hold I to irrigate)")
    teleop.set_defaults(func=_teleop)
    render = sub.add_parser("render", help="render a scene from its endoscope camera and print a summary")
    render.add_argument("--scene", default="collaborative", help="a scene with an endoscope camera: collaborative "
                        "(default), pick_lnd, pick_lnd_v1, reach_lnd, reach_suction_irrigation")
    render.add_argument("--out", type=image_file, default="collaborative.png",
                        help=f"image file to write ({', '.join(IMAGE_SUFFIXES)}; default collaborative.png)")
    render.add_argument("--width", type=COUNT, default=640)
    render.add_argument("--height", type=COUNT, default=480)
    render.set_defaults(func=_render)

    robot = sub.add_parser("robot", help="a shipped single-arm policy on a dVRK arm through the dVRK's socket "
                           "streamer (UDP, no ROS; docs/robot.md), or --dry-run")
    robot.add_argument("--policy", default="reach-lnd", help="a shipped Reach or Pick policy or its folder (default "
                       "reach-lnd; pick-lnd: the object is the env's model of it)")
    robot.add_argument("--partner", default="scripted", help="a scene's seat: who works the other arm in the model "
                       "(scripted, the default, or a shipped seat's name)")
    robot.add_argument("--preset", choices=sorted(PRESETS), default="default", help="a scene's seat: the scene")
    robot.add_argument("--seed", type=SEED, default=0, help="a scene's seat: the modelled scene's seed")
    robot.add_argument("--object", type=METRES, nargs=3, metavar=("X", "Y", "Z"),
                       help="Pick: where the modelled object starts (m; default on the table below the start)")
    robot.add_argument("--arm", default="PSM1", help="the arm's name, as in the logs (default PSM1)")
    robot.add_argument("--goal", type=METRES, nargs=3, metavar=("X", "Y", "Z"),
                       help="the goal (m) in the arm's base frame, the measured_cp point, inside the env's workspace")
    robot.add_argument("--host", type=host_address, default="127.0.0.1",
                       help="the dVRK's machine: datagrams from elsewhere are ignored (default 127.0.0.1)")
    robot.add_argument("--local-port", type=PORT, default=10002,
                       help="the port the arm's streamer sends to (its configuration's port; default 10002)")
    robot.add_argument("--power-on", action="store_true", help="power the system on first (through its streamer)")
    robot.add_argument("--home", action="store_true", help="home the arms first (through the system's streamer)")
    robot.add_argument("--home-wait", type=SECONDS, default=10.0, help="seconds to wait after homing (default 10)")
    robot.add_argument("--system-local-port", type=PORT, default=10004,
                       help="the port the system's streamer sends to (default 10004)")
    robot.add_argument("--steps", type=COUNT, default=100, help="control periods at most (default 100, the env's)")
    robot.add_argument("--log", type=output_file, help="the datagrams' log, JSON lines (default runs/robot-<time>.jsonl)")
    robot.add_argument("--dry-run", action="store_true", help="send nothing: a perfect kinematic arm at --start "
                       "answers, and the commands are printed")
    robot.add_argument("--start", type=METRES, nargs=3, metavar=("X", "Y", "Z"),
                       help="the dry run's start (m; default the workspace centre)")
    robot.add_argument("--show", type=COUNT, default=5, help="commands a dry run prints (default 5)")
    robot.add_argument("--write-configs", metavar="DIR", type=output_folder, help="write the streamers' "
                       "configuration files (the arm's, the system's and the component manager's) into DIR and stop")
    robot.add_argument("--seat-ip", type=host_address, default="127.0.0.1",
                       help="with --write-configs: the address the streamers send to (this machine's; default "
                       "127.0.0.1)")
    robot.set_defaults(func=_robot)

    train = sub.add_parser("train", help="train a policy from a configuration (baselines/configs/*.toml)")
    train.add_argument("config", help="configuration TOML file, or the name of a shipped one (e.g. "
                       "suction_debris_mappo; see baselines/configs)")
    train.add_argument("--seed", type=SEED, default=0)
    train.add_argument("--steps", type=COUNT, help="override total_timesteps")
    train.add_argument("--out", type=output_folder, help="run folder (default runs/<config>-seed<seed>)")
    train.add_argument("--resume", action="store_true", help="continue from the run folder's checkpoint")
    train.add_argument("--tensorboard", action="store_true", help="also write TensorBoard logs to <out>/sb3_log")
    train.add_argument("--export", type=output_folder, help="folder to export the final policy to (numpy format)")
    train.add_argument("--no-progress", action="store_true", help="no progress bar")
    train.add_argument("--ray-address", help="MAPPO/IPPO: collect experience on a Ray cluster (auto: the cluster "
                       "this machine joined with `ray start`; host:port; local: a Ray instance of this process)")
    train.add_argument("--num-collectors", type=COUNT, help="MAPPO/IPPO: Ray collector actors (each steps "
                       "num_envs / N worlds; default 1 with --ray-address); without --ray-address, starts Ray here")
    train.add_argument("--trainer", help="who trains it (default: the first that can): MAPPO/IPPO: jax, each update "
                       'cycle compiled whole by JAX (the default; pip install "dvrl-marl[jax]"), or torchrl (TorchRL: '
                       "checkpoints, Ray collectors, partners in a seat, pretraining); other configurations have one")
    train.add_argument("--device", type=device_name, help="--trainer jax: cpu, cuda or cuda:<index> (default: the "
                       "configuration's device)")
    train.add_argument("--validators", type=COUNT, help="--trainer jax: validations scored at once (default 1)")
    train.set_defaults(func=_train)

    evaluate = sub.add_parser("evaluate", help="success rate of a policy over seeded episodes")
    evaluate.add_argument("policy", help="a shipped policy name (see dvrl_marl.policies.available()) or a folder")
    evaluate.add_argument("--env", help="environment id (default: the one the policy was trained on)")
    evaluate.add_argument("--tool", choices=["lnd", "suction_irrigation"], help="Reach: roll out on this tool")
    evaluate.add_argument("--episodes", type=COUNT, default=50)
    evaluate.add_argument("--seed", type=SEED, default=1_000_000)
    evaluate.add_argument("--video", type=output_file, help="write the first episodes to this MP4 (single-arm policies)")
    evaluate.set_defaults(func=_evaluate)

    team = sub.add_parser("evaluate-team", help="success of a collaborative team (or a cross-play matrix) on "
                                                 "held-out seeds")
    team.add_argument("--suction", nargs="+", default=["marl-suction"],
                      help="suction seat(s): scripted, pipeline, a shipped policy name or a folder")
    team.add_argument("--grasper", nargs="+", default=["marl-grasper"], help="grasper seat(s), the same choices")
    team.add_argument("--episodes", type=COUNT, default=100)
    team.add_argument("--seed", type=SEED, help="first evaluation seed (default: the held-out range)")
    team.add_argument("--json", type=output_file, help="also write the rows to this JSON file")
    team.add_argument("--preset", choices=sorted(PRESETS), default=None,
                      help=f"the scene's preset ({TASK}; default: the one the learned seats record, else "
                           "default); its learning options (reward, observation features) are left out, since the "
                           "seats compute their own features")
    team.add_argument("--noise", action="store_true",
                      help="learned seats act with the exploration noise they trained with (seeded; their policy.json "
                           "records it), not their mean action")
    team.set_defaults(func=_evaluate_team)

    plot = sub.add_parser("plot", help="success rate against training steps (paper Fig. 4 style)")
    plot.add_argument("runs", nargs="+", help="run folders (each with progress.csv), or such CSV files")
    plot.add_argument("--team", action="store_true",
                      help="multi-agent runs: success and blood removed against steps (baselines/results/marl)")
    plot.add_argument("--out", type=lambda text: output_file(text + ".png")[:-4], default="baselines/results/learning_curves",
                      help="output path without suffix")
    plot.set_defaults(func=_plot)
    return parser


def main(argv: list[str] | None = None) -> int:
    import dvrl_marl  # noqa: F401  (sets MUJOCO_GL=egl on headless machines before MuJoCo loads)

    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except ModuleNotFoundError as error:
        if (error.name or "").split(".")[0] not in _EXTRA_MODULES:
            raise
        extra = "teleop" if args.command == "teleop" else (  # [teleop] brings [data] too
            "data" if error.name == "minari" else "ray" if error.name == "ray" else "train")
        print(f"dvrl-marl: {args.command} needs the {extra} extra ({error.name} is not installed): "
              f'pip install "dvrl-marl[{extra}]"', file=sys.stderr)
        return 2
    except (OSError, ValueError, RuntimeError) as error:  # (a file, a value, a device or OpenGL: said, no traceback)
        print(f"dvrl-marl: error: {error}", file=sys.stderr)
        return 2


#: What the optional extras bring ([train], [teleop], [data]); a command missing one of them ends with the install
#: hint, not a traceback.
_EXTRA_MODULES = {"torch", "torchrl", "tensordict", "stable_baselines3", "sb3_contrib", "supersuit", "matplotlib",
                  "tensorboard", "starlette", "uvicorn", "websockets", "minari", "ray"}


if __name__ == "__main__":
    sys.exit(main())
