"""The collaborative scene's step, written once: N worlds as arrays (suction_debris_v8).

One step advances every world: eta moves of both arms (workspace box, the phantom's surface, joint limits,
instruments that may not pass through each other), suction and the blood level in each cavity, bleeding, debris
revealed, grasped by the paper's rule, carried, dropped and delivered, the team's reward, completion and truncation.
Every form of the scene (the parallel and AEC envs, one world; the batched env; the seat envs; the Gymnasium vector
envs) is a shell over this core, and one world is a batch of one. It is built from the task's parameters and the
scene file's geometry (:class:`~dvrl_marl.suction_debris.scene_geometry.SceneGeometry`) and imports no MuJoCo: a MuJoCo model
only mirrors a world to render it.

Memory: about 1.5 kB per world with 3 debris.
"""

from __future__ import annotations

import copy
import math

import numpy as np

from dvrl_marl import kinematics
from dvrl_marl.core import tools
from dvrl_marl.core.arms import ArmBatch
from dvrl_marl.core.backend import join, namespace, needed, put, rows_of, take
from dvrl_marl.core.streams import STREAMS, ResetStreams, uniforms
from dvrl_marl.core.worlds import check_action_batch, world_indices
from dvrl_marl.suction_debris import layout, scene_state, sliding
from dvrl_marl.suction_debris.instruments import SHAFT_RADIUS, WRIST_RADIUS, instrument_clearance, segment_distance
from dvrl_marl.suction_debris.lean_move import LeanMove
from dvrl_marl.suction_debris.phantom import Cavities
from dvrl_marl.suction_debris.scene_geometry import SceneGeometry
from dvrl_marl.suction_debris.scene_state import SceneState
from dvrl_marl.suction_debris.task import PIN_SLOTS, SuctionDebrisParams

__all__ = ["CollaborativeCore", "Cavities", "PIN_SLOTS", "AGENTS", "closest_on_segment", "distance", "TOOLS", "place_debris", "segment_distance",
           "SHAFT_RADIUS", "WRIST_RADIUS"]

AGENTS = ("suction", "grasper")
TOOLS = {"suction": kinematics.SUCTION_IRRIGATION, "grasper": kinematics.LND}
#: Instruments closer than this beyond touching also count as in contact (they touch after a refused move).
CONTACT_MARGIN = 5e-4
#: Every value of an observation and of the state lies within +/- this (positions are normalised by rho; a blood
#: fraction is capped at it).
OBSERVATION_BOUND = 10.0
#: Released pins fall at g (m/s^2) when the task's ``pins_fall`` is set (suction_debris_v8).
GRAVITY = 9.81
#: Pin geometry (spring pins: 3 mm x 28 mm; the slots they lie in: collaborative_task.PIN_SLOTS).
PIN_RADIUS = 0.0015
PIN_HALF_LENGTH = 0.0125  # capsule axis half length: 2 * (0.0125 + 0.0015) = 28 mm
#: The proximity sensor sees a pin whose axis passes within this distance of the jaw's control point.
PIN_SENSOR_RANGE = PIN_RADIUS + 0.0015
#: No pin whose centre lies farther from the jaws than this is within the sensor's range of its axis (the triangle
#: inequality, with room for rounding): a closing jaw without one takes nothing, and one world skips the grasp's work.
_CENTRE_IN_REACH = PIN_SENSOR_RANGE + PIN_HALF_LENGTH + 1e-9
#: suction_debris_v8: a pin released beyond the phantom lands this far inside its top's nearest edge (about a pin's
#: radius and a jaw's width: it lies wholly on the top, in the endoscope's view, where the grasper can take it again).
PHANTOM_EDGE_MARGIN = 0.005
#: A spill covers the phantom this far beyond its cavity's mouth (m): a pin's length, where a pin dropped by the
#: cavity lies (a chosen value: the spill's extent is not modelled).
SPILL_MARGIN = 0.028
#: The figures of a scene with fluids that ``info()`` adds (:meth:`CollaborativeCore.fluid_figures`).
FLUID_FIGURES = ("clot_remaining", "saline_used_ml", "saline_wasted_ml", "overflow_events", "overflow_s",
                 "overflow_ml")
#: Tip start positions (world) before the seeded jitter.
STARTS = {"suction": (-0.045, -0.015, 0.065), "grasper": (0.05, -0.012, 0.07)}
START_JITTER = 0.005


#: Where the core keeps each field of its state record (:class:`~dvrl_marl.suction_debris.scene_state.SceneState`) that is not
#: an attribute of its own name: an arm's, a per-agent dict's, the random streams'.
_ARM_FIELDS = {"suction_tip": ("suction", "tip"), "suction_q": ("suction", "q"), "grasper_tip": ("grasper", "tip"),
               "grasper_q": ("grasper", "q"), "jaw": ("grasper", "jaw")}
_PER_AGENT_FIELDS = {f"{agent}_{kind}": (kind, agent) for agent in AGENTS for kind in ("work_distance", "blocked")}
_STREAM_FIELDS = {"stream_key_low": "key_low", "stream_key_high": "key_high", "stream_episode": "episode"}


def _one_hot(index, count: int, xp):
    """(..., count) booleans: True at ``index``."""
    return index[..., None] == xp.arange(count)[None, :]


def place_debris(draw, cavities, count: int, xp=np):
    """Seeded pin placement for M worlds: ``count`` pins lying across the bowls, each in a slot of
    :data:`PIN_SLOTS` of a cavity drawn uniformly (the other when that one's slots are taken), turned by the cavity's
    yaw and a few degrees more. ``draw(stream, k)``: (M, k) uniforms of the worlds' streams
    (:mod:`dvrl_marl.core.streams`). Returns positions ``(M, count, 3)``, yaws and cavity indices ``(M, count)``."""
    c, s = cavities.count, len(PIN_SLOTS)
    keys = draw("pin_slots", c * s)
    m = keys.shape[0]
    slot_order = xp.reshape(xp.argsort(xp.reshape(keys, (m, c, s)), axis=2), (m, c * s))
    cavity_yaw = draw("pin_yaws", c) * math.pi
    chosen = xp.minimum(xp.astype(draw("pin_cavities", count) * c, xp.int64), c - 1)
    turns = -0.15 + 0.3 * draw("pin_turns", count)
    used = xp.zeros((m, c), dtype=xp.int64)
    slots = xp.asarray(np.asarray(PIN_SLOTS, dtype=np.float64))
    per_cavity = cavities.per_cavity
    # Lying across the bowl: its end caps touch the sphere, so its axis sits this far below the sphere's centre.
    radius = cavities.sphere_radius - PIN_RADIUS
    sphere_centre_z = cavities.floor_z + cavities.sphere_radius
    positions, yaws, indices = [], [], []
    for pin in range(count):
        cavity = chosen[:, pin]
        full = _pick(used, cavity, xp) >= s
        cavity = xp.where(full, xp.argmax(xp.astype(used < s, xp.int64), axis=1), cavity)
        taken = _pick(used, cavity, xp)
        offset = slots[_pick(slot_order, cavity * s + taken, xp)]
        used = used + xp.astype(_one_hot(cavity, c, xp), xp.int64)
        yaw = _pick(cavity_yaw, cavity, xp) + turns[:, pin]
        below_centre = xp.sqrt(per_cavity(radius, cavity) ** 2 - PIN_HALF_LENGTH**2 - offset**2)
        positions.append(xp.stack([per_cavity(cavities.centre_x, cavity) - offset * xp.sin(yaw),
                                   per_cavity(cavities.centre_y, cavity) + offset * xp.cos(yaw),
                                   per_cavity(sphere_centre_z, cavity) - below_centre], axis=1))
        yaws.append(yaw)
        indices.append(cavity)
    return xp.stack(positions, axis=1), xp.stack(yaws, axis=1), xp.stack(indices, axis=1)


def _dot(u, v):
    return u[..., 0] * v[..., 0] + u[..., 1] * v[..., 1] + u[..., 2] * v[..., 2]


def closest_on_segment(point, start, end):
    """The point of segment ``start``-``end`` nearest ``point``, batched over leading axes (..., 3)."""
    xp = namespace(point, start, end)
    d, v = end - start, point - start
    length2 = _dot(d, d)
    positive = length2 > 0
    t = xp.where(positive, xp.minimum(xp.maximum(_dot(v, d) / xp.where(positive, length2, 1.0), 0.0), 1.0), 0.0)
    return start + t[..., None] * d


def distance(u, v):
    """Euclidean distances between points ``u`` and ``v`` (..., 3)."""
    difference = u - v
    return namespace(difference).sqrt(_dot(difference, difference))


def _pick(values, index, xp):
    """``values[i, index[i]]`` for every row i (``values`` (N, K, ...), ``index`` (N,) in [0, K))."""
    if xp is np:
        return values[np.arange(len(index)), index]
    chosen = xp.arange(values.shape[1])[None, :] == index[:, None]
    chosen = xp.reshape(chosen, chosen.shape + (1,) * (values.ndim - 2))
    return xp.sum(xp.where(chosen, values, xp.zeros_like(values)), axis=1)  # (integers stay integers)


def _copy(x):
    return x.copy() if isinstance(x, np.ndarray) else x  # (other libraries' arrays are not changed in place here)


class CollaborativeCore:
    """N worlds of the collaborative scene, built from the task's parameters and the scene file's geometry.

    ``step(commands)`` takes ``{agent: (N, 4)}`` for both arms (already validated, clipped to [-1, 1]) and returns
    ``(rewards {agent: (N,)}, terminated (N,), truncated (N,))``; it never resets. ``reset(worlds)`` draws new
    episodes for some worlds from their own streams.
    """

    def __init__(self, params: SuctionDebrisParams, num_worlds: int, *, reward_type: str = "sparse",
                 rewarded_agents=AGENTS, geometry: SceneGeometry | None = None, name: str | None = None):
        if int(num_worlds) < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_worlds!r}")
        self.name = name or "suction_debris"
        self.num_worlds = n = int(num_worlds)
        p = self.params = params
        self.geometry = geometry = geometry or SceneGeometry.from_scene(p.scene)
        self.phantom = geometry.phantom
        self.sparse = reward_type == "sparse"
        self.move_rules = {agent: sliding.MoveRules.of(p.blocked_moves, agent) for agent in AGENTS}
        self.cavities = Cavities(geometry.phantom)
        c = self.cavities
        self._cavity_bottoms = np.stack([c.centre_x, c.centre_y, c.floor_z], axis=1)  # (C, 3): the suction's goals
        self.arms = {agent: ArmBatch(TOOLS[agent], n, geometry.base_positions[agent]) for agent in AGENTS}
        self.centre = np.asarray(p.workspace_centre, dtype=np.float64)
        self.inverse_range = 1.0 / p.workspace_range
        self.low = self.centre - p.workspace_range
        self.high = self.centre + p.workspace_range
        self.handoff = np.asarray(geometry.handoff, dtype=np.float64)
        self.handoff_normalised = self.normalise(self.handoff)
        self._handoff_block = np.broadcast_to(self.handoff_normalised[None, :], (n, 3))
        self.rewarded_agents = tuple(rewarded_agents)
        #: the cavities hold more than blood: clots or saline (a rule's state in play; off: the earlier fast paths)
        self.fluids = p.fluids
        self.work_distance = {agent: np.zeros(n) for agent in AGENTS}
        self.blocked = {agent: np.zeros(n, dtype=bool) for agent in AGENTS}  # its last move was refused
        self.random = ResetStreams(n)
        #: each field's shape in one world (scene_state.SPECS): what a record given to set_state must have
        self.world_shapes = scene_state.world_shapes(self.cavities.count, p.debris_count,
                                                     {agent: arm.tool.n_joints for agent, arm in self.arms.items()})
        for name, spec in scene_state.SPECS.items():  # every field, as an episode starts it (else zeros)
            if name not in _ARM_FIELDS and name not in _STREAM_FIELDS:
                fill = 0 if spec.start is None else spec.start
                self._set(name, np.full((n,) + self.world_shapes[name], fill, dtype=scene_state.dtype_of(name)))
        self.initial_ml = np.tile(np.asarray(p.blood_ml, dtype=np.float64), (n, 1))
        self.remaining_ml = self.initial_ml.copy()
        self.bleed_onset = np.full((n, self.cavities.count), np.inf)  # s; inf: no bleeding
        self.limit = np.full(n, p.max_cycles, dtype=np.int64)  # each episode's time limit (start levels shorten it)
        self._rows = np.arange(n)
        #: one numpy world (the parallel env): its moves' common case in Python floats, bit for bit the arrays'
        self._lean = LeanMove(self) if n == 1 and not any(arm.tool_point_drop for arm in self.arms.values()) else None

    # --- helpers ------------------------------------------------------------------------------------------
    def normalise(self, position) -> np.ndarray:
        return (position - self.centre) * self.inverse_range

    def worlds_of(self, worlds) -> np.ndarray:
        return world_indices(worlds, self.num_worlds, self.name)

    def _update_surfaces(self, worlds, cavity) -> None:
        surface = self.surface_z.copy()  # (a new array: a record the core was loaded from stays as it was)
        surface[worlds, cavity] = self.cavities.floor_z[cavity] + self.cavities.fill_depth(
            cavity, self._fluid_ml()[worlds, cavity])
        self.surface_z = surface

    def set_blood(self, worlds, blood_ml) -> None:
        """Set the initial blood (ml per cavity) of ``worlds`` for this and later episodes (a reset option)."""
        c = self.cavities.count
        try:
            volumes = np.asarray(blood_ml, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"{self.name}: blood_ml needs one volume (ml) per cavity ({c}), got {blood_ml!r}") from None
        if volumes.shape[-1:] != (c,) or volumes.ndim > 2:
            raise ValueError(f"{self.name}: blood_ml needs one volume per cavity ({c}), got {volumes.tolist()}")
        if not np.all(np.isfinite(volumes)) or np.any(volumes < 0.0) or np.any(volumes > self.cavities.capacity_ml):
            raise ValueError(f"{self.name}: blood volumes {volumes.tolist()} ml must lie in "
                             f"[0, {self.cavities.capacity_ml.tolist()}] ml (the cavities' capacity)")
        self.initial_ml[worlds] = volumes

    # --- reset --------------------------------------------------------------------------------------------
    def reset(self, worlds=None, *, seed=None, blood_ml=None) -> None:
        """Start new episodes in ``worlds`` (all by default; indices or a mask)."""
        if seed is not None:
            self.random.seed(seed)
        indices = self.worlds_of(worlds)
        if blood_ml is not None:
            self.set_blood(indices, blood_ml)
        if len(indices) == 0:
            return
        mask = np.zeros(self.num_worlds, dtype=bool)
        mask[indices] = True
        self.start_episodes(mask)

    def start_episodes(self, mask) -> None:
        """New episodes in the worlds where ``mask`` (N,) holds, drawn from their streams. Written once for every
        array library: numpy draws for those rows only; under ``jax.jit`` every row draws and the others keep theirs
        (the device's autoreset)."""
        xp = namespace(mask, self.remaining_ml)
        p, rows, n_agents = self.params, rows_of(mask), len(AGENTS)
        streams = self.random
        low, high, episode = take(streams.key_low, rows), take(streams.key_high, rows), take(streams.episode, rows)

        def draw(stream, count):
            return uniforms(low, high, episode, STREAMS[stream], count)

        def renew(value, fresh):
            return put(value, rows, mask, fresh)

        jitter = -START_JITTER + 2 * START_JITTER * draw("tips", 3 * n_agents)
        for k, agent in enumerate(AGENTS):
            arm = self.arms[agent]
            tips = (xp.asarray(np.asarray(STARTS[agent])) + jitter[:, 3 * k:3 * k + 3]) - arm.base_position
            arm.tip = renew(arm.tip, tips)
            arm.q = renew(arm.q, kinematics.inverse_kinematics_batch(arm.tool, arm._tool_points(tips))[0])
        position, yaw, cavity = place_debris(draw, self.cavities, p.debris_count, xp)
        self.debris_position = renew(self.debris_position, position)
        self.debris_yaw = renew(self.debris_yaw, yaw)
        self.debris_cavity = renew(self.debris_cavity, cavity)
        if p.bleeding_ml_s > 0.0:
            c = self.cavities.count
            bleeding = draw("bleeding", 2 * c)
            self.bleed_onset = renew(self.bleed_onset, bleeding[:, :c] * p.bleeding_onset_s)
            self.bleed_rate = renew(self.bleed_rate, (0.5 + 0.5 * bleeding[:, c:]) * p.bleeding_ml_s)
        streams.next_episode(mask)
        for name, spec in scene_state.SPECS.items():  # what every episode starts alike (the valve shut, no pin held..)
            if spec.start is not None:
                value = self._get(name)
                started = xp.reshape(mask, mask.shape + (1,) * (value.ndim - 1))
                self._set(name, xp.where(started, xp.asarray(spec.start, dtype=value.dtype), value))
        initial = take(self.initial_ml, rows)
        self.remaining_ml = renew(self.remaining_ml, initial)
        if p.clot_share > 0.0:  # that share of each cavity's blood starts clotted
            self.clot_ml = renew(self.clot_ml, p.clot_share * initial)
        cavity_of = xp.broadcast_to(xp.arange(self.cavities.count)[None, :], initial.shape)
        surface = self.cavities.per_cavity(self.cavities.floor_z, cavity_of) + self.cavities.fill_depth(cavity_of,
                                                                                                           initial)
        self.surface_z = renew(self.surface_z, surface)
        pin_surface = xp.zeros_like(yaw)
        for index in range(self.cavities.count):
            pin_surface = xp.where(cavity == index, surface[:, index:index + 1], pin_surface)
        self.visible = renew(self.visible, position[:, :, 2] + PIN_RADIUS > pin_surface)
        self.limit = xp.where(mask, p.max_cycles, self.limit)
        for agent in AGENTS:
            self.work_distance[agent] = xp.where(mask, self._work_distance(agent), self.work_distance[agent])

    # --- start-state curricula ----------------------------------------------------------------------------
    def place_tips(self, worlds, tips: dict) -> None:
        """Move the tips of ``worlds`` to ``tips[agent]`` (metres, world frame, one row per world in ``worlds``)
        at the start of an episode. Each must lie in the workspace box, above the phantom, be reachable and leave
        the instruments apart; the shaping potential restarts from there."""
        indices = self.worlds_of(worlds)
        previous = {agent: (arm.tip[indices].copy(), arm.q[indices].copy()) for agent, arm in self.arms.items()}
        try:
            for agent, positions in tips.items():
                self._place_one(agent, indices, positions)
            clearance = self._instrument_distance()[indices]
            if np.any(clearance < 0.0):
                row = int(np.argmax(clearance < 0.0))
                raise ValueError(f"{self.name}: tip positions make the instruments intersect "
                                 f"(world {int(indices[row])})")
        except ValueError:  # a refused placement leaves every tip where it was, whichever agent failed
            for agent, (tip, q) in previous.items():
                self.arms[agent].tip[indices], self.arms[agent].q[indices] = tip, q
            raise
        for agent in AGENTS:
            self.work_distance[agent][indices] = self._work_distance(agent)[indices]

    def _place_one(self, agent: str, indices: np.ndarray, positions) -> None:
        if agent not in AGENTS:
            raise ValueError(f"{self.name}: unknown agent {agent!r} in tip positions; agents are {list(AGENTS)}")
        positions = np.asarray(positions, dtype=np.float64)
        if positions.shape != (len(indices), 3) or not np.all(np.isfinite(positions)):
            raise ValueError(f"{self.name}: tip positions of {agent!r} must be finite, shape "
                             f"({len(indices)}, 3), got shape {positions.shape}")
        outside = np.any((positions < self.low - 1e-12) | (positions > self.high + 1e-12), axis=1)
        below = positions[:, 2] < self._floor(positions[:, 0], positions[:, 1]) - 1e-12
        bad = outside | below
        if bad.any():
            row = int(np.argmax(bad))
            raise ValueError(f"{self.name}: tip position {positions[row].tolist()} of {agent!r} (world "
                             f"{int(indices[row])}) is {'outside the workspace box' if outside[row] else 'below the surface'}")
        arm = self.arms[agent]
        try:
            arm.set_tips(indices, positions - arm.base_position)
        except kinematics.UnreachableError as error:
            raise ValueError(f"{self.name}: a tip position of {agent!r} is unreachable: {error}") from None

    def limit_debris(self, worlds, count) -> None:
        """Keep only the first ``count`` debris (per world in ``worlds``) in play this episode: the others start
        delivered, as if they had never been there."""
        indices = self.worlds_of(worlds)
        count = np.broadcast_to(np.asarray(count), (len(indices),))
        if not np.issubdtype(count.dtype, np.integer) or np.any(count < 0) or np.any(count > self.params.debris_count):
            raise ValueError(f"{self.name}: debris_count must be integers in 0..{self.params.debris_count}, "
                             f"got {count.tolist()}")
        mask = np.zeros(self.num_worlds, dtype=bool)
        mask[indices] = True
        counts = np.full(self.num_worlds, self.params.debris_count)
        counts[indices] = count
        self.keep_debris(mask, counts)

    def keep_debris(self, mask, count) -> None:
        """:meth:`limit_debris` for the worlds of ``mask`` (N,), ``count`` (N,) checked (any array library)."""
        xp = namespace(mask, self.remaining_ml)
        out = (xp.arange(self.params.debris_count)[None, :] >= count[:, None]) & mask[:, None]
        self.delivered = self.delivered | out
        self.visible = self.visible & ~out
        self.complete = self.complete & ~mask
        self.work_distance["grasper"] = xp.where(mask, self._work_distance("grasper"), self.work_distance["grasper"])

    def try_grasper_starts(self, mask, targets) -> None:
        """Start the grasper's tip at ``targets`` (N, 3, world) in the worlds of ``mask`` where that start is possible
        (in the workspace box, above the surface, reachable, apart from the suction); elsewhere, and where it is
        not, nothing changes. :meth:`place_tips`' checks, as a mask (any array library)."""
        xp = namespace(mask, targets, self.remaining_ml)
        arm = self.arms["grasper"]
        inside = xp.all((targets >= self.low - 1e-12) & (targets <= self.high + 1e-12), axis=1)
        above = targets[:, 2] >= self._floor(targets[:, 0], targets[:, 1]) - 1e-12
        tips = targets - arm.base_position
        q, reachable = kinematics.inverse_kinematics_batch(arm.tool, arm._tool_points(tips))
        previous_tip, previous_q = arm.tip, arm.q
        placed = mask & inside & above & reachable
        arm.tip, arm.q = xp.where(placed[:, None], tips, arm.tip), xp.where(placed[:, None], q, arm.q)
        placed = placed & (self._instrument_distance() >= 0.0)
        arm.tip = xp.where(placed[:, None], tips, previous_tip)
        arm.q = xp.where(placed[:, None], q, previous_q)
        for agent in AGENTS:
            self.work_distance[agent] = xp.where(placed, self._work_distance(agent), self.work_distance[agent])

    # --- step ---------------------------------------------------------------------------------------------
    def step(self, commands: dict):
        """Advance every world by one control step. ``commands[agent]``: (N, 4) in [-1, 1]; for a held seat the
        tool value may be NaN, meaning "unchanged". (Arrays of any array API library: numpy's, JAX's.)"""
        eta = self.params.step_size
        xp = namespace(commands[AGENTS[0]])
        contact = xp.zeros(commands[AGENTS[0]].shape[:1], dtype=xp.bool)
        for agent in AGENTS:
            command = commands[agent]
            contact = contact | self._move(agent, eta * command[:, layout.MOVE])
            tool = command[:, layout.TOOL]
            given = ~xp.isnan(tool)
            if agent == "suction":
                opening = tools.moved_towards(self.valve_opening, tools.valve_target(tool), self.params.tool_speed)
                self.valve_opening = xp.where(given, opening, self.valve_opening)
                if self.params.irrigation_ml_s > 0.0:  # the signed valve: a negative command irrigates
                    opening = tools.moved_towards(self.irrigation_opening, tools.irrigation_target(tool),
                                                  self.params.tool_speed)
                    self.irrigation_opening = xp.where(given, opening, self.irrigation_opening)
            else:
                arm = self.arms["grasper"]
                jaw = tools.moved_towards(arm.jaw, tools.jaw_target(tool, self.params.jaw_command),
                                          self.params.tool_speed)
                if self.params.hold_until_handoff:  # a held pin's jaw stays shut until the hand-off
                    given = given & (self.holding < 0)
                arm.jaw = xp.where(given, jaw, arm.jaw)
        removed = self.drawn_ml = self._suction()
        wasted_before = self.saline_wasted_ml
        self._irrigate()
        self._bleed()
        self._clot()
        lifted, delivered = self._grasping()
        self._fall()
        self.elapsed = self.elapsed + 1
        self.contact = contact
        self.complete = self._complete()
        truncated = (self.elapsed >= self.limit) & ~self.complete
        rewards = self._rewards(removed, lifted, delivered, contact, wasted_before)
        return rewards, _copy(self.complete), truncated

    @property
    def valve_open(self) -> np.ndarray:
        """(N,) bool: the valve draws (more than half open; :mod:`dvrl_marl.core.tools`)."""
        return self.valve_opening > tools.VALVE_OPEN_ABOVE

    @property
    def irrigating(self) -> np.ndarray:
        """(N,) bool: the valve irrigates (its irrigating side more than half open)."""
        return self.irrigation_opening > tools.VALVE_OPEN_ABOVE

    def _floor(self, x, y):
        return self.cavities.surface_height(x, y) + self.params.tip_clearance

    def _move(self, agent: str, delta: np.ndarray) -> np.ndarray:
        arm = self.arms[agent]
        if self._lean is not None and isinstance(delta, np.ndarray) and isinstance(arm.tip, np.ndarray):
            # one numpy world: its common move in floats
            partner = AGENTS[1 - AGENTS.index(agent)]
            other = self.arms[partner]
            made = self._lean.move(agent, partner, arm.tip[0].tolist(), other.q[0].tolist(), other.tip[0].tolist(),
                                   delta[0].tolist())
            if made is not None:
                tip, q, clearance = made
                arm.tip, arm.q = np.array([tip]), np.array([q])
                self.blocked[agent] = np.zeros(1, dtype=bool)
                return np.array([clearance < CONTACT_MARGIN])
        old = arm.tip_world()
        p, rules = self.params, self.move_rules[agent]
        target = sliding.surface_target(self.cavities, p.tip_clearance, p.step_size, self.low, self.high, old, delta,
                                        slide_on_walls=rules.slide, **rules.descents)
        xp = namespace(old, delta)
        previous_tip, previous_q = arm.tip, arm.q
        cut = arm.move(target - old, -1.0, 1.0)
        clearance = self._instrument_distance()
        refused = clearance < 0.0  # instruments never pass through each other
        self.blocked[agent] = refused  # (a person's cue: the move as commanded was refused, slid or not)
        if rules.slide:
            stuck = refused | (cut & xp.all(arm.tip == previous_tip, axis=1))
            if needed(stuck):
                refused, clearance = self._fall_back(agent, stuck, old, delta, refused, clearance)
        if needed(refused):
            arm.tip = xp.where(refused[:, None], previous_tip, arm.tip)
            arm.q = xp.where(refused[:, None], previous_q, arm.q)
        return refused | (clearance < CONTACT_MARGIN)

    def _fall_back(self, agent, stuck, old, delta, refused, clearance):
        """The blocked moves of the ``stuck`` worlds slide (:func:`sliding.resolve_blocked`); returns ``refused``
        and ``clearance`` with those made."""
        p = self.params
        arm, other = self.arms[agent], self.arms[AGENTS[1 - AGENTS.index(agent)]]
        rows = rows_of(stuck)
        made, tip, q, gap = sliding.resolve_blocked(
            {"tool": arm.tool, "base": arm.base_position, "tip": take(old, rows)},
            {"tool": other.tool, "base": other.base_position, "tip": take(other.tip_world(), rows)},
            agent == "suction", take(delta, rows), self.cavities, p.tip_clearance, p.step_size, self.low, self.high,
            **self.move_rules[agent].descents)
        made_here = put(namespace(stuck).zeros_like(stuck), rows, stuck, made)  # the worlds whose slide was made
        arm.tip = put(arm.tip, rows, made_here, namespace(tip).where(made[:, None], tip - arm.base_position,
                                                                    take(arm.tip, rows)))
        arm.q = put(arm.q, rows, made_here, namespace(q).where(made[:, None], q, take(arm.q, rows)))
        return refused & ~made_here, put(clearance, rows, made_here, namespace(gap).where(made, gap,
                                                                                          take(clearance, rows)))

    def instrument_clearance(self) -> np.ndarray:
        """Clearance between the two instruments in every world (m; they never intersect: never negative)."""
        return self._instrument_distance()

    def _instrument_distance(self) -> np.ndarray:
        """Clearance between the two instruments (negative when they intersect)."""
        a, b = self.arms["suction"], self.arms["grasper"]
        return instrument_clearance(a.base_position, a.wrist_world(), a.tip_world(),
                                    b.base_position, b.wrist_world(), b.tip_world())

    def _suction(self):
        xp = namespace(self.remaining_ml)
        removed = xp.zeros(self.remaining_ml.shape[:1], dtype=self.remaining_ml.dtype)
        open_ = self.valve_open
        if not needed(open_):
            return removed
        tip = self.arms["suction"].tip_world()
        cavity = self.cavities.cavity_at(tip[:, 0], tip[:, 1])
        safe = xp.maximum(cavity, 0)
        remaining = _pick(self.remaining_ml, safe, xp)
        liquid = remaining
        if self.fluids:  # suction draws the liquid: blood not clotted, and saline
            clot = _pick(self.clot_ml, safe, xp)
            blood = xp.maximum(remaining - clot, 0.0)
            saline = _pick(self.saline_ml, safe, xp)
            liquid = blood + saline
        height = tip[:, 2] - _pick(self.surface_z, safe, xp)
        reach = self.params.suction_reach
        if reach <= 0.0:  # the simple rule: full flow under the surface, none at or above it
            flow = xp.where(height < 0.0, 1.0, 0.0)
        else:  # 1 at or below the surface, falling linearly to 0 at reach above it
            flow = xp.where(height <= 0.0, 1.0, xp.where(height < reach, 1.0 - height / reach, 0.0))
        sucking = open_ & (cavity >= 0) & (liquid > 0.0) & (flow > 0.0)
        if not needed(sucking):
            return removed
        amount = xp.minimum(flow * self.params.suction_rate_ml_s * self.params.control_dt, liquid)
        drawn = self._in_cavity(safe, sucking)  # (N, C): the cavity each sucking world draws from
        if self.fluids:  # the mix: blood in proportion to its share of the liquid
            saline_drawn = amount * (saline / xp.maximum(liquid, 1e-300))
            self.saline_ml = xp.where(drawn, xp.maximum(saline - saline_drawn, 0.0)[:, None], self.saline_ml)
            amount = amount - saline_drawn
        self.remaining_ml = xp.where(drawn, xp.maximum(remaining - amount, 0.0)[:, None], self.remaining_ml)
        self._update_surfaces_where(drawn)
        removed = xp.where(sucking, amount, removed)
        surface = _pick(self.surface_z, safe, xp)
        if self.fluids and needed(clot > 0.0):  # a clot settles on the floor: a pin under its level stays hidden
            clot_level = (self.cavities.per_cavity(self.cavities.floor_z, safe)  # (until it is broken up)
                          + self.cavities.fill_depth(safe, clot))
            surface = xp.maximum(surface, clot_level)
        revealed = ((self.debris_cavity == safe[:, None]) & ~self.visible & sucking[:, None]
                    & (self.debris_position[:, :, 2] + PIN_RADIUS > surface[:, None]))
        self.visible = self.visible | revealed
        return removed

    def _fluid_ml(self):
        """(N, C): what each cavity holds (ml): its blood, clotted or not, and with irrigation its saline."""
        return self.remaining_ml + self.saline_ml if self.params.irrigation_ml_s > 0.0 else self.remaining_ml

    def _irrigate(self) -> None:
        """The S&I valve's other half (``irrigation_ml_s``): while it irrigates, saline flows from the tip. Over a
        cavity with the tip below the phantom's top it enters that cavity (up to its capacity; the rest spills over
        and covers the phantom around it for ``spill_s``) and breaks up ``clot_per_saline_ml`` of clot per ml of
        flow into liquid blood; anywhere else it wets nothing useful and is wasted. Saline mixes with the liquid
        blood, and suction draws the mix (:meth:`_suction`)."""
        p = self.params
        if p.irrigation_ml_s <= 0.0:
            return
        xp = namespace(self.remaining_ml)
        self.spill_s = xp.maximum(self.spill_s - p.control_dt, 0.0)  # a spill dries
        on = self.irrigating
        if not needed(on):
            self.spilling = xp.zeros_like(self.spilling)
            return
        flow = p.irrigation_ml_s * p.control_dt
        tip = self.arms["suction"].tip_world()
        cavity = self.cavities.cavity_at(tip[:, 0], tip[:, 1])
        safe = xp.maximum(cavity, 0)
        into = on & (cavity >= 0) & (tip[:, 2] < self.phantom.top_z)
        self.saline_used_ml = self.saline_used_ml + xp.where(on, flow, 0.0)
        self.saline_wasted_ml = self.saline_wasted_ml + xp.where(on & ~into, flow, 0.0)
        saline, clot = _pick(self.saline_ml, safe, xp), _pick(self.clot_ml, safe, xp)
        room = xp.maximum(self.cavities.per_cavity(self.cavities.capacity_ml, safe)
                          - _pick(self.remaining_ml, safe, xp) - saline, 0.0)
        added = xp.where(into, xp.minimum(flow, room), 0.0)
        spilt = xp.where(into, flow - added, 0.0)
        broken = xp.where(into, xp.minimum(clot, p.clot_per_saline_ml * flow), 0.0)
        wetted = self._in_cavity(safe, into)  # (N, C): the cavity each irrigating world's saline enters
        self.saline_ml = xp.where(wetted, (saline + added)[:, None], self.saline_ml)
        self.clot_ml = xp.where(wetted, (clot - broken)[:, None], self.clot_ml)
        overflowing = spilt > 0.0
        spills = wetted & overflowing[:, None]
        self.overflow_events = self.overflow_events + xp.sum(xp.astype(spills & ~self.spilling, xp.int64), axis=1)
        self.overflow_steps = self.overflow_steps + xp.astype(overflowing, xp.int64)
        self.overflow_ml = self.overflow_ml + spilt
        self.spilling = spills
        self.spill_s = xp.where(spills, p.spill_s, self.spill_s)
        self._update_surfaces_where(wetted & (added > 0.0)[:, None])

    def covered_pins(self):
        """(N, D) bool: pins a spill covers now (within its cavity's mouth and a pin's length of it, on the
        phantom): the observations show them as not seen (the endoscope draws the spill over them)."""
        xp = namespace(self.debris_position)
        position = self.debris_position
        covered = xp.zeros(position.shape[:2], dtype=xp.bool)
        if self.params.irrigation_ml_s <= 0.0 or not needed(self.spill_s > 0.0):
            return covered
        c = self.cavities
        for index in range(c.count):
            near = ((position[..., 0] - c.centre_x[index]) ** 2 + (position[..., 1] - c.centre_y[index]) ** 2
                    < (c.mouth_radius[index] + SPILL_MARGIN) ** 2)
            covered = covered | (near & (self.spill_s[:, index:index + 1] > 0.0))
        return covered & ~self.held

    def _in_cavity(self, cavity, where):
        """(N, C): True at each world's ``cavity`` where ``where`` holds."""
        xp = namespace(cavity)
        return (xp.arange(self.cavities.count)[None, :] == cavity[:, None]) & where[:, None]

    def _update_surfaces_where(self, changed) -> None:
        """The blood's surface again where ``changed`` (N, C) says its volume changed."""
        if isinstance(changed, np.ndarray):  # numpy: those cavities only (a surface is 30 Newton steps)
            worlds, cavity = np.nonzero(changed)
            if len(worlds):
                self._update_surfaces(worlds, cavity)
            return
        xp = namespace(changed)
        cavity = xp.broadcast_to(xp.arange(self.cavities.count)[None, :], changed.shape)
        surfaces = xp.asarray(self.cavities.floor_z)[cavity] + self.cavities.fill_depth(cavity, self._fluid_ml())
        self.surface_z = xp.where(changed, surfaces, self.surface_z)

    def _grasping(self):
        """The paper's grasp rule for the LND and the hand-off. Returns per-world (first lifts, deliveries)."""
        xp = namespace(self.debris_position)
        n, d = self.debris_position.shape[:2]
        pins_of = xp.arange(d)[None, :]
        lifted = xp.zeros((n,), dtype=self.debris_position.dtype)
        delivered = xp.zeros((n,), dtype=self.debris_position.dtype)
        tip = self.arms["grasper"].tip_world()
        closed = self.arms["grasper"].jaw < self.params.grasp_threshold
        holding = self.holding >= 0
        release = holding & ~closed
        if needed(release):  # released away from the assistant: it drops onto the surface below it
            dropped = (pins_of == self.holding[:, None]) & release[:, None]  # (N, D)
            position = self.debris_position
            if self.params.pins_stay_on_phantom:  # beyond the phantom, it lands on the nearest edge (in view)
                x, y = self.cavities.nearest_on_top(position[..., 0], position[..., 1], PHANTOM_EDGE_MARGIN)
                position = xp.where(dropped[..., None], xp.stack([x, y, position[..., 2]], axis=-1), position)
            if self.params.pins_fall:  # it falls (see _fall)
                self.fall_speed = xp.where(dropped, 0.0, self.fall_speed)
            else:  # the simple rule: it appears on the surface below it at once
                z = self._surface(position[..., 0], position[..., 1]) + PIN_RADIUS
                position = xp.where(dropped[..., None], xp.stack([position[..., 0], position[..., 1], z], axis=-1),
                                    position)
            self.debris_position = position
            self.held = self.held & ~dropped
            self.holding = xp.where(release, -1, self.holding)
        grab = ~holding & closed
        if self._lean is not None and isinstance(grab, np.ndarray) and grab.any():  # one numpy world: a pin in reach?
            grab = grab & xp.any(distance(tip[:, None, :], self.debris_position) <= _CENTRE_IN_REACH, axis=1)
        if needed(grab):  # (numpy: on the closing worlds only)
            rows = rows_of(grab)
            position, yaw, tip_here = take(self.debris_position, rows), take(self.debris_yaw, rows), take(tip, rows)
            axis = xp.stack([PIN_HALF_LENGTH * xp.cos(yaw), PIN_HALF_LENGTH * xp.sin(yaw), 0.0 * yaw], axis=-1)
            grip = closest_on_segment(tip_here[:, None, :], position - axis, position + axis)  # (M, D, 3)
            gap = distance(tip_here[:, None, :], grip)
            seen = (take(self.visible, rows) & ~take(self.delivered, rows) & (gap <= PIN_SENSOR_RANGE)
                    & take(grab, rows)[:, None])
            found = xp.any(seen, axis=1)
            pins = xp.argmax(seen * 1, axis=1)  # the first pin in reach
            chosen = (pins_of == pins[:, None]) & found[:, None]
            first = found & ~xp.any(take(self.lifted, rows) & chosen, axis=1)
            taken = put(xp.zeros_like(self.held), rows, grab, chosen)  # (N, D): the pin each world took
            self.holding = put(self.holding, rows, grab, xp.where(found, pins, take(self.holding, rows)))
            self.held = self.held | taken
            self.fall_speed = xp.where(taken, float("nan"), self.fall_speed)  # caught
            self.hold_offset = put(self.hold_offset, rows, grab, xp.where(
                found[:, None], _pick(position, pins, xp) - tip_here, take(self.hold_offset, rows)))
            self.grip_offset = put(self.grip_offset, rows, grab, xp.where(
                found[:, None], _pick(grip, pins, xp) - tip_here, take(self.grip_offset, rows)))
            self.lifted = self.lifted | taken
            lifted = put(lifted, rows, grab, xp.where(found, xp.astype(first, lifted.dtype), 0.0))
        holding = self.holding >= 0
        if needed(holding):
            carried = (pins_of == self.holding[:, None]) & holding[:, None]
            position = tip + self.hold_offset
            self.debris_position = xp.where(carried[..., None], position[:, None, :], self.debris_position)
            if self.params.deliver_at_grip:  # judged where the jaws hold the pin
                position = tip + self.grip_offset
            arrived = holding & (distance(position, self.handoff) <= self.params.distance_threshold)
            handed = carried & arrived[:, None]
            self.held = self.held & ~handed
            self.delivered = self.delivered | handed
            self.holding = xp.where(arrived, -1, self.holding)
            delivered = xp.where(arrived, 1.0, delivered)
        return lifted, delivered

    def _bleed(self) -> None:
        """Each bleeding cavity gains rate x dt of blood (up to its capacity) once its onset has passed."""
        if self.params.bleeding_ml_s <= 0.0:
            return
        xp = namespace(self.remaining_ml)
        dt = self.params.control_dt
        now = self.elapsed * dt
        bleeding = now[:, None] >= self.bleed_onset
        if not needed(bleeding):
            return
        room = self.cavities.capacity_ml - self._fluid_ml()
        added = xp.where(bleeding, xp.minimum(self.bleed_rate * dt, room), 0.0)
        grew = added > 0.0
        self.remaining_ml = xp.where(grew, self.remaining_ml + added, self.remaining_ml)
        self.added_ml = xp.where(grew, self.added_ml + added, self.added_ml)
        self._update_surfaces_where(grew)

    def _clot(self) -> None:
        """Liquid blood clots at ``clotting_ml_s`` in every cavity, up to the blood there (suction draws no clot)."""
        if self.params.clotting_ml_s <= 0.0:
            return
        xp = namespace(self.clot_ml)
        self.clot_ml = xp.minimum(self.clot_ml + self.params.clotting_ml_s * self.params.control_dt, self.remaining_ml)

    def _fall(self) -> None:
        """Released pins fall under gravity onto the surface below them."""
        if not self.params.pins_fall:  # the simple rule: released pins never fall
            return
        xp = namespace(self.fall_speed)
        falling = ~xp.isnan(self.fall_speed)
        if not needed(falling):
            return
        dt = self.params.control_dt
        n, d = falling.shape
        flat = xp.reshape(falling, (n * d,))
        rows = rows_of(flat)
        speed = take(xp.reshape(self.fall_speed, (n * d,)), rows) + GRAVITY * dt
        position = take(xp.reshape(self.debris_position, (n * d, 3)), rows)
        floor = self._surface(position[:, 0], position[:, 1]) + PIN_RADIUS
        z = xp.maximum(position[:, 2] - speed * dt, floor)
        landed = xp.where(z <= floor, float("nan"), speed)
        moved = xp.stack([position[:, 0], position[:, 1], z], axis=1)
        self.debris_position = xp.reshape(put(xp.reshape(self.debris_position, (n * d, 3)), rows, flat, moved),
                                          (n, d, 3))
        self.fall_speed = xp.reshape(put(xp.reshape(self.fall_speed, (n * d,)), rows, flat, landed), (n, d))

    def _surface(self, x, y):
        return self.cavities.surface_height(x, y)

    def _cleared(self) -> np.ndarray:
        """(N, C): which cavities are clear (below the threshold, or empty)."""
        return (self.remaining_ml < self.params.blood_threshold_ml) | (self.remaining_ml <= 0.0)

    def _complete(self):
        cleared = self._cleared()
        if isinstance(cleared, np.ndarray):  # (the arrays' own methods: numpy's functions cost more a call)
            return cleared.all(axis=1) & self.delivered.all(axis=1)
        xp = namespace(cleared)
        return xp.all(cleared, axis=1) & xp.all(self.delivered, axis=1)

    def is_complete(self):
        """(N,) whether each world's field is clear now: every cavity cleared, every pin delivered."""
        return self._complete()

    def _rewards(self, removed, lifted, delivered, contact, wasted_before) -> dict:
        xp = namespace(removed)
        if self.sparse:
            team = xp.where(self.complete, 0.0, -1.0)
            rewards = {agent: team * 1.0 for agent in self.rewarded_agents}  # (an array each)
        else:
            team = removed + 2.0 * lifted + 5.0 * delivered
            rewards = {}
            for agent in self.rewarded_agents:
                # Potential-based shaping (Ng et al. 1999): it rewards progress without changing the optimum.
                distance = self._work_distance(agent)
                rewards[agent] = team + 10.0 * (self.work_distance[agent] - distance)
                self.work_distance[agent] = distance
        if needed(contact):
            for agent in rewards:
                rewards[agent] = xp.where(contact, rewards[agent] - self.params.contact_penalty, rewards[agent])
        if self.params.waste_penalty > 0.0:  # (the ml of saline wasted this step: a cost, not shaping)
            cost = self.params.waste_penalty * (self.saline_wasted_ml - wasted_before)
            for agent in rewards:
                rewards[agent] = rewards[agent] - cost
        return rewards

    def _work_distance(self, agent: str):
        """Distance (m) from the agent's tip to what it should work on next (0 when nothing is left)."""
        tip = self.arms[agent].tip_world()
        xp = namespace(tip)
        if agent == "suction":
            away = distance(tip[:, None, :], self._cavity_bottoms)
            pending = (self.remaining_ml >= self.params.blood_threshold_ml) & (self.remaining_ml > 0.0)
        else:
            away = distance(tip[:, None, :], self.debris_position)
            pending = self.visible & ~self.delivered
        nearest = xp.min(xp.where(pending, away, float("inf")), axis=1)
        nearest = xp.where(xp.any(pending, axis=1), nearest, 0.0)
        if agent == "grasper":
            holding = self.holding >= 0
            if needed(holding):
                held = _pick(self.shown_positions(), xp.maximum(self.holding, 0), xp)
                nearest = xp.where(holding, distance(held, self.handoff), nearest)
        return nearest

    # --- observations -------------------------------------------------------------------------------------
    def _blood_fraction(self):
        """Each cavity's blood as a fraction of what it started with (of its capacity if it started empty), at most
        :data:`OBSERVATION_BOUND` (a bleed into a cavity that started nearly empty would leave the space)."""
        xp = namespace(self.remaining_ml)
        started = self.initial_ml > 0.0
        fraction = xp.where(started, self.remaining_ml / xp.where(started, self.initial_ml, 1.0),
                            self.remaining_ml / self.cavities.capacity_ml)
        return xp.minimum(fraction, OBSERVATION_BOUND)

    def observation(self, agent: str) -> np.ndarray:
        """(N, obs_dim): the agent's observation in every world (layout: the env's ``observation_layout``)."""
        return self.observations((agent,))[agent]

    def observations(self, agents=AGENTS) -> dict:
        """``{agent: (N, obs_dim)}`` for ``agents``; what they share (tips, blood, pins) is computed once."""
        xp = namespace(self.remaining_ml)
        n, d = self.debris_position.shape[:2]
        tips = {agent: self.normalise(self.arms[agent].tip_world()) for agent in AGENTS}
        tools_ = {"suction": 2.0 * self.valve_opening - 1.0, "grasper": 2.0 * self.arms["grasper"].jaw - 1.0}
        seen = self.visible
        if self.params.irrigation_ml_s > 0.0:  # a spill covers the pins around its cavity
            seen = seen & ~self.covered_pins()
        shown = seen & ~self.delivered
        pins = self._pins(xp.where(shown[..., None], self.normalise(self.shown_positions()), 0.0), xp, seen)
        blood, handoff = self._blood_fraction(), self._handoff_rows(n, xp)
        fluids = [self._fluid_rows(xp)] if self.fluids else []
        return {agent: join([tips[agent], tools_[agent][:, None], tips[AGENTS[1 - AGENTS.index(agent)]], blood, pins,
                             handoff, *fluids], xp) for agent in agents}

    def _fluid_rows(self, xp):
        """(N, 1 + 4 C): what a scene with fluids adds to observations and the state (:data:`layout.FLUID_FIELDS`)."""
        capacity = xp.asarray(self.cavities.capacity_ml, dtype=self.remaining_ml.dtype)[None, :]
        blood = xp.maximum(self.remaining_ml - self.clot_ml, 0.0)
        liquid = blood + self.saline_ml
        concentration = xp.where(liquid > 0.0, blood / xp.maximum(liquid, 1e-300), 0.0)
        spill = self.spill_s / self.params.spill_s if self.params.spill_s > 0.0 else xp.zeros_like(self.spill_s)
        return join([(2.0 * self.irrigation_opening - 1.0)[:, None], liquid / capacity, concentration,
                     self.clot_ml / capacity, spill], xp)

    def _pins(self, positions, xp, visible=None):
        """(N, PIN_WIDTH D): each pin's slot (:mod:`dvrl_marl.suction_debris.layout`): its position, then whether it is visible,
        held, delivered."""
        n, d = positions.shape[:2]
        width = layout.PIN_WIDTH
        visible = self.visible if visible is None else visible
        if xp is np:
            out = np.empty((n, d, width))
            out[..., layout.PIN_POSITION] = positions
            out[..., layout.PIN_VISIBLE], out[..., layout.PIN_HELD] = visible, self.held
            out[..., layout.PIN_DELIVERED] = self.delivered
            return out.reshape(n, width * d)
        flags = [xp.astype(flag, positions.dtype)[..., None] for flag in (visible, self.held, self.delivered)]
        return xp.reshape(xp.concat([positions, *flags], axis=-1), (n, width * d))  # (the layout's order)

    def _handoff_rows(self, n, xp):
        if xp is np and n == self.num_worlds:  # (numpy: made once; a read-only view)
            return self._handoff_block
        return xp.broadcast_to(xp.asarray(self.handoff_normalised, dtype=self.remaining_ml.dtype)[None, :], (n, 3))

    def shown_positions(self):
        """(N, D, 3) world: where observations, the state and the dense reward's carry place the pins: their centres,
        a held pin with ``held_pin_at_grip`` where the jaws hold it, the point the hand-off judges."""
        if not (self.params.held_pin_at_grip and self.params.deliver_at_grip):  # (without the grip rule: the centre)
            return self.debris_position
        holding = self.holding >= 0
        if not needed(holding):
            return self.debris_position
        xp = namespace(self.debris_position)
        at = (xp.arange(self.debris_position.shape[1])[None, :] == self.holding[:, None]) & holding[:, None]
        grip = self.arms["grasper"].tip_world() + self.grip_offset
        return xp.where(at[..., None], grip[:, None, :], self.debris_position)

    def state(self):
        """(N, state_dim): tips, valve, jaw, blood, every debris (hidden included), hand-off point."""
        xp = namespace(self.remaining_ml)
        n = self.debris_position.shape[0]
        return join([self.normalise(self.arms["suction"].tip_world()), (2.0 * self.valve_opening - 1.0)[:, None],
                     self.normalise(self.arms["grasper"].tip_world()), (2.0 * self.arms["grasper"].jaw - 1.0)[:, None],
                     self._blood_fraction(), self._pins(self.normalise(self.shown_positions()), xp),
                     self._handoff_rows(n, xp), *([self._fluid_rows(xp)] if self.fluids else [])], xp)

    def info(self) -> dict:
        """Per-world figures (arrays of leading dimension N), the single env's info keys."""
        xp = namespace(self.remaining_ml)
        return {
            "blood_remaining": xp.sum(self.remaining_ml, axis=1),
            "blood_remaining_per_cavity": _copy(self.remaining_ml),
            "debris_delivered": xp.sum(xp.astype(self.delivered, xp.int64), axis=1),
            "collision": _copy(self.contact),
            "is_success": _copy(self.complete),
            **(self.fluid_figures() if self.fluids else {}),
        }

    def fluid_figures(self) -> dict:
        """Per-world figures of a scene with fluids (:data:`FLUID_FIGURES`), as CRESSim reports them: clotted blood
        left (ml), saline used and wasted (ml), overflows begun, time overflowing (s) and volume spilt (ml)."""
        xp = namespace(self.remaining_ml)
        return dict(zip(FLUID_FIGURES, (xp.sum(self.clot_ml, axis=1), _copy(self.saline_used_ml),
                                        _copy(self.saline_wasted_ml), _copy(self.overflow_events),
                                        self.overflow_steps * self.params.control_dt, _copy(self.overflow_ml))))

    # --- the state as one record -------------------------------------------------------------------------
    def _get(self, name: str):
        if name in _ARM_FIELDS:
            agent, attribute = _ARM_FIELDS[name]
            return getattr(self.arms[agent], attribute)
        if name in _PER_AGENT_FIELDS:
            kind, agent = _PER_AGENT_FIELDS[name]
            return getattr(self, kind)[agent]
        if name in _STREAM_FIELDS:
            return getattr(self.random, _STREAM_FIELDS[name])
        return getattr(self, name)

    def _set(self, name: str, value) -> None:
        if name in _ARM_FIELDS:
            agent, attribute = _ARM_FIELDS[name]
            setattr(self.arms[agent], attribute, value)
        elif name in _PER_AGENT_FIELDS:
            kind, agent = _PER_AGENT_FIELDS[name]
            getattr(self, kind)[agent] = value
        elif name in _STREAM_FIELDS:
            setattr(self.random, _STREAM_FIELDS[name], value)
        else:
            setattr(self, name, value)

    def get_state(self, copy: bool = True) -> SceneState:
        """Every world's state as one record (numpy arrays copied unless ``copy=False``)."""
        return SceneState(**{name: _copy(self._get(name)) if copy else self._get(name) for name in scene_state.SPECS})

    def set_state(self, state: SceneState, copy: bool = True) -> None:
        """The worlds' state from a record of as many worlds as this core has, checked field by field (a
        ``ValueError`` names the first of another shape or kind). numpy arrays are copied in unless ``copy=False``;
        another library's (JAX's) are taken as they are, and the core then steps on that library."""
        scene_state.check_state(state, self.world_shapes, self.num_worlds, self.name)
        for name in scene_state.SPECS:
            value = getattr(state, name)
            self._set(name, np.array(value) if copy and isinstance(value, np.ndarray) else value)

    def snapshot(self) -> SceneState:
        """Every world's state (copies): :meth:`get_state`. A step from it is the step from the state it was taken in
        (the golden trajectories hold the step to that, step by step)."""
        return self.get_state()

    def restore(self, state: SceneState) -> None:
        """Put back a :meth:`snapshot`: :meth:`set_state`."""
        self.set_state(state)

    def _scratch(self) -> "CollaborativeCore":
        """A core sharing this one's parameters and geometry whose state the pure functions load and read (this
        core's own state is left as it is)."""
        scratch = getattr(self, "_scratch_core", None)
        if scratch is None:
            scratch = copy.copy(self)
            scratch.arms = {agent: copy.copy(arm) for agent, arm in self.arms.items()}
            scratch.work_distance, scratch.blocked = dict(self.work_distance), dict(self.blocked)
            scratch.random = copy.copy(self.random)
            scratch._scratch_core = scratch
            self._scratch_core = scratch
        return scratch

    def step_state(self, state: SceneState, commands: dict):
        """The step as a pure function: ``(state after, rewards {agent: (N,)}, terminated (N,), truncated (N,))``
        from a record and ``{agent: (N, 4)}`` commands in [-1, 1] (:meth:`step`); the record given is not changed.
        Traceable by ``jax.jit`` (a record of JAX arrays: :func:`scene_state.register_with_jax`)."""
        scratch = self._scratch()
        scratch.set_state(state, copy=False)
        rewards, terminated, truncated = scratch.step(commands)
        return scratch.get_state(copy=False), rewards, terminated, truncated

    def reset_state(self, state: SceneState, mask) -> SceneState:
        """New episodes in the worlds where ``mask`` (N,) holds, drawn from their streams (:meth:`start_episodes`),
        as a pure function of the record."""
        scratch = self._scratch()
        scratch.set_state(state, copy=False)
        scratch.start_episodes(mask)
        return scratch.get_state(copy=False)

    @property
    def removed_ml(self) -> np.ndarray:
        """(N, C): blood removed from each cavity this episode (ml): what it started with and gained, less what is left."""
        return self.initial_ml + self.added_ml - self.remaining_ml

    def world_state(self, world: int) -> dict:
        """World ``world``'s state, as :meth:`set_world` takes it (and the MuJoCo mirror shows it)."""
        return {key: ({agent: part[0] for agent, part in value.items()} if isinstance(value, dict) else
                      value[0].item() if key in ("jaw", "valve_open", "valve_opening") else value[0])
                for key, value in self.world_states([int(world)]).items()}

    def world_states(self, worlds) -> dict:
        """What the MuJoCo mirror and the endoscope's renderer draw of the worlds ``worlds`` (copies, numpy; each value
        stacked along a first axis of ``len(worlds)``): read from the state record."""
        state = scene_state.take_worlds(scene_state.map_arrays(np.asarray, self.get_state(copy=False)),
                                        np.asarray(worlds, dtype=np.int64))
        return {
            "tips": {agent: getattr(state, f"{agent}_tip") for agent in AGENTS},
            "joints": {agent: getattr(state, f"{agent}_q") for agent in AGENTS},
            "jaw": state.jaw.astype(np.float64),
            "valve_open": state.valve_opening > tools.VALVE_OPEN_ABOVE,
            "valve_opening": state.valve_opening.astype(np.float64),
            "blood_ml": state.remaining_ml,
            "debris_positions": state.debris_position,
            "debris_yaws": state.debris_yaw,
            "visible": state.visible,
            "delivered": state.delivered,
            # a scene with fluids: each cavity's saline and clot (ml) and whether a spill covers the phantom around it
            **({"saline_ml": state.saline_ml, "clot_ml": state.clot_ml, "spill": state.spill_s > 0.0}
               if self.fluids else {}),
        }

    def set_world(self, world: int, *, tips, jaw, valve_open, blood_ml, debris_positions, debris_yaws, visible,
                  delivered, valve_opening=None, joints=None, saline_ml=None, clot_ml=None, spill=None) -> None:
        """Put world ``world`` in a given state (tips in each arm's base frame, metres; ``joints`` the arms' joint
        values where known, else inverse kinematics finds them), e.g. to set up a scene or show a recorded one.
        ``valve_opening`` (0..1, :mod:`dvrl_marl.core.tools`): the valve's stroke; by default all or nothing. A scene
        with fluids also takes each cavity's ``saline_ml`` and ``clot_ml`` and whether a ``spill`` covers it."""
        rows = np.array([int(world)])
        if self.fluids:
            c = self.cavities.count
            self.saline_ml[world] = 0.0 if saline_ml is None else np.maximum(np.asarray(saline_ml, np.float64), 0.0)
            self.clot_ml[world] = 0.0 if clot_ml is None else np.maximum(np.asarray(clot_ml, np.float64), 0.0)
            shown = np.zeros(c, dtype=bool) if spill is None else np.asarray(spill, dtype=bool)
            self.spill_s[world] = np.where(shown, max(self.params.spill_s, self.params.control_dt), 0.0)
        for agent in AGENTS:
            tip = np.asarray(tips[agent], dtype=np.float64).reshape(1, 3)
            if joints is None:
                self.arms[agent].set_tips(rows, tip)
            else:
                self.arms[agent].tip[rows], self.arms[agent].q[rows] = tip, np.asarray(joints[agent], dtype=np.float64)
        self.arms["grasper"].jaw[world] = float(jaw)
        self.valve_opening[world] = float(bool(valve_open)) if valve_opening is None else float(valve_opening)
        volumes = np.asarray(blood_ml, dtype=np.float64)
        self.remaining_ml[world] = np.minimum(np.maximum(volumes, 0.0), self.cavities.capacity_ml)
        if self.fluids:  # a clot is part of the blood; saline fills at most the rest of a cavity
            self.clot_ml[world] = np.minimum(self.clot_ml[world], self.remaining_ml[world])
            self.saline_ml[world] = np.minimum(self.saline_ml[world],
                                               self.cavities.capacity_ml - self.remaining_ml[world])
        for cavity in range(self.cavities.count):
            self._update_surfaces(rows, np.array([cavity]))
        self.debris_position[world] = np.asarray(debris_positions, dtype=np.float64)
        self.debris_yaw[world] = np.asarray(debris_yaws, dtype=np.float64)
        self.visible[world] = np.asarray(visible, dtype=bool)
        self.delivered[world] = np.asarray(delivered, dtype=bool)

    def read_commands(self, actions, agents) -> dict:
        """Validate ``{agent: (N, 4)}`` for ``agents`` (ValueError naming agent and world)."""
        if not isinstance(actions, dict):
            raise ValueError(f"{self.name}: actions must be a dict keyed by agent, got {type(actions).__name__}")
        for agent in actions:
            if agent not in agents:
                raise ValueError(f"{self.name}: unknown agent {agent!r} in actions; agents are {list(agents)}")
        commands = {}
        for agent in agents:
            if agent not in actions:
                raise ValueError(f"{self.name}: no action for agent {agent!r}")
            commands[agent] = check_action_batch(actions[agent], self.num_worlds, layout.ACTION_WIDTH,
                                                 f"{self.name}: agent {agent!r}")
        return commands
