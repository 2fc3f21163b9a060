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
are never reset for you; ``reset(options={"reset_mask": mask})`` resets some; a world whose episode ended keeps its
last images until it is reset (it is not drawn again: an evaluation's finished worlds cost nothing while the others
play on). Agents never leave ``agents``.

## Start-state options (for curricula)
Besides ``blood_ml`` ((C,) or one row per world), ``reset(options=...)`` takes ``debris_count`` (an int or
``(N,)`` ints: only the first k debris are in play, the others start delivered) and ``tip_positions``
(``{agent: (N, 3)}`` metres in the world frame: each tip must be inside the workspace box, above the surface,
reachable, and leave the instruments apart). Rows of worlds that are not reset are ignored.
``set_tip_positions(tips, worlds)`` moves tips of episodes just drawn (to start near what the draw placed). The
default task is what you get without them.

``level`` (one level, ``"easy"`` / ``"default"``, or one per world) sets the start level of those worlds' episodes,
this one and the later ones, automatic resets included (:mod:`dvrl_marl.suction_debris.start_levels`; ``set_start_level``
does the same between resets); below 1 it draws blood, debris and starts itself, so it is refused together with
the three options above. World ``i``'s level draws are those of a single env reset with ``seed + i``.

## The surgeon seat
``surgeon="scripted"`` runs the batched scripted expert in every world; a callable gets the seat's observations
``(N, obs_dim)`` and returns ``(N, 4)``. Teleoperation devices drive one world: use ``parallel_env`` for them.

## Seeding
``reset(seed=s)`` gives world ``i`` the seed ``s + i``: it starts the episodes ``parallel_env().reset(seed=s + i)``
starts, episode after episode. A reset's draws are counter-based (:mod:`dvrl_marl.core.streams`): a function of
the world's seed, its episode count and the quantity drawn, so a world is the same world in a batch of any size,
whatever the other worlds do, and on every array library.

## Rendering
``render()`` draws world ``render_world`` (default 0; ``render(world=i)`` any other) through the single
environment's MuJoCo scene.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from gymnasium import spaces

from dvrl_marl import assets
from dvrl_marl.core.backend import namespace, needed, put, rows_of, take
from dvrl_marl.core.worlds import check_action_batch
from dvrl_marl.envs.scene_keywords import form_signature
from dvrl_marl.suction_debris import layout, features, start_levels
from dvrl_marl.suction_debris.appearance import APPEARANCES, Appearance
from dvrl_marl.suction_debris.guidance import GuidedReward, OverRims
from dvrl_marl.suction_debris.observation_scaling import ObservationScaling
from dvrl_marl.suction_debris.rules import AGENTS, OBSERVATION_BOUND, CollaborativeCore
from dvrl_marl.suction_debris.scene_options import REWARD_TYPES, SceneOptions
from dvrl_marl.suction_debris.scene_state import EnvState, SceneState, check_state
from dvrl_marl.suction_debris.task import TASK, env_name

__all__ = ["SuctionDebrisBatchedEnv", "AUTORESET_MODES", "REWARD_TYPES", "IMAGE_PARTS", "SceneLayout", "batched_env",
           "takes_worlds"]

AUTORESET_MODES = ("same_step", "disabled")
#: What ``images()`` draws of a view: the endoscope's (left eye's) colour image, the right eye's, the left eye's depth
#: and segmentation mask, and the right eye's segmentation (on request only: no observation carries it).
IMAGE_PARTS = ("image", "image_right", "depth", "segmentation", "segmentation_right")


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
    irrigates: bool = False  # the suction's valve irrigates on a negative command (irrigation_ml_s > 0)
    fluids: bool = False  # observations end with the fluids' slots (irrigation or clots: suction_debris.layout.FLUID_FIELDS)


class SuctionDebrisBatchedEnv:
    """N worlds of suction_debris_v8 (see the module documentation)."""

    metadata = {"name": TASK, "render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(self, num_envs: int = 1, surgeon=None, surgeon_seat: str = "grasper", render_mode: str | None = None,
                 max_cycles: int | None = None, autoreset_mode: str = "same_step", render_world: int = 0,
                 task: str = TASK, width: int = 640, height: int = 480, preset: str = "default", **options):
        from dvrl_marl.schemas import PositiveInt, validated

        if not isinstance(task, (str, Path)):
            raise ValueError(f"{TASK}: task must be a task file's name or path, got {task!r}")
        #: The environment's name (its version), as its messages say it.
        self.name = env_name(Path(task).stem)
        self.metadata = {**self.metadata, "name": self.name}
        num_envs = validated(PositiveInt, num_envs, f"{self.name}: num_envs")
        #: every option by concern (the rules, the observation, the images, the learning aids), checked once
        #: (:mod:`dvrl_marl.suction_debris.scene_options`), from ``preset`` and the keywords over it
        self.options = SceneOptions.of(self.name, preset=preset, task=task, max_cycles=max_cycles, **options)
        self.preset = self.options.preset
        observation, images, learning = self.options.observation, self.options.images, self.options.learning
        reward_type = learning.reward_type
        if autoreset_mode not in AUTORESET_MODES:
            raise ValueError(f"{self.name}: autoreset_mode must be one of {AUTORESET_MODES}, got {autoreset_mode!r}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"{self.name}: the batched env renders 'rgb_array' only, got {render_mode!r}")
        if surgeon_seat not in AGENTS:
            raise ValueError(f"{self.name}: surgeon_seat must be one of {AGENTS}, got {surgeon_seat!r}")
        if hasattr(surgeon, "action") and callable(surgeon.action):
            raise ValueError(f"{self.name}: a teleop device drives one world; use parallel_env(surgeon=device)")
        self.params = p = self.options.rules
        self.reward_type = reward_type
        self.surgeon_seat = surgeon_seat if surgeon is not None else None
        self.possible_agents = [agent for agent in AGENTS if agent != self.surgeon_seat]
        self.agents = list(self.possible_agents)
        self.core = CollaborativeCore(p, num_envs, reward_type=reward_type, rewarded_agents=self.possible_agents,
                                      name=self.name)
        self.core.set_blood(np.arange(num_envs), p.blood_ml)  # (each volume within its cavity's capacity)
        self.phantom, self.handoff = self.core.phantom, tuple(self.core.handoff.tolist())
        self.workspace_centre = self.core.centre.copy()
        self.workspace_range = float(p.workspace_range)
        self._check_scene_fits()
        self.num_envs = self.core.num_worlds
        self.autoreset_mode = autoreset_mode
        self.render_mode = render_mode
        if not isinstance(render_world, (int, np.integer)) or not 0 <= int(render_world) < self.num_envs:
            raise ValueError(f"{self.name}: render_world must be in [0, {self.num_envs}), got {render_world!r}")
        self.render_world = int(render_world)
        self._render_size = tuple(validated(PositiveInt, value, f"{self.name}: render {name}")
                                  for name, value in (("width", width), ("height", height)))
        self._mirror = None  # the MuJoCo scene that shows a world (made on the first render)
        self._spaces(observation.observation_features, observation.state_observations,
                     observation.normalize_observations)
        self._image_spaces(images.image_size, images.image_depth, images.image_segmentation, images.image_stereo)
        #: GL contexts that draw the images, each in a thread of its own (more pay on a GPU; endoscope_renderer)
        self.image_contexts = images.image_contexts
        #: the range each world's look is drawn from per episode (None: the scene's own look)
        self.image_appearance = images.image_appearance
        # Options that help learning: start levels, the guided reward.
        self.start_level = learning.level
        #: an easy episode's time limit (None: the task's max_cycles)
        self.easy_episode_steps = learning.easy_steps
        #: the guided reward's settings (:class:`dvrl_marl.suction_debris.guidance.Guidance`; None unless reward_type="guided")
        self.guidance = learning.guidance_settings(self.name)
        self._surgeon = self._bind_surgeon(surgeon, surgeon_seat)
        self._surgeon_resets_worlds = takes_worlds(getattr(self._surgeon, "reset", None))
        self.levels = np.full(self.num_envs, self.start_level)  # each world's start level
        self._rims = None  # the way around the rims, for easy starts that recede (built on first use)
        self._level_blood = np.zeros(self.num_envs, dtype=bool)  # worlds whose blood a level's draw set
        self._guided = GuidedReward(self, self.possible_agents, self.guidance) if self.guidance is not None else None
        self._potential = None

    def _spaces(self, observation_features: str, state_observations: bool, normalize: bool) -> None:
        """Observation, action and state spaces and their layouts, with the observation options."""
        p, c = self.params, self.core.cavities.count
        d = p.debris_count
        fluids = self.core.fluids
        self.observation_layout = layout.observation_layout(c, d, fluids)
        #: Slices of ``state()``: both tips and tools, blood, every debris (hidden ones too), hand-off point (and
        #: with irrigation or clots, the fluids).
        self.state_layout = layout.state_layout(c, d, fluids)
        obs_dim, state_dim = layout.plain_width(self.observation_layout), layout.plain_width(self.state_layout)
        observation_space = spaces.Box(-OBSERVATION_BOUND, OBSERVATION_BOUND, shape=(obs_dim,), dtype=np.float64)
        if not isinstance(observation_features, str):
            raise ValueError(f"{self.name}: observation_features must be a feature set's name or '', "
                             f"got {observation_features!r}")
        self.feature_spec = None
        self._last_features = None  # (the plain observations, their features), reused row by row
        if observation_features:
            try:
                self.feature_spec = features.spec(observation_features, self.layout(), d)
            except ValueError as error:
                raise ValueError(f"{self.name}: observation_features: {error}") from None
            # appended after the plain observation (differences of positions: twice the bound)
            count = features.feature_count(observation_features)
            self.observation_layout["features"] = slice(obs_dim, obs_dim + count)
            low = np.concatenate([np.full(obs_dim, -OBSERVATION_BOUND), np.full(count, -2 * OBSERVATION_BOUND)])
            observation_space = spaces.Box(low, -low, dtype=np.float64)
        self._observation_spaces = {agent: observation_space for agent in AGENTS}
        self._action_spaces = {agent: spaces.Box(-1.0, 1.0, shape=(layout.ACTION_WIDTH,), dtype=np.float32)
                               for agent in AGENTS}
        self.state_space = spaces.Box(-OBSERVATION_BOUND, OBSERVATION_BOUND, shape=(state_dim,), dtype=np.float64)
        #: ``state()`` followed by every arm's observation, features included (the option; see the module's docs)
        self.state_observations = state_observations
        if state_observations:
            width = observation_space.shape[0]
            for index, agent in enumerate(AGENTS):
                self.state_layout[f"{agent}_observation"] = slice(state_dim + index * width,
                                                                  state_dim + (index + 1) * width)
            low = np.concatenate([self.state_space.low, *([observation_space.low] * len(AGENTS))])
            self.state_space = spaces.Box(low, -low, dtype=np.float64)
        #: ``normalize_observations``: every agent's observation and the state mapped by fixed, measured centres and
        #: spreads (:mod:`dvrl_marl.suction_debris.observation_scaling`); None without the option. The seat's observation stays
        #: plain (a scripted surgeon and an exported policy read the scene's units).
        self.observation_scaling = None
        if normalize and fluids:
            raise ValueError(f"{self.name}: normalize_observations' centres and spreads were measured on scenes without "
                             "fluids; this one has irrigation or clots (irrigation_ml_s, clot_share, clotting_ml_s), "
                             "whose observation slots were never measured: leave normalize_observations off")
        if normalize:
            scaling = ObservationScaling.for_env(self.name, observation_features, AGENTS, observation_space.shape[0],
                                                 state_dim, state_observations)
            self._observation_spaces = {
                agent: spaces.Box(*scaling.observation_bounds(agent, observation_space.low, observation_space.high),
                                  dtype=np.float64) for agent in AGENTS}
            self.state_space = spaces.Box(*scaling.state_bounds(self.state_space.low, self.state_space.high),
                                          dtype=np.float64)
            self.observation_scaling = scaling

    def _image_spaces(self, size, depth: bool, segmentation: bool, stereo: bool) -> None:
        """``image_size``: every agent's observation becomes ``{"observation": the observation above, "image": the
        endoscope's view (S, S, 3) uint8}`` (and ``"image_right"``, the stereo pair's right eye, (S, S, 3) uint8, with
        ``image_stereo``; ``"depth"``, (S, S) float32 metres, with ``image_depth``; ``"segmentation"``, (S, S) uint8
        indices of :data:`~dvrl_marl.envs.endoscope.SEGMENT_CLASSES`, with ``image_segmentation``: both of the left
        eye's view), drawn by :func:`dvrl_marl.envs.endoscope.endoscope_renderer` (the first time an observation is
        made)."""
        from dvrl_marl.envs.endoscope import SEGMENT_CLASSES

        #: the image observations' size (0: none) and whether they carry the right eye, depth and a segmentation mask
        self.image_size, self.image_depth, self.image_segmentation = size, depth, segmentation
        self.image_stereo = stereo
        self._endoscope = self._right_eye = None
        # autoreset_mode="disabled": the worlds whose episode ended (not drawn again until reset) and each part's
        # last images, which an ended world keeps
        self._ended = np.zeros(self.num_envs, dtype=bool)
        self._last_images: dict = {}
        # and what an ended world is drawn from (its state and clock when it ended: any part asked later is drawn as
        # it was then, though the world's arms may have gone on moving), rows of ended worlds valid
        self._end_states = None
        if not size:
            return
        parts = {"image": spaces.Box(0, 255, shape=(size, size, 3), dtype=np.uint8)}
        if stereo:
            parts["image_right"] = spaces.Box(0, 255, shape=(size, size, 3), dtype=np.uint8)
        if depth:
            parts["depth"] = spaces.Box(0.0, np.inf, shape=(size, size), dtype=np.float32)
        if segmentation:
            parts["segmentation"] = spaces.Box(0, len(SEGMENT_CLASSES) - 1, shape=(size, size), dtype=np.uint8)
        self._observation_spaces = {agent: spaces.Dict({"observation": space, **parts})
                                    for agent, space in self._observation_spaces.items()}

    def images(self, parts=None) -> dict:
        """The endoscope's view of every world now: ``{"image": (N, S, S, 3) uint8[, "image_right", "depth",
        "segmentation"]}``. ``parts`` draws only those of :data:`IMAGE_PARTS` (default: what the observations carry),
        whether or not the observations carry them: a dataset may take the segmentation on the steps it records
        alone, at the cost of one drawing of what moves each time."""
        if not self.image_size:
            raise ValueError(f"{self.name}: images need image_size (made with image_size=84, say)")
        if parts is None:
            named = ("image", *(part for part, on in (("image_right", self.image_stereo), ("depth", self.image_depth),
                                                      ("segmentation", self.image_segmentation)) if on))
        else:
            try:
                named = (parts,) if isinstance(parts, str) else tuple(parts)
            except TypeError:  # (a number, say)
                named = None
            if not named or any(not isinstance(part, str) or part not in IMAGE_PARTS for part in named):
                raise ValueError(f"{self.name}: images' parts must be some of {list(IMAGE_PARTS)} (a name or a list "
                                 f"of them), got {parts!r}")
            named = tuple(part for part in IMAGE_PARTS if part in named)
        # an ended episode's world keeps its last images (autoreset_mode="disabled": nothing is drawn for it until it
        # is reset; an evaluation's worlds that finished early cost nothing while the others play on)
        kept = self._ended.any() and all(part in self._last_images for part in named)
        worlds = np.flatnonzero(~self._ended) if kept else np.arange(self.num_envs)
        drawn = self._draw(worlds, named) if len(worlds) else {}
        if self.autoreset_mode == "disabled":
            for part in named:
                if kept:
                    if len(worlds):
                        self._last_images[part][worlds] = drawn[part]
                else:
                    self._last_images[part] = drawn[part]
            drawn = {part: self._last_images[part].copy() for part in named}
        return drawn

    def _draw(self, worlds: np.ndarray, named: tuple) -> dict:
        """The endoscope's view of ``worlds`` (indices of the batch), ``{part: (len(worlds), ...)}`` for the
        :data:`IMAGE_PARTS` ``named``: the left eye's parts drawn by one renderer, the right eye's by another."""
        from dvrl_marl.envs.endoscope import STEREO_BASELINE_MM, endoscope_renderer

        states, elapsed = self._drawn_states(worlds)
        looks = self._looks(worlds, elapsed)
        drawn = {}
        left = [{"image": "rgb"}.get(part, part) for part in named if not part.endswith("_right")]
        if left:
            if self._endoscope is None:
                self._endoscope = endoscope_renderer(self.params, self.image_size, depth=self.image_depth,
                                                     segmentation=self.image_segmentation,
                                                     contexts=self.image_contexts)
            images = self._endoscope.render(states, *looks, parts=left, worlds=worlds)
            drawn.update({"image" if part == "rgb" else part: value for part, value in images.items()})
        right = [{"image_right": "rgb", "segmentation_right": "segmentation"}[part] for part in named
                 if part.endswith("_right")]
        if right:
            if self._right_eye is None:
                self._right_eye = endoscope_renderer(self.params, self.image_size, contexts=self.image_contexts,
                                                     eye_mm=STEREO_BASELINE_MM)
            images = self._right_eye.render(states, *looks, parts=right, worlds=worlds)
            drawn.update({("image" if part == "rgb" else part) + "_right": value for part, value in images.items()})
        return drawn

    def _keep_end_states(self, worlds: np.ndarray) -> None:
        """Keep what ``worlds``, whose episodes just ended, are drawn from (:meth:`_drawn_states`)."""
        ended = {"state": self.core.world_states(worlds), "elapsed": np.asarray(self.core.elapsed)[worlds]}
        if self._end_states is None:
            self._end_states = _rows_like(ended, self.num_envs)
        _write_rows(self._end_states, worlds, ended)

    def _drawn_states(self, worlds: np.ndarray):
        """What the renderers draw ``worlds`` from: each one's state and clock now, or, where its episode has ended
        (autoreset_mode="disabled"), as they were when it ended."""
        states, elapsed = self.core.world_states(worlds), np.asarray(self.core.elapsed)[worlds]
        ended = self._ended[worlds] if self._end_states is not None else np.zeros(len(worlds), dtype=bool)
        if ended.any():
            kept = _take_rows(self._end_states, np.asarray(worlds)[ended])
            _write_rows(states, np.flatnonzero(ended), kept["state"])  # (world_states' rows are copies already)
            elapsed = elapsed.copy()
            elapsed[ended] = kept["elapsed"]
        return states, elapsed

    def _looks(self, worlds: np.ndarray, elapsed=None) -> tuple:
        """``(looks, keys, frames)`` of ``worlds`` for the renderers (all None: the scene's own look)."""
        if self.image_appearance is None:
            return None, None, None
        # each world's look for its episode, from its own stream (a function of its seed and episode)
        from dvrl_marl.core.streams import STREAMS, uniforms

        streams = self.core.random
        episode = np.maximum(np.asarray(streams.episode)[worlds] - 1, 0)  # (the episode under way)
        draws = uniforms(np.asarray(streams.key_low)[worlds], np.asarray(streams.key_high)[worlds], episode,
                         STREAMS["appearance"], Appearance.UNIFORMS)
        appearance = (self.image_appearance if isinstance(self.image_appearance, Appearance)
                      else APPEARANCES[self.image_appearance])
        keys = list(zip(np.asarray(streams.key_low)[worlds].tolist(), np.asarray(streams.key_high)[worlds].tolist(),
                        episode.tolist()))
        return ([appearance.draw(row) for row in np.asarray(draws)], keys,
                np.asarray(self.core.elapsed)[worlds] if elapsed is None else elapsed)

    def _check_scene_fits(self) -> None:
        """Every position an observation holds (tips in the workspace box, pins in the cavities, the hand-off point)
        must normalise inside the observation space's bound: a tiny workspace_range would put them outside it."""
        p = self.params
        points = [self.handoff] + [(c.centre_x + dx, c.centre_y + dy, c.floor_z) for c in self.phantom.cavities
                                   for dx, dy in ((-c.mouth_radius, 0.0), (c.mouth_radius, 0.0),
                                                  (0.0, -c.mouth_radius), (0.0, c.mouth_radius))]
        farthest = max(abs(v - c) for point in points for v, c in zip(point, p.workspace_centre)) / p.workspace_range
        if farthest > OBSERVATION_BOUND:
            raise ValueError(f"{self.name}: workspace_range {p.workspace_range!r} (m) with workspace_centre "
                             f"{p.workspace_centre!r} puts the scene's cavities or hand-off point {farthest:.3g} "
                             f"ranges from the centre, outside the observation space's bound of "
                             f"{OBSERVATION_BOUND:g}; the scene needs workspace_range >= "
                             f"{farthest * p.workspace_range / OBSERVATION_BOUND:.3g} m")

    def _bind_surgeon(self, surgeon, seat):
        if surgeon is None:
            return None
        if isinstance(surgeon, str):
            if surgeon != "scripted":
                raise ValueError(f"{self.name}: surgeon must be None, 'scripted' or a callable, got {surgeon!r}")
            from dvrl_marl.suction_debris.scripted_team import ScriptedSuction, ScriptedSurgeon

            return (ScriptedSurgeon if seat == "grasper" else ScriptedSuction).for_env(self)
        if callable(surgeon):
            return surgeon
        raise ValueError(f"{self.name}: surgeon {surgeon!r} is not callable")

    # --- spaces and facts ---------------------------------------------------------------------------------
    def observation_space(self, agent):
        try:
            return self._observation_spaces[agent]
        except (KeyError, TypeError):
            raise ValueError(f"{self.name}: unknown agent {agent!r}; agents are {list(AGENTS)}") from None

    def action_space(self, agent):
        try:
            return self._action_spaces[agent]
        except (KeyError, TypeError):
            raise ValueError(f"{self.name}: unknown agent {agent!r}; agents are {list(AGENTS)}") from None

    def normalise(self, position_world) -> np.ndarray:
        """x~ = (x - p_c) / rho for world positions (..., 3)."""
        return self.core.normalise(np.asarray(position_world, dtype=np.float64))

    def layout(self) -> SceneLayout:
        """The scene's fixed facts in normalised coordinates (for scripted agents and pipelines)."""
        k = 1.0 / self.workspace_range
        cavities = self.phantom.cavities
        norm = self.normalise
        return SceneLayout(
            cavity_centres=tuple(tuple(norm((c.centre_x, c.centre_y, 0.0))[:2].tolist()) for c in cavities),
            cavity_mouth_radius=assets.CAVITY_MOUTH_RADIUS * k,
            cavity_floor=tuple(float(norm((0.0, 0.0, c.floor_z))[2]) for c in cavities),
            phantom_top=float(norm((0.0, 0.0, self.phantom.top_z))[2]),
            blood_threshold_fraction=tuple(
                self.params.blood_threshold_ml / v if v > 0 else 0.0 for v in self.params.blood_ml
            ),
            handoff=tuple(norm(self.handoff).tolist()),
            base_positions={a: tuple(norm(self.core.arms[a].base_position).tolist()) for a in AGENTS},
            gain=self.workspace_range / self.params.step_size,
            clearance=self.params.tip_clearance * k,
            irrigates=self.params.irrigation_ml_s > 0.0,
            fluids=self.params.fluids,
        )

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
        if tips is not None and not isinstance(tips, dict):
            raise ValueError(f"{self.name}: tip_positions must be a dict {{agent: (num_envs, 3) metres}}, got "
                             f"{type(tips).__name__}")
        # A start option is checked against the episode it starts (a tip must clear the other, reset, instrument):
        # one refused after the worlds were reset puts them back as they were.
        before = ((self.core.snapshot(), self.levels.copy())
                  if blood_ml is not None or debris_count is not None or tips is not None else None)
        try:
            if seed is not None:
                self.core.random.seed(seed)  # (validates the seed before anything is drawn)
            self.levels = levels
            if np.any(self.levels[worlds] < start_levels.DEFAULT):
                self._start_at_levels(worlds)
            else:
                self._reset_at_default(worlds, blood_ml)
            if debris_count is not None:
                count = np.asarray(debris_count)
                if count.ndim > 1 or (count.ndim == 1 and len(count) != self.num_envs):
                    raise ValueError(f"{self.name}: debris_count is one count, or one per world ({self.num_envs}), "
                                     f"got {debris_count!r}")
                self.core.limit_debris(worlds, count[worlds] if count.ndim == 1 else count)
            if tips is not None:
                self.core.place_tips(worlds, {agent: self._rows(value, worlds, f"tip_positions[{agent!r}]")
                                              for agent, value in tips.items()})
        except (ValueError, TypeError) as error:
            if before is not None:
                self.core.restore(before[0])
                self.levels = before[1]
            if isinstance(error, TypeError):  # (a value numpy cannot read as numbers)
                raise ValueError(f"{self.name}: reset options: {error}") from None
            raise
        self._reset_surgeon(None if mask is None else worlds)
        self._restart_potential()
        self._started = True
        self._ended[worlds] = False
        info = self.core.info()
        return self.observations(), {agent: dict(info) for agent in self.agents}

    def _start_episodes(self, worlds: np.ndarray) -> None:
        """Automatic resets of ``worlds``, at their levels."""
        if np.any(self.levels[worlds] < start_levels.DEFAULT):
            self._start_at_levels(worlds)
        else:
            self._reset_at_default(worlds)
        self._reset_surgeon(worlds)
        self._restart_potential(worlds)

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
        """The start level (:mod:`dvrl_marl.suction_debris.start_levels`) of the next episodes of ``worlds`` (default all; a
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

    def _start_at_levels(self, worlds: np.ndarray) -> None:
        """New episodes for ``worlds`` at their levels (easy starts: :mod:`dvrl_marl.suction_debris.start_levels`)."""
        mask = np.zeros(self.num_envs, dtype=bool)
        mask[worlds] = True
        self.start_at_levels(mask, self.levels)
        self._level_blood[worlds] = True

    def start_at_levels(self, mask, levels) -> None:
        """New episodes in the worlds of ``mask`` (N,) at ``levels`` (N,): written once for every array library (numpy
        draws for those worlds only; under ``jax.jit`` every world draws and the others keep their state)."""
        core, params = self.core, self.params
        xp = namespace(mask, core.remaining_ml)
        rows = rows_of(mask)
        drawn = start_levels.draw(core.random, rows, xp.minimum(take(levels, rows), start_levels.DEFAULT),
                                  params.blood_ml, params.debris_count)
        grasper_draws = start_levels.grasper_uniforms(core.random, rows)  # (this episode's: before the reset)
        core.initial_ml = put(core.initial_ml, rows, mask, drawn.blood_ml)
        core.start_episodes(mask)
        no = xp.zeros(mask.shape, dtype=xp.bool)
        easy = put(no, rows, mask, drawn.easy)
        if not needed(easy):
            return
        core.keep_debris(easy, put(xp.full(mask.shape, params.debris_count), rows, mask, drawn.debris_count))
        core.limit = xp.where(easy, min(params.max_cycles, self.easy_episode_steps or params.max_cycles), core.limit)
        if self._rims is None:
            self._rims = OverRims(core.cavities)
        grasper = core.arms["grasper"]
        pending = take(core.visible & ~core.delivered, rows)
        targets, has = start_levels.grasper_starts(grasper_draws, take(core.debris_position, rows), pending,
                                                   take(grasper.tip_world(), rows), drawn.reach, self._rims)
        core.try_grasper_starts(easy & put(no, rows, mask, has), put(xp.zeros((mask.shape[0], 3)), rows, mask,
                                                                    targets))

    def restore(self, state: SceneState) -> None:
        """Put every world back in a state :meth:`CollaborativeCore.snapshot` took (the guided terms restart there)."""
        self.core.restore(state)
        self._last_features = None
        self._restart_potential()

    @property
    def world_state(self) -> EnvState:
        """The worlds' state as one record (copies): the scene's :class:`~dvrl_marl.suction_debris.scene_state.SceneState`, each
        world's start level and the guided reward's potentials; the device env's ``world_state`` is the same record
        of JAX arrays. Setting it puts every world there (checked first: a wrong field is named and nothing
        changes); a seat's filler keeps its own state."""
        potential = {} if self._guided is None or self._potential is None else \
            {agent: value.copy() for agent, value in self._potential.items()}
        return EnvState(scene=self.core.get_state(), levels=self.levels.copy(), potential=potential)

    @world_state.setter
    def world_state(self, state: EnvState) -> None:
        self.check_state(state)
        self.core.set_state(state.scene)
        self.levels = np.array(state.levels, dtype=np.float64)
        self._last_features = None
        if self._guided is not None:
            self._potential = {agent: np.array(value, dtype=np.float64) for agent, value in state.potential.items()}

    def check_state(self, state, num_worlds="env") -> None:
        """``ValueError`` naming what of ``state`` is not an :class:`EnvState` of this env's worlds (``num_worlds``:
        the leading axis, None for one world's record); shapes and dtypes only, so it also runs at trace time (the
        device env and ``jax_env`` check their records with it)."""
        if not isinstance(state, EnvState):
            raise ValueError(f"{self.name}: world_state must be an EnvState record; the state must be the EnvState "
                             f"reset gave, got {type(state).__name__}")
        count = self.num_envs if num_worlds == "env" else num_worlds
        check_state(state.scene, self.core.world_shapes, count, self.name)
        want = () if count is None else (count,)
        if tuple(np.shape(state.levels)) != want:
            raise ValueError(f"{self.name}: state.levels must have shape {want}, got {tuple(np.shape(state.levels))}")
        agents = sorted(self.possible_agents) if self._guided is not None else []
        if sorted(state.potential) != agents:
            raise ValueError(f"{self.name}: state.potential must hold the guided reward's agents {agents}, got "
                             f"{sorted(state.potential)}")

    def guided_potentials(self) -> dict:
        """``{agent: (N,)}``: the guided reward's potentials in the worlds' present state (empty without it)."""
        return self._guided.potentials(self.core.state(), self.core.remaining_ml) if self._guided is not None else {}

    def _restart_potential(self, worlds=None) -> None:
        """The guided terms' potentials again, in every world or in ``worlds`` (indices) only: rows are independent,
        and an autoreset that restarts a few of many worlds leaves the others' as they were."""
        if self._guided is None:
            return
        if worlds is None or self._potential is None:
            self._potential = self._guided.potentials(self.core.state(), self.core.remaining_ml)
            return
        fresh = self._guided.potentials(self.core.state()[worlds], self.core.remaining_ml[worlds])
        potential = {agent: value.copy() for agent, value in self._potential.items()}
        for agent, value in fresh.items():
            potential[agent][worlds] = value
        self._potential = potential

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
        try:
            value = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"{self.name}: {name} must be numbers, one row per world ({self.num_envs}), got "
                             f"{value!r}") from None
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
        restart = self._restart_ended if self.autoreset_mode == "same_step" else None
        rewards, terminated, truncated, self._potential, ended = self.transition(commands, self._potential, restart)
        return self._outcome(rewards, terminated, truncated, ended)

    def _restart_ended(self, done) -> None:
        self._start_episodes(np.flatnonzero(done))

    def advance(self, commands: dict):
        """One step of the core with both arms' commands, already checked: ``{agent: (N, 4)}`` float64 in [-1, 1],
        a NaN tool value meaning "unchanged" (a held seat). Returns ``(rewards {agent: (N,)}, terminated (N,),
        truncated (N,))`` with the guided terms; nothing resets."""
        rewards, terminated, truncated, self._potential, _ = self.transition(commands, self._potential)
        return rewards, terminated, truncated

    def transition(self, commands: dict, potential, restart=None):
        """The env's step, written once for this env and the compiled one (:mod:`.suction_debris_device`, which
        traces it with the state loaded from its record): the core's step, the guided reward's change of potential
        from ``potential`` (``{agent: (N,)}``; ignored without the guided reward), and, given ``restart`` (a function
        of the mask of ended worlds that starts their next episodes), the same-step autoreset.

        Returns ``(rewards, terminated, truncated, potential after, ended)``; ``ended`` is None when no episode
        ended (or without ``restart``), else a dict of what the step ended on, taken before the restart: ``done``
        (the ended worlds), ``is_success``, ``final_observation``, ``final_state`` and ``info`` (the core's figures).
        numpy skips it all when no world ended; traced, every world restarts where the mask holds."""
        core = self.core
        rewards, terminated, truncated = core.step(commands)
        after = {}
        if self._guided is not None:  # the guided terms' change over the step (potential-based)
            after = self.guided_potentials()
            rewards = {agent: value + (after[agent] - potential[agent]) if agent in after else value
                       for agent, value in rewards.items()}
        done = terminated | truncated
        if restart is None or not needed(done):
            return rewards, terminated, truncated, after, None
        info = core.info()  # (its is_success: a copy of the ended episodes' completion)
        ended = {"done": done, "is_success": info["is_success"], "final_observation": self.observations(),
                 "final_state": self.state(), "info": info}
        restart(done)
        if after:
            xp = namespace(done)
            restarted = self.guided_potentials()
            after = {agent: xp.where(done, restarted[agent], value) for agent, value in after.items()}
        return rewards, terminated, truncated, after, ended

    def _outcome(self, rewards, terminated, truncated, ended=None):
        observations = self.observations()
        info = self.core.info() if ended is None else ended["info"]  # (the ended episodes' figures, not the new ones')
        infos = {agent: dict(info) for agent in self.agents}
        done = terminated | truncated
        if self.autoreset_mode == "disabled":
            if self.image_size and np.any(done & ~self._ended):
                self._keep_end_states(np.flatnonzero(done & ~self._ended))
            self._ended |= done
        if ended is not None:
            for agent in self.agents:
                infos[agent].update(final_observation=ended["final_observation"][agent],
                                    final_state=ended["final_state"], _final=done)
        terminations = {agent: terminated.copy() for agent in self.agents}
        truncations = {agent: truncated.copy() for agent in self.agents}
        return observations, rewards, terminations, truncations, infos

    def observations(self) -> dict:
        """The current observations of every world, ``{agent: (N, obs_dim)}`` (after ``set_tip_positions``, or
        several masked resets in a row)."""
        observations = self.core.observations(self.agents)
        if self.feature_spec is not None:
            observations = self._with_features(observations)
        if self.observation_scaling is not None:
            observations = {agent: self.observation_scaling.observation(agent, value)
                            for agent, value in observations.items()}
        if self.image_size:  # one endoscope: every agent sees the same view
            images = self.images()
            observations = {agent: {"observation": value, **images} for agent, value in observations.items()}
        return observations

    def _with_features(self, observations: dict) -> dict:
        """Every agent's observations with the feature set appended, computed for all agents in one call (rows are
        independent; one call instead of one per agent is what a small batch needs)."""
        values = list(observations.values())
        if len({value.shape for value in values}) > 1:
            return {agent: features.apply(self.feature_spec, value) for agent, value in observations.items()}
        xp = namespace(values[0])
        plain = xp.concatenate(values, axis=0)
        if xp is not np:
            together = features.apply(self.feature_spec, plain)
        else:  # rows seen last time keep their features: state() after step(), the worlds an autoreset left alone
            last = self._last_features
            changed = None if last is None or last[0].shape != plain.shape else (last[0] != plain).any(axis=1)
            if changed is None or changed.all():
                together = features.apply(self.feature_spec, plain)
            else:
                together = last[1].copy()
                if changed.any():
                    together[changed] = features.apply(self.feature_spec, plain[changed])
            self._last_features = (plain, together.copy())
        n = values[0].shape[0]
        return {agent: together[k * n:(k + 1) * n] for k, agent in enumerate(observations)}

    def state(self) -> np.ndarray:
        """(N, state_dim): the global state of every world, for centralised critics (with ``state_observations``,
        every arm's observation after it, as the single env's)."""
        state = self.core.state()
        if self.state_observations:
            observations = self.core.observations(AGENTS)
            if self.feature_spec is not None:
                observations = self._with_features(observations)
            observations = list(observations.values())
            state = namespace(state).concatenate([state, *observations], axis=1)
        return state if self.observation_scaling is None else self.observation_scaling.state(state)

    def render(self, world: int | None = None):
        """World ``world`` (default :attr:`render_world`) from the endoscope (None without a render mode)."""
        world = self.render_world if world is None else world
        if not isinstance(world, (int, np.integer)) or not 0 <= int(world) < self.num_envs:
            raise ValueError(f"{self.name}: world must be in [0, {self.num_envs}), got {world!r}")
        if self.render_mode is None:
            return None
        mirror = self.mirror()
        mirror.show(self.core.world_state(int(world)))
        return mirror.render()

    def mirror(self, **renderer_options):
        """The MuJoCo scene that shows a world (made on first use: stepping needs no MuJoCo)."""
        if self._mirror is None:
            from dvrl_marl.envs.scene_mirror import SceneMirror

            width, height = self._render_size
            self._mirror = SceneMirror(self.params, self.render_mode, width=width, height=height, **renderer_options)
        return self._mirror

    #: What draws (OpenGL contexts, their threads, a window): a copy or a pickle of the env carries none of them and
    #: makes its own when it first draws (a copy that shared them lost them when the original closed).
    _DRAWING = ("_endoscope", "_right_eye", "_mirror")

    def __getstate__(self):
        state = self.__dict__.copy()
        state.update(dict.fromkeys(self._DRAWING))
        return state

    def __copy__(self):
        copied = type(self).__new__(type(self))
        copied.__dict__.update(self.__getstate__())
        return copied

    def close(self) -> None:
        if self._mirror is not None:
            self._mirror.close()
        for renderer in (self._endoscope, self._right_eye):
            if renderer is not None:
                renderer.close()
        self._endoscope = self._right_eye = None


def _rows_like(tree, count: int):
    """Arrays of ``count`` rows shaped as ``tree``'s (a dict of dicts of arrays), zeros."""
    if isinstance(tree, dict):
        return {key: _rows_like(value, count) for key, value in tree.items()}
    return np.zeros((count,) + np.shape(tree)[1:], dtype=np.asarray(tree).dtype)


def _take_rows(tree, rows):
    """``tree``'s rows ``rows`` (copies)."""
    if isinstance(tree, dict):
        return {key: _take_rows(value, rows) for key, value in tree.items()}
    return np.asarray(tree)[rows]


def _write_rows(tree, rows, values) -> None:
    """``values``' rows written into ``tree``'s rows ``rows``, in place."""
    for key, value in values.items():
        if isinstance(value, dict):
            _write_rows(tree[key], rows, value)
        else:
            tree[key][rows] = value


def takes_worlds(reset) -> bool:
    """Whether a filler's ``reset`` can restart some worlds of a batch only (``reset(worlds)``)."""
    import inspect

    try:
        return reset is not None and "worlds" in inspect.signature(reset).parameters
    except (TypeError, ValueError):
        return False


def batched_env(num_envs: int = 1, **kwargs) -> SuctionDebrisBatchedEnv:
    """N worlds stepped as numpy arrays; the keyword arguments of ``parallel_env``, plus ``num_envs``,
    ``autoreset_mode`` and ``render_world``."""
    return SuctionDebrisBatchedEnv(num_envs, **kwargs)


batched_env.__signature__ = form_signature(batched_env, SuctionDebrisBatchedEnv.__init__)
