"""The collaborative env's guided reward: ``reward_type="guided"`` adds potential-based shaping to the dense reward.

Potential-based (F = Phi(s') - Phi(s), Ng et al. 1999, the form of the env's own dense shaping): the
optimal policy is unchanged and success keeps the paper's sparse rule. These terms are what made both arms of the
collaborative task learnable from scratch (``baselines/README.md``, "Both arms learnt from scratch"); they lived in
the MAPPO trainer until 0.1.0 moved them into the env, so that any library (BenchMARL, RLlib, SB3, your own) gets them
as an env option:

- :class:`GraspPathShaping` (the grasper): the way tip -> pin -> hand-off over the pins to collect, continuous
  through the grasp, a hold bonus, centred grasps, a charge for off-centre ones, a waiting place when idle;
- :class:`SuctionRouteShaping` (the suction): the route over the cavities still to clear, continuous when one
  clears, a clearing bonus, a parking place at the end, and in a scene with clots the clot broken up;
- :class:`OverRims`: both measured around the phantom (a tip cannot pass through it).

:class:`Guidance` holds the settings; its defaults are the configuration of record
(``baselines/configs/suction_debris_mappo.toml`` before both arms 1.00 on the test seeds, three seeds).
:class:`GuidedReward` adds the terms of the agents that act in the env (a seat filled by a partner gets none).
"""

from __future__ import annotations

import itertools
from dataclasses import asdict

import numpy as np
from pydantic.dataclasses import dataclass

from dvrl_marl.core.backend import namespace
from dvrl_marl.schemas import STRICT, Flag, NonNegative
from dvrl_marl.suction_debris import layout
from dvrl_marl.suction_debris.places import suction_parking_place, surgeon_waiting_place
from dvrl_marl.suction_debris.rules import Cavities

__all__ = ["Guidance", "GuidedReward", "SceneFacts", "GraspPathShaping", "SuctionRouteShaping", "OverRims"]


def _length(v):
    """Lengths of (..., 3) vectors (the sum written out: numpy's ``linalg.norm`` reduces a short axis slowly; the
    same additions in the same order)."""
    return namespace(v).sqrt(v[..., 0] * v[..., 0] + v[..., 1] * v[..., 1] + v[..., 2] * v[..., 2])


def _squared_2d(v):
    return v[..., 0] * v[..., 0] + v[..., 1] * v[..., 1]


@dataclass(frozen=True, config=STRICT)
class Guidance:
    """The guided reward's settings (``guidance={...}`` beside ``reward_type="guided"``); the defaults are the
    configuration of record. Each is measured in ``baselines/README.md``."""

    #: the grasper's path potential (units of reward per metre of path; the env's own dense terms use 10)
    grasp_path: NonNegative = 10.0
    #: potential while a pin is held (a drop costs what the grasp earned)
    hold_bonus: NonNegative = 1.0
    #: pins approached from above their centre; a grasp that can never be delivered costs
    centred_grasps: Flag = True
    #: a held pin costs this x ``grasp_path`` per metre off the tip (0 for a grasp at its centre)
    off_centre_grasps: NonNegative = 20.0
    #: with nothing to collect, the grasper's potential leads to the scripted surgeon's waiting place
    wait_at_home: Flag = True
    #: only pins in cleared cavities are collected (the scripted surgeon's rule)
    cleared_pins_only: Flag = True
    #: the suction's route potential (per metre of route)
    suction_route: NonNegative = 10.0
    #: potential per cleared cavity
    clear_bonus: NonNegative = 2.0
    #: the suction's route ends at its parking place
    route_to_park: Flag = True
    #: a scene with clots (irrigation): potential per ml of clot broken up (the dense reward pays 1 per ml drawn, but
    #: only once the broken clot is drawn: irrigating itself earned nothing)
    clot_broken: NonNegative = 1.0
    #: paths measured around the phantom's rims, not through it
    over_rims: Flag = True

    def as_dict(self) -> dict:
        return asdict(self)


class SceneFacts:
    """What the guided terms read of an env (single or batched): its parameters, state layout, normalisation,
    layout and cavities (each term takes an env or these)."""

    def __init__(self, env):
        self.params = env.params
        self.state_layout = env.state_layout
        self.workspace_range = env.workspace_range
        self.layout = env.layout()
        core = getattr(env, "core", None)
        self.cavities = core.cavities if core is not None else Cavities(env.phantom)


class GuidedReward:
    """The guided reward's extra terms for ``agents`` (those the env rewards), from the state: ``potentials(state,
    blood_ml)`` is ``{agent: (N,)}``; the env adds its change over each step to that agent's dense reward."""

    def __init__(self, env, agents, guidance: Guidance | None = None):
        self.guidance = guidance = guidance or Guidance()
        scene = SceneFacts(env)
        agents = list(agents)
        self.grasp = GraspPathShaping(scene, guidance.grasp_path, agents, guidance.hold_bonus,
                                      over_rims=guidance.over_rims, home=guidance.wait_at_home,
                                      cleared_only=guidance.cleared_pins_only, centred=guidance.centred_grasps,
                                      off_centre=guidance.off_centre_grasps)
        self.route = SuctionRouteShaping(scene, guidance.suction_route, agents, guidance.clear_bonus,
                                         over_rims=guidance.over_rims, park=guidance.route_to_park,
                                         clot_broken=guidance.clot_broken)
        self.agents = agents

    def potentials(self, state: np.ndarray, blood_ml: np.ndarray) -> dict:
        """``state`` (N, state_dim), ``blood_ml`` (N, C) -> ``{agent: (N,)}`` (zeros for an agent without a term)."""
        xp = namespace(state)
        out = {agent: xp.zeros(len(state)) for agent in self.agents}
        if self.grasp.active:
            out["grasper"] = self.grasp.potential(state)
        if self.route.active:
            out["suction"] = self.route.potential(state, blood_ml)
        return out


class GraspPathShaping:
    """The grasper's guided-reward term (potential-based: Ng et al. 1999, F = Phi(s') - Phi(s) leaves the optimal
    policy unchanged; the env's own shaping has the same form). ``env``: the scene's facts (:class:`GuidedReward`).

    The env's dense reward pays the grasper for closing on the nearest pin (potential -10 x tip-to-pin distance) and,
    once it holds one, for bringing it to the hand-off point (-10 x pin-to-hand-off distance). At the grasp the second
    distance replaces the first, so closing the jaw costs about 0.8 at once and a grasp looks worse than no grasp to
    a young value function (measured: the grasper learnt to reach pins, grasp rarely and never carry). With ``weight``
    10 this potential turns the sum into the shortest path tip -> pin -> hand-off over the pending pins while the
    grasper holds nothing (continuous in the state, through the grasp too). ``hold_bonus`` adds that much potential
    while a pin is held: a drop then costs what the grasp earned, the only signal that says "keep the jaw closed"
    before the first delivery is ever seen.

    ``home``: while no pin is in view and none is held, the potential leads to the scripted surgeon's waiting place
    (above the phantom, beside the grasper's RCM) instead of nowhere. Measured without it: the grasper waited at
    table height beside the phantom and, once a pin showed, pushed into the phantom's side. (A pin's appearing is
    the suction's doing, not the grasper's: the potential's change then says nothing about the grasper's action.)

    ``cleared_only``: only pins in a cleared cavity are collected (the scripted surgeon's rule), and the env's own
    pull toward the others is cancelled. Measured without it: a grasper drifting toward pins revealed where the
    suction still worked touched it for 128 of 1,500 steps (return 1.75 against 14.5 for one keeping away) and
    learnt to keep away from every pin, in a corner of the workspace.

    ``centred``: a grasp must be one that can be delivered. The jaw takes a pin wherever its axis passes within 3 mm
    of the tip, anywhere along its 25 mm, and the hand-off point lies 2 mm inside the workspace's +x face: a pin held
    more than about 5 mm toward -x of the tip can never come within the 3 mm of the hand-off that delivery asks
    (the tip would have to leave the workspace). Measured: 28 % of a from-scratch grasper's grasps were such
    (it closed on a pin's end, sliding along the cavity floor), and it carried them to the workspace's face for the
    rest of the episode; the scripted surgeon closes on the pin's centre. So the way to a pin is measured over a point
    ``APPROACH_HEIGHT`` above its centre (a tip coming down there meets the axis at the centre), and a held pin's
    potential counts how far the tip would have to leave the workspace to deliver it (x ``UNDELIVERABLE_WEIGHT``),
    the hold bonus fading to nothing over the hand-off's 3 mm: a grasp by the end costs at once, its release pays
    that back.

    ``off_centre``: every grasp is charged by how far off the pin's centre it took the pin (the held pin's horizontal
    distance from the tip, x ``off_centre`` x ``weight`` per metre). Measured with ``centred`` alone: the learnt
    graspers' grasps sit a median 2.3-3.3 mm off-centre toward the hand-off side, deliverable in principle but only
    with the tip within 2 mm of the workspace's face; a collapsed grasper held such pins for 900 steps and delivered
    0.13 per episode. A centre grasp (the scripted surgeon's) costs nothing; releasing a bad one pays its charge back.

    With ``held_pin_at_grip`` (the scene's rule) the state shows a held pin where the hand-off judges it, the grip, within the
    jaw's sensor range of the tip: ``centred`` and ``off_centre`` then measure that point (a grasp anywhere along the
    pin can be delivered, and costs at most the few millimetres between the grip and the tip).
    """

    #: ``centred``: the approach point's height above a pin's centre (m): more than the jaw's 3 mm sensor range.
    APPROACH_HEIGHT = 0.005
    #: ``centred``: potential per metre the tip would have to leave the workspace to deliver the held pin, in units
    #: of ``weight`` per metre of path (a 12.5 mm end grasp then costs about the hold bonus again).
    UNDELIVERABLE_WEIGHT = 10.0

    def __init__(self, env, weight: float, agents, hold_bonus: float = 0.0, over_rims: bool = False,
                 home: bool = False, cleared_only: bool = False, centred: bool = False, off_centre: float = 0.0):
        env = env if isinstance(env, SceneFacts) else SceneFacts(env)
        self.over_rims = OverRims(env.cavities) if over_rims else None
        self.centre = np.asarray(env.params.workspace_centre)
        self.weight = float(weight)
        self.hold_bonus = float(hold_bonus)
        self.index = agents.index("grasper") if "grasper" in agents else None
        layout = env.state_layout
        self.tip = layout["grasper_tip"]
        self.debris = layout["debris"].start
        self.count = env.params.debris_count
        self.handoff = layout["handoff"]
        self.range = env.workspace_range
        self.home = (surgeon_waiting_place(env.layout, self.range) * self.range + self.centre) if home else None
        self.cleared_only = bool(cleared_only)
        self.centred = bool(centred)
        self.off_centre = float(off_centre)
        if not self.off_centre >= 0.0:
            raise ValueError(f"off_centre must be >= 0, got {off_centre!r}")
        self.delivery_threshold = float(env.params.distance_threshold)
        scene = env.layout
        self.cavity_centres = np.asarray(scene.cavity_centres)  # normalised, as the state's positions
        self.clear_fraction = np.asarray(scene.blood_threshold_fraction)
        self.blood = layout["blood"]

    @property
    def active(self) -> bool:
        return (self.weight > 0.0 or self.hold_bonus > 0.0) and self.index is not None

    def potential(self, state: np.ndarray) -> np.ndarray:
        xp = namespace(state)
        debris = state[:, self.debris:self.debris + layout.PIN_WIDTH * self.count].reshape(len(state), self.count,
                                                                                            layout.PIN_WIDTH)
        tip = state[:, None, self.tip]
        handoff = state[:, None, self.handoff]
        visible, held = debris[..., layout.PIN_VISIBLE] > 0.5, debris[..., layout.PIN_HELD] > 0.5
        delivered = debris[..., layout.PIN_DELIVERED] > 0.5
        pending = visible & ~delivered & ~held
        to_pin = _length(debris[..., layout.PIN_POSITION] - tip) * self.range
        to_handoff = _length(debris[..., layout.PIN_POSITION] - handoff) * self.range
        rise = xp.asarray([0.0, 0.0, self.APPROACH_HEIGHT / self.range if self.centred else 0.0])
        approach = debris[..., layout.PIN_POSITION] + rise  # centred: come down onto the pin's centre from above it
        # The env's potential is -10 x (distance to the nearest pin); this term replaces it by the shortest path
        # tip -> pin -> hand-off over the pins to collect, a continuous function of the state.
        env_term = xp.where(pending.any(axis=1), xp.where(pending, to_pin, xp.inf).min(axis=1), 0.0)
        targets = pending & self._in_cleared_cavity(state, debris) if self.cleared_only else pending
        holding = held.any(axis=1)
        live = targets.any(axis=1) & ~holding
        carry = xp.zeros(len(state))
        height = self.APPROACH_HEIGHT if self.centred else 0.0
        if self.over_rims is None:
            to_approach = _length(approach - tip) * self.range + height if self.centred else to_pin
            path = xp.where(targets, to_approach + to_handoff, xp.inf).min(axis=1)
        else:  # the same path, measured around the phantom (and the carry too)
            world = lambda x: x * self.range + self.centre  # noqa: E731
            pins, tip_w, handoff_w = world(debris[..., layout.PIN_POSITION]), world(tip), world(handoff)
            to_pin_geo = self.over_rims.distance(tip_w, world(approach)) + height
            to_handoff_geo = self.over_rims.distance(pins, handoff_w)
            path = xp.where(targets, to_pin_geo + to_handoff_geo, xp.inf).min(axis=1)
            carry = xp.where(held, to_handoff_geo - to_handoff, 0.0).sum(axis=1)  # env's carry term: straight
        idle = ~targets.any(axis=1) & ~holding
        way_home = xp.zeros(len(state))
        if self.home is not None:  # nothing to collect or carry: the way to the waiting place
            tip_w = tip[:, 0] * self.range + self.centre
            way_home = self.over_rims.distance(tip_w, self.home) if self.over_rims is not None else _length(
                tip_w - self.home)
        # idle: the env's pull toward pins not to be collected yet (cleared_only) is cancelled
        detour = (xp.where(live, xp.where(live, path, 0.0) - env_term, 0.0) + xp.where(idle, way_home - env_term, 0.0)
                  + xp.where(holding, carry, 0.0))
        bonus = self.hold_bonus * holding
        if self.centred:
            beyond = self._beyond_workspace(debris, tip[:, 0], handoff[:, 0], held)
            detour = detour + self.UNDELIVERABLE_WEIGHT * beyond
            bonus = bonus * xp.clip(1.0 - beyond / self.delivery_threshold, 0.0, 1.0)
        if self.off_centre > 0.0:  # the held pin's horizontal distance from the tip: 0 for a grasp at its centre
            pin = (debris[..., layout.PIN_POSITION] * held[..., None]).sum(axis=1)  # at most one pin is held
            off = xp.sqrt(_squared_2d((pin - tip[:, 0])[:, :2])) * self.range
            detour = detour + self.off_centre * xp.where(holding, off, 0.0)
        return -self.weight * detour + bonus

    def _beyond_workspace(self, debris, tip, handoff, held) -> np.ndarray:
        xp = namespace(debris)
        """(N,): how far (m) the tip would have to leave the workspace (the box [-1, 1] in normalised units) to bring
        the held pin onto the hand-off point, keeping its grasp; 0 when nothing is held."""
        pin = (debris[..., layout.PIN_POSITION] * held[..., None]).sum(axis=1)  # at most one pin is held
        needed = handoff - (pin - tip)
        outside = _length(needed - xp.clip(needed, -1.0, 1.0)) * self.range
        return xp.where(held.any(axis=1), outside, 0.0)

    def _in_cleared_cavity(self, state, debris) -> np.ndarray:
        xp = namespace(state)
        """(N, D): whether each pin lies in a cavity below its clearing threshold (the cavity nearest it)."""
        horizontal = debris[..., None, 0:2] - self.cavity_centres  # (N, D, C, 2)
        cavity = (horizontal * horizontal).sum(-1).argmin(-1)  # (N, D)
        blood = state[:, self.blood]
        cleared = (blood < self.clear_fraction) | (blood <= 0.0)  # (N, C)
        return xp.take_along_axis(cleared, cavity, axis=1)


class OverRims:
    """Distances for a tip that cannot pass through the phantom: the length of the way up out of a cavity, across
    above the phantom's top, and down into another (vertical legs; exact enough for a potential); a point beside the
    phantom, below its top, rises the same way. Within one cavity, or between two points above the phantom's top
    outside every cavity, the straight line is clear (the bowl is convex) and is used.

    Why: the env's potentials measure straight lines. Between the two cavities the straight line runs through the
    phantom, and a tip pushing along it is held at the rim (the env refuses a horizontal move into a steep wall); a
    deterministic policy that learnt with noise stays there for the rest of the episode (measured: with the straight
    route the suction cleared both cavities in 76 % of episodes with noise and 12 % without; the stuck ones sat on a
    rim, pushing down toward the other cavity's floor).
    """

    #: The region of a point beside the phantom below its top (its sides are walls too; measured: a grasper that
    #: waited there pushed into the side toward a pin for the rest of the episode).
    BESIDE = -2

    def __init__(self, cavities, margin: float = 0.002):
        """``cavities``: a :class:`~dvrl_marl.suction_debris.rules.Cavities`, or an env (its scene's)."""
        if not isinstance(cavities, Cavities):
            cavities = SceneFacts(cavities).cavities
        self.cavities = cavities
        self.phantom = self.cavities.phantom
        self.height = self.phantom.top_z + margin  # margin above the top: the tip clearance and a bit

    def _lift(self, point, region):
        xp = namespace(point)
        z = xp.where(region != -1, xp.maximum(point[..., 2], self.height), point[..., 2])
        if xp is not np:
            return xp.concatenate([point[..., :2], z[..., None]], axis=-1)
        lifted = np.array(point, dtype=np.float64)  # (numpy: a copy set in place, cheaper than a concatenation)
        lifted[..., 2] = z
        return lifted

    def region(self, point) -> np.ndarray:
        xp = namespace(point)
        """The cavity a point lies over (its index), BESIDE the phantom below its top, or -1 (above the top)."""
        p = self.phantom
        beside = ((xp.abs(point[..., 0] - p.centre_x) > p.half_x) | (xp.abs(point[..., 1] - p.centre_y) > p.half_y)) & (
            point[..., 2] < p.top_z)
        return xp.where(beside, self.BESIDE, self.cavities.cavity_at(point[..., 0], point[..., 1]))

    def distance(self, start, goal) -> np.ndarray:
        """``start``, ``goal``: (..., 3) world positions (broadcast) -> (...) path lengths."""
        xp = namespace(start, goal)
        start, goal = xp.broadcast_arrays(start, goal)
        from_cavity = self.region(start)
        to_cavity = self.region(goal)
        straight = _length(goal - start)
        up, down = self._lift(start, from_cavity), self._lift(goal, to_cavity)
        around = _length(up - start) + _length(down - up) + _length(goal - down)
        return xp.where(from_cavity == to_cavity, straight, around)

    def point_along(self, start, goal, fraction):
        """The point ``fraction`` of the way (the one :meth:`distance` measures) from ``start`` to ``goal``: straight
        within a region, else up to just above the top, across, and down. ``start``, ``goal``: (..., 3) world
        positions, ``fraction`` (...) in [0, 1]; any array library's arrays."""
        xp = namespace(start, goal)
        from_region, to_region = self.region(start), self.region(goal)
        same = (from_region == to_region)[..., None]
        # four corners; within one region the middle leg is the whole way and the outer ones have no length
        corners = (start, xp.where(same, start, self._lift(start, from_region)),
                   xp.where(same, goal, self._lift(goal, to_region)), goal)
        legs = [_length(corners[k + 1] - corners[k]) for k in range(3)]
        travelled = fraction * (legs[0] + legs[1] + legs[2])
        second = travelled - legs[0]
        third = second - legs[1]
        on_first = corners[0] + (corners[1] - corners[0]) * (travelled / xp.maximum(legs[0], 1e-12))[..., None]
        on_second = corners[1] + (corners[2] - corners[1]) * (second / xp.maximum(legs[1], 1e-12))[..., None]
        last = corners[2] + (corners[3] - corners[2]) * xp.minimum(third / xp.maximum(legs[2], 1e-12), 1.0)[..., None]
        return xp.where((travelled <= legs[0])[..., None], on_first,
                        xp.where((second <= legs[1])[..., None], on_second, last))


class SuctionRouteShaping:
    """The suction's guided-reward term (potential-based, F = Phi(s') - Phi(s), as the env's own dense shaping).

    The env's dense reward pays the suction for closing on the nearest cavity that still holds blood (potential -10 x
    tip-to-floor distance) and for each millilitre removed. When a cavity falls below the clearing threshold its
    target jumps to the other cavity: the potential drops by about 10 x the distance between them (about 0.6) at
    the very step that clears it, and the dense reward has no term for clearing. A cavity left at 0.51 ml costs
    nothing, one cleared costs 0.6: a learner takes every millilitre but the last one (measured: 12-15 ml of 16
    removed, success swinging between 0 and 0.5, and runs collapsing to no suction at all). With ``weight`` 10 this
    term turns the env's potential into the length of the route from the tip over every cavity still to clear
    (continuous when one clears), and ``clear_bonus`` adds that much potential per cleared cavity (a refill, as by
    bleeding, takes it back).

    ``park``: the route ends at the scripted suction's parking place (on its own side, above the phantom), so once
    every cavity is clear the potential still points somewhere: out of the surgeon's way. Measured without it: a
    suction that cleared both cavities stayed in the last one, where the surgeon then picks, ran up 285 contact
    steps per episode and, to escape their penalty, learnt to flee to a corner and suck nothing (success 0.49 at
    3M steps, 0 ml removed from 4M on). The leg joins the route continuously (the last cavity's floor to the park),
    and the visiting order it favours (the far cavity first, ending near the park) is the scripted expert's.
    """

    def __init__(self, env, weight: float, agents, clear_bonus: float = 0.0, over_rims: bool = False,
                 park: bool = False, clot_broken: float = 0.0):
        env = env if isinstance(env, SceneFacts) else SceneFacts(env)
        # a scene with clots: -clot_broken per ml of clot left (the state's clot slots: shares of each capacity)
        self.clot = env.state_layout.get("clot")
        self.clot_broken = float(clot_broken) if self.clot is not None else 0.0
        self.capacity = np.asarray(env.cavities.capacity_ml, dtype=np.float64)
        self.over_rims = OverRims(env.cavities) if over_rims else None
        self.weight = float(weight)
        self.clear_bonus = float(clear_bonus)
        self.index = agents.index("suction") if "suction" in agents else None
        self.tip = env.state_layout["suction_tip"]
        self.range = env.workspace_range
        self.centre = np.asarray(env.params.workspace_centre)
        self.threshold = env.params.blood_threshold_ml
        cavities = env.cavities
        self.floors = np.stack([cavities.centre_x, cavities.centre_y, cavities.floor_z], axis=1)  # (C, 3)
        self.orders = np.array(list(itertools.permutations(range(len(self.floors)))))  # (P, C)
        self.park = (suction_parking_place(env.layout, self.range) * self.range + self.centre) if park else None
        self.between = self._measure(self.floors[:, None, :], self.floors[None])  # (C, C): floor to floor
        self.floor_to_park = self._measure(self.floors, self.park) if park else None  # (C,)

    @property
    def active(self) -> bool:
        return (self.weight > 0.0 or self.clear_bonus > 0.0 or self.clot_broken > 0.0) and self.index is not None

    def potential(self, state: np.ndarray, blood_ml: np.ndarray) -> np.ndarray:
        """``state``: (N, state_dim); ``blood_ml``: (N, C), each cavity's remaining blood."""
        xp = namespace(state)
        tip = state[:, self.tip] * self.range + self.centre
        pending = (blood_ml >= self.threshold) & (blood_ml > 0.0)
        to_floor = _length(tip[:, None, :] - self.floors[None])  # (N, C)
        nearest = xp.where(pending, to_floor, xp.inf).min(axis=1)
        nearest = xp.where(pending.any(axis=1), nearest, 0.0)
        # shortest route tip -> every pending cavity, over the visiting orders (2 cavities: 2 orders); only the
        # first leg starts at the tip, the others join fixed points (measured once, in __init__)
        measure = self._measure
        from_tip = measure(tip[:, None, :], self.floors[None])  # (N, C)
        to_park = measure(tip, self.park) if self.park is not None else None
        route = xp.full(len(state), xp.inf)
        for order in self.orders:
            length = xp.zeros(len(state))
            here = xp.full(len(state), -1)  # -1: the tip, else the cavity whose floor the route has reached
            for cavity in order:
                leg = xp.where(here < 0, from_tip[:, cavity], xp.asarray(self.between)[xp.maximum(here, 0), cavity])
                length = length + xp.where(pending[:, cavity], leg, 0.0)
                here = xp.where(pending[:, cavity], cavity, here)
            if self.park is not None:
                length = length + xp.where(here < 0, to_park, xp.asarray(self.floor_to_park)[xp.maximum(here, 0)])
            route = xp.minimum(route, length)
        cleared = (~pending).sum(axis=1)
        potential = -self.weight * (route - nearest) + self.clear_bonus * cleared
        if self.clot_broken > 0.0:
            clot_ml = (state[:, self.clot] * xp.asarray(self.capacity, dtype=state.dtype)).sum(axis=1)
            potential = potential - self.clot_broken * clot_ml
        return potential

    def _measure(self, start, goal):
        if self.over_rims is None:
            return _length(goal - start)
        return self.over_rims.distance(start, goal)
