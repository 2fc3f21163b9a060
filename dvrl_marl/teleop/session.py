"""A person's episodes in the surgeon seat, run in real time in a thread of their own: what the web seat serves.

:class:`TeleopSession` owns one seat of ``suction_debris_v8`` (``dvrl_marl/SurgeonSeat-v8``, the partner arm driven
inside it), a :class:`~dvrl_marl.teleop.browser.BrowserDevice` in the seat, and a loop that steps at the 50 Hz
control rate once the person starts, draws the endoscope view (JPEG) at ``frames_per_second`` and publishes each
frame with the episode's status. It records every episode it runs as a Minari episode (the seat's observations,
the executed actions, rewards, terminations, truncations, infos with ``teleop_lost``, the env spec and the
seed) and writes them as a dataset when recording stops or the session closes, so each episode replays exactly
(:func:`dvrl_marl.datasets.replay`) and trains a surgeon (``dvrl-marl train``, algorithm ``bc``).

The seat's semantics are those of every device: while the device raises (no page, or a silent one) the seat holds
still (zero motion, jaw or valve as last commanded) and the step's info says ``teleop_lost``; the episode goes on.
Nothing here knows HTTP; :mod:`dvrl_marl.teleop.web` serves it.
"""

from __future__ import annotations

import io
import json
import queue
import struct
import threading
import time
from collections.abc import Callable

import numpy as np

from dvrl_marl.envs.scene_view import SceneView
from dvrl_marl.pacing import RealTimePacer
from dvrl_marl.suction_debris.layout import ACTION_WIDTH
from dvrl_marl.suction_debris.task import TASK
from dvrl_marl.teleop.browser import BrowserDevice

__all__ = ["TeleopSession", "PARTNERS", "TELEOP_MAX_CYCLES", "DEFAULT_DATASET_ID", "TELEOP_ENV_ID", "scene_view", "pack_frame", "unpack_frame"]

#: ``learned`` is the learned seat for the partner's arm (``marl-suction-yielding`` beside a person at the LND: it
#: waits rather than push where the person's instrument is in its way; ``marl-grasper`` beside a person at the
#: suction: deployable by their mean action); ``pipeline`` is the learned_team
#: pipeline's arm (the learned Reach policy for the suction, Reach + Pick for the
#: LND); a shipped policy name or folder also works.
PARTNERS = ("scripted", "learned", "pipeline")
#: ``--partner learned``: the learned seat that works the other arm beside a person in ``seat``.
LEARNED_PARTNERS = {"grasper": "marl-suction-yielding", "suction": "marl-grasper"}
#: A person gets 2 minutes (6,000 steps at 50 Hz); the task's 1,500 steps (30 s) suit a script, not a newcomer.
TELEOP_MAX_CYCLES = 6000
DEFAULT_DATASET_ID = "dvrl_marl/surgeon-teleop-v1"
#: The seat a person works: the current scene, whose hand-off is judged at the grip and whose dropped pins stay in view.
TELEOP_ENV_ID = "dvrl_marl/SurgeonSeat-v8"
_TOOLS = {"grasper": "Large Needle Driver (grasper)", "suction": "Suction & Irrigation"}
_IDLE_PUBLISH_S = 0.1  # frames while nobody moves anything (waiting to start, episode over): 10 per second


def pack_frame(status: dict, jpeg: bytes) -> bytes:
    """One message to the page: 4 bytes (big-endian length of the JSON status), the status, the JPEG."""
    header = json.dumps(status, separators=(",", ":")).encode()
    return struct.pack(">I", len(header)) + header + jpeg


def unpack_frame(payload: bytes) -> tuple[dict, bytes]:
    """The inverse of :func:`pack_frame`."""
    (length,) = struct.unpack(">I", payload[:4])
    return json.loads(payload[4:4 + length]), payload[4 + length:]


def _rounded(value, digits: int = 1):
    """``value`` with every float rounded (to 0.1 mm for the cues and outlines the page draws), JSON-ready."""
    if isinstance(value, dict):
        return {key: _rounded(item, digits) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_rounded(item, digits) for item in value]
    if isinstance(value, (bool, type(None), str)):
        return value
    return round(float(value), digits)


def scene_view(scene, seat: str, outline: dict | None = None) -> dict:
    """What the page shows of ``scene`` (a ``suction_debris`` parallel env) to the person in ``seat``: blood (ml and
    as read: "clear"), debris found and delivered, time, both tips (mm, world), the visible pins, the seat's cues
    (:meth:`~dvrl_marl.envs.scene_view.SceneView.cues`), the jaw and valve, and the scene's outline
    for the top and side views (pass it in to reuse it: it never changes). A person-like script reads this and
    nothing else (:mod:`dvrl_marl.teleop.person`)."""
    view = SceneView(scene)
    progress = view.progress()
    return {
        "time_s": round(progress["time_s"], 2),
        "blood_ml": [round(v, 2) for v in progress["blood_ml"]], "blood_text": view.blood_text(),
        "debris_found": progress["debris_found"], "debris_delivered": progress["debris_delivered"],
        "debris_total": progress["debris_total"],
        "seat": seat, "seat_tool": _TOOLS[seat],
        "tip_mm": [round(1000.0 * v, 2) for v in progress["tips"][seat]],
        "tips_mm": {agent: [round(1000.0 * v, 1) for v in tip] for agent, tip in progress["tips"].items()},
        "cues": _rounded(view.cues(seat)), "pins": _rounded(view.pins()),
        "outline": outline if outline is not None else _rounded(view.outline()),
        "jaw": round(progress["jaw"], 3), "valve_open": progress["valve_open"],
        "irrigating": progress["irrigating"],
        **({"saline_used_ml": round(progress["saline_used_ml"], 2), "overflow_events": progress["overflow_events"]}
           if "saline_used_ml" in progress and scene.params.irrigation_ml_s > 0.0 else {}),
    }


class TeleopSession:
    """The seat's loop (see the module documentation).

    ``seat``: ``"grasper"`` (the LND, default) or ``"suction"``; ``partner``: ``"scripted"``, ``"learned"`` /
    ``"pipeline"``, or a shipped policy name or folder; ``seed``: episode k runs seed ``seed + k``; ``record``:
    keep every episode for a Minari dataset (needs ``dvrl-marl[data]``) written as ``dataset_id`` (the next free
    version when taken); ``max_cycles``: steps before an episode is cut (default :data:`TELEOP_MAX_CYCLES`);
    ``frames_per_second`` while an episode runs; ``realtime=False`` steps as fast as it can (tests, replays);
    ``silence_timeout``: seconds of silence before the page counts as gone. Other keywords go to the scene.
    """

    def __init__(self, seat: str = "grasper", partner: str = "scripted", *, seed: int = 0, record: bool = True,
                 dataset_id: str = DEFAULT_DATASET_ID, max_cycles: int | None = None, width: int = 640,
                 height: int = 480, frames_per_second: float = 25.0, jpeg_quality: int = 80, realtime: bool = True,
                 silence_timeout: float = 1.0, device: BrowserDevice | None = None, **scene_kwargs):
        import gymnasium as gym

        import dvrl_marl  # noqa: F401  (registration)

        if seat not in _TOOLS:
            raise ValueError(f"TeleopSession: seat must be one of {sorted(_TOOLS)}, got {seat!r}")
        if not isinstance(partner, str) or not partner:
            raise ValueError(f"TeleopSession: partner must be one of {PARTNERS} or a policy name, got {partner!r}")
        if not 0 < frames_per_second <= 50:
            raise ValueError(f"TeleopSession: frames_per_second must be in (0, 50], got {frames_per_second!r}")
        if not 1 <= int(jpeg_quality) <= 95:
            raise ValueError(f"TeleopSession: jpeg_quality must be in [1, 95], got {jpeg_quality!r}")
        if record:
            from dvrl_marl.datasets import next_free_id

            next_free_id(dataset_id)  # Minari is there and the id is well formed: say so now, not at the end
        self.seat, self.partner_name = seat, partner
        self.dataset_id, self.record_default = dataset_id, bool(record)
        self.seed = int(seed)
        self.max_cycles = int(max_cycles or TELEOP_MAX_CYCLES)
        self.realtime = bool(realtime)
        self.jpeg_quality = int(jpeg_quality)
        # The seat's tool starts as the scene's reset leaves it: the jaw open, the valve closed (a valve that opened by
        # itself once the page spoke was a device defaulting to "open" in the suction seat).
        env_partner = LEARNED_PARTNERS[seat] if partner == "learned" else partner
        self.env = gym.make(TELEOP_ENV_ID, seat=seat, partner=env_partner, max_cycles=self.max_cycles, **scene_kwargs)
        self.scene = self.env.unwrapped.scene
        # the suction seat of a scene that irrigates gets the irrigate key (I)
        irrigates = seat == "suction" and self.scene.params.irrigation_ml_s > 0.0
        if device is not None and getattr(device, "irrigate", False) and not irrigates:
            raise ValueError(f"TeleopSession: the device irrigates, but the {seat} seat "
                             + ("(the Large Needle Driver) cannot" if seat != "suction"
                                else "of this scene does not (irrigation_ml_s = 0; preset='irrigation' turns it on)"))
        self.device = device or BrowserDevice(silence_timeout=silence_timeout,
                                              initial_tool=1.0 if seat == "grasper" else -1.0, irrigate=irrigates)
        self.control_dt = float(self.scene.params.control_dt)
        self.frame_every = max(1, round(1.0 / (frames_per_second * self.control_dt)))
        self.width, self.height = int(width), int(height)
        self._commands: queue.Queue = queue.Queue()
        self._wake = threading.Event()
        self._stopping = threading.Event()
        self._frame_lock = threading.Lock()
        self._frame: tuple[int, bytes] = (0, b"")
        self._subscribers: list[Callable[[], None]] = []
        self._saver_lock = threading.Lock()
        self._savers: list[threading.Thread] = []
        self.saved: list[dict] = []
        self.audience = {"controller": False, "spectators": 0, "dropped_messages": 0, "last_drop": ""}
        self.error: str | None = None
        self._served = []  # publish times of the last frames, for the frames-per-second figure
        # The loop's state (its thread owns it; status() reads it, also before the first episode)
        self._state, self._episode, self._episode_seed, self._steps = "starting", -1, self.seed, 0
        self._lost, self._success, self._recording = True, False, self.record_default
        self._recorder, self._buffers = None, []
        self._outline = _rounded(SceneView(self.scene).outline())  # fixed: the page's top and side views
        self._thread = threading.Thread(target=self._run, name="teleop-session", daemon=True)
        self._started = False

    # --- control (any thread) -------------------------------------------------------------------------------
    def start(self) -> "TeleopSession":
        """Start the loop (the first episode waits for :meth:`begin`)."""
        if not self._started:
            self._started = True
            self._thread.start()
        return self

    def begin(self) -> None:
        """The person is ready: the waiting episode starts running."""
        self._command("begin")

    def reset(self) -> None:
        """Start over with a new episode (the current one, if recorded, is kept as stopped)."""
        self._command("reset")

    def set_recording(self, on: bool) -> None:
        """Stop recording (the episodes so far are written as a dataset) or record again from the next episode."""
        self._command("record_on" if on else "record_off")

    def close(self, timeout: float = 30.0) -> list[dict]:
        """Stop the loop, write what is recorded, release the scene; returns the datasets written."""
        self._stopping.set()
        self._wake.set()
        if self._started:
            self._thread.join(timeout)
        else:
            self.env.close()
        for saver in list(self._savers):
            saver.join(timeout)
        return list(self.saved)

    def subscribe(self, callback: Callable[[], None]) -> None:
        """``callback()`` runs (in the loop's thread: keep it short) after each new frame."""
        self._subscribers.append(callback)

    @property
    def observation(self) -> np.ndarray | None:
        """What the seat sees now (a copy of its latest observation), e.g. for an assistive display; None before
        the first episode."""
        observation = getattr(self, "_observation", None)
        return None if observation is None else np.array(observation)

    def latest(self) -> tuple[int, bytes]:
        """The newest frame: (its number, :func:`pack_frame` bytes)."""
        with self._frame_lock:
            return self._frame

    def _command(self, name: str) -> None:
        self._commands.put(name)
        self._wake.set()

    # --- the loop (its own thread: MuJoCo's OpenGL context lives here) --------------------------------------------
    def _run(self) -> None:
        from dvrl_marl.rendering import SceneRenderer

        mirror = self.scene.mirrored()
        renderer = SceneRenderer(mirror.model, mirror.data, "rgb_array", width=self.width,
                                 height=self.height, frame_budget=0.5 * self.frame_every * self.control_dt,
                                 decorate=SceneView(self.scene).draw_marks)
        self._renderer = renderer
        try:
            self._new_episode()
            while not self._stopping.is_set():
                self._apply_commands()
                if self._state == "running":
                    self._step()
                    if self._steps % self.frame_every == 0 or self._state != "running":
                        self._publish()
                    if self.realtime:
                        self._pacer.wait()
                else:
                    self._publish()
                    self._wake.wait(_IDLE_PUBLISH_S)
                    self._wake.clear()
        except Exception as error:  # noqa: BLE001  (the page must say what went wrong; the server stays up)
            self.error = f"{type(error).__name__}: {error}"
            self._state = "error"
            try:
                self._publish()
            except Exception:  # noqa: BLE001
                pass
        finally:
            self._keep_episode(stopped=True)
            self._save_recording()
            renderer.close()
            self.env.close()

    def _apply_commands(self) -> None:
        while True:
            try:
                name = self._commands.get_nowait()
            except queue.Empty:
                return
            if name == "begin" and self._state == "waiting":
                self._state = "running"
                self._pacer = RealTimePacer(self.control_dt)
            elif name == "reset":
                self._keep_episode(stopped=True)
                self._new_episode()
            elif name == "record_off" and self._recording:
                self._keep_episode(stopped=True)  # (and drops the recorder)
                self._recording = False
                self._save_recording()
            elif name == "record_on":
                self._recording = True  # from the next episode: a recording starts at a seeded reset

    def _new_episode(self) -> None:
        from dvrl_marl.datasets import EpisodeRecorder

        self._episode += 1
        self._episode_seed = self.seed + self._episode
        self._observation, info = self.env.reset(seed=self._episode_seed)
        self.device.reset()
        self._recorder = (EpisodeRecorder(len(self._buffers), self._episode_seed, self._observation,
                                          {**info, "teleop_lost": False}, extra_info=("teleop_lost",))
                          if self._recording else None)
        self._tool = 1.0 if self.seat == "grasper" else -1.0  # the reset's jaw (open) or valve (closed)
        self._steps = 0
        self._lost = self.device.lost
        self._success = False
        self._state = "waiting"

    def _step(self) -> None:
        try:
            action = np.asarray(self.device.action(self._observation), dtype=np.float32)
            if action.shape != (ACTION_WIDTH,) or not np.all(np.isfinite(action)):
                raise ValueError(f"unusable action {action!r}")
            self._lost = False
        except Exception:  # noqa: BLE001  (no page, a silent one or a bad action: the seat holds still)
            action = np.array([0.0, 0.0, 0.0, self._tool], dtype=np.float32)
            self._lost = True
        self._tool = float(action[3])
        self._observation, reward, terminated, truncated, info = self.env.step(action)
        self._steps += 1
        if self._recorder is not None:
            self._recorder.step(action, self._observation, reward, terminated, truncated,
                                {**info, "teleop_lost": self._lost})
        if terminated or truncated:
            self._success = bool(info["is_success"])
            self._state = "over"
            self._keep_episode(stopped=False)

    def _keep_episode(self, stopped: bool) -> None:
        if self._recorder is not None and len(self._recorder):
            self._buffers.append(self._recorder.buffer(stopped=stopped))
        self._recorder = None

    def _save_recording(self) -> None:
        """Write the recorded episodes as a dataset, in the background (HDF5 takes a moment; the seat keeps time)."""
        buffers, self._buffers = self._buffers, []
        if not buffers:
            return
        saver = threading.Thread(target=self._write, args=(buffers,), name="teleop-dataset", daemon=False)
        self._savers.append(saver)
        saver.start()

    def _write(self, buffers) -> None:
        from dvrl_marl.datasets import next_free_id, save_episodes

        with self._saver_lock:  # one at a time: each takes the next free version
            try:
                dataset_id = next_free_id(self.dataset_id)
                dataset = save_episodes(
                    dataset_id, buffers, self.env, algorithm_name="dvrl-marl teleop (a person in the browser)",
                    description=f"{len(buffers)} episodes of a person in the {self.seat} seat of {TASK} "
                                f"beside the {self.partner_name} partner, recorded by dvrl-marl teleop")
                self.saved.append({"id": dataset_id, "episodes": len(buffers),
                                   "successes": sum(bool(b.infos["is_success"][-1]) for b in buffers),
                                   "path": str(dataset.spec.data_path)})
            except Exception as error:  # noqa: BLE001  (reported on the page and by close())
                self.saved.append({"id": None, "episodes": len(buffers), "error": f"{type(error).__name__}: {error}"})

    # --- frames -------------------------------------------------------------------------------------------------
    def status(self) -> dict:
        """What the page shows: the scene as :func:`scene_view` gives it, and the session's state."""
        now = time.monotonic()
        served = [t for t in self._served if now - t <= 1.0]
        return {
            **scene_view(self.scene, self.seat, self._outline),
            "state": self._state, "error": self.error,
            "episode": self._episode, "seed": self._episode_seed,
            "step": self._steps, "max_steps": self.max_cycles, "max_time_s": round(self.max_cycles * self.control_dt, 2),
            "success": self._success or SceneView(self.scene).progress()["success"], "partner": self.partner_name,
            "teleop_lost": bool(self._lost if self._state == "running" else self.device.lost),
            "input_seq": int(self.device.applied_seq),
            "recording": self._recording, "recorded_steps": len(self._recorder) if self._recorder else 0,
            "recorded_episodes": len(self._buffers), "saved": list(self.saved),
            "fps": len(served), "steps_late": getattr(getattr(self, "_pacer", None), "steps_late", 0),
            **self.audience,
        }

    def _publish(self) -> None:
        from PIL import Image

        self.scene.mirrored()  # the world as it is now
        pixels = self._renderer.render()
        buffer = io.BytesIO()
        Image.fromarray(pixels).save(buffer, format="JPEG", quality=self.jpeg_quality)
        now = time.monotonic()
        self._served = [t for t in self._served if now - t <= 1.0] + [now]
        payload = pack_frame(self.status(), buffer.getvalue())
        with self._frame_lock:
            self._frame = (self._frame[0] + 1, payload)
        for callback in self._subscribers:
            callback()
