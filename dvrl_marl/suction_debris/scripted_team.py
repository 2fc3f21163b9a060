"""Scripted experts for the collaborative scene (suction_debris_v8): the suction arm and the surgeon (LND).

They read only their agent's observation plus the scene's fixed layout (:meth:`SuctionDebrisEnv.layout`), so they
can sit in the surgeon seat or act as an agent's policy. Their plan keeps the instruments apart: the suction clears
the cavity farther from its own RCM first and parks on its own side afterwards; the surgeon only works in cavities
the suction has cleared.

For the bleeding field, where clearing first and picking afterwards fails (a cleared cavity refills before the last
hand-off), :class:`KeepClearSuction` and :class:`KeepClearSurgeon` work at the same time: the suction keeps going
back to whichever cavity fills and keeps out of the grasper's way, the grasper picks where the suction is not and
holds the last pin over the hand-off point until the field is clear (``benchmarks/bleeding_field.py``).
:class:`SweepingSuction` and :class:`SweepingSurgeon` do better there: pins once revealed stay revealed, so the
suction clears the field once, keeps out of the way while the grasper picks, and sweeps it again only while the
grasper holds the last pin over the hand-off point.
"""

from __future__ import annotations

import numpy as np

from dvrl_marl.core import tools
from dvrl_marl.suction_debris.instruments import keep_clear
from dvrl_marl.suction_debris.layout import (ACTION_WIDTH, MOVE, PIN_DELIVERED, PIN_HELD, PIN_POSITION, PIN_VISIBLE,
                                             PIN_WIDTH, TOOL)
from dvrl_marl.suction_debris.places import SAFE_HEIGHT, park_height, suction_parking_place, surgeon_waiting_place

__all__ = ["ScriptedSuction", "ScriptedSurgeon", "KeepClearSuction", "KeepClearSurgeon", "SweepingSuction",
           "SweepingSurgeon", "YieldingSuction", "keep_clear_rule", "burst_valve"]



def _far_first(layout) -> list[int]:
    """The cavities, the one farthest from the suction's remote centre of motion first (the order it clears them)."""
    base = np.asarray(layout.base_positions["suction"][:2])
    distances = [np.linalg.norm(np.asarray(c) - base) for c in layout.cavity_centres]
    return [int(i) for i in np.argsort(distances)[::-1]]


class _Scripted:
    """Shared by both experts. ``__call__`` takes one observation ``(d,)`` or a batch ``(N, d)`` (the batched
    environment's worlds)."""

    def __init__(self, layout, observation_layout, workspace_range: float):
        self.layout = layout
        self.slices = observation_layout
        self.gain = layout.gain
        self.safe_z = layout.phantom_top + SAFE_HEIGHT / workspace_range
        self.park_z = park_height(layout, workspace_range)
        self.near = 0.001 / workspace_range  # 1 mm
        self.cavity_centres = np.asarray(layout.cavity_centres, dtype=np.float64)  # (C, 2)
        self.threshold = np.asarray(layout.blood_threshold_fraction, dtype=np.float64)
        #: the suction's shut valve: -1 as ever, but 0 where -1 would irrigate (core.tools.SHUT)
        self.shut = tools.shut_command(getattr(layout, "irrigates", False))

    @classmethod
    def for_env(cls, env):
        """An expert for ``env`` (a single or batched suction_debris_v8 environment)."""
        unwrapped = getattr(env, "unwrapped", env)
        return cls(unwrapped.layout(), unwrapped.observation_layout, unwrapped.workspace_range)

    def reset(self) -> None:
        """Stateless; present so a scripted expert can stand wherever a device can."""

    def __call__(self, observation) -> np.ndarray:
        obs = np.asarray(observation)
        if obs.ndim == 2:
            return self.act(obs.astype(np.float64, copy=False))
        return self.act_one(obs)

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Actions ``(N, 4)`` for observations ``(N, d)``."""
        raise NotImplementedError

    def act_one(self, obs: np.ndarray) -> np.ndarray:
        """The action for one observation: the same plan on plain rows, several times faster than ``act`` on one
        row (the single env's seat calls it every step); a test holds both to the same actions."""
        raise NotImplementedError

    def _parts(self, obs: np.ndarray):
        """One observation's own tip, other tip, blood fractions, debris rows (D, 6) and hand-off point."""
        s = self.slices
        return (obs[s["own_tip"]], obs[s["other_tip"]], obs[s["blood"]], obs[s["debris"]].reshape(-1, PIN_WIDTH),
                obs[s["handoff"]])

    def _cavity_of(self, position) -> int:
        """The cavity whose centre is nearest (x, y) of ``position``."""
        return int(np.argmin(np.hypot(self.cavity_centres[:, 0] - position[0], self.cavity_centres[:, 1] - position[1])))

    def _towards_one(self, tip, target) -> np.ndarray:
        return np.clip((np.asarray(target) - tip) * self.gain, -1.0, 1.0)

    def _via_safe_height_one(self, tip, target, tolerance) -> np.ndarray:
        horizontal = np.linalg.norm(np.asarray(target[:2]) - tip[:2])
        if horizontal > tolerance:
            return np.array([target[0], target[1], max(self.safe_z, target[2])])
        return np.asarray(target, dtype=float)

    def _towards(self, tip, target) -> np.ndarray:
        return np.clip((target - tip) * self.gain, -1.0, 1.0)

    def _via_safe_height(self, tip, target, tolerance) -> np.ndarray:
        """Rise to the safe height before travelling sideways, then descend on the target (rows of (N, 3));
        ``tolerance`` is a number or one per row."""
        target = np.broadcast_to(target, tip.shape)
        offset = target[:, :2] - tip[:, :2]
        far = np.sqrt(offset[:, 0] * offset[:, 0] + offset[:, 1] * offset[:, 1]) > tolerance
        via = target.copy()
        via[:, 2] = np.where(far, np.maximum(self.safe_z, target[:, 2]), target[:, 2])
        return via

    @staticmethod
    def _with_tool(move, tool) -> np.ndarray:
        action = np.empty((move.shape[0], ACTION_WIDTH), dtype=np.float32)
        action[:, MOVE] = move
        action[:, TOOL] = tool
        return action


class ScriptedSuction(_Scripted):
    """Clears each cavity in turn (valve open while inside it), then parks out of the surgeon's way.

    Where the scene irrigates (``irrigation_ml_s``) and a cavity holds a clot, it irrigates there in short bursts and
    sucks the mix between them: it irrigates once the liquid is drawn down to ``low`` (a share of the cavity's
    capacity) until the liquid reaches ``high`` or the cavity holds ``full`` of its capacity, then sucks, the valve's
    stroke (its observation) carrying the burst on between those marks; without a clot it sucks as before.
    ``irrigate=False`` keeps today's suction-only plan in such a scene (its valve shut at 0, not -1, which
    irrigates)."""

    def __init__(self, layout, observation_layout, workspace_range: float, irrigate: bool | None = None):
        super().__init__(layout, observation_layout, workspace_range)
        self.order = _far_first(layout)
        self.park = suction_parking_place(layout, workspace_range)
        irrigates = bool(getattr(layout, "irrigates", False))
        if irrigate and not irrigates:
            raise ValueError("ScriptedSuction: irrigate=True needs a scene whose valve irrigates (irrigation_ml_s > 0)")
        #: it irrigates clotted cavities (by default wherever the scene irrigates)
        self.irrigate = irrigates if irrigate is None else bool(irrigate)

    def _valve_in(self, obs: np.ndarray, cavity: int) -> float:
        """The valve's command for a tip working inside ``cavity``: suck, or irrigate a clot in bursts."""
        return burst_valve(obs, self.slices, cavity) if self.irrigate else 1.0

    def act(self, obs: np.ndarray) -> np.ndarray:
        if self.irrigate:  # (the bursts read the valve row by row)
            return np.stack([self.act_one(row) for row in obs])
        tip = obs[:, self.slices["own_tip"]]
        blood = obs[:, self.slices["blood"]]
        target = np.broadcast_to(self.park, tip.shape).copy()
        tolerance = np.full(len(obs), 4 * self.near)
        valve = np.full(len(obs), self.shut)
        for cavity in reversed(self.order):  # the first cavity in the order that still needs clearing wins
            pending = (blood[:, cavity] >= self.threshold[cavity]) & (blood[:, cavity] > 0.0)
            cx, cy = self.cavity_centres[cavity]
            target[pending] = (cx, cy, self.layout.cavity_floor[cavity] + self.layout.clearance)
            tolerance[pending] = 2 * self.near
            inside = (np.hypot(tip[:, 0] - cx, tip[:, 1] - cy) < self.layout.cavity_mouth_radius) & (
                tip[:, 2] < self.layout.phantom_top)
            valve[pending] = np.where(inside[pending], 1.0, self.shut)
        return self._with_tool(self._towards(tip, self._via_safe_height(tip, target, tolerance)), valve)

    def act_one(self, obs: np.ndarray) -> np.ndarray:
        tip = obs[self.slices["own_tip"]]
        blood = obs[self.slices["blood"]]
        for cavity in self.order:
            cx, cy = self.layout.cavity_centres[cavity]
            inside = np.hypot(tip[0] - cx, tip[1] - cy) < self.layout.cavity_mouth_radius and tip[2] < self.layout.phantom_top
            # irrigating, it works a cavity it is in down to half the threshold (the clot's last bits with it)
            threshold = self.layout.blood_threshold_fraction[cavity] * (0.5 if self.irrigate and inside else 1.0)
            if blood[cavity] >= threshold and blood[cavity] > 0.0:
                bottom = (cx, cy, self.layout.cavity_floor[cavity] + self.layout.clearance)
                move = self._towards_one(tip, self._via_safe_height_one(tip, bottom, 2 * self.near))
                return np.append(move, self._valve_in(obs, cavity) if inside else self.shut).astype(np.float32)
        return np.append(self._towards_one(tip, self._via_safe_height_one(tip, self.park, 4 * self.near)),
                         self.shut).astype(np.float32)


class YieldingSuction(ScriptedSuction):
    """The scripted suction that waits instead of pushing: a move that would bring its instrument within ``keep_mm``
    of the other's (their axes, each from its remote centre of motion to its tip), and nearer than it is, is not made;
    it holds its place, the valve as planned, until the way clears. A surgeon resting in its way that moves off once
    the suction has waited beside it (:mod:`dvrl_marl.agents.in_the_way`) lets it through without a contact.
    ``rule`` is that rule as a policy's ``keep_clear`` table (:mod:`dvrl_marl.policies`)."""

    def __init__(self, layout, observation_layout, workspace_range: float, keep_mm: float = 12.0):
        super().__init__(layout, observation_layout, workspace_range)
        self.rule = keep_clear_rule(layout, observation_layout, workspace_range, "suction", keep_mm)

    def act(self, obs: np.ndarray) -> np.ndarray:
        return keep_clear(super().act(obs), obs, self.rule)

    def act_one(self, obs: np.ndarray) -> np.ndarray:
        return self.act(np.asarray(obs, dtype=np.float64)[None])[0]


#: An irrigation burst's marks, shares of a cavity's capacity: irrigate from ``BURST_LOW`` liquid up to
#: ``BURST_HIGH``, never past ``BURST_FULL`` of fluid in all (liquid and clot); a clot under ``CLOT_LEFT`` is gone.
BURST_LOW, BURST_HIGH, BURST_FULL, CLOT_LEFT = 0.01, 0.2, 0.85, 1e-4


def burst_valve(obs: np.ndarray, slices: dict, cavity: int) -> float:
    """The suction valve's command (1 sucks, -1 irrigates) for a tip working inside ``cavity`` of a scene that
    irrigates, from one observation (``slices``: its layout): where the cavity holds a clot, irrigate once the liquid
    is drawn down to :data:`BURST_LOW` until it reaches :data:`BURST_HIGH` or the cavity :data:`BURST_FULL`, then
    suck; between the marks the valve's stroke (observed) carries the burst on. Without a clot: suck."""
    clot = obs[slices["clot"]][cavity]
    if clot <= CLOT_LEFT:
        return 1.0
    liquid = obs[slices["liquid"]][cavity]
    if liquid >= BURST_HIGH or liquid + clot >= BURST_FULL:
        return 1.0
    if liquid <= BURST_LOW:
        return -1.0
    irrigating = obs[slices["irrigation"]][0] > obs[slices["own_tool"]][0]  # the burst under way goes on
    return -1.0 if irrigating else 1.0


def keep_clear_rule(layout, observation_layout, workspace_range: float, agent: str, keep_mm: float) -> dict:
    """The rule by which a seat waits rather than push, for ``agent`` (its moves withheld that would bring its
    instrument within ``keep_mm`` of the other's and nearer), in the observation's coordinates: a policy's
    ``keep_clear`` table (:mod:`dvrl_marl.policies`)."""
    if keep_mm <= 0.0:
        raise ValueError(f"keep_mm must be positive, got {keep_mm}")
    other = {"suction": "grasper", "grasper": "suction"}[agent]
    span = [observation_layout["own_tip"], observation_layout["other_tip"]]
    return {"keep_mm": float(keep_mm), "keep": keep_mm / 1000.0 / workspace_range, "gain": float(layout.gain),
            "own_tip": [span[0].start, span[0].stop], "other_tip": [span[1].start, span[1].stop],
            "own_centre": [float(v) for v in layout.base_positions[agent]],
            "other_centre": [float(v) for v in layout.base_positions[other]]}


def felt_contact_rule(workspace_range: float, near_mm: float, retreat_mm: float, hold_steps: int,
                      threshold_mm: float) -> dict:
    """A policy's ``felt_contact`` table (:mod:`dvrl_marl.policies.felt_contact`; it reads the geometry of the
    policy's ``keep_clear``): a move ``threshold_mm`` or more short of its command with the other instrument's axis
    within ``near_mm`` is a touch, after which the tip keeps ``retreat_mm`` behind it for ``hold_steps`` steps."""
    for name, value in (("near_mm", near_mm), ("retreat_mm", retreat_mm), ("threshold_mm", threshold_mm)):
        if not value > 0.0:
            raise ValueError(f"felt_contact: {name} must be positive, got {value}")
    if int(hold_steps) != hold_steps or hold_steps < 1:
        raise ValueError(f"felt_contact: hold_steps must be a whole number of steps, at least 1, got {hold_steps}")
    unit = 1000.0 * workspace_range  # mm per observation unit
    return {"near_mm": float(near_mm), "near": near_mm / unit, "retreat_mm": float(retreat_mm),
            "retreat": retreat_mm / unit, "threshold_mm": float(threshold_mm), "threshold": threshold_mm / unit,
            "hold_steps": int(hold_steps)}


class ScriptedSurgeon(_Scripted):
    """Picks each revealed debris in a cleared cavity, carries it over the phantom to the hand-off point."""

    def __init__(self, layout, observation_layout, workspace_range: float):
        super().__init__(layout, observation_layout, workspace_range)
        self.home = surgeon_waiting_place(layout, workspace_range)

    def act(self, obs: np.ndarray) -> np.ndarray:
        n = len(obs)
        rows = np.arange(n)
        tip = obs[:, self.slices["own_tip"]]
        blood = obs[:, self.slices["blood"]]
        debris = obs[:, self.slices["debris"]].reshape(n, -1, PIN_WIDTH)
        handoff = obs[:, self.slices["handoff"]]
        # Default: wait at home with the jaw open.
        action = self._with_tool(self._towards(tip, self._via_safe_height(tip, self.home, 4 * self.near)), 1.0)

        # A pin whose cavity is clear, visible and not delivered, nearest the tip.
        dx = debris[:, :, None, 0] - self.cavity_centres[:, 0]
        dy = debris[:, :, None, 1] - self.cavity_centres[:, 1]
        cavity = np.argmin(np.hypot(dx, dy), axis=2)  # (N, D)
        cleared = blood[rows[:, None], cavity] < self.threshold[cavity]
        candidate = (debris[:, :, PIN_VISIBLE] > 0.5) & (debris[:, :, PIN_DELIVERED] < 0.5) & cleared
        offset = debris[:, :, PIN_POSITION] - tip[:, None, :]
        distance = np.linalg.norm(offset, axis=2)
        hunting = candidate.any(axis=1)
        if hunting.any():
            nearest = np.argmin(np.where(candidate, distance, np.inf), axis=1)
            pin = debris[rows, nearest, :3]
            on_it = distance[rows, nearest] <= self.near
            move = self._towards(tip, self._via_safe_height(tip, pin, self.near))
            approach = self._with_tool(move, 1.0)
            approach[on_it] = (0.0, 0.0, 0.0, -1.0)  # close the jaw on it
            action[hunting] = approach[hunting]

        held = debris[:, :, PIN_HELD] > 0.5
        carrying = held.any(axis=1)
        if carrying.any():
            pin = debris[rows, np.argmax(held, axis=1), :3]
            # Carry: move so that the pin (not the tip) reaches the hand-off point, above the phantom.
            move = self._towards(pin, self._via_safe_height(pin, handoff, 2 * self.near))
            action[carrying] = self._with_tool(move, -1.0)[carrying]
        return action

    def act_one(self, obs: np.ndarray) -> np.ndarray:
        tip, _, blood, debris, handoff = self._parts(obs)
        held = [d for d in debris if d[4] > 0.5]
        if held:
            pin = held[0][:3]
            target_for_pin = self._via_safe_height_one(pin, handoff, 2 * self.near)
            return np.append(self._towards_one(pin, target_for_pin), -1.0).astype(np.float32)
        candidates = [
            d[:3] for d in debris
            if d[3] > 0.5 and d[5] < 0.5
            and blood[self._cavity_of(d[:3])] < self.layout.blood_threshold_fraction[self._cavity_of(d[:3])]
        ]
        if candidates:
            pin = min(candidates, key=lambda c: np.linalg.norm(c - tip))
            if np.linalg.norm(pin - tip) <= self.near:
                return np.array([0.0, 0.0, 0.0, -1.0], dtype=np.float32)
            return np.append(self._towards_one(tip, self._via_safe_height_one(tip, pin, self.near)), 1.0).astype(np.float32)
        return np.append(self._towards_one(tip, self._via_safe_height_one(tip, self.home, 4 * self.near)), 1.0).astype(np.float32)


class _KeepClear(_Scripted):
    """What the two cooperative experts share: where each arm is, and which cavity lies on whose side.

    The arms come from opposite sides, so their shafts cross when the grasper reaches over the cavity on its own side
    while the suction works in it: the grasper's *near* cavity is the suction's *far* one."""

    def __init__(self, layout, observation_layout, workspace_range: float):
        super().__init__(layout, observation_layout, workspace_range)
        bases = {agent: np.asarray(layout.base_positions[agent][:2]) for agent in ("suction", "grasper")}
        distance = {agent: np.hypot(*(self.cavity_centres - base).T) for agent, base in bases.items()}
        self.suction_near = int(np.argmin(distance["suction"]))
        self.grasper_near = int(np.argmin(distance["grasper"]))
        self.grasper_base = bases["grasper"]
        self.spare = 0.005 / workspace_range
        # Where the suction waits when no cavity needs it: outside its own near cavity, on its side.
        near = self.cavity_centres[self.suction_near]
        outward = (bases["suction"] - near) / np.linalg.norm(bases["suction"] - near)
        self.wait = np.array([*(near + outward * (layout.cavity_mouth_radius + 0.012 / workspace_range)), self.safe_z])
        # How far (in x, from its base) the grasper's tip reaches before its shaft is over its near cavity.
        self.reach_over = (abs(self.cavity_centres[self.grasper_near, 0] - self.grasper_base[0])
                           - layout.cavity_mouth_radius)
        self.settled = 0.003 / workspace_range  # a suction tip within 3 mm of a cavity's floor works there

    def _inside(self, tip, cavity) -> bool:
        cx, cy = self.cavity_centres[cavity]
        return bool(np.hypot(tip[0] - cx, tip[1] - cy) < self.layout.cavity_mouth_radius
                    and tip[2] < self.layout.phantom_top + 0.5 * (self.safe_z - self.layout.phantom_top))

    def _over(self, tip, cavity) -> bool:
        """Above (at any height) or in the cavity's mouth, with 5 mm to spare."""
        cx, cy = self.cavity_centres[cavity]
        return bool(np.hypot(tip[0] - cx, tip[1] - cy) < self.layout.cavity_mouth_radius + self.spare)

    def _grasper_reaching_over(self, grasper_tip) -> bool:
        return bool(abs(grasper_tip[0] - self.grasper_base[0]) > self.reach_over)

    def _down(self, tip, cavity) -> bool:
        """The suction's tip has settled near the cavity's floor (once it rises, it has left)."""
        return bool(tip[2] < self.layout.cavity_floor[cavity] + self.layout.clearance + self.settled)

    def _wait_outside(self, tip) -> np.ndarray:
        """The suction's move to its waiting place, the valve closed."""
        return np.append(self._towards_one(tip, self._via_safe_height_one(tip, self.wait, 4 * self.near)),
                         self.shut).astype(np.float32)

    def _suck(self, tip, cavity) -> np.ndarray:
        """Down to the cavity's floor, the valve open once inside it (the suction's move)."""
        cx, cy = self.cavity_centres[cavity]
        bottom = (cx, cy, self.layout.cavity_floor[cavity] + self.layout.clearance)
        move = self._towards_one(tip, self._via_safe_height_one(tip, bottom, 2 * self.near))
        return np.append(move, 1.0 if self._inside(tip, cavity) else self.shut).astype(np.float32)

    def act(self, obs: np.ndarray) -> np.ndarray:
        return np.stack([self.act_one(row) for row in obs])


class KeepClearSuction(_KeepClear):
    """The suction for a bleeding field: keeps going back to whichever cavity fills up, and keeps out of the
    grasper's way (never into a cavity the grasper's tip is in, nor into the grasper's near cavity while the grasper
    reaches over it).

    It empties the cavity it is in (to ``empty`` x the threshold), then waits outside its own near cavity's mouth
    until a cavity it may enter holds ``refill`` x the threshold."""

    def __init__(self, layout, observation_layout, workspace_range: float, empty: float = 0.1, refill: float = 1.5):
        super().__init__(layout, observation_layout, workspace_range)
        self.empty, self.refill = float(empty), float(refill)

    def act_one(self, obs: np.ndarray) -> np.ndarray:
        tip, other, blood, _, _ = self._parts(obs)
        level = blood / self.threshold  # in thresholds
        free = [c for c in range(len(level)) if not self._inside(other, c)
                and not (c == self.grasper_near and self._grasper_reaching_over(other))]
        for cavity in free:  # keep emptying the cavity it works in: all of a full one; a low one while still down
            committed = level[cavity] > self.refill or (self._down(tip, cavity) and level[cavity] > self.empty)
            if self._inside(tip, cavity) and committed:
                return self._suck(tip, cavity)
        wanted = [c for c in free if level[c] > self.refill]
        if wanted:
            return self._suck(tip, max(wanted, key=lambda c: level[c]))
        return self._wait_outside(tip)


class KeepClearSurgeon(_KeepClear):
    """The surgeon for a bleeding field: picks revealed pins where the suction is not in its way (its near cavity
    when the suction is not over it; its far cavity only while the suction waits), and holds the last pin
    ``hold_height`` above the hand-off point until every cavity is below ``margin`` x the threshold, then hands it
    over: the arms time the end together."""

    def __init__(self, layout, observation_layout, workspace_range: float, hold_height: float = 0.004,
                 margin: float = 0.7):
        super().__init__(layout, observation_layout, workspace_range)
        self.home = surgeon_waiting_place(layout, workspace_range, self.grasper_base)
        self.hold = np.array([0.0, 0.0, hold_height / workspace_range])
        self.margin = float(margin)

    def act_one(self, obs: np.ndarray) -> np.ndarray:
        tip, other, blood, debris, handoff = self._parts(obs)
        held = [d for d in debris if d[4] > 0.5]
        if held:
            pin = held[0][:3]
            last = sum(d[5] < 0.5 for d in debris) == 1
            clear = bool(np.all(blood < self.margin * self.threshold))
            goal = handoff + self.hold if last and not clear else handoff
            return np.append(self._towards_one(pin, self._via_safe_height_one(pin, goal, 2 * self.near)),
                             -1.0).astype(np.float32)
        # Its near cavity when the suction is not over it; anywhere when the suction waits (its shaft would cross
        # the suction's on the way to the far cavity otherwise).
        allowed = set() if self._over(other, self.grasper_near) else {self.grasper_near}
        if np.hypot(*(other[:2] - self.wait[:2])) < self.spare:
            allowed = set(range(len(self.cavity_centres)))
        candidates = [d[:3] for d in debris if d[3] > 0.5 and d[5] < 0.5 and self._cavity_of(d[:3]) in allowed]
        if candidates:
            pin = min(candidates, key=lambda c: np.linalg.norm(c - tip))
            if np.linalg.norm(pin - tip) <= self.near:
                return np.array([0.0, 0.0, 0.0, -1.0], dtype=np.float32)
            return np.append(self._towards_one(tip, self._via_safe_height_one(tip, pin, self.near)),
                             1.0).astype(np.float32)
        return np.append(self._towards_one(tip, self._via_safe_height_one(tip, self.home, 4 * self.near)),
                         1.0).astype(np.float32)


class SweepingSuction(_KeepClear):
    """The suction for a bleeding field that sweeps at the end: it clears the cavities until every pin is revealed
    (a revealed pin stays graspable under blood), waits outside its own near cavity's mouth while the grasper picks,
    and once the grasper holds the last pin sweeps the field, fullest cavity first, never into a cavity the grasper's
    tip is in. In a cavity it works down to ``empty`` x the threshold before it leaves (once its tip has settled
    near the floor); it enters one holding at least the threshold."""

    def __init__(self, layout, observation_layout, workspace_range: float, empty: float = 0.1):
        super().__init__(layout, observation_layout, workspace_range)
        self.empty = float(empty)
        self.order = _far_first(layout)

    def act_one(self, obs: np.ndarray) -> np.ndarray:
        tip, other, blood, debris, _ = self._parts(obs)
        level = blood / self.threshold  # in thresholds
        left = debris[debris[:, PIN_DELIVERED] < 0.5]  # not yet delivered
        hidden = bool(np.any(left[:, PIN_VISIBLE] < 0.5))
        sweeping = not hidden and (len(left) == 0 or (len(left) == 1 and left[0, PIN_HELD] > 0.5))
        if hidden or sweeping:
            free = [c for c in self.order if not self._inside(other, c)]
            for cavity in free:  # finish the cavity it works in
                if self._inside(tip, cavity) and level[cavity] > (self.empty if self._down(tip, cavity) else 1.0):
                    return self._suck(tip, cavity)
            wanted = [c for c in free if level[c] >= 1.0]
            if wanted:  # revealing: the far cavity first (the scripted order); sweeping: the fullest
                return self._suck(tip, max(wanted, key=lambda c: level[c]) if sweeping else wanted[0])
        return self._wait_outside(tip)


class SweepingSurgeon(KeepClearSurgeon):
    """The keep-clear surgeon beside a :class:`SweepingSuction`: the suction waits while it picks, so it picks in
    either cavity. It holds the last pin ``hold_height`` above the hand-off point (8 mm: a clone hovering there must
    not hand it over early, the hand-off reaching 3 mm) until every cavity is below ``margin`` x the threshold (0.9:
    the sweep leaves the field just clear and the first cavity swept refills while it waits; 0.9 finished more
    episodes at 0.3 ml/s than the keep-clear surgeon's 0.7, docs/results.md)."""

    def __init__(self, layout, observation_layout, workspace_range: float, hold_height: float = 0.008,
                 margin: float = 0.9):
        super().__init__(layout, observation_layout, workspace_range, hold_height, margin)
