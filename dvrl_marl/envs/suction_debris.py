"""The collaborative scene's parallel env: one world of the core, with a seat a script or a person may fill.

Users import the current version, :mod:`dvrl_marl.envs.suction_debris_v8`, whose module documentation is the
environment's page; this module holds what that version re-exports. The step itself is the core's
(:mod:`dvrl_marl.core.collaborative`), reached through the batched env with one world
(:class:`~dvrl_marl.envs.suction_debris_batched.SuctionDebrisBatchedEnv`): this class turns its arrays into
PettingZoo's dicts of one agent's values, fills the surgeon seat, and shows the world in MuJoCo when asked to.
"""

from __future__ import annotations

import concurrent.futures
import math
import warnings

import numpy as np
from pettingzoo import ParallelEnv
from pettingzoo.utils.conversions import parallel_to_aec

from dvrl_marl.core import tools
from dvrl_marl.core.collaborative import AGENTS, PIN_HALF_LENGTH, PIN_SENSOR_RANGE
from dvrl_marl.core.collaborative_task import TASK, SuctionDebrisParams, env_name
from dvrl_marl.envs import start_levels
from dvrl_marl.envs.marks import COLOURS, Mark, add_marks
from dvrl_marl.envs.presets import accepts_preset
from dvrl_marl.envs.suction_debris_batched import REWARD_TYPES, SceneLayout, SuctionDebrisBatchedEnv
from dvrl_marl.rendering import render_modes_here
from dvrl_marl.teleop.pacing import PacedDisplay

__all__ = ["parallel_env", "env", "raw_env", "TASK", "SuctionDebrisEnv", "SuctionDebrisParams", "SceneLayout", "AGENTS",
           "env_name", "REWARD_TYPES"]

#: Attributes of the one-world batch the env shows as its own (the scene's parameters, spaces' layouts, options).
_SHARED = ("name", "params", "reward_type", "core", "phantom", "handoff", "workspace_centre", "workspace_range",
           "observation_layout", "state_layout", "state_space", "feature_spec", "observation_scaling",
           "state_observations", "easy_episode_steps", "guidance")


class SuctionDebrisEnv(ParallelEnv):
    """The collaborative suction and debris-removal environment (see the module documentation)."""

    metadata = {
        "name": TASK,
        "render_modes": ["human", "rgb_array"],  # (each instance: what this machine can show, render_modes_here)
        "render_fps": 50,
        "is_parallelizable": True,
    }

    @accepts_preset
    def __init__(self, surgeon=None, surgeon_seat: str = "grasper", reward_type: str = "sparse",
                 render_mode: str | None = None, max_cycles: int | None = None, teleop_timeout: float | None = 0.5,
                 width: int = 640, height: int = 480, **options):
        #: one world of the scene: the core's step, the options, the spaces (the seat is filled here)
        self.world = SuctionDebrisBatchedEnv(1, reward_type=reward_type, max_cycles=max_cycles,
                                             autoreset_mode="disabled", width=width, height=height, **options)
        for attribute in _SHARED:
            setattr(self, attribute, getattr(self.world, attribute))
        self.metadata = {**self.metadata, "name": self.name,
                         "render_modes": render_modes_here(("human", "rgb_array"))}  # (the display now)
        if render_mode is not None and render_mode not in ("human", "rgb_array"):
            raise ValueError(f"{self.name}: render_mode must be 'human' or 'rgb_array', got {render_mode!r}")
        if surgeon_seat not in AGENTS:
            raise ValueError(f"{self.name}: surgeon_seat must be one of {AGENTS}, got {surgeon_seat!r}")
        if teleop_timeout is not None:  # -1 once made a seat that never moved
            from dvrl_marl.schemas import Positive, validated

            teleop_timeout = validated(Positive, teleop_timeout, f"{self.name}: teleop_timeout (seconds, or None)")
        self.teleop_timeout = teleop_timeout
        self.render_mode = render_mode
        self.surgeon_seat = surgeon_seat if surgeon is not None else None
        self._surgeon, self._surgeon_is_device = self._bind_surgeon(surgeon, surgeon_seat)
        self.possible_agents = [a for a in AGENTS if a != self.surgeon_seat]
        self.agents = []
        device = self._surgeon if self._surgeon_is_device else None
        #: A person works the seat (their device says so): episodes start on ENTER and run in real time.
        self.human_seat = bool(getattr(device, "human_operated", False))
        self._mirror = None
        self._display = None
        if render_mode is not None:
            self._mirror = self._window(render_mode, device, width, height)
            if render_mode == "human":
                self._display = PacedDisplay(self._mirror.renderer, self.params.control_dt)
        self._executor = None
        self._pending_teleop = None
        self._episodes = 0  # episodes begun (reset() calls)
        self._steps = 0  # steps of this episode

    def _window(self, render_mode, device, width, height):
        from dvrl_marl.envs.scene_mirror import SceneMirror

        return SceneMirror(self.params, render_mode, width=width, height=height,
                           key_listener=getattr(device, "key_event", None), overlay=self.overlay,
                           decorate=self.draw_marks, title="dvrl-marl: suction & debris",
                           frame_budget=0.5 * self.params.control_dt)

    def _bind_surgeon(self, surgeon, seat):
        if surgeon is None:
            return None, False
        if isinstance(surgeon, str):
            if surgeon != "scripted":
                raise ValueError(f"{self.name}: surgeon must be None, 'scripted', a callable or a teleop device, got {surgeon!r}")
            from dvrl_marl.agents.collaborative import ScriptedSuction, ScriptedSurgeon  # agents build on this env

            return (ScriptedSurgeon if seat == "grasper" else ScriptedSuction).for_env(self), False
        if hasattr(surgeon, "action") and callable(surgeon.action):
            return surgeon, True
        if callable(surgeon):
            return surgeon, False
        raise ValueError(f"{self.name}: surgeon {surgeon!r} is neither callable nor a teleop device")

    # --- PettingZoo API -------------------------------------------------------------------------------------
    def observation_space(self, agent):
        return self.world.observation_space(agent)

    def action_space(self, agent):
        return self.world.action_space(agent)

    @property
    def start_level(self) -> float:
        """The start level of the next episodes (:mod:`dvrl_marl.envs.start_levels`)."""
        return float(self.world.levels[0])

    @start_level.setter
    def start_level(self, level) -> None:
        self.world.set_start_level(level)

    def reset(self, seed=None, options=None):
        # Everything is checked before anything changes: a refused reset leaves the env as it was.
        if seed is not None:
            from dvrl_marl.schemas import Seed, validated

            seed = validated(Seed, seed, f"{self.name}: reset(seed=...)")
        if options is not None and not isinstance(options, dict):
            raise ValueError(f"{self.name}: options must be a dict or None, got {type(options).__name__}")
        options = dict(options or {})
        known = {key: options.pop(key) for key in ("blood_ml", "level") if options.get(key) is not None}
        for key in ("blood_ml", "level"):
            options.pop(key, None)
        level = (self.start_level if "level" not in known else
                 start_levels.checked_level(known["level"], f"{self.name}: reset option level"))
        if level < start_levels.DEFAULT and "blood_ml" in known:
            raise ValueError(f"{self.name}: a level below 1 draws the blood itself; pass blood_ml or level, not both")
        if "blood_ml" in known:
            known["blood_ml"] = np.atleast_1d(np.asarray(known["blood_ml"], dtype=np.float64))
        if options:  # PettingZoo's own API test passes arbitrary options, so unknown ones warn rather than raise
            warnings.warn(f"{self.name}: ignoring unknown reset option(s) {sorted(options)}; known: "
                          "['blood_ml', 'level']", stacklevel=2)
        self.world.reset(seed=seed, options=known or None)
        self.agents = list(self.possible_agents)
        self._episodes += 1
        self._steps = 0
        if self._surgeon is not None and hasattr(self._surgeon, "reset"):
            self._safe_device_call(self._surgeon.reset) if self._surgeon_is_device else self._surgeon.reset()
        if self._display is not None:
            self._mirror.show(self.core.world_state(0))
            self._display.start_episode(wait_for_enter=self.human_seat)
        observations = self._observations()
        infos = {agent: self._info() for agent in self.agents}
        return observations, infos

    def step(self, actions):
        if not self.agents:
            raise ValueError(f"{self.name}: step() called " + ("after the episode ended" if self._episodes
                                                                 else "before reset()") + "; call reset()")
        commands = self._read_actions(actions)
        if self._display is not None:
            self._display.before_step()  # the key events since the last step reach the seat's device now
        teleop_lost = False
        if self._surgeon is not None:
            command, teleop_lost = self._seat_command()
            commands[self.surgeon_seat] = [math.nan if value is None else value for value in command]
        rewards, terminated, truncated = self.world.advance(
            {agent: np.array([commands[agent]], dtype=np.float64) for agent in AGENTS})
        self._steps += 1
        complete, truncated = bool(terminated[0]), bool(truncated[0])
        rewards = {agent: float(rewards[agent][0]) for agent in self.agents}
        observations = self._observations()
        infos = {agent: self._info() for agent in self.agents}
        if teleop_lost:
            for info in infos.values():
                info["teleop_lost"] = True
        terminations = {agent: complete for agent in self.agents}
        truncations = {agent: truncated for agent in self.agents}
        if self._display is not None:
            self._mirror.show(self.core.world_state(0))
            self._display.after_step()  # draw if there is time, then wait for the end of the 20 ms period
            if self._display.closed and not complete:  # the person closed the window: the episode ends here
                truncations = {agent: True for agent in self.agents}
                for info in infos.values():
                    info["viewer_closed"] = True
        if complete or any(truncations.values()):
            self.agents = []
        return observations, rewards, terminations, truncations, infos

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
        return self._mirror.viewer if self._mirror is not None else None

    def realtime_stats(self) -> dict | None:
        """``render_mode="human"``: how well the episode kept real time (steps late, worst lag, frames dropped)."""
        return self._display.stats() if self._display is not None else None

    def state(self) -> np.ndarray:
        """The global state: tips, jaw, valve, blood, every debris (hidden included), hand-off point; with
        ``state_observations``, every arm's observation after it."""
        return self.world.state()[0]

    def render(self):
        if self.render_mode is None:
            return None
        self._mirror.show(self.core.world_state(0))
        return self._mirror.render()

    def close(self):
        if self._mirror is not None:
            self._mirror.close()
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = None
        if self._surgeon_is_device and hasattr(self._surgeon, "close"):
            self._safe_device_call(self._surgeon.close)

    # --- the world as a person follows it ---------------------------------------------------------------------
    def progress(self) -> dict:
        """Where the episode stands, for a person watching it: blood left per cavity (ml), debris found (uncovered
        or delivered), delivered and in all, elapsed time (s), steps, whether the field is clear, and each arm's
        tool tip (world frame, m) with the jaw opening (0 closed .. 1 open) and whether the suction valve is open."""
        return {
            "blood_ml": [float(v) for v in self.blood.remaining_ml],
            "debris_found": int(sum(pin.visible or pin.delivered for pin in self.debris)),
            "debris_delivered": int(sum(pin.delivered for pin in self.debris)),
            "debris_total": len(self.debris),
            "time_s": self._steps * self.params.control_dt,
            "steps": self._steps,
            "success": bool(self.core.is_complete()[0]),
            "tips": {agent: [float(v) for v in self.arms[agent].tip_world()] for agent in AGENTS},
            "jaw": float(self.arms["grasper"].jaw),
            "valve_open": bool(self.valve_open),
        }

    def blood_text(self) -> list[str]:
        """Each cavity's blood as a person reads it: ml left, or "clear" once below ``blood_threshold_ml`` (a
        cleared cavity may still hold a few tenths of a millilitre, which rounded reads like the threshold)."""
        threshold = self.params.blood_threshold_ml
        return ["clear" if v < threshold or v <= 0.0 else f"{v:.1f} ml" for v in self.blood.remaining_ml]

    def cues(self, agent: str) -> dict:
        """What a person working ``agent``'s arm cannot read from one endoscope view: the tip's height above the
        surface below it (mm) and above the blood there (suction); whether its last move was refused because the
        other instrument is in the way (``blocked``); for the grasper, the nearest pin's distance from the jaws
        (mm), whether closing now takes it (``in_reach``), whether it holds one and how far that is from the hand-off
        (mm, judged as the scene judges it); for the suction, whether it drew blood in the last step."""
        if agent not in AGENTS:
            raise ValueError(f"{self.name}: unknown agent {agent!r}; agents are {list(AGENTS)}")
        x, y, z = self.arms[agent].tip_world()
        cues = {"tip_height_mm": 1000.0 * (z - self.phantom.surface_height(x, y)), "blocked": bool(self.core.blocked[agent][0])}
        if agent == "suction":
            cavity = self.phantom.cavity_at(x, y)
            wet = cavity >= 0 and self.blood.remaining_ml[cavity] > 0.0
            cues["above_blood_mm"] = 1000.0 * (z - self.blood.surface_z[cavity]) if wet else None
            cues["drawing"] = self.valve_open and float(self.core.drawn_ml[0]) > 0.0
            return cues
        tip = (x, y, z)
        held_pin = self._held_pin()
        held = held_pin is not None
        cues["holding"] = held
        cues["handoff_mm"] = (1000.0 * math.dist(self._judged_point(held_pin), self.handoff)
                              if held else None)
        reachable = [_point_segment_distance(tip, *pin.axis_ends()) for pin in self.debris
                     if pin.visible and not pin.delivered and not pin.held]
        nearest = min(reachable, default=None)
        cues["pin_mm"] = None if nearest is None else 1000.0 * nearest
        cues["in_reach"] = not held and nearest is not None and nearest <= PIN_SENSOR_RANGE
        return cues

    def outline(self) -> dict:
        """The scene's fixed geometry in millimetres (world frame), for a person's top and side views: the
        phantom's top (x, y half extents about its centre, height), each cavity (centre, mouth radius, floor), the
        hand-off point and the workspace box."""
        phantom = self.phantom
        mm = 1000.0
        return {
            "phantom": {"centre": [mm * phantom.centre_x, mm * phantom.centre_y], "half": [mm * phantom.half_x,
                        mm * phantom.half_y], "top": mm * phantom.top_z, "table": mm * phantom.table_z},
            "cavities": [{"centre": [mm * c.centre_x, mm * c.centre_y], "radius": mm * c.mouth_radius,
                          "floor": mm * c.floor_z} for c in phantom.cavities],
            "handoff": [mm * v for v in self.handoff],
            "workspace": {"low": [mm * v for v in self.core.low.tolist()], "high": [mm * v for v in self.core.high.tolist()]},
        }

    def pins(self) -> list[dict]:
        """The pins a person can see (uncovered, not yet delivered): position (mm, world), whether held, and for a
        held pin ``grip_mm``, the point the hand-off judges (where the jaws hold it)."""
        return [{"mm": [1000.0 * v for v in pin.position], "held": pin.held,
                 **({"grip_mm": [1000.0 * v for v in self._judged_point(index)]} if pin.held else {})}
                for index, pin in enumerate(self.debris) if pin.visible and not pin.delivered]

    def marks(self) -> list:
        """The drop lines drawn into the scene (:mod:`dvrl_marl.envs.marks`): one per arm, tip to surface."""
        reach = self.cues("grasper")["in_reach"]
        marks = []
        for agent in AGENTS:
            x, y, z = self.arms[agent].tip_world()
            colour = COLOURS["in_reach"] if agent == "grasper" and reach else COLOURS[agent]
            marks.append(Mark((x, y, z), (x, y, self.phantom.surface_height(x, y)), colour))
        return marks

    def draw_marks(self, scene) -> None:
        """Add the marks to an updated ``MjvScene`` (the renderers call this for every frame)."""
        add_marks(scene, self.marks(), self.handoff)

    def overlay(self) -> list[tuple[str, str, str]]:
        """What the window draws over the scene (``render_mode="human"``): ``(position, labels, values)`` panels."""
        progress = self.progress()
        total = progress["debris_total"]
        seat = f"{self.surgeon_seat} ({self.surgeon_label})" if self.surgeon_seat else "none"
        limit = self.params.max_cycles * self.params.control_dt
        labels = ["Blood left", "Debris found", "Debris delivered", "Time", "Surgeon seat"]
        values = [" + ".join(self.blood_text()), f"{progress['debris_found']} / {total}",
                  f"{progress['debris_delivered']} / {total}", f"{progress['time_s']:.1f} s of {limit:.4g} s", seat]
        if self.surgeon_seat is not None:
            labels_, values_ = self._cue_rows(self.surgeon_seat)
            labels += labels_
            values += values_
        overlays = [("top left", "\n".join(labels), "\n".join(values))]
        help_rows = getattr(self._surgeon, "KEY_HELP", None) if self._surgeon_is_device else None
        if help_rows:
            overlays.append(("bottom right", "\n".join(k for k, _ in help_rows), "\n".join(v for _, v in help_rows)))
        if self._display is not None and self._display.waiting:
            overlays.append(("top", "Press ENTER to start", ""))
        elif self.agents == [] and self._steps > 0:
            overlays.append(("top", "SUCCESS: the field is clear" if self.core.is_complete()[0]
                             else f"Episode over: {progress['debris_delivered']} of {total} debris delivered", ""))
        return overlays

    def _cue_rows(self, agent) -> tuple[list[str], list[str]]:
        """The seat's cues as overlay rows (labels, values)."""
        cues = self.cues(agent)
        labels, values = ["Tip height"], [f"{cues['tip_height_mm']:.1f} mm above the surface"]
        if agent == "grasper":
            labels.append("Jaw")
            if cues["holding"]:
                values.append(f"closed, holding a pin: {cues['handoff_mm']:.1f} mm to the hand-off")
            else:
                pin = "no pin in sight" if cues["pin_mm"] is None else (
                    f"pin IN REACH ({cues['pin_mm']:.1f} mm): close" if cues["in_reach"]
                    else f"nearest pin {cues['pin_mm']:.1f} mm")
                values.append(("open" if self.arms["grasper"].jaw >= self.params.grasp_threshold else "closed")
                              + f", {pin}")
        else:
            labels.append("Valve")
            depth = ("not over blood" if cues["above_blood_mm"] is None
                     else f"{cues['above_blood_mm']:.1f} mm above the blood")
            values.append(("open" if self.valve_open else "closed") + (", drawing" if cues["drawing"] else "")
                          + f", {depth}")
        if cues["blocked"]:
            labels.append("BLOCKED")
            values.append("the other instrument is in the way")
        return labels, values

    @property
    def valve_open(self) -> bool:
        """The valve draws (more than half open; :mod:`dvrl_marl.core.tools`)."""
        return self.valve_opening > tools.VALVE_OPEN_ABOVE

    @property
    def valve_opening(self) -> float:
        """The valve's stroke, 0 closed .. 1 open (:mod:`dvrl_marl.core.tools`)."""
        return float(self.core.valve_opening[0])

    def set_state(self, **state) -> None:
        """Put the scene in a given state (:meth:`CollaborativeCore.set_world`'s keywords: tips in each arm's base
        frame, jaw, valve, blood, pins), e.g. to set up a situation or show a recorded one."""
        self.core.set_world(0, **state)

    def layout(self) -> SceneLayout:
        """The scene's fixed facts in normalised coordinates (for scripted agents and pipelines)."""
        return self.world.layout()

    def normalise(self, position_world) -> np.ndarray:
        """x~ = (x - p_c) / rho for world positions (..., 3)."""
        return self.world.normalise(position_world)

    def instrument_clearance(self) -> float:
        """Clearance between the two instruments (m; they never intersect: never negative)."""
        return float(self.core.instrument_clearance()[0])

    @property
    def arms(self) -> dict:
        """Each arm of the world as one arm (tip, joints, jaw; ``set_tip`` moves it by inverse kinematics)."""
        return {agent: WorldArm(self.core.arms[agent]) for agent in AGENTS}

    @property
    def blood(self) -> "WorldBlood":
        """The blood in each cavity (ml): what it started with, gained, lost, holds; its surfaces."""
        return WorldBlood(self.core)

    @property
    def debris(self) -> list:
        """Each pin of the world, read live (position, yaw, cavity, visible, held, delivered, lifted, fall_speed)."""
        return [WorldPin(self.core, i) for i in range(self.params.debris_count)]

    @property
    def bleeding(self) -> list[tuple[float, float]]:
        """(onset s, rate ml/s) of each cavity's bleeding this episode (the bleeding field; empty without it)."""
        if self.params.bleeding_ml_s <= 0.0:
            return []
        return [(float(onset), float(rate)) for onset, rate in zip(self.core.bleed_onset[0], self.core.bleed_rate[0])]

    def mirrored(self):
        """The MuJoCo scene showing the world now (its ``model`` and ``data``; the step never reads them)."""
        mirror = self._mirror or self.world.mirror()
        mirror.show(self.core.world_state(0))
        return mirror

    # --- internals ------------------------------------------------------------------------------------------
    def _read_actions(self, actions) -> dict:
        if not isinstance(actions, dict):
            raise ValueError(f"{self.name}: actions must be a dict keyed by agent, got {type(actions).__name__}")
        for agent in actions:
            if agent not in self.agents:
                raise ValueError(f"{self.name}: unknown agent {agent!r} in actions; live agents are {self.agents}")
        commands = {}
        for agent in self.agents:
            if agent not in actions:
                raise ValueError(f"{self.name}: no action for agent {agent!r}")
            commands[agent] = self._validate(agent, actions[agent])
        return commands

    def _validate(self, agent, action):
        try:
            array = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError) as error:
            raise ValueError(f"{self.name}: action for {agent!r} is not numeric: {action!r}") from error
        if array.shape != (4,):
            raise ValueError(f"{self.name}: action for {agent!r} must have shape (4,), got {array.shape}")
        values = array.tolist()
        for value in values:
            if not math.isfinite(value):
                raise ValueError(f"{self.name}: action for {agent!r} contains NaN or inf: {values}")
        return [-1.0 if v < -1.0 else 1.0 if v > 1.0 else v for v in values]

    def _seat_command(self):
        """The bound seat's command; a failing device holds the seat still (tool value None = unchanged)."""
        seat = self.surgeon_seat
        observation = self.seat_observation(seat)
        hold = [0.0, 0.0, 0.0, None]
        if not self._surgeon_is_device:
            return self._validate(seat, self._surgeon(observation)), False
        action = self._safe_device_call(self._surgeon.action, observation)
        if action is None:
            return hold, True
        try:
            return self._validate(seat, action), False
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

    def _held_pin(self):
        holding = int(self.core.holding[0])
        return None if holding < 0 else holding

    def _judged_point(self, index: int) -> list[float]:
        """Where the hand-off judges held pin ``index``: where the jaws hold it, or (without ``deliver_at_grip``)
        its centre."""
        core = self.core
        if self.params.deliver_at_grip:
            return (core.arms["grasper"].tip_world()[0] + core.grip_offset[0]).tolist()
        return core.debris_position[0, index].tolist()

    def _observations(self) -> dict:
        observations = self.world.observations()
        return {agent: observations[agent][0] for agent in self.agents}

    def seat_observation(self, agent) -> np.ndarray:
        """What a seat's filler (a script, an exported policy, a device) reads of ``agent``'s view: the plain
        observation in the scene's units, whatever ``observation_features`` and ``normalize_observations`` give the
        learning agents (an exported policy computes its own features and scaling). The batched env's seat reads the
        same."""
        return self.core.observation(agent)[0]

    def _info(self) -> dict:
        core = self.core
        remaining = tuple(core.remaining_ml[0].tolist())
        return {
            "blood_remaining": float(sum(remaining)),
            "blood_remaining_per_cavity": remaining,
            "debris_delivered": int(core.delivered[0].sum()),
            "collision": bool(core.contact[0]),
            "is_success": bool(core.complete[0]),
        }


class WorldArm:
    """World 0 of an :class:`~dvrl_marl.core.arms.ArmBatch` as one arm (the single env's ``arms[agent]``)."""

    def __init__(self, batch):
        self._batch = batch
        self.tool = batch.tool
        self.base_position = batch.base_position
        self.base_rotation = np.eye(3)  # (the collaborative scene's bases are upright: SceneGeometry checks)

    @property
    def tip(self) -> list[float]:
        """The tip (base frame, m)."""
        return self._batch.tip[0].tolist()

    @property
    def q(self) -> tuple:
        return tuple(self._batch.q[0].tolist())

    @property
    def jaw(self) -> float:
        return float(self._batch.jaw[0])

    def tip_world(self) -> tuple[float, float, float]:
        return tuple((self._batch.tip[0] + self.base_position).tolist())

    def to_base(self, position_world) -> np.ndarray:
        return np.asarray(position_world, dtype=np.float64) - self.base_position

    def to_world(self, position_base) -> np.ndarray:
        return np.asarray(position_base, dtype=np.float64) + self.base_position

    def set_tip(self, x: float, y: float, z: float) -> None:
        """Put the tip at (x, y, z) (base frame) by inverse kinematics (UnreachableError where it cannot be)."""
        self._batch.set_tips(np.array([0]), np.array([[x, y, z]], dtype=np.float64))

    def set_jaw(self, jaw: float) -> None:
        self._batch.jaw[0] = float(jaw)


class WorldBlood:
    """World 0's blood (the single env's ``blood``, a record): volumes per cavity in ml, surfaces in m."""

    def __init__(self, core):
        cavities = core.phantom.cavities
        self.initial_ml = tuple(core.initial_ml[0].tolist())
        self.added_ml = core.added_ml[0].tolist()
        self.remaining_ml = core.remaining_ml[0].tolist()
        self.removed_ml = tuple(core.removed_ml[0].tolist())
        self.surface_z = tuple(core.surface_z[0].tolist())
        self.surface_radius = tuple(c.surface_radius(z - c.floor_z) for c, z in zip(cavities, self.surface_z))
        self._capacity_ml = tuple(c.capacity_ml for c in cavities)
        self.suction_rate_ml_s = core.params.suction_rate_ml_s

    def fraction(self, index: int) -> float:
        """Fraction of the cavity's initial blood still in it (above 1 when a bleed added more); a cavity that
        started empty reports its blood as a fraction of its capacity."""
        initial = self.initial_ml[index]
        return self.remaining_ml[index] / (initial if initial > 0.0 else self._capacity_ml[index])


class WorldPin:
    """Pin ``index`` of world 0, read live from the core (the single env's ``debris[index]``)."""

    def __init__(self, core, index: int):
        self._core, self._index = core, index

    @property
    def position(self) -> list[float]:
        return self._core.debris_position[0, self._index].tolist()

    @property
    def yaw(self) -> float:
        return float(self._core.debris_yaw[0, self._index])

    @property
    def cavity(self) -> int:
        return int(self._core.debris_cavity[0, self._index])

    @property
    def visible(self) -> bool:
        return bool(self._core.visible[0, self._index])

    @property
    def held(self) -> bool:
        return bool(self._core.held[0, self._index])

    @property
    def delivered(self) -> bool:
        return bool(self._core.delivered[0, self._index])

    @property
    def lifted(self) -> bool:
        return bool(self._core.lifted[0, self._index])

    @property
    def fall_speed(self) -> float | None:
        """m/s while it falls, None at rest."""
        speed = float(self._core.fall_speed[0, self._index])
        return None if math.isnan(speed) else speed

    def axis_ends(self):
        dx, dy = PIN_HALF_LENGTH * math.cos(self.yaw), PIN_HALF_LENGTH * math.sin(self.yaw)
        x, y, z = self.position
        return (x - dx, y - dy, z), (x + dx, y + dy, z)


def _closest_on_segment(point, start, end) -> tuple[float, float, float]:
    d = (end[0] - start[0], end[1] - start[1], end[2] - start[2])
    v = (point[0] - start[0], point[1] - start[1], point[2] - start[2])
    length2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
    t = min(max((v[0] * d[0] + v[1] * d[1] + v[2] * d[2]) / length2, 0.0), 1.0) if length2 > 0 else 0.0
    return (start[0] + t * d[0], start[1] + t * d[1], start[2] + t * d[2])


def _point_segment_distance(point, start, end) -> float:
    return math.dist(point, _closest_on_segment(point, start, end))


def parallel_env(**kwargs) -> SuctionDebrisEnv:
    """The parallel environment (the native form)."""
    return SuctionDebrisEnv(**kwargs)


raw_env = parallel_env


def env(**kwargs):
    """The AEC form, through PettingZoo's parallel-to-AEC conversion."""
    return parallel_to_aec(parallel_env(**kwargs))
