"""The surgeon seat of the collaborative scene: a script, a learned policy or a person's device drives one arm.

``suction_debris_v8.parallel_env(surgeon=...)`` wraps the scene in a :class:`SurgeonSeat`: the seat's agent leaves
``agents`` and its filler acts in ``step()``, reading the seat's plain observation. A teleoperation device (an object
with ``action(observation)``) is called under a timeout in a thread of its own: a device that fails or stalls holds its
arm still for that step (``info["teleop_lost"]``) and never ends the episode. ``render_mode="human"`` opens the
scene's window, with the person's panels (:class:`~dvrl_marl.envs.scene_view.SceneView`) drawn over it, and runs
episodes in real time (:mod:`dvrl_marl.pacing`); a person in the seat starts each episode with ENTER.
"""

from __future__ import annotations

import concurrent.futures
import math

from pettingzoo.utils.wrappers import BaseParallelWrapper

from dvrl_marl.envs.scene_view import SceneView
from dvrl_marl.pacing import PacedDisplay
from dvrl_marl.suction_debris.rules import AGENTS

__all__ = ["SurgeonSeat", "check_seat"]


def check_seat(name: str, surgeon_seat, teleop_timeout):
    """The seat's arguments, checked (``teleop_timeout`` in seconds, or None to wait for ever)."""
    if surgeon_seat not in AGENTS:
        raise ValueError(f"{name}: surgeon_seat must be one of {AGENTS}, got {surgeon_seat!r}")
    if teleop_timeout is not None:
        from dvrl_marl.schemas import Positive, validated

        teleop_timeout = validated(Positive, teleop_timeout, f"{name}: teleop_timeout (seconds, or None)")
    return teleop_timeout


class SurgeonSeat(BaseParallelWrapper):
    """The scene with its surgeon seat filled (see the module documentation); every other attribute is the scene's."""

    def __init__(self, env, surgeon=None, surgeon_seat: str = "grasper", render_mode: str | None = None,
                 teleop_timeout: float | None = 0.5, width: int = 640, height: int = 480):
        super().__init__(env)
        self.teleop_timeout = check_seat(env.name, surgeon_seat, teleop_timeout)
        if render_mode is not None and render_mode not in ("human", "rgb_array"):
            raise ValueError(f"{env.name}: render_mode must be 'human' or 'rgb_array', got {render_mode!r}")
        self.metadata = env.metadata
        self.render_mode = render_mode
        self.surgeon_seat = surgeon_seat if surgeon is not None else None
        self._surgeon, self._surgeon_is_device = self._bind_surgeon(surgeon, surgeon_seat)
        self.possible_agents = [agent for agent in env.possible_agents if agent != self.surgeon_seat]
        self.agents = []
        device = self._surgeon if self._surgeon_is_device else None
        #: A person works the seat (their device says so): episodes start on ENTER and run in real time.
        self.human_seat = bool(getattr(device, "human_operated", False))
        #: what a person is shown of the scene
        self.view = SceneView(env)
        self._window = self._display = None
        if render_mode == "human":
            from dvrl_marl.envs.scene_mirror import SceneMirror

            self._window = SceneMirror(env.params, "human", width=width, height=height,
                                       key_listener=getattr(device, "key_event", None), overlay=self.overlay,
                                       decorate=self.view.draw_marks, title="dvrl-marl: suction & debris",
                                       frame_budget=0.5 * env.params.control_dt)
            self._display = PacedDisplay(self._window.renderer, env.params.control_dt)
        self._executor = None
        self._pending_teleop = None

    def _bind_surgeon(self, surgeon, seat):
        if surgeon is None:
            return None, False
        if getattr(surgeon, "image_options", None):  # a pixel policy: it needs the endoscope's image as well
            raise ValueError(f"{self.env.name}: the surgeon {getattr(surgeon, 'name', surgeon)!r} sees the endoscope "
                             f"({surgeon.image_options}); a bound seat reads the plain observation. Seat it in a "
                             "team instead: dvrl_marl.training.teams.evaluate_team_batched, or drive it on the "
                             "batched env made with those options")
        if isinstance(surgeon, str):
            if surgeon != "scripted":
                raise ValueError(f"{self.env.name}: surgeon must be None, 'scripted', a callable or a teleop device, "
                                 f"got {surgeon!r}")
            from dvrl_marl.suction_debris.scripted_team import ScriptedSuction, ScriptedSurgeon

            return (ScriptedSurgeon if seat == "grasper" else ScriptedSuction).for_env(self.env), False
        if hasattr(surgeon, "action") and callable(surgeon.action):
            if getattr(surgeon, "irrigate", False):  # a device with an irrigate key: the S&I valve's, where it irrigates
                if seat != "suction":
                    raise ValueError(f"{self.env.name}: the {seat} seat's tool (the Large Needle Driver) cannot "
                                     f"irrigate; irrigate=True is the suction seat's (its Suction & Irrigation valve)")
                if self.env.params.irrigation_ml_s <= 0.0:
                    raise ValueError(f"{self.env.name}: irrigate=True, but this scene's valve does not irrigate "
                                     f"(irrigation_ml_s = {self.env.params.irrigation_ml_s}; preset='irrigation' "
                                     f"turns it on)")
            return surgeon, True
        if callable(surgeon):
            return surgeon, False
        raise ValueError(f"{self.env.name}: surgeon {surgeon!r} is neither callable nor a teleop device")

    def reset(self, seed=None, options=None):
        observations, infos = self.env.reset(seed=seed, options=options)
        self.agents = list(self.possible_agents)
        if self._surgeon is not None and hasattr(self._surgeon, "reset"):
            self._safe_device_call(self._surgeon.reset) if self._surgeon_is_device else self._surgeon.reset()
        if self._display is not None:
            self._window.show(self.env.core.world_state(0))
            self._display.start_episode(wait_for_enter=self.human_seat)
        return {a: observations[a] for a in self.agents}, {a: infos[a] for a in self.agents}

    def step(self, actions):
        if not self.agents:
            raise ValueError(f"{self.env.name}: step() called " + ("after the episode ended" if self.env.episodes
                                                                     else "before reset()") + "; call reset()")
        commands = self.env.read_actions(actions, self.agents)
        if self._display is not None:
            self._display.before_step()  # the key events since the last step reach the seat's device now
        teleop_lost = False
        if self._surgeon is not None:
            commands[self.surgeon_seat], teleop_lost = self._seat_command()
        observations, rewards, terminations, truncations, infos = self.env.advance(commands)
        keep = self.agents
        observations, rewards, infos = ({a: part[a] for a in keep} for part in (observations, rewards, infos))
        terminations, truncations = {a: terminations[a] for a in keep}, {a: truncations[a] for a in keep}
        if teleop_lost:
            for info in infos.values():
                info["teleop_lost"] = True
        if self._display is not None:
            self._window.show(self.env.core.world_state(0))
            self._display.after_step()  # draw if there is time, then wait for the end of the 20 ms period
            complete = any(terminations.values())
            if self._display.closed and not complete:  # the person closed the window: the episode ends here
                truncations = {agent: True for agent in keep}
                for info in infos.values():
                    info["viewer_closed"] = True
        if any(terminations.values()) or any(truncations.values()):
            self.agents = []
        return observations, rewards, terminations, truncations, infos

    def render(self):
        if self.render_mode == "human":
            self._window.show(self.env.core.world_state(0))
            return self._window.render()
        return self.env.render()

    def close(self):
        if self._window is not None:
            self._window.close()
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = None
        if self._surgeon_is_device and hasattr(self._surgeon, "close"):
            self._safe_device_call(self._surgeon.close)
        self.env.close()

    @property
    def surgeon_label(self) -> str | None:
        """Who fills the surgeon seat, in a word (a device's ``label``, else its type); None when it is empty."""
        if self._surgeon is None:
            return None
        return str(getattr(self._surgeon, "label", None) or type(self._surgeon).__name__)

    @property
    def window(self):
        """``render_mode="human"``: the scene's window (:class:`dvrl_marl.viewer.ViewerWindow`), e.g. for a
        screenshot; None in the other modes."""
        return self._window.viewer if self._window is not None else None

    def realtime_stats(self) -> dict | None:
        """``render_mode="human"``: how well the episode kept real time (steps late, worst lag, frames dropped)."""
        return self._display.stats() if self._display is not None else None

    def overlay(self) -> list[tuple[str, str, str]]:
        """What the window draws over the scene (``render_mode="human"``): ``(position, labels, values)`` panels."""
        progress = self.view.progress()
        total = progress["debris_total"]
        seat = f"{self.surgeon_seat} ({self.surgeon_label})" if self.surgeon_seat else "none"
        limit = self.env.params.max_cycles * self.env.params.control_dt
        labels = ["Blood left", "Debris found", "Debris delivered", "Time", "Surgeon seat"]
        values = [" + ".join(self.view.blood_text()), f"{progress['debris_found']} / {total}",
                  f"{progress['debris_delivered']} / {total}", f"{progress['time_s']:.1f} s of {limit:.4g} s", seat]
        if self.surgeon_seat is not None:
            labels_, values_ = self.view.cue_rows(self.surgeon_seat)
            labels += labels_
            values += values_
        overlays = [("top left", "\n".join(labels), "\n".join(values))]
        help_rows = (getattr(self._surgeon, "key_help", None) or getattr(self._surgeon, "KEY_HELP", None)
                     if self._surgeon_is_device else None)
        if help_rows:
            overlays.append(("bottom right", "\n".join(k for k, _ in help_rows), "\n".join(v for _, v in help_rows)))
        if self._display is not None and self._display.waiting:
            overlays.append(("top", "Press ENTER to start", ""))
        elif self.agents == [] and self.env.steps > 0:
            overlays.append(("top", "SUCCESS: the field is clear" if self.env.core.is_complete()[0]
                             else f"Episode over: {progress['debris_delivered']} of {total} debris delivered", ""))
        return overlays

    def _seat_command(self):
        """The bound seat's command; a failing device holds the seat still (a NaN tool value: unchanged)."""
        seat = self.surgeon_seat
        observation = self.env.seat_observation(seat)
        hold = [0.0, 0.0, 0.0, math.nan]
        if not self._surgeon_is_device:
            return self.env.check_action(seat, self._surgeon(observation)), False
        action = self._safe_device_call(self._surgeon.action, observation)
        if action is None:
            return hold, True
        try:
            return self.env.check_action(seat, action), False
        except ValueError:
            return hold, True

    def _safe_device_call(self, method, *args):
        """Call a device method; None if it raises or misses the timeout (the episode must go on)."""
        try:
            if self.teleop_timeout is None:
                return method(*args)
            if self._pending_teleop is not None and not self._pending_teleop.done():
                return None  # still stuck in an earlier call
            if self._executor is None:
                self._executor = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="teleop")
            self._pending_teleop = self._executor.submit(method, *args)
            return self._pending_teleop.result(timeout=self.teleop_timeout)
        except Exception:  # noqa: BLE001  (any device failure holds the seat; it never ends the episode)
            return None
