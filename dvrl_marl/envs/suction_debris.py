"""The collaborative scene's parallel env: one world of the core as a PettingZoo ``ParallelEnv``.

Users import the current version, :mod:`dvrl_marl.envs.suction_debris_v8`, whose module documentation is the
environment's page; this module holds what that version re-exports. The step itself is the core's
(:mod:`dvrl_marl.suction_debris.rules`), reached through the batched env with one world
(:class:`~dvrl_marl.envs.suction_debris_batched.SuctionDebrisBatchedEnv`): this class turns its arrays into PettingZoo's
dicts. A filled surgeon seat and the window a person watches are a wrapper's (:mod:`dvrl_marl.envs.surgeon_seat`),
what a person is shown a view's (:mod:`dvrl_marl.envs.scene_view`); :func:`parallel_env` puts them together.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
from pettingzoo import ParallelEnv
from pettingzoo.utils.conversions import parallel_to_aec

from dvrl_marl.core import tools
from dvrl_marl.envs.one_world import WorldArm, WorldBlood, WorldPin
from dvrl_marl.envs.scene_keywords import form_signature
from dvrl_marl.envs.suction_debris_batched import REWARD_TYPES, SceneLayout, SuctionDebrisBatchedEnv
from dvrl_marl.envs.surgeon_seat import SurgeonSeat, check_seat
from dvrl_marl.rendering import render_modes_here
from dvrl_marl.suction_debris import layout, start_levels
from dvrl_marl.suction_debris.rules import AGENTS
from dvrl_marl.suction_debris.task import TASK, SuctionDebrisParams, env_name

__all__ = ["parallel_env", "env", "raw_env", "batched_env", "jax_env", "TASK", "PRESETS", "SuctionDebrisEnv",
           "SuctionDebrisParams", "SceneLayout", "AGENTS", "env_name", "REWARD_TYPES"]

#: Attributes of the one-world batch the env shows as its own (the scene's parameters, spaces' layouts, options).
_SHARED = ("name", "preset", "options", "params", "reward_type", "core", "phantom", "handoff", "workspace_centre",
           "workspace_range",
           "observation_layout", "state_layout", "state_space", "feature_spec", "observation_scaling",
           "state_observations", "easy_episode_steps", "guidance")


class SuctionDebrisEnv(ParallelEnv):
    """The collaborative suction and debris-removal environment, both arms learning (see the module documentation)."""

    metadata = {
        "name": TASK,
        "render_modes": ["human", "rgb_array"],  # (each instance: what this machine can show, render_modes_here)
        "render_fps": 50,
        "is_parallelizable": True,
    }

    def __init__(self, render_mode: str | None = None, max_cycles: int | None = None, width: int = 640,
                 height: int = 480, **options):
        if render_mode == "human":
            raise ValueError(f"{TASK}: render_mode 'human' opens a window through parallel_env(render_mode='human')")
        #: one world of the scene: the core's step, the options, the spaces
        self.world = SuctionDebrisBatchedEnv(1, max_cycles=max_cycles, render_mode=render_mode,
                                             autoreset_mode="disabled", width=width, height=height, **options)
        for attribute in _SHARED:
            setattr(self, attribute, getattr(self.world, attribute))
        self.metadata = {**self.metadata, "name": self.name,
                         "render_modes": render_modes_here(("human", "rgb_array"))}  # (the display now)
        self.render_mode = render_mode
        self.possible_agents = list(AGENTS)
        self.agents = []
        self.episodes = 0  # episodes begun (reset() calls)

    # --- PettingZoo API -------------------------------------------------------------------------------------
    def observation_space(self, agent):
        return self.world.observation_space(agent)

    def action_space(self, agent):
        return self.world.action_space(agent)

    @property
    def start_level(self) -> float:
        """The start level of the next episodes (:mod:`dvrl_marl.suction_debris.start_levels`)."""
        return float(self.world.levels[0])

    @start_level.setter
    def start_level(self, level) -> None:
        self.world.set_start_level(level)

    @property
    def steps(self) -> int:
        """Steps of this episode so far."""
        return int(self.core.elapsed[0])

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
        self.episodes += 1
        info = self._info()
        return self._observations(), {agent: dict(info) for agent in self.agents}

    def step(self, actions):
        if not self.agents:
            raise ValueError(f"{self.name}: step() called " + ("after the episode ended" if self.episodes
                                                                 else "before reset()") + "; call reset()")
        return self.advance(self.read_actions(actions))

    def advance(self, commands: dict):
        """A step with both arms' commands, already checked (:meth:`read_actions`): 4 values each, a NaN tool value
        meaning "unchanged" (a held seat). Returns what :meth:`step` returns."""
        rewards, terminated, truncated = self.world.advance(
            {agent: np.array([commands[agent]], dtype=np.float64) for agent in AGENTS})
        complete, truncated = bool(terminated[0]), bool(truncated[0])
        rewards = {agent: float(rewards[agent][0]) for agent in self.agents}
        observations = self._observations()
        info = self._info()
        infos = {agent: dict(info) for agent in self.agents}
        terminations = {agent: complete for agent in self.agents}
        truncations = {agent: truncated for agent in self.agents}
        if complete or truncated:
            self.agents = []
        return observations, rewards, terminations, truncations, infos

    def state(self) -> np.ndarray:
        """The global state: tips, jaw, valve, blood, every debris (hidden included), hand-off point; with
        ``state_observations``, every arm's observation after it."""
        return self.world.state()[0]

    def render(self):
        return self.world.render(0)

    def close(self):
        self.world.close()

    # --- the world as one scene ---------------------------------------------------------------------------------
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
        mirror = self.world.mirror()
        mirror.show(self.core.world_state(0))
        return mirror

    # --- internals ------------------------------------------------------------------------------------------
    def read_actions(self, actions, agents=None) -> dict:
        """``{agent: action}`` for ``agents`` (default: the live ones), each checked and clipped."""
        agents = self.agents if agents is None else agents
        if not isinstance(actions, dict):
            raise ValueError(f"{self.name}: actions must be a dict keyed by agent, got {type(actions).__name__}")
        for agent in actions:
            if agent not in agents:
                raise ValueError(f"{self.name}: unknown agent {agent!r} in actions; live agents are {agents}")
        commands = {}
        for agent in agents:
            if agent not in actions:
                raise ValueError(f"{self.name}: no action for agent {agent!r}")
            commands[agent] = self.check_action(agent, actions[agent])
        return commands

    def check_action(self, agent, action) -> list[float]:
        """One agent's action as 4 floats clipped to [-1, 1]; a ValueError naming the agent when it is not 4 finite
        numbers."""
        try:
            array = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError) as error:
            raise ValueError(f"{self.name}: action for {agent!r} is not numeric: {action!r}") from error
        if array.shape != (layout.ACTION_WIDTH,):
            raise ValueError(f"{self.name}: action for {agent!r} must have shape ({layout.ACTION_WIDTH},), got "
                             f"{array.shape}")
        values = array.tolist()
        for value in values:
            if not math.isfinite(value):
                raise ValueError(f"{self.name}: action for {agent!r} contains NaN or inf: {values}")
        return [-1.0 if v < -1.0 else 1.0 if v > 1.0 else v for v in values]

    def _observations(self) -> dict:
        observations = self.world.observations()
        if self.world.image_size:  # {"observation", "image"[, "depth", "segmentation"]} per agent
            return {agent: {key: value[0] for key, value in observations[agent].items()} for agent in self.agents}
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
            **({key: value[0].item() for key, value in core.fluid_figures().items()} if core.fluids else {}),
        }


def parallel_env(surgeon=None, surgeon_seat: str = "grasper", render_mode: str | None = None,
                 teleop_timeout: float | None = 0.5, width: int = 640, height: int = 480, **kwargs):
    """The parallel environment (the native form). ``surgeon`` fills ``surgeon_seat`` (None: both arms learn;
    ``"scripted"``, a callable or a teleop device) and ``render_mode="human"`` opens a window: both through
    :class:`~dvrl_marl.envs.surgeon_seat.SurgeonSeat` around the scene."""
    teleop_timeout = check_seat(env_name(kwargs.get("task", TASK)), surgeon_seat, teleop_timeout)
    if render_mode is not None and render_mode not in ("human", "rgb_array"):
        raise ValueError(f"{TASK}: render_mode must be 'human' or 'rgb_array', got {render_mode!r}")
    scene = SuctionDebrisEnv(render_mode="rgb_array" if render_mode == "rgb_array" else None, width=width,
                             height=height, **kwargs)
    if surgeon is None and render_mode != "human":
        return scene
    return SurgeonSeat(scene, surgeon, surgeon_seat, render_mode, teleop_timeout, width, height)


raw_env = parallel_env


def env(**kwargs):
    """The AEC form, through PettingZoo's parallel-to-AEC conversion."""
    return parallel_to_aec(parallel_env(**kwargs))


#: What one world in PettingZoo's form does not take (the batch's) or takes in ``SurgeonSeat`` (the seat's).
_NOT_PETTINGZOO = ("num_envs", "autoreset_mode", "render_world")
parallel_env.__signature__ = form_signature(parallel_env, SuctionDebrisBatchedEnv.__init__, without=_NOT_PETTINGZOO)
env.__signature__ = parallel_env.__signature__


# The scene's every form, from this unversioned module: the library imports it (PettingZoo's way); only users and
# dvrl_marl.envs say the version (suction_debris_v8), whose name is the task's (suction_debris.task.TASK).
from dvrl_marl.suction_debris.presets import PRESETS  # noqa: E402
from dvrl_marl.envs.suction_debris_device import batched_env  # noqa: E402
from dvrl_marl.envs.suction_debris_jax import jax_env  # noqa: E402
