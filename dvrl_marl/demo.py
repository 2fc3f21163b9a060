"""The end-to-end demonstration: the collaborative episode (suction_debris_v8) with the shipped policies, recorded
from the endoscope.

``team="pipeline"`` (default): the suction arm runs the learned Reach policy through the ``learned_team``
pipeline; the surgeon seat (the LND) is filled by the learned Reach + Pick pipeline, the scripted surgeon, or a
keyboard. ``team="marl"``: the learned suction seat (the shipped ``marl-suction``, cloned from the scripted
suction and chosen by its mean action beside scripted, learned and person-like surgeons), beside the scripted
surgeon, a person at the keyboard, or (``surgeon="learned"``) the learned ``marl-grasper``. Learned seats act by
their mean action, as a robot is driven (the first ``marl-suction`` needed its exploration noise: it is still
shipped, for the results made with it). Writes ``demo.mp4`` and ``metrics.json`` into a new run folder and returns
the metrics.

``surgeon="keyboard"``: a person works the LND in the scene's window (held keys move, see
:class:`~dvrl_marl.teleop.KeyboardDevice`); the episode starts when they press ENTER and runs in real time at the
50 Hz control rate; the metrics add how well it kept time (steps late, worst lag). Closing the window ends the
episode and still writes the metrics. ``record``: save what the surgeon seat did (any surgeon) as a demonstration
file that :class:`~dvrl_marl.teleop.ReplayDevice` plays back and behaviour cloning learns from.
"""

from __future__ import annotations

import json
import time
from datetime import datetime
from pathlib import Path

from dvrl_marl import policies
from dvrl_marl.envs import suction_debris as scene_env
from dvrl_marl.pipeline import ArmPipeline, load_pipeline, pipeline_policies

__all__ = ["run_demo", "SURGEONS", "TEAMS", "format_summary"]

SURGEONS = ("learned", "scripted", "keyboard")
#: The scene the demo runs: the current version, with its default preset (no bleeding).
ENV_NAME = scene_env.TASK
#: A person at the keyboard gets 2 minutes (6,000 steps) unless ``max_cycles`` says otherwise: the task's 1,500
#: steps (30 s) are enough for a script (an expert pressing the keys finishes in 13-24 s), tight for a person.
KEYBOARD_MAX_CYCLES = 6000
TEAMS = ("pipeline", "marl")
def _pipeline_name() -> str:
    """The learned pipeline when the shipped policies are there, else the scripted one."""
    return "learned_team" if pipeline_policies("learned_team") <= set(policies.available()) else "scripted_team"


#: The learned seats of team="marl": deployable by their default call (benchmarks/partner_zoo.py measures them).
MARL_SEATS = {"suction": "marl-suction", "grasper": "marl-grasper"}


def run_demo(surgeon: str = "learned", out: Path | None = None, seed: int = 0, max_cycles: int | None = None,
             video: bool = True, frame_every: int = 4, width: int = 640, height: int = 480,
             progress: bool = True, pipeline: str | None = None, team: str = "pipeline",
             record: Path | str | None = None) -> dict:
    """Run one collaborative episode; returns the metrics (also written to ``<out>/metrics.json``)."""
    if surgeon not in SURGEONS:
        raise ValueError(f"surgeon must be one of {SURGEONS}, got {surgeon!r}")
    if team not in TEAMS:
        raise ValueError(f"team must be one of {TEAMS}, got {team!r}")
    if team == "marl" and pipeline is not None:
        raise ValueError("team='marl' runs the learned multi-agent policies; a pipeline applies to team='pipeline'")
    out = Path(out) if out else Path("runs") / f"demo-{datetime.now().strftime('%Y%m%d-%H%M%S')}"
    out.mkdir(parents=True, exist_ok=True)
    needed = tuple(MARL_SEATS.values()) if surgeon == "learned" else (MARL_SEATS["suction"],)
    missing = [name for name in needed if name not in policies.available()]
    if team == "marl" and missing:
        raise FileNotFoundError(f"team='marl' with surgeon={surgeon!r} seats the multi-agent policies "
                                f"{' and '.join(needed)}; {' and '.join(missing)} "
                                f"{'is' if len(missing) == 1 else 'are'} not shipped with this release (train: "
                                "dvrl-marl train baselines/configs/suction_debris_mappo.toml; or seat another "
                                "surgeon: --surgeon scripted or keyboard)")
    pipeline = "marl" if team == "marl" else (pipeline or _pipeline_name())
    plans = None if team == "marl" else load_pipeline(pipeline)
    render_mode = "human" if surgeon == "keyboard" else ("rgb_array" if video else None)
    kwargs = {"render_mode": render_mode, "width": width, "height": height}
    if max_cycles is None and surgeon == "keyboard":
        max_cycles = KEYBOARD_MAX_CYCLES
    if max_cycles is not None:
        kwargs["max_cycles"] = max_cycles
    keyboard = None
    if surgeon == "scripted":
        kwargs["surgeon"] = "scripted"
    elif surgeon == "keyboard":
        from dvrl_marl.teleop import KeyboardDevice

        keyboard = KeyboardDevice()
        kwargs["surgeon"] = keyboard
    if surgeon == "learned" and team == "marl":
        kwargs["surgeon"] = policies.load(MARL_SEATS["grasper"])
    elif surgeon == "learned" or (surgeon == "scripted" and record):
        # The pipeline (or the expert, bound here so that it can be recorded) reads the scene layout from an env
        # built with the same parameters.
        layout_env = scene_env.parallel_env(**{k: v for k, v in kwargs.items() if k != "render_mode"})
        if surgeon == "learned":
            kwargs["surgeon"] = ArmPipeline(plans["grasper"], "grasper", layout_env)
        else:
            from dvrl_marl.agents.collaborative import ScriptedSurgeon

            kwargs["surgeon"] = ScriptedSurgeon.for_env(layout_env)
        layout_env.close()
    recorder = None
    if record:
        from dvrl_marl.teleop import Recorder

        recorder = Recorder(kwargs["surgeon"], seat="grasper", surgeon=surgeon, team=team, pipeline=pipeline,
                            seed=seed, env=ENV_NAME, max_cycles=kwargs.get("max_cycles"))
        kwargs["surgeon"] = recorder
    env = scene_env.parallel_env(**kwargs)
    if team == "marl":
        suction = policies.load(MARL_SEATS["suction"])
    else:
        suction = ArmPipeline(plans["suction"], "suction", env)
    if render_mode == "rgb_array":
        # Shadow maps triple the cost of a software-rendered frame; the demo must finish within a minute.
        env.unwrapped.mirrored().model.light_castshadow[:] = 0

    frames = []
    if render_mode == "human" and progress:
        print("The window shows the scene: press ENTER in it to start, hold A/D, S/W, F/R to move the LND, SPACE "
              "for the jaw; ESC or closing the window ends the episode.", flush=True)
    observations, infos = env.reset(seed=seed)  # with a person in the seat: returns when they press ENTER
    contacts, steps, teleop_lost = 0, 0, 0
    start = time.perf_counter()
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=env.params.max_cycles, desc="demo", unit="step", dynamic_ncols=True, mininterval=0.5,
                   disable=None)  # None: a bar on terminals, silence in logs
    info = infos["suction"]
    interrupted = False
    try:
        while env.agents:
            observations, rewards, terminations, truncations, infos = env.step(
                {"suction": suction(observations["suction"])})
            steps += 1
            info = infos["suction"]
            contacts += bool(info["collision"])
            teleop_lost += bool(info.get("teleop_lost"))
            if render_mode == "rgb_array" and steps % frame_every == 0:
                frames.append(env.render())  # ("human": the env draws its window inside step())
            if bar is not None:
                bar.update(1)
                bar.set_postfix(blood=f"{info['blood_remaining']:.1f}ml", debris=info["debris_delivered"])
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM (the CLI turns it into this): the episode ends, nothing is lost
        interrupted = True
    if bar is not None:
        bar.close()
    if render_mode == "rgb_array":
        frames.append(env.render())
    wall = time.perf_counter() - start
    removed = [round(v, 4) for v in env.blood.removed_ml]
    metrics = {
        "success": bool(info["is_success"]),
        "surgeon": surgeon,
        "pipeline": pipeline,
        "team": team,
        "env": ENV_NAME,
        "seed": seed,
        "steps": steps,
        "max_cycles": env.params.max_cycles,
        "blood_removed_ml": removed,
        "blood_remaining_ml": [round(v, 4) for v in env.blood.remaining_ml],
        "debris_delivered": int(info["debris_delivered"]),
        "debris_total": len(env.debris),
        "instrument_contacts": contacts,
        "teleop_lost_steps": teleop_lost,
        "sim_seconds": round(steps * env.params.control_dt, 2),
        "wall_seconds": round(wall, 2),
        "viewer_closed": bool(info.get("viewer_closed", False)),
        "interrupted": interrupted,
    }
    if render_mode == "human":
        metrics["realtime"] = env.realtime_stats()
    if recorder is not None:
        if recorder.actions:
            metrics["recording"] = str(recorder.save(record))
        else:
            metrics["recording"] = None  # the window was closed before the first step: nothing to save
    if render_mode == "rgb_array" and frames:
        from dvrl_marl.video import write_video

        write_video(out / "demo.mp4", frames, fps=max(1, round(env.metadata["render_fps"] / frame_every)))
        metrics["video"] = str(out / "demo.mp4")
    env.close()
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    metrics["out"] = str(out)
    return metrics


def format_summary(metrics: dict) -> str:
    rows = [
        ("result", "SUCCESS" if metrics["success"] else "not complete"),
        ("surgeon seat (LND)", f"{metrics['surgeon']} ({metrics['pipeline']})"),
        ("steps", f"{metrics['steps']} of {metrics['max_cycles']} ({metrics['sim_seconds']} s simulated)"),
        ("blood removed (ml)", " + ".join(f"{v:.2f}" for v in metrics["blood_removed_ml"])),
        ("blood left (ml)", " + ".join(f"{v:.2f}" for v in metrics["blood_remaining_ml"])),
        ("debris delivered", f"{metrics['debris_delivered']} / {metrics['debris_total']}"),
        ("instrument contacts", str(metrics["instrument_contacts"])),
        ("wall time", f"{metrics['wall_seconds']} s"),
    ]
    if metrics.get("realtime"):
        paced = metrics["realtime"]
        rows.append(("real time", f"{paced['steps_late']} of {paced['paced_steps']} steps late (worst by "
                                  f"{paced['worst_lag_ms']} ms), {paced['frames_dropped']} frames dropped"))
    if metrics.get("viewer_closed"):
        rows.append(("ended", "the window was closed"))
    if metrics.get("interrupted"):
        rows.append(("ended", "interrupted (Ctrl-C or SIGTERM); what ran is kept"))
    if "recording" in metrics:
        rows.append(("recording", metrics["recording"] or "nothing recorded (no step was taken)"))
    rows.append(("run folder", metrics["out"]))
    width = max(len(k) for k, _ in rows)
    line = "-" * (width + 40)
    return "\n".join([line] + [f"{k:<{width}}  {v}" for k, v in rows] + [line])

