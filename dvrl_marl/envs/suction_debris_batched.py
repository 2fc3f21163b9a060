"""Suction & debris removal, N worlds at once: the batched form of ``suction_debris_v8``.

```python
from dvrl_marl.envs import suction_debris_v8
env = suction_debris_v8.batched_env(num_envs=4096)                      # both arms learn
env = suction_debris_v8.batched_env(num_envs=4096, surgeon="scripted")  # the scripted surgeon in every world
observations, infos = env.reset(seed=0)           # world i == parallel_env().reset(seed=0 + i)
observations, rewards, terminations, truncations, infos = env.step(
    {agent: actions_of(agent) for agent in env.agents})                 # each (N, 4)
```

Every per-agent value has a leading world dimension: ``observations[agent]`` ``(N, obs_dim)``, ``rewards[agent]``,
``terminations[agent]``, ``truncations[agent]`` ``(N,)``; ``infos[agent]`` is a dict of arrays (the single env's
keys: ``blood_remaining``, ``blood_remaining_per_cavity``, ``debris_delivered``, ``collision``, ``is_success``).
``state()`` is ``(N, state_dim)``. Spaces, rewards, the observation layout and every keyword argument are those of
:mod:`dvrl_marl.envs.suction_debris_v8`, whose documentation applies world by world.

## Automatic reset
``autoreset_mode="same_step"`` (default): a world whose episode ended (terminated or truncated) starts its next
episode inside the same ``step``; the returned observation is the new episode's first, and the ended episode's last
observation and state are in ``infos[agent]["final_observation"]`` / ``infos[agent]["final_state"]``, rows valid
where ``infos[agent]["_final"]`` is True (what PPO needs to bootstrap a truncated episode). ``"disabled"``: worlds
are never reset for you; ``reset(options={"reset_mask": mask})`` resets some. Agents never leave ``agents``.

## Start-state options (for curricula)
Besides ``blood_ml`` ((C,) or one row per world), ``reset(options=...)`` takes ``debris_count`` (an int or
``(N,)`` ints: only the first k debris are in play, the others start delivered) and ``tip_positions``
(``{agent: (N, 3)}`` metres in the world frame: each tip must be inside the workspace box, above the surface,
reachable, and leave the instruments apart). Rows of worlds that are not reset are ignored.
``set_tip_positions(tips, worlds)`` moves tips of episodes just drawn (to start near what the draw placed). The
default task is what you get without them.

``level`` (one level, ``"easy"`` / ``"default"``, or one per world) sets the start level of those worlds' episodes,
this one and the later ones, automatic resets included (:mod:`dvrl_marl.envs.start_levels`; ``set_start_level``
does the same between resets); below 1 it draws blood, debris and starts itself, so it is refused together with
the three options above. World ``i``'s level draws are those of a single env reset with ``seed + i``.

## The surgeon seat
``surgeon="scripted"`` runs the batched scripted expert in every world; a callable gets the seat's observations
``(N, obs_dim)`` and returns ``(N, 4)``. Teleoperation devices drive one world: use ``parallel_env`` for them.

## Seeding
``reset(seed=s)`` gives world ``i`` the random stream of ``parallel_env().reset(seed=s + i)``; a world that
resets automatically continues that stream, as a single env reset without a seed does. Same seeds and actions
give the single environment's trajectories, world by world (tested over 1,000 steps with resets).

## Rendering
``render()`` draws world ``render_world`` (default 0; ``render(world=i)`` any other) through the single
environment's MuJoCo scene.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dvrl_marl.core.collaborative import AGENTS, CollaborativeCore
from dvrl_marl.core.worlds import check_action_batch
from dvrl_marl.envs import start_levels
from dvrl_marl.envs.guidance import GuidedReward, OverRims
from dvrl_marl.envs.presets import accepts_preset
from dvrl_marl.envs.suction_debris import TASK, SuctionDebrisEnv, env_name
from dvrl_marl.policies import features

__all__ = ["SuctionDebrisBatchedEnv", "AUTORESET_MODES", "batched_env", "takes_worlds"]

AUTORESET_MODES = ("same_step", "disabled")


class SuctionDebrisBatchedEnv:
    """N worlds of suction_debris_v8 (see the module documentation)."""

    metadata = {"name": "suction_debris_v8", "render_modes": ["rgb_array"], "render_fps": 50}

    @accepts_preset
    def __init__(self, num_envs: int = 1, surgeon=None, surgeon_seat: str = "grasper", reward_type: str = "sparse",
                 render_mode: str | None = None, max_cycles: int | None = None, autoreset_mode: str = "same_step",
                 render_world: int = 0, **kwargs):
        self.name = env_name(Path(str(kwargs.get("task", TASK))).stem)
        self.metadata = {**self.metadata, "name": self.name}
        from dvrl_marl.schemas import PositiveInt, validated

        num_envs = validated(PositiveInt, num_envs, f"{self.name}: num_envs")
        if autoreset_mode not in AUTORESET_MODES:
            raise ValueError(f"{self.name}: autoreset_mode must be one of {AUTORESET_MODES}, got {autoreset_mode!r}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"{self.name}: the batched env renders 'rgb_array' only, got {render_mode!r}")
        if hasattr(surgeon, "action") and callable(surgeon.action):
            raise ValueError(f"{self.name}: a teleop device drives one world; use parallel_env(surgeon=device)")
        # The single env validates every argument and holds the scene (for rendering and the layout).
        self.template = SuctionDebrisEnv(surgeon=None, surgeon_seat=surgeon_seat, reward_type=reward_type,
                                         render_mode=render_mode, max_cycles=max_cycles, **kwargs)
        self.surgeon_seat = surgeon_seat if surgeon is not None else None
        self.possible_agents = [agent for agent in AGENTS if agent != self.surgeon_seat]
        self.agents = list(self.possible_agents)
        self.core = CollaborativeCore(self.template, num_envs)
        self.core.rewarded_agents = tuple(self.possible_agents)
        self.num_envs = self.core.num_worlds
        self.autoreset_mode = autoreset_mode
        self.render_mode = render_mode
        if not 0 <= int(render_world) < self.num_envs:
            raise ValueError(f"{self.name}: render_world must be in [0, {self.num_envs}), got {render_world!r}")
        self.render_world = int(render_world)
        self.params = self.template.params
        self.observation_layout = self.template.observation_layout
        self.state_layout = self.template.state_layout
        self.state_space = self.template.state_space
        self.workspace_range = self.template.workspace_range
        self._surgeon = self._bind_surgeon(surgeon, surgeon_seat)
        self._surgeon_resets_worlds = takes_worlds(getattr(self._surgeon, "reset", None))
        # Options that help learning (validated by the template): features, start levels, guided reward.
        self.feature_spec = self.template.feature_spec
        self.observation_scaling = self.template.observation_scaling
        self.levels = np.full(self.num_envs, self.template.start_level)  # each world's start level
        self._level_rngs = [start_levels.level_generator(None) for _ in range(self.num_envs)]
        self._rims = None  # the way around the rims, for easy starts that recede (built on first use)
        self._level_blood = np.zeros(self.num_envs, dtype=bool)  # worlds whose blood a level's draw set
        self._guided = (GuidedReward(self.template, self.possible_agents, self.template.guidance)
                        if reward_type == "guided" else None)
        self._potential = None

    def _bind_surgeon(self, surgeon, seat):
        if surgeon is None:
            return None
        if isinstance(surgeon, str):
            if surgeon != "scripted":
                raise ValueError(f"{self.name}: surgeon must be None, 'scripted' or a callable, got {surgeon!r}")
            from dvrl_marl.agents.collaborative import ScriptedSuction, ScriptedSurgeon  # agents build on envs

            return (ScriptedSurgeon if seat == "grasper" else ScriptedSuction).for_env(self.template)
        if callable(surgeon):
            return surgeon
        raise ValueError(f"{self.name}: surgeon {surgeon!r} is not callable")

    # --- spaces and facts ---------------------------------------------------------------------------------
    def observation_space(self, agent):
        return self.template.observation_space(agent)

    def action_space(self, agent):
        return self.template.action_space(agent)

    def layout(self):
        """The scene's fixed facts in normalised coordinates (for scripted agents and pipelines)."""
        return self.template.layout()

    @property
    def unwrapped(self):
        return self

    # --- API ----------------------------------------------------------------------------------------------
    def reset(self, seed=None, options=None):
        if options is not None and not isinstance(options, dict):
            raise ValueError(f"{self.name}: options must be a dict or None, got {type(options).__name__}")
        options = dict(options or {})
        mask = options.pop("reset_mask", None)
        blood_ml = options.pop("blood_ml", None)
        tips = options.pop("tip_positions", None)
        debris_count = options.pop("debris_count", None)
        level = options.pop("level", None)
        if options:
            raise ValueError(f"{self.name}: unknown reset option(s) {sorted(options)}; "
                             "known: ['blood_ml', 'debris_count', 'level', 'reset_mask', 'tip_positions']")
        if mask is not None and not getattr(self, "_started", False):
            raise ValueError(f"{self.name}: the first reset starts every world; reset_mask is for the resets after it")
        worlds = self.core.worlds_of(mask)
        if blood_ml is not None and np.ndim(blood_ml) == 2 and np.shape(blood_ml)[0] == self.num_envs:
            blood_ml = np.asarray(blood_ml)[worlds]
        levels = self.levels.copy()  # checked before anything changes: a refused reset leaves the worlds as they were
        if level is not None:  # these worlds' level, for this and their later episodes (until set again)
            levels[worlds] = self._checked_levels(level)[worlds]
        if np.any(levels[worlds] < start_levels.DEFAULT) and (
                blood_ml is not None or debris_count is not None or tips is not None):
            raise ValueError(f"{self.name}: a level below 1 draws blood, debris and starts itself; pass "
                             "blood_ml / debris_count / tip_positions or level, not both")
        if seed is not None:
            self.core.random.seed(seed)  # (validates the seed before anything is drawn)
            self._seed_levels(seed)
        self.levels = levels
        if np.any(self.levels[worlds] < start_levels.DEFAULT):
            self._start_at_levels(worlds)
        else:
            self._reset_at_default(worlds, blood_ml)
        if debris_count is not None:
            count = np.asarray(debris_count)
            self.core.limit_debris(worlds, count[worlds] if count.ndim == 1 else count)
        if tips is not None:
            if not isinstance(tips, dict):
                raise ValueError(f"{self.name}: tip_positions must be a dict {{agent: (num_envs, 3) metres}}")
            self.core.place_tips(worlds, {agent: self._rows(value, worlds, f"tip_positions[{agent!r}]")
                                          for agent, value in tips.items()})
        self._reset_surgeon(None if mask is None else worlds)
        self._restart_potential()
        self._started = True
        info = self.core.info()
        return self.observations(), {agent: dict(info) for agent in self.agents}

    def _start_episodes(self, worlds: np.ndarray) -> None:
        """Automatic resets of ``worlds``, at their levels."""
        if np.any(self.levels[worlds] < start_levels.DEFAULT):
            self._start_at_levels(worlds)
        else:
            self._reset_at_default(worlds)
        self._reset_surgeon(worlds)
        self._restart_potential()

    def _reset_surgeon(self, worlds) -> None:
        """The seat's filler starts its episode again: in every world (``worlds`` None), or in those worlds only
        where it can (a ``reset(worlds)``, as the person-like partners have: state kept world by world)."""
        reset = getattr(self._surgeon, "reset", None)
        if reset is None:
            return
        if worlds is None:
            reset()
        elif self._surgeon_resets_worlds:
            reset(worlds)

    def _reset_at_default(self, worlds: np.ndarray, blood_ml=None) -> None:
        """The default task in ``worlds``: the blood of ``blood_ml``, else each world's own (the task's where an
        easier level's draw had set it)."""
        drawn = worlds[self._level_blood[worlds]]
        if blood_ml is None and len(drawn):
            self.core.set_blood(drawn, self.params.blood_ml)
        self._level_blood[worlds] = False
        self.core.reset(worlds, blood_ml=blood_ml)

    def set_start_level(self, level, worlds=None) -> None:
        """The start level (:mod:`dvrl_marl.envs.start_levels`) of the next episodes of ``worlds`` (default all; a
        mask or indices), automatic resets included: for a library's curriculum that cannot pass reset options."""
        worlds = self.core.worlds_of(worlds)
        self.levels[worlds] = self._checked_levels(level)[worlds]

    def _checked_levels(self, level) -> np.ndarray:
        """(N,) levels from one level or one per world."""
        if isinstance(level, (list, tuple, np.ndarray)):
            values = list(level)
            if len(values) != self.num_envs:
                raise ValueError(f"{self.name}: level needs one value or one per world ({self.num_envs}), "
                                 f"got {len(values)}")
            return np.array([start_levels.checked_level(v, f"{self.name}: level") for v in values])
        return np.full(self.num_envs, start_levels.checked_level(level, f"{self.name}: level"))

    def _seed_levels(self, seed) -> None:
        """World i's level stream: a single env's reset with seed + i (or the i-th of a list of seeds)."""
        seeds = [int(s) for s in seed] if hasattr(seed, "__iter__") and not isinstance(seed, (str, bytes)) else [
            int(seed) + i for i in range(self.num_envs)]
        self._level_rngs = [start_levels.level_generator(s) for s in seeds]

    def _start_at_levels(self, worlds: np.ndarray) -> None:
        """New episodes for ``worlds`` at their levels (easy starts: :mod:`dvrl_marl.envs.start_levels`)."""
        core, params = self.core, self.params
        draws = {}
        for world in worlds.tolist():
            if self.levels[world] < start_levels.DEFAULT:
                draws[world] = start_levels.draw(self._level_rngs[world], float(self.levels[world]), params.blood_ml,
                                                 params.debris_count)
        blood = np.tile(np.asarray(params.blood_ml, dtype=np.float64), (len(worlds), 1))
        for row, world in enumerate(worlds.tolist()):
            if world in draws:
                blood[row] = draws[world].blood_ml
        core.reset(worlds, blood_ml=blood)
        self._level_blood[worlds] = True
        easy = [world for world, drawn in draws.items() if drawn.easy]
        if not easy:
            return
        easy = np.array(easy)
        core.limit_debris(easy, np.array([draws[world].debris_count for world in easy.tolist()]))
        core.limit[easy] = min(params.max_cycles, self.template.easy_episode_steps or params.max_cycles)
        if self._rims is None:
            self._rims = OverRims(core.cavities)
        grasper = core.arms["grasper"]
        for world in easy.tolist():
            pending = core.visible[world] & ~core.delivered[world]
            target = start_levels.grasper_start(self._level_rngs[world], core.debris_position[world], pending,
                                                grasper.tip[world] + grasper.base_position, draws[world].reach,
                                                self._rims)
            if target is None:
                continue
            try:
                core.place_tips([world], {"grasper": target[None]})
            except ValueError:
                pass  # that start is not possible (unreachable, or into the other instrument): the ordinary one

    def _restart_potential(self) -> None:
        if self._guided is not None:
            self._potential = self._guided.potentials(self.core.state(), self.core.remaining_ml)

    def set_tip_positions(self, tips: dict, worlds=None) -> None:
        """Move tips at the start of an episode, keeping everything else of it (for curricula that start an arm
        near what the episode drew, e.g. a pin): ``tips`` is ``{agent: (N, 3)}`` metres, world frame; ``worlds``
        a mask or indices (default all). The same checks as the ``tip_positions`` reset option."""
        worlds = self.core.worlds_of(worlds)
        if not isinstance(tips, dict):
            raise ValueError(f"{self.name}: tip positions must be a dict {{agent: (num_envs, 3) metres}}")
        self.core.place_tips(worlds, {agent: self._rows(value, worlds, f"tip positions of {agent!r}")
                                      for agent, value in tips.items()})
        self._restart_potential()

    def _rows(self, value, worlds, name):
        value = np.asarray(value, dtype=np.float64)
        if value.ndim != 2 or value.shape[0] != self.num_envs:
            raise ValueError(f"{self.name}: {name} needs one row per world ({self.num_envs}), got shape {value.shape}")
        return value[worlds]

    def step(self, actions):
        core = self.core
        commands = core.read_commands(actions, self.possible_agents)
        if self._surgeon is not None:
            seat = self.surgeon_seat
            commands[seat] = check_action_batch(self._surgeon(core.observation(seat)), self.num_envs, 4,
                                                f"{self.name}: surgeon in seat {seat!r}")
        rewards, terminated, truncated = core.step(commands)
        if self._guided is not None:  # the guided terms' change over the step (potential-based)
            potential = self._guided.potentials(core.state(), core.remaining_ml)
            for agent in rewards:
                rewards[agent] = rewards[agent] + (potential[agent] - self._potential[agent])
            self._potential = potential
        observations = self.observations()
        info = core.info()
        infos = {agent: dict(info) for agent in self.agents}
        done = terminated | truncated
        if self.autoreset_mode == "same_step" and done.any():
            final_state = self.state()
            for agent in self.agents:
                infos[agent].update(final_observation=observations[agent], final_state=final_state, _final=done)
            self._start_episodes(np.flatnonzero(done))
            observations = self.observations()
        terminations = {agent: terminated.copy() for agent in self.agents}
        truncations = {agent: truncated.copy() for agent in self.agents}
        return observations, rewards, terminations, truncations, infos

    def observations(self) -> dict:
        """The current observations of every world, ``{agent: (N, obs_dim)}`` (after ``set_tip_positions``, or
        several masked resets in a row)."""
        observations = {agent: self.core.observation(agent) for agent in self.agents}
        if self.feature_spec is not None:
            observations = {agent: features.apply(self.feature_spec, value) for agent, value in observations.items()}
        if self.observation_scaling is not None:
            observations = {agent: self.observation_scaling.observation(agent, value)
                            for agent, value in observations.items()}
        return observations


    def state(self) -> np.ndarray:
        """(N, state_dim): the global state of every world, for centralised critics (with ``state_observations``,
        every arm's observation after it, as the single env's)."""
        state = self.core.state()
        if self.template.state_observations:
            observations = [self.core.observation(agent) for agent in AGENTS]
            if self.feature_spec is not None:
                observations = [features.apply(self.feature_spec, observation) for observation in observations]
            state = np.concatenate([state, *observations], axis=1)
        return state if self.observation_scaling is None else self.observation_scaling.state(state)

    def render(self, world: int | None = None):
        """World ``world`` (default :attr:`render_world`) from the endoscope, through the single env's scene."""
        world = self.render_world if world is None else int(world)
        if not 0 <= world < self.num_envs:
            raise ValueError(f"{self.name}: world must be in [0, {self.num_envs}), got {world}")
        self.template.set_state(**self.core.world_state(world))
        return self.template.render()

    def close(self) -> None:
        self.template.close()


def takes_worlds(reset) -> bool:
    """Whether a filler's ``reset`` can restart some worlds of a batch only (``reset(worlds)``)."""
    import inspect

    try:
        return reset is not None and "worlds" in inspect.signature(reset).parameters
    except (TypeError, ValueError):
        return False


def batched_env(num_envs: int = 1, **kwargs) -> SuctionDebrisBatchedEnv:
    """N worlds stepped as arrays; the keyword arguments of ``parallel_env``, plus ``num_envs``, ``autoreset_mode``
    and ``render_world``."""
    return SuctionDebrisBatchedEnv(num_envs, **kwargs)
