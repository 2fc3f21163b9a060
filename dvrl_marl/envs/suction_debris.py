"""The collaborative scene's implementation: :class:`SuctionDebrisEnv`, its parameters and its presets.

Users import the current version, :mod:`dvrl_marl.envs.suction_debris_v8`, whose module documentation is the
environment's page; this module holds what that version re-exports.
"""

from __future__ import annotations

import concurrent.futures
import math
import warnings
from dataclasses import dataclass, fields, replace
from pathlib import Path

import mujoco
import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv
from pettingzoo.utils.conversions import parallel_to_aec

from dvrl_marl import assets, kinematics
from dvrl_marl.arm import Arm
from dvrl_marl.core.collaborative import (
    AGENTS,
    TOOLS,
    CONTACT_MARGIN as _CONTACT_MARGIN,
    OBSERVATION_BOUND,
    GRAVITY,
    PIN_HALF_LENGTH as _PIN_HALF_LENGTH,
    PIN_RADIUS as _PIN_RADIUS,
    PIN_SENSOR_RANGE as _PIN_SENSOR_RANGE,
    PHANTOM_EDGE_MARGIN as _PHANTOM_EDGE_MARGIN,
    PIN_SLOTS as _PIN_SLOTS,
    SHAFT_RADIUS as _SHAFT_RADIUS,
    START_JITTER as _START_JITTER,
    STARTS as _STARTS,
    WRIST_RADIUS as _WRIST_RADIUS,
    sample_debris,
)
from dvrl_marl.core.collaborative import Cavities
from dvrl_marl.core import sliding, tools
from dvrl_marl.envs import start_levels
from dvrl_marl.envs.blood import BloodState, Cavity, Phantom
from dvrl_marl.envs.guidance import Guidance, GuidedReward, OverRims
from dvrl_marl.envs.observation_scaling import ObservationScaling
from dvrl_marl.envs.presets import accepts_preset
from dvrl_marl.policies import features
from dvrl_marl.envs.marks import COLOURS, Mark, add_marks
from dvrl_marl.rendering import SceneRenderer, render_modes_here
from dvrl_marl.teleop.pacing import PacedDisplay
from dvrl_marl.scene import geom_top, load_model, object_id
from dvrl_marl.task import load_task_table

__all__ = ["parallel_env", "env", "raw_env", "TASK", "SuctionDebrisEnv", "SuctionDebrisParams", "SceneLayout", "AGENTS",
           "env_name"]

#: The task file of the current version (``tasks/suction_debris_v8.toml``); the environment takes its name from it.
TASK = "suction_debris_v8"
_TOOLS = TOOLS
_PREFIX = {"suction": "suction/", "grasper": "grasper/"}
_OBS_POSITION_BOUND = OBSERVATION_BOUND  # (a blood fraction is capped at it too)
#: "guided": the dense reward plus the guided terms (:mod:`dvrl_marl.envs.guidance`).
REWARD_TYPES = ("sparse", "dense", "guided")


def _guidance_settings(values, owner: str) -> Guidance:
    """``guidance`` (a dict of :class:`Guidance` fields, or None for the defaults), checked."""
    if values is None:
        return Guidance()
    if isinstance(values, Guidance):
        return values
    from dvrl_marl.schemas import validated

    if not isinstance(values, dict):
        raise ValueError(f"{owner}: guidance must be a dict of Guidance settings, got {type(values).__name__}")
    return validated(Guidance, values, f"{owner}: guidance")


@dataclass(frozen=True)
class SuctionDebrisParams:
    """The task's parameters (see ``tasks/suction_debris_v8.toml`` for defaults and sources)."""

    scene: str
    workspace_centre: tuple[float, float, float]
    workspace_range: float
    step_size: float
    distance_threshold: float
    grasp_threshold: float
    control_dt: float
    tip_clearance: float
    blood_ml: tuple[float, ...]
    blood_threshold_ml: float
    suction_rate_ml_s: float
    debris_count: int
    contact_penalty: float
    max_cycles: int
    # The scene's rules; the task file sets the current ones, the defaults here are the simple rules each one
    # replaces (docs/deviations.md: the keyword that gives each back).
    pins_fall: bool = False  # a released pin falls under gravity (simple: it appears on the surface below at once)
    suction_reach: float = 0.0  # flow falls linearly to none this far above the surface (m; 0: on/off at the surface)
    bleeding_ml_s: float = 0.0  # largest bleeding rate per cavity (0: no bleeding)
    bleeding_onset_s: float = 0.0  # each cavity starts bleeding at a seeded time in [0, this] (s)
    deliver_at_grip: bool = False  # hand-off judged where the jaws hold the pin (simple: at the pin's centre)
    pins_stay_on_phantom: bool = False  # a pin released beyond the phantom lands on its nearest edge (simple: table)
    blocked_moves: str = "stop"  # "slide", "climb", "climb_ahead", "settle": how a blocked move slides (core.sliding)
    held_pin_at_grip: bool = False  # a held pin is observed (and carried, in the dense reward) at the point judged
    # Options that help learning (default: the paper's instant tool and jaw):
    tool_speed: float = 1.0  # fraction of the jaw's / valve's stroke per control step (dvrl_marl.core.tools)
    jaw_command: str = "proportional"  # "switch": the jaw's target by the command's sign, as the valve's
    hold_until_handoff: bool = False  # a held pin's jaw stays shut, whatever the command, until the hand-off

    @classmethod
    def from_task(cls, task: str = TASK, **overrides) -> "SuctionDebrisParams":
        """The task file's values (checked against :class:`dvrl_marl.schemas.CollaborativeTask`: a misspelt key in
        the file is an error naming it), keyword by keyword overridden, then checked as :meth:`validated`."""
        from dvrl_marl.schemas import CollaborativeTask, validated

        task_name, table = load_task_table(task)
        owner = env_name(task_name)
        names = {f.name for f in fields(cls)}
        unknown = set(overrides) - names
        if unknown:
            raise TypeError(f"{owner}() got an unexpected keyword argument {sorted(unknown)[0]!r}")
        path = task if str(task).endswith(".toml") else f"tasks/{task_name}.toml"
        values = validated(CollaborativeTask, table, path, table="task").model_dump(exclude={"description"})
        values.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**values).validated(owner)

    def validated(self, owner: str = TASK) -> "SuctionDebrisParams":
        """Every parameter checked against :class:`dvrl_marl.schemas.CollaborativeTask` (finite numbers in range,
        true/false flags), one blood volume per cavity, at most two pins per slot; a copy with the checked values.
        (Each cavity's capacity is checked by BloodState, which knows the cavities.)"""
        from dvrl_marl.schemas import CollaborativeTask, validated

        values = {f.name: getattr(self, f.name) for f in fields(self)}
        for key in ("workspace_centre", "blood_ml"):  # any sequence (a numpy array too) of numbers
            if isinstance(values[key], np.ndarray) or (hasattr(values[key], "__iter__")
                                                       and not isinstance(values[key], (str, bytes, dict))):
                values[key] = tuple(values[key])
        checked = validated(CollaborativeTask, values, owner)
        if len(checked.blood_ml) != len(assets.CAVITY_CENTRES):
            raise ValueError(f"{owner}: blood_ml needs {len(assets.CAVITY_CENTRES)} values (one per cavity), "
                             f"got {self.blood_ml!r}")
        if checked.debris_count > 2 * len(_PIN_SLOTS):
            raise ValueError(f"{owner}: debris_count must be <= {2 * len(_PIN_SLOTS)} (the cavities' slots), "
                             f"got {self.debris_count!r}")
        return replace(self, **{key: getattr(checked, key) for key in values})


def env_name(task: str) -> str:
    """The environment's name for a task file (a path or a name): the file's stem."""
    return Path(str(task)).stem


@dataclass(frozen=True)
class SceneLayout:
    """Fixed facts of the scene in normalised coordinates, for scripted agents and pipelines."""

    cavity_centres: tuple[tuple[float, float], ...]  # x~, y~
    cavity_mouth_radius: float  # normalised
    cavity_floor: tuple[float, ...]  # z~ of each floor centre
    phantom_top: float  # z~
    blood_threshold_fraction: tuple[float, ...]
    handoff: tuple[float, float, float]
    base_positions: dict  # agent -> RCM position~
    gain: float  # rho / eta: steps per normalised unit
    clearance: float  # tip clearance, normalised


def _segment_distance(p1, q1, p2, q2) -> float:
    """Shortest distance between segments p1-q1 and p2-q2 (3-tuples), in plain floats."""
    d1 = (q1[0] - p1[0], q1[1] - p1[1], q1[2] - p1[2])
    d2 = (q2[0] - p2[0], q2[1] - p2[1], q2[2] - p2[2])
    r = (p1[0] - p2[0], p1[1] - p2[1], p1[2] - p2[2])
    a = d1[0] * d1[0] + d1[1] * d1[1] + d1[2] * d1[2]
    e = d2[0] * d2[0] + d2[1] * d2[1] + d2[2] * d2[2]
    f = d2[0] * r[0] + d2[1] * r[1] + d2[2] * r[2]
    c = d1[0] * r[0] + d1[1] * r[1] + d1[2] * r[2]
    b = d1[0] * d2[0] + d1[1] * d2[1] + d1[2] * d2[2]
    denominator = a * e - b * b
    s = min(max((b * f - c * e) / denominator, 0.0), 1.0) if denominator > 1e-18 else 0.0
    t = (b * s + f) / e if e > 1e-18 else 0.0
    if t < 0.0:
        t, s = 0.0, (min(max(-c / a, 0.0), 1.0) if a > 1e-18 else 0.0)
    elif t > 1.0:
        t, s = 1.0, (min(max((b - c) / a, 0.0), 1.0) if a > 1e-18 else 0.0)
    dx = r[0] + d1[0] * s - d2[0] * t
    dy = r[1] + d1[1] * s - d2[1] * t
    dz = r[2] + d1[2] * s - d2[2] * t
    return math.sqrt(dx * dx + dy * dy + dz * dz)


def _closest_on_segment(point, start, end) -> tuple[float, float, float]:
    d = (end[0] - start[0], end[1] - start[1], end[2] - start[2])
    v = (point[0] - start[0], point[1] - start[1], point[2] - start[2])
    length2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
    t = min(max((v[0] * d[0] + v[1] * d[1] + v[2] * d[2]) / length2, 0.0), 1.0) if length2 > 0 else 0.0
    return (start[0] + t * d[0], start[1] + t * d[1], start[2] + t * d[2])


def _point_segment_distance(point, start, end) -> float:
    return math.dist(point, _closest_on_segment(point, start, end))


class _Debris:
    """One spring pin: plain state; the env mirrors it into the MuJoCo body."""

    __slots__ = ("position", "yaw", "cavity", "visible", "held", "delivered", "lifted", "fall_speed")

    def __init__(self):
        self.position = [0.0, 0.0, 0.0]
        self.yaw = 0.0
        self.cavity = 0
        self.visible = False
        self.held = False
        self.delivered = False
        self.lifted = False
        self.fall_speed = None  # m/s while falling (pins_fall), None at rest

    def axis_ends(self):
        dx, dy = _PIN_HALF_LENGTH * math.cos(self.yaw), _PIN_HALF_LENGTH * math.sin(self.yaw)
        x, y, z = self.position
        return (x - dx, y - dy, z), (x + dx, y + dy, z)


class SuctionDebrisEnv(ParallelEnv):
    """The collaborative suction and debris-removal environment (see the module documentation)."""

    metadata = {
        "name": TASK,
        "render_modes": ["human", "rgb_array"],  # (each instance: what this machine can show, render_modes_here)
        "render_fps": 50,
        "is_parallelizable": True,
    }

    @accepts_preset
    def __init__(
        self,
        surgeon=None,
        surgeon_seat: str = "grasper",
        reward_type: str = "sparse",
        render_mode: str | None = None,
        max_cycles: int | None = None,
        teleop_timeout: float | None = 0.5,
        width: int = 640,
        height: int = 480,
        task: str = TASK,
        guidance: dict | None = None,
        observation_features: str = "",
        start_level: float | str = 1.0,
        easy_episode_steps: int | None = start_levels.EASY_EPISODES.episode_steps,
        state_observations: bool = False,
        normalize_observations: bool = False,
        **params,
    ):
        if not isinstance(task, (str, Path)):
            raise ValueError(f"{TASK}: task must be a task file's name or path, got {task!r}")
        #: The environment's name (its version), as its messages say it.
        self.name = env_name(Path(task).stem)
        self.metadata = {**self.metadata, "name": self.name,
                         "render_modes": render_modes_here(("human", "rgb_array"))}  # (the display now)
        if reward_type not in REWARD_TYPES:
            raise ValueError(f"{self.name}: reward_type must be one of {REWARD_TYPES}, got {reward_type!r}")
        if render_mode is not None and render_mode not in ("human", "rgb_array"):
            raise ValueError(f"{self.name}: render_mode must be 'human' or 'rgb_array', got {render_mode!r}")
        if surgeon_seat not in AGENTS:
            raise ValueError(f"{self.name}: surgeon_seat must be one of {AGENTS}, got {surgeon_seat!r}")
        self.params = SuctionDebrisParams.from_task(task, max_cycles=max_cycles, **params)
        p = self.params
        self.reward_type = reward_type
        self.render_mode = render_mode
        if teleop_timeout is not None:  # -1 once made a seat that never moved
            from dvrl_marl.schemas import Positive, validated

            teleop_timeout = validated(Positive, teleop_timeout, f"{self.name}: teleop_timeout (seconds, or None)")
        self.teleop_timeout = teleop_timeout

        self.model = load_model(p.scene)
        self._hide_unused_debris()
        self.data = mujoco.MjData(self.model)
        self.arms = {agent: Arm(self.model, self.data, _PREFIX[agent], _TOOLS[agent]) for agent in AGENTS}
        for arm in self.arms.values():
            if not np.allclose(arm.base_rotation, np.eye(3)):
                raise ValueError(f"{self.name} needs upright, unrotated PSM bases in its scene")
        self.phantom = self._phantom_from_model()
        self.blood = BloodState(self.phantom, p.blood_ml, p.suction_rate_ml_s)
        self._cavities = Cavities(self.phantom)  # the batched geometry the sliding rules read (core.sliding)
        self._move_rules = {agent: sliding.MoveRules.of(self.params.blocked_moves, agent) for agent in AGENTS}
        self._blood_geoms = [object_id(self.model, "geom", f"blood_{i}") for i in range(len(self.phantom.cavities))]
        self._blood_rgba = [self.model.geom_rgba[g].copy() for g in self._blood_geoms]
        self.handoff = tuple(float(v) for v in self.data.site_xpos[object_id(self.model, "site", "handoff")])
        self._check_scene_fits()
        self._debris_bodies = [object_id(self.model, "body", f"debris_{i}") for i in range(p.debris_count)]
        self._debris_qpos = [int(self.model.jnt_qposadr[self.model.body_jntadr[b]]) for b in self._debris_bodies]
        self.debris = [_Debris() for _ in range(p.debris_count)]

        # Workspace (world): the paper's box around p_c, tips kept above every surface by tip_clearance.
        self.workspace_centre = np.array(p.workspace_centre)
        self.workspace_range = float(p.workspace_range)
        self._centre = p.workspace_centre
        self._inv_range = 1.0 / self.workspace_range
        self._low = tuple((self.workspace_centre - self.workspace_range).tolist())
        self._high = tuple((self.workspace_centre + self.workspace_range).tolist())

        n_cav = len(self.phantom.cavities)
        self.observation_layout = {
            "own_tip": slice(0, 3), "own_tool": slice(3, 4), "other_tip": slice(4, 7),
            "blood": slice(7, 7 + n_cav), "debris": slice(7 + n_cav, 7 + n_cav + 6 * p.debris_count),
            "handoff": slice(7 + n_cav + 6 * p.debris_count, 10 + n_cav + 6 * p.debris_count),
        }
        #: Slices of ``state()``: both tips and tools, blood, every debris (hidden ones too), hand-off point.
        self.state_layout = {
            "suction_tip": slice(0, 3), "valve": slice(3, 4), "grasper_tip": slice(4, 7), "jaw": slice(7, 8),
            "blood": slice(8, 8 + n_cav), "debris": slice(8 + n_cav, 8 + n_cav + 6 * p.debris_count),
            "handoff": slice(8 + n_cav + 6 * p.debris_count, 11 + n_cav + 6 * p.debris_count),
        }
        obs_dim = 10 + n_cav + 6 * p.debris_count
        self._observation_space = spaces.Box(
            -_OBS_POSITION_BOUND, _OBS_POSITION_BOUND, shape=(obs_dim,), dtype=np.float64
        )
        self.feature_spec = self._feature_spec(observation_features, p.debris_count)
        if self.feature_spec is not None:  # appended after the plain observation (differences of positions: twice the bound)
            count = features.feature_count(observation_features)
            self.observation_layout["features"] = slice(obs_dim, obs_dim + count)
            low = np.concatenate([np.full(obs_dim, -_OBS_POSITION_BOUND), np.full(count, -2 * _OBS_POSITION_BOUND)])
            self._observation_space = spaces.Box(low, -low, dtype=np.float64)
        self._action_space = spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)
        self._observation_spaces = {a: self._observation_space for a in AGENTS}
        self._action_spaces = {a: self._action_space for a in AGENTS}
        self.state_space = spaces.Box(-_OBS_POSITION_BOUND, _OBS_POSITION_BOUND, shape=(11 + n_cav + 6 * p.debris_count,),
                                      dtype=np.float64)
        from dvrl_marl.schemas import Flag, validated

        #: ``state()`` followed by every arm's observation, features included (the option; see the module's docs)
        self.state_observations = validated(Flag, state_observations, f"{self.name}: state_observations")
        if self.state_observations:
            width, plain = self._observation_space.shape[0], self.state_space.shape[0]
            for index, agent in enumerate(AGENTS):
                self.state_layout[f"{agent}_observation"] = slice(plain + index * width, plain + (index + 1) * width)
            low = np.concatenate([self.state_space.low, *([self._observation_space.low] * len(AGENTS))])
            self.state_space = spaces.Box(low, -low, dtype=np.float64)
        #: ``normalize_observations``: every agent's observation and the state mapped by fixed, measured centres and
        #: spreads (:mod:`dvrl_marl.envs.observation_scaling`); None without the option. The seat's observation stays
        #: plain (a scripted surgeon and an exported policy read the scene's units).
        self.observation_scaling = None
        if validated(Flag, normalize_observations, f"{self.name}: normalize_observations"):
            scaling = ObservationScaling.for_env(self.name, observation_features, AGENTS,
                                                 self._observation_space.shape[0], 11 + n_cav + 6 * p.debris_count,
                                                 self.state_observations)
            self._observation_spaces = {
                a: spaces.Box(*scaling.observation_bounds(a, self._observation_space.low, self._observation_space.high),
                              dtype=np.float64) for a in AGENTS}
            self.state_space = spaces.Box(*scaling.state_bounds(self.state_space.low, self.state_space.high),
                                          dtype=np.float64)
            self.observation_scaling = scaling
        # Seats and agents (a scripted surgeon reads the layout above).
        self.surgeon_seat = surgeon_seat if surgeon is not None else None
        self._surgeon, self._surgeon_is_device = self._bind_surgeon(surgeon, surgeon_seat)
        self.possible_agents = [a for a in AGENTS if a != self.surgeon_seat]
        self.agents = []
        device = self._surgeon if self._surgeon_is_device else None
        #: A person works the seat (their device says so): episodes start on ENTER and run in real time.
        self.human_seat = bool(getattr(device, "human_operated", False))
        self._renderer = SceneRenderer(self.model, self.data, render_mode, width=width, height=height,
                                       key_listener=getattr(device, "key_event", None), overlay=self.overlay,
                                       decorate=self.draw_marks,
                                       title="dvrl-marl: suction & debris",
                                       frame_budget=0.5 * p.control_dt if render_mode == "human" else None)
        self._display = PacedDisplay(self._renderer, p.control_dt) if render_mode == "human" else None
        self._executor = None
        self._pending_teleop = None
        self._rng = np.random.default_rng()
        self._step_count = 0
        self.valve_opening = 0.0  # the valve's stroke, 0 closed .. 1 open (core.tools); valve_open derives from it
        self.bleeding = []
        self._blocked = {agent: False for agent in AGENTS}  # the last move was refused: the other instrument
        self._drawn_ml = 0.0  # blood the suction drew in the last step
        self._episodes = 0  # episodes begun (reset() calls)
        self._held = None  # the held pin's index (cues and renders may come before the first reset)
        self._hold_offset = self._grip_offset = (0.0, 0.0, 0.0)
        # Options that help learning: start levels, the guided reward.
        self.start_level = start_levels.checked_level(start_level, f"{self.name}: start_level")
        if easy_episode_steps is not None:
            from dvrl_marl.schemas import NonNegativeInt, validated

            # 0 says what None does where there is no null (a TOML configuration): no limit of its own
            easy_episode_steps = validated(NonNegativeInt, easy_episode_steps,
                                           f"{self.name}: easy_episode_steps") or None
        #: an easy episode's time limit (None: the task's max_cycles)
        self.easy_episode_steps = easy_episode_steps
        self._level_rng = start_levels.level_generator(None)
        self._limit = p.max_cycles  # this episode's time limit (an easy start shortens it)
        self._rims = None  # the way around the rims (guidance.OverRims), for easy starts that recede
        self._level_blood = False  # the blood is a level's draw (the task's comes back at the default level)
        if guidance is not None and reward_type != "guided":
            raise ValueError(f"{self.name}: guidance settings need reward_type='guided', got {reward_type!r}")
        #: the guided reward's settings (:class:`dvrl_marl.envs.guidance.Guidance`; None unless reward_type="guided")
        self.guidance = _guidance_settings(guidance, self.name) if reward_type == "guided" else None
        self._guided = GuidedReward(self, self.possible_agents, self.guidance) if self.guidance is not None else None
        self._potential = None

    # --- construction helpers -----------------------------------------------------------------------------
    def _hide_unused_debris(self) -> None:
        count = self.params.debris_count
        index = count
        available = 0
        while mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, f"debris_{available}") >= 0:
            available += 1
        if count > available:
            self.model = _model_with_more_debris(self.params.scene, count)
            return
        while index < available:  # more pins in the scene than asked for: take them out of sight and play
            geom = object_id(self.model, "geom", f"debris_{index}")
            self.model.geom_rgba[geom][3] = 0.0
            self.model.geom_contype[geom] = 0
            self.model.geom_conaffinity[geom] = 0
            body = object_id(self.model, "body", f"debris_{index}")
            self.model.body_pos[body] = (0.0, 0.0, -1.0)
            self.model.qpos0[self.model.jnt_qposadr[self.model.body_jntadr[body]] + 2] = -1.0
            index += 1

    def _check_scene_fits(self) -> None:
        """Every position an observation holds (tips in the workspace box, pins in the cavities, the hand-off point)
        must normalise inside the observation space's bound: a tiny workspace_range would put them outside it."""
        p, phantom = self.params, self.phantom
        points = [self.handoff] + [(c.centre_x + dx, c.centre_y + dy, c.floor_z) for c in phantom.cavities
                                   for dx, dy in ((-c.mouth_radius, 0.0), (c.mouth_radius, 0.0), (0.0, -c.mouth_radius),
                                                  (0.0, c.mouth_radius))]
        farthest = max(abs(v - c) for point in points for v, c in zip(point, p.workspace_centre)) / p.workspace_range
        if farthest > _OBS_POSITION_BOUND:
            raise ValueError(f"{self.name}: workspace_range {p.workspace_range!r} (m) with workspace_centre "
                             f"{p.workspace_centre!r} puts the scene's cavities or hand-off point {farthest:.3g} "
                             f"ranges from the centre, outside the observation space's bound of "
                             f"{_OBS_POSITION_BOUND:g}; the scene needs workspace_range >= "
                             f"{farthest * p.workspace_range / _OBS_POSITION_BOUND:.3g} m")

    def _phantom_from_model(self) -> Phantom:
        geom = object_id(self.model, "geom", "phantom")
        hfield = self.model.geom_dataid[geom]
        size = self.model.hfield_size[hfield]
        px, py, pz = (float(v) for v in self.model.geom_pos[geom])
        top = pz + float(size[2])
        cavities = tuple(
            Cavity(px + cx, py + cy, top, assets.CAVITY_MOUTH_RADIUS, assets.CAVITY_DEPTH)
            for cx, cy in assets.CAVITY_CENTRES
        )
        return Phantom(px, py, float(size[0]), float(size[1]), top, geom_top(self.model, "table"), cavities)

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
        try:
            return self._observation_spaces[agent]
        except KeyError:
            raise ValueError(f"{self.name}: unknown agent {agent!r}; agents are {list(AGENTS)}") from None

    def action_space(self, agent):
        try:
            return self._action_spaces[agent]
        except KeyError:
            raise ValueError(f"{self.name}: unknown agent {agent!r}; agents are {list(AGENTS)}") from None

    def _blood_state(self, blood_ml) -> BloodState:
        return BloodState(self.phantom, [float(v) for v in np.atleast_1d(blood_ml)], self.params.suction_rate_ml_s)

    def reset(self, seed=None, options=None):
        # Everything is checked before anything changes: a refused reset leaves the env as it was.
        if seed is not None:
            from dvrl_marl.schemas import Seed, validated

            seed = validated(Seed, seed, f"{self.name}: reset(seed=...)")
        if options is not None and not isinstance(options, dict):
            raise ValueError(f"{self.name}: options must be a dict or None, got {type(options).__name__}")
        options = dict(options or {})
        blood_ml = options.pop("blood_ml", None)
        level = options.pop("level", None)
        start_level = (self.start_level if level is None else
                       start_levels.checked_level(level, f"{self.name}: reset option level"))
        if start_level < start_levels.DEFAULT and blood_ml is not None:
            raise ValueError(f"{self.name}: a level below 1 draws the blood itself; pass blood_ml or level, not both")
        given_blood = None if blood_ml is None else self._blood_state(blood_ml)  # (checked by BloodState)
        if options:  # PettingZoo's own API test passes arbitrary options, so unknown ones warn rather than raise
            warnings.warn(f"{self.name}: ignoring unknown reset option(s) {sorted(options)}; known: "
                          "['blood_ml', 'level']", stacklevel=2)
        if seed is not None:
            self._rng = np.random.default_rng(seed)
            self._level_rng = start_levels.level_generator(seed)
        self.start_level = start_level  # this episode's and the later ones' (until set again)
        drawn = None
        if self.start_level < start_levels.DEFAULT:
            drawn = start_levels.draw(self._level_rng, self.start_level, self.params.blood_ml, self.params.debris_count)
            given_blood = self._blood_state(drawn.blood_ml)
            self._level_blood = True
        elif self._level_blood and given_blood is None:  # back to the task's blood after easy starts
            given_blood, self._level_blood = self._blood_state(self.params.blood_ml), False
        if given_blood is not None:
            self.blood = given_blood
        mujoco.mj_resetData(self.model, self.data)
        rng = self._rng
        for agent in AGENTS:
            start = np.array(_STARTS[agent]) + rng.uniform(-_START_JITTER, _START_JITTER, 3)
            arm = self.arms[agent]
            arm.set_tip(*arm.to_base(start).tolist())
            if arm.tool.has_jaw:
                arm.set_jaw(1.0)
        self.valve_opening = 0.0
        self.blood.reset()
        for index in range(len(self._blood_geoms)):
            self._update_blood_visual(index)
        self._place_debris(rng)
        #: (onset s, rate ml/s) of each cavity's bleeding this episode (the bleeding field; empty without it).
        self.bleeding = self._draw_bleeding(rng)
        self._held = None
        self._hold_offset = (0.0, 0.0, 0.0)
        self._grip_offset = (0.0, 0.0, 0.0)
        self._step_count = 0
        self._contact = False
        self._blocked = {agent: False for agent in AGENTS}
        self._drawn_ml = 0.0
        self._limit = self.params.max_cycles
        if drawn is not None and drawn.easy:
            self._start_easy(drawn)
        self.agents = list(self.possible_agents)
        self._episodes += 1
        self._work_distances = {agent: self._work_distance(agent) for agent in AGENTS}
        if self._guided is not None:
            self._potential = self._guided.potentials(self._plain_state()[None],
                                                      np.asarray(self.blood.remaining_ml)[None])
        if self._surgeon is not None and hasattr(self._surgeon, "reset"):
            self._safe_device_call(self._surgeon.reset) if self._surgeon_is_device else self._surgeon.reset()
        if self._display is not None:
            self._display.start_episode(wait_for_enter=self.human_seat)
        observations = {agent: self._agent_observation(agent) for agent in self.agents}
        infos = {agent: self._info(False, False) for agent in self.agents}
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
            commands[self.surgeon_seat] = command
        p = self.params
        eta = p.step_size
        contact = False
        for agent in AGENTS:
            dx, dy, dz, tool_value = commands[agent]
            contact |= self._move(agent, eta * dx, eta * dy, eta * dz)
            if tool_value is None:
                continue
            if agent == "suction":
                self.valve_opening = float(tools.moved_towards(self.valve_opening, tools.valve_target(tool_value),
                                                               p.tool_speed))
            else:
                if p.hold_until_handoff and self._held is not None:  # a held pin's jaw stays shut until the hand-off
                    continue
                grasper = self.arms["grasper"]
                grasper.set_jaw(float(tools.moved_towards(grasper.jaw, tools.jaw_target(tool_value, p.jaw_command),
                                                          p.tool_speed)))
        removed = self._drawn_ml = self._suction()
        self._bleed()
        lifted, delivered = self._grasping()
        self._fall()
        self._step_count += 1
        self._contact = contact

        complete = self._complete()
        truncated = self._step_count >= self._limit and not complete
        rewards = self._rewards(removed, lifted, delivered, complete, contact)
        if self._guided is not None:  # the guided terms' change over the step (potential-based)
            potential = self._guided.potentials(self._plain_state()[None], np.asarray(self.blood.remaining_ml)[None])
            for agent in rewards:
                rewards[agent] += float(potential[agent][0] - self._potential[agent][0])
            self._potential = potential
        observations = {agent: self._agent_observation(agent) for agent in self.agents}
        infos = {agent: self._info(contact, complete) for agent in self.agents}
        if teleop_lost:
            for info in infos.values():
                info["teleop_lost"] = True
        terminations = {agent: complete for agent in self.agents}
        truncations = {agent: truncated for agent in self.agents}
        if self._display is not None:
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
        return self._renderer.viewer

    def realtime_stats(self) -> dict | None:
        """``render_mode="human"``: how well the episode kept real time (steps late, worst lag, frames dropped)."""
        return self._display.stats() if self._display is not None else None

    def state(self) -> np.ndarray:
        """The global state: tips, jaw, valve, blood, every debris (hidden included), hand-off point; with
        ``state_observations``, every arm's observation after it."""
        state = self._plain_state()
        if self.state_observations:
            state = np.concatenate([state, *(self._observe(agent) for agent in AGENTS)])
        return state if self.observation_scaling is None else self.observation_scaling.state(state)

    def _plain_state(self) -> np.ndarray:
        values = [*self._norm(*self.arms["suction"].tip_world()), 2.0 * self.valve_opening - 1.0,
                  *self._norm(*self.arms["grasper"].tip_world()), 2.0 * self.arms["grasper"].jaw - 1.0]
        values += [min(self.blood.fraction(i), _OBS_POSITION_BOUND) for i in range(len(self.phantom.cavities))]
        for pin in self.debris:
            values += [*self._norm(*self._shown_position(pin)), float(pin.visible), float(pin.held),
                       float(pin.delivered)]
        values += self._norm(*self.handoff)
        return np.array(values)

    def render(self):
        return self._renderer.render()

    def close(self):
        self._renderer.close()
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = None
        if self._surgeon_is_device and hasattr(self._surgeon, "close"):
            self._safe_device_call(self._surgeon.close)

    def progress(self) -> dict:
        """Where the episode stands, for a person watching it: blood left per cavity (ml), debris found (uncovered
        or delivered), delivered and in all, elapsed time (s), steps, whether the field is clear, and each arm's
        tool tip (world frame, m) with the jaw opening (0 closed .. 1 open) and whether the suction valve is open."""
        return {
            "blood_ml": [float(v) for v in self.blood.remaining_ml],
            "debris_found": int(sum(pin.visible or pin.delivered for pin in self.debris)),
            "debris_delivered": int(sum(pin.delivered for pin in self.debris)),
            "debris_total": len(self.debris),
            "time_s": self._step_count * self.params.control_dt,
            "steps": self._step_count,
            "success": bool(self._complete()),
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
        cues = {"tip_height_mm": 1000.0 * (z - self.phantom.surface_height(x, y)), "blocked": self._blocked[agent]}
        if agent == "suction":
            cavity = self.phantom.cavity_at(x, y)
            wet = cavity >= 0 and self.blood.remaining_ml[cavity] > 0.0
            cues["above_blood_mm"] = 1000.0 * (z - self.blood.surface_z[cavity]) if wet else None
            cues["drawing"] = self.valve_open and self._drawn_ml > 0.0
            return cues
        tip = (x, y, z)
        held = self._held is not None
        cues["holding"] = held
        cues["handoff_mm"] = (1000.0 * math.dist(self._judged_point(tip, self.debris[self._held]), self.handoff)
                              if held else None)
        reachable = [_point_segment_distance(tip, *pin.axis_ends()) for pin in self.debris
                     if pin.visible and not pin.delivered and not pin.held]
        nearest = min(reachable, default=None)
        cues["pin_mm"] = None if nearest is None else 1000.0 * nearest
        cues["in_reach"] = not held and nearest is not None and nearest <= _PIN_SENSOR_RANGE
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
            "workspace": {"low": [mm * v for v in self._low], "high": [mm * v for v in self._high]},
        }

    def pins(self) -> list[dict]:
        """The pins a person can see (uncovered, not yet delivered): position (mm, world), whether held, and for a
        held pin ``grip_mm``, the point the hand-off judges (where the jaws hold it)."""
        tip = self.arms["grasper"].tip_world()
        return [{"mm": [1000.0 * v for v in pin.position], "held": pin.held,
                 **({"grip_mm": [1000.0 * v for v in self._judged_point(tip, pin)]} if pin.held else {})}
                for pin in self.debris if pin.visible and not pin.delivered]

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
        elif self.agents == [] and self._step_count > 0:
            overlays.append(("top", "SUCCESS: the field is clear" if self._complete()
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

    def set_state(self, *, tips, jaw, valve_open, blood_ml, debris_positions, debris_yaws, visible, delivered,
                  valve_opening=None) -> None:
        """Put the scene in a given state (tips in each arm's base frame), e.g. to render a batched world.
        ``valve_opening`` (0..1, see :mod:`dvrl_marl.core.tools`): the valve's stroke; by default all or nothing."""
        for agent in AGENTS:
            self.arms[agent].set_tip(*np.asarray(tips[agent], dtype=np.float64).tolist())
        self.arms["grasper"].set_jaw(float(jaw))
        self.valve_opening = float(bool(valve_open)) if valve_opening is None else float(valve_opening)
        self.blood.set_remaining(blood_ml)
        for index in range(len(self._blood_geoms)):
            self._update_blood_visual(index)
        for index, pin in enumerate(self.debris):
            pin.position = [float(v) for v in debris_positions[index]]
            pin.yaw = float(debris_yaws[index])
            pin.visible, pin.delivered = bool(visible[index]), bool(delivered[index])
            self._sync_debris(index)

    # --- public helpers -------------------------------------------------------------------------------------
    def layout(self) -> SceneLayout:
        """The scene's fixed facts in normalised coordinates (for scripted agents and pipelines)."""
        k = self._inv_range
        cavities = self.phantom.cavities
        return SceneLayout(
            cavity_centres=tuple(self._norm(c.centre_x, c.centre_y, 0.0)[:2] for c in cavities),
            cavity_mouth_radius=assets.CAVITY_MOUTH_RADIUS * k,
            cavity_floor=tuple(self._norm(0.0, 0.0, c.floor_z)[2] for c in cavities),
            phantom_top=self._norm(0.0, 0.0, self.phantom.top_z)[2],
            blood_threshold_fraction=tuple(
                self.params.blood_threshold_ml / v if v > 0 else 0.0 for v in self.params.blood_ml
            ),
            handoff=self._norm(*self.handoff),
            base_positions={a: self._norm(*self.arms[a].base_position.tolist()) for a in AGENTS},
            gain=self.workspace_range / self.params.step_size,
            clearance=self.params.tip_clearance * k,
        )

    def normalise(self, position_world) -> np.ndarray:
        """x~ = (x - p_c) / rho for world positions (..., 3)."""
        return (np.asarray(position_world, float) - self.workspace_centre) * self._inv_range

    # --- internals ------------------------------------------------------------------------------------------
    def _norm(self, x, y, z):
        c, k = self._centre, self._inv_range
        return ((x - c[0]) * k, (y - c[1]) * k, (z - c[2]) * k)

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

    def _floor(self, x, y) -> float:
        return self.phantom.surface_height(x, y) + self.params.tip_clearance

    def _move(self, agent, dx, dy, dz) -> bool:
        """Move one arm's tip (world deltas); returns True when the instruments are in contact."""
        if self._move_rules[agent].slide:
            return self._slide(agent, np.array([[dx, dy, dz]]))
        arm = self.arms[agent]
        old = arm.tip_world()
        low, high = self._low, self._high
        x = min(max(old[0] + dx, low[0]), high[0])
        y = min(max(old[1] + dy, low[1]), high[1])
        z = min(max(old[2] + dz, low[2]), high[2])
        floor = self._floor(x, y)
        if z < floor:
            if floor - old[2] <= self.params.step_size + 1e-12:
                z = floor  # slide up a gentle slope by at most one step
            else:  # a wall: keep the horizontal position, move only vertically
                x, y = old[0], old[1]
                z = max(z, self._floor(x, y))
        previous = list(arm.tip)
        arm.move(x - old[0], y - old[1], z - old[2], (-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))
        clearance = self._instrument_distance()
        self._blocked[agent] = blocked = clearance < 0.0
        if blocked:
            arm.set_tip(*previous)  # instruments never pass through each other
            return True
        return clearance < _CONTACT_MARGIN

    def _slide(self, agent, delta: np.ndarray) -> bool:
        """The sliding move (:mod:`dvrl_marl.core.sliding`): a wall slid along, a blocked move resolved by
        :func:`~dvrl_marl.core.sliding.resolve_blocked` ("climb": a descent that makes no headway given up); the batched
        core's functions, on one row."""
        arm, p, descents = self.arms[agent], self.params, self._move_rules[agent].descents
        old = np.asarray(arm.tip_world(), dtype=np.float64)[None]
        low, high = np.asarray(self._low), np.asarray(self._high)
        target = sliding.surface_target(self._cavities, p.tip_clearance, p.step_size, low, high, old, delta,
                                        **descents)[0]
        previous, previous_q = list(arm.tip), arm.q  # (restored as they were: no IK, see Arm.set_solved_tip)
        cut = arm.move(*(target - old[0]).tolist(), (-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))
        clearance = self._instrument_distance()
        self._blocked[agent] = refused = clearance < 0.0
        if refused or (cut and list(arm.tip) == previous):
            other = self.arms[AGENTS[1 - AGENTS.index(agent)]]
            made, tip, q, gap = sliding.resolve_blocked(
                {"tool": arm.tool, "base": arm.base_position, "tip": old},
                {"tool": other.tool, "base": other.base_position,
                 "tip": np.asarray(other.tip_world(), dtype=np.float64)[None]},
                agent == "suction", delta, self._cavities, p.tip_clearance, p.step_size, low, high, **descents)
            if made[0]:  # the batched solution as is: a tip slid onto a joint limit stays on it (Arm.set_solved_tip)
                arm.set_solved_tip(*(tip[0] - arm.base_position).tolist(), q[0])
                return bool(gap[0] < _CONTACT_MARGIN)
            arm.set_solved_tip(*previous, previous_q)
            if refused:
                return True
        return clearance < _CONTACT_MARGIN

    def _instrument_segments(self, agent):
        arm = self.arms[agent]
        bx, by, bz = arm.base_position.tolist()
        wx, wy, wz = kinematics.wrist_position_point(arm.tool, arm.q)
        wrist = (wx + bx, wy + by, wz + bz)
        return (bx, by, bz), wrist, arm.tip_world()

    def instrument_clearance(self) -> float:
        """Clearance between the two instruments (m; they never intersect: never negative)."""
        return self._instrument_distance()

    def _instrument_distance(self) -> float:
        """Clearance between the two instruments (negative when they intersect)."""
        rcm_a, wrist_a, tip_a = self._instrument_segments("suction")
        rcm_b, wrist_b, tip_b = self._instrument_segments("grasper")
        ra, rb = _WRIST_RADIUS["suction"], _WRIST_RADIUS["grasper"]
        return min(
            _segment_distance(rcm_a, wrist_a, rcm_b, wrist_b) - 2 * _SHAFT_RADIUS,
            _segment_distance(rcm_a, wrist_a, wrist_b, tip_b) - _SHAFT_RADIUS - rb,
            _segment_distance(wrist_a, tip_a, rcm_b, wrist_b) - ra - _SHAFT_RADIUS,
            _segment_distance(wrist_a, tip_a, wrist_b, tip_b) - ra - rb,
        )

    def _suction(self) -> float:
        if not self.valve_open:
            return 0.0
        x, y, z = self.arms["suction"].tip_world()
        cavity, removed = self.blood.suck(x, y, z, self.params.control_dt, self.params.suction_reach)
        if removed > 0.0:
            self._update_blood_visual(cavity)
            surface = self.blood.surface_z[cavity]
            for pin in self.debris:
                if pin.cavity == cavity and not pin.visible and pin.position[2] + _PIN_RADIUS > surface:
                    pin.visible = True
        return removed

    def _draw_bleeding(self, rng) -> list[tuple[float, float]]:
        """(onset in s, rate in ml/s) per cavity for this episode: onset uniform in [0, bleeding_onset_s], rate
        uniform in [0.5, 1] x bleeding_ml_s. Nothing is drawn without bleeding (the random stream is as without the field)."""
        p = self.params
        if p.bleeding_ml_s <= 0.0:
            return []
        return [(float(rng.uniform(0.0, p.bleeding_onset_s)), float(rng.uniform(0.5, 1.0)) * p.bleeding_ml_s)
                for _ in self.phantom.cavities]

    def _bleed(self) -> None:
        if not self.bleeding:  # no bleeding field: nothing to do on the step path
            return
        now, dt = self._step_count * self.params.control_dt, self.params.control_dt
        for index, (onset, rate) in enumerate(self.bleeding):
            if now >= onset and self.blood.bleed(index, rate * dt) > 0.0:
                self._update_blood_visual(index)

    def _fall(self) -> None:
        """Released pins fall under gravity onto the surface below them (never into it)."""
        if not self.params.pins_fall:  # the simple rule: released pins never fall
            return
        dt = self.params.control_dt
        for index, pin in enumerate(self.debris):
            if pin.fall_speed is None:
                continue
            pin.fall_speed += GRAVITY * dt
            floor = self.phantom.surface_height(pin.position[0], pin.position[1]) + _PIN_RADIUS
            pin.position[2] = max(pin.position[2] - pin.fall_speed * dt, floor)
            if pin.position[2] <= floor:
                pin.fall_speed = None
            self._sync_debris(index)

    def _update_blood_visual(self, index: int) -> None:
        geom = self._blood_geoms[index]
        radius = self.blood.surface_radius[index]
        if self.blood.remaining_ml[index] <= 0.0 or radius <= 1e-4:
            self.model.geom_rgba[geom][3] = 0.0
            return
        self.model.geom_rgba[geom] = self._blood_rgba[index]
        self.model.geom_size[geom][0] = radius
        self.model.geom_pos[geom][2] = self.blood.surface_z[index] - self.model.geom_size[geom][1]

    def _place_debris(self, rng) -> None:
        for index, (pin, (position, yaw, cavity_index)) in enumerate(
                zip(self.debris, sample_debris(rng, self.phantom.cavities, len(self.debris)))):
            pin.position, pin.yaw, pin.cavity = position, yaw, cavity_index
            pin.held = pin.delivered = pin.lifted = False
            pin.fall_speed = None
            pin.visible = pin.position[2] + _PIN_RADIUS > self.blood.surface_z[cavity_index]
            self._sync_debris(index)

    def _sync_debris(self, index: int) -> None:
        pin = self.debris[index]
        adr = self._debris_qpos[index]
        if pin.delivered:  # handed to the assistant: out of the scene
            self.data.qpos[adr:adr + 3] = (0.0, 0.0, -1.0)
            return
        self.data.qpos[adr:adr + 3] = pin.position
        # Capsule axis is the body z axis: turn it horizontal (about y), then to the pin's yaw (about z).
        half_yaw, c = 0.5 * pin.yaw, math.sqrt(0.5)
        self.data.qpos[adr + 3:adr + 7] = (c * math.cos(half_yaw), -c * math.sin(half_yaw), c * math.cos(half_yaw),
                                           c * math.sin(half_yaw))

    def _grasping(self) -> tuple[int, int]:
        """The paper's grasp rule for the LND and the hand-off. Returns (debris first lifted, delivered) counts."""
        grasper = self.arms["grasper"]
        tip = grasper.tip_world()
        closed = grasper.jaw < self.params.grasp_threshold
        lifted = delivered = 0
        if self._held is not None and not closed:
            pin = self.debris[self._held]
            pin.held = False
            if self.params.pins_stay_on_phantom:  # beyond the phantom, it lands on the nearest edge (in view)
                pin.position[0], pin.position[1] = self.phantom.nearest_on_top(pin.position[0], pin.position[1],
                                                                               _PHANTOM_EDGE_MARGIN)
            if self.params.pins_fall:  # released away from the assistant: it falls (see _fall)
                pin.fall_speed = 0.0
            else:  # the simple rule: it appears on the surface below it at once
                pin.position[2] = self.phantom.surface_height(pin.position[0], pin.position[1]) + _PIN_RADIUS
            self._sync_debris(self._held)
            self._held = None
        elif self._held is None and closed:
            for index, pin in enumerate(self.debris):
                if pin.visible and not pin.delivered:
                    grip = _closest_on_segment(tip, *pin.axis_ends())  # where the jaws would hold the pin
                    if math.dist(tip, grip) <= _PIN_SENSOR_RANGE:
                        self._held = index
                        pin.held = True
                        pin.fall_speed = None  # caught
                        self._hold_offset = tuple(pin.position[i] - tip[i] for i in range(3))
                        self._grip_offset = tuple(grip[i] - tip[i] for i in range(3))
                        if not pin.lifted:
                            pin.lifted = True
                            lifted = 1
                        break
        if self._held is not None:
            pin = self.debris[self._held]
            pin.position = [tip[i] + self._hold_offset[i] for i in range(3)]
            if math.dist(self._judged_point(tip, pin), self.handoff) <= self.params.distance_threshold:
                pin.held, pin.delivered = False, True
                self._held = None
                delivered = 1
            self._sync_debris(self.debris.index(pin))
        return lifted, delivered

    def _judged_point(self, tip, pin):
        """Where the hand-off is judged: the pin's centre or where the jaws hold it (``deliver_at_grip``:
        a pin held off its centre can still reach the assistant, whose point lies 2 mm inside the workspace)."""
        if self.params.deliver_at_grip:
            return [tip[i] + self._grip_offset[i] for i in range(3)]
        return pin.position

    def _shown_position(self, pin):
        """Where observations, the state and the dense reward's carry place ``pin``: its centre, or while it is held
        with ``held_pin_at_grip`` the point the hand-off judges (:meth:`_judged_point`)."""
        if pin.held and self.params.held_pin_at_grip:
            return self._judged_point(self.arms["grasper"].tip_world(), pin)
        return pin.position

    def _complete(self) -> bool:
        threshold = self.params.blood_threshold_ml
        return all(v < threshold or v <= 0.0 for v in self.blood.remaining_ml) and all(p.delivered for p in self.debris)

    def _start_easy(self, start) -> None:
        """An easy start (:mod:`dvrl_marl.envs.start_levels`): some debris out of play, the episode shorter, the
        grasper's tip near a visible pin (kept where it was when that start is not possible)."""
        for index in range(start.debris_count, len(self.debris)):
            pin = self.debris[index]
            pin.delivered, pin.visible = True, False
            self._sync_debris(index)
        self._limit = min(self.params.max_cycles, self.easy_episode_steps or self.params.max_cycles)
        if self._rims is None:
            self._rims = OverRims(self._cavities)
        pins = np.array([pin.position for pin in self.debris])
        pending = np.array([pin.visible and not pin.delivered for pin in self.debris])
        arm = self.arms["grasper"]
        target = start_levels.grasper_start(self._level_rng, pins, pending, arm.tip_world(), start.reach, self._rims)
        if target is None:
            return
        low, high = self._low, self._high
        if (any(v < lo - 1e-12 or v > hi + 1e-12 for v, lo, hi in zip(target, low, high))
                or target[2] < self._floor(target[0], target[1]) - 1e-12):
            return
        previous = list(arm.tip)
        try:
            arm.set_tip(*arm.to_base(target).tolist())
        except kinematics.UnreachableError:
            arm.set_tip(*previous)
            return
        if self._instrument_distance() < 0.0:
            arm.set_tip(*previous)

    def _rewards(self, removed, lifted, delivered, complete, contact) -> dict:
        if self.reward_type == "sparse":  # ("guided": the dense reward, the guided terms added in step)
            team = 0.0 if complete else -1.0
            rewards = {agent: team for agent in self.agents}
        else:
            team = removed + 2.0 * lifted + 5.0 * delivered
            rewards = {}
            for agent in self.agents:
                # Potential-based shaping (Ng et al. 1999): it rewards progress without changing the optimum.
                distance = self._work_distance(agent)
                rewards[agent] = team + 10.0 * (self._work_distances[agent] - distance)
                self._work_distances[agent] = distance
        if contact:
            for agent in rewards:
                rewards[agent] -= self.params.contact_penalty
        return rewards

    def _work_distance(self, agent) -> float:
        """Distance (m) from the agent's tip to what it should work on next (0 when nothing is left)."""
        tip = self.arms[agent].tip_world()
        if agent == "suction":
            targets = [(c.centre_x, c.centre_y, c.floor_z) for c, v in zip(self.phantom.cavities, self.blood.remaining_ml)
                       if v >= self.params.blood_threshold_ml and v > 0.0]
            return min((math.dist(tip, t) for t in targets), default=0.0)
        if self._held is not None:
            return math.dist(self._shown_position(self.debris[self._held]), self.handoff)
        targets = [pin.position for pin in self.debris if pin.visible and not pin.delivered]
        return min((math.dist(tip, t) for t in targets), default=0.0)

    def _feature_spec(self, name: str, debris: int):
        """The ``observation_features`` option's spec (None without it)."""
        if not isinstance(name, str):
            raise ValueError(f"{self.name}: observation_features must be a feature set's name or '', got {name!r}")
        if not name:
            return None
        try:
            return features.spec(name, self.layout(), debris)
        except ValueError as error:
            raise ValueError(f"{self.name}: observation_features: {error}") from None

    def _agent_observation(self, agent) -> np.ndarray:
        """What ``agent`` is given: its observation, normalised with the option."""
        observation = self._observe(agent)
        return observation if self.observation_scaling is None else self.observation_scaling.observation(agent, observation)

    def seat_observation(self, agent) -> np.ndarray:
        """What a seat's filler (a script, an exported policy, a device) reads of ``agent``'s view: the plain
        observation in the scene's units, whatever ``observation_features`` and ``normalize_observations`` give the
        learning agents (an exported policy computes its own features and scaling). The batched env's seat reads the
        same."""
        return self._observe(agent, with_features=False)

    def _observe(self, agent, with_features: bool = True) -> np.ndarray:
        own = self.arms[agent]
        other = self.arms["grasper" if agent == "suction" else "suction"]
        tool = 2.0 * (self.valve_opening if agent == "suction" else own.jaw) - 1.0
        values = [*self._norm(*own.tip_world()), tool, *self._norm(*other.tip_world())]
        values += [min(self.blood.fraction(i), _OBS_POSITION_BOUND) for i in range(len(self.phantom.cavities))]
        for pin in self.debris:
            if pin.visible and not pin.delivered:
                values += self._norm(*self._shown_position(pin))
            else:
                values += (0.0, 0.0, 0.0)
            values += (float(pin.visible), float(pin.held), float(pin.delivered))
        values += self._norm(*self.handoff)
        if with_features and self.feature_spec is not None:
            return features.apply(self.feature_spec, np.array(values))  # the observation, the features appended
        return np.array(values)

    def _info(self, contact: bool, complete: bool) -> dict:
        remaining = tuple(self.blood.remaining_ml)
        return {
            "blood_remaining": float(sum(remaining)),
            "blood_remaining_per_cavity": remaining,
            "debris_delivered": sum(p.delivered for p in self.debris),
            "collision": bool(contact),
            "is_success": bool(complete),
        }


def _model_with_more_debris(scene: str, count: int) -> mujoco.MjModel:
    """The scene with extra pins (copies of debris_0) when ``debris_count`` exceeds the pins in the file."""
    spec = mujoco.MjSpec.from_file(str(assets.scene_path(scene)))
    # Lookups through the lists (MjSpec.geom/.body by name are newer than the mujoco floor, 3.2).
    template = next(geom for geom in spec.geoms if geom.name == "debris_0")
    bodies = {body.name for body in spec.bodies}
    index = 0
    while f"debris_{index}" in bodies:
        index += 1
    while index < count:
        body = spec.worldbody.add_body(name=f"debris_{index}", pos=[0.0, 0.0, -1.0])
        body.add_freejoint(name=f"debris_{index}")
        body.add_geom(name=f"debris_{index}", type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=template.size,
                      material=template.material, density=template.density)
        index += 1
    return spec.compile()


def parallel_env(**kwargs) -> SuctionDebrisEnv:
    """The parallel environment (the native form)."""
    return SuctionDebrisEnv(**kwargs)


raw_env = parallel_env


def env(**kwargs):
    """The AEC form, through PettingZoo's parallel-to-AEC conversion."""
    return parallel_to_aec(parallel_env(**kwargs))

