"""How a blocked move resolves (``blocked_moves`` of the task file; ``"settle"`` in ``suction_debris_v8``): it
slides, it does not stop.

A move that a cavity's wall, the joint limits or the other instrument blocks could simply stop (``"stop"``, the
simple rule, kept as a keyword): the tip keeps its horizontal position at a wall, stays where it was when the
instruments would intersect, and goes as far as it can along the move at a joint limit. A policy whose mean action
pushes into such a blocker then sees the same observation again and sends the same action again, for the rest of the
episode (measured: 87 of 89 failed test episodes of a MAPPO team acting by its mean action ended with the suction
motionless for 100+ steps against a blocker; its exploration noise had shaken it loose in training). No robot adds
exploration noise to its commands, so the scene resolves contacts as a frictionless constraint does (a
forbidden-region virtual fixture). The rules, each adding to the ones before it:

- ``slide``. **A cavity's wall** is a sphere (the bowl, :class:`~dvrl_marl.suction_debris.rules.Cavities`): the move's
  component into it is taken away and the rest slides along it (``d - min(d.n, 0) n``, ``n`` the wall's normal at
  the tip, toward the sphere's centre). Its upward part lifts a tip pushed outward over the rim, as a tool tip
  pressed sideways against a bowl rides up its side. The phantom's vertical sides stay walls (a horizontal push
  into a vertical wall has no component along it). **The other instrument or the joint limits**
  (:func:`resolve_blocked`), when the move is refused, or cut short with no progress: first the move less its
  component into the other instrument (the normal where the two come closest), then that step lifted off the contact
  by a tenth of its length (a step along a round shaft enters it a little), then the move's components given up one
  at a time, the smallest first, then all but one, the largest first (:func:`fallback_moves`). A candidate beyond the
  joint limits goes where the outer joints (yaw, pitch, insertion) clamped to their limits put the wrist (the arm
  slides along its limit). The first candidate that keeps the tip in the box, above the surface, within the joint
  limits and clear of the other instrument is made. Only if none does does the tip stay.
- ``climb``: **a descending move that the surface and the wall slide leave (almost) nothing of gives up its
  descent**, and its level part is made as any move (slid along the wall). A tip pressed out of a cavity and down
  against the bowl, along the wall's normal, made no headway under the frictionless rule (measured: the commonest end
  of the episodes learnt teams failed by their mean action, both arms heading for the other cavity); with it the tip
  rides up the wall the way it was heading and over the rim. A move that makes headway is unchanged.
- ``climb_ahead`` (``ahead``): a descent's headway, for a move with a level part, is what its made part advances the
  way that level part heads, and the descent is given up only where the level part gets further that way. Pressed
  almost along the wall's normal, a tip otherwise climbed one step and then slipped back down the bowl on the rest of
  the move (made, though away from where it heads), a cycle in place (measured: the commonest end of the episodes
  learnt BenchMARL teams failed by their mean action under ``climb``); with it the tip keeps climbing the way it heads.
- ``settle`` (the suction's moves only): **a descending move that still makes less than a tenth of its length slides
  down the bowl** (over a cavity: its component into the bowl taken away, :func:`wall_slide`, on the gentle slopes as
  on the steep walls). On a slope a tip may climb by a step, the rules above keep a move's horizontal part and lift
  the tip onto the surface, so a command straight down was made as nothing: a suction pressed down a few millimetres
  above the last of a cavity's blood, above the pool, stayed there (measured: the commonest end of the episodes a
  learnt BenchMARL team failed by its mean action under ``climb_ahead``). A grasper pressing down onto a pin must
  stay over it, so its moves follow ``climb_ahead``.

Every rule here is a function of the tip's position and the command: deterministic, the same for one world and for
N (the single env calls these functions on one row).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dvrl_marl import kinematics
from dvrl_marl.core.backend import columns, namespace, needed, scan
from dvrl_marl.suction_debris.instruments import contact_normal, instrument_clearance

__all__ = ["MoveRules", "BLOCKED_MOVES", "wall_slide", "surface_target", "fallback_moves", "resolve_blocked", "OUTER_JOINTS", "CONTACT_LIFT",
           "NO_HEADWAY"]

#: The lift off the other instrument of a step along it, per unit of the step's length (see :func:`resolve_blocked`).
CONTACT_LIFT = 0.1
#: ``climb``: a move whose made part is shorter than this share of it made no headway.
NO_HEADWAY = 0.1
#: numpy: blocked moves of at most this many rows x candidates are tried all at once (a numpy call on a few hundred
#: rows costs about what one on a single row does), more one candidate after another, stopping once every row has
#: made one. Measured side by side (farm-bench, one core): one world pressing into blockers every step 2.2x faster,
#: N = 4,096 worlds of random actions unchanged (1.01x); the choice is the same row by row (tests/test_sliding_at_once.py).
ALL_AT_ONCE_ROWS = 1024
#: The joints that place the wrist (outer yaw, outer pitch, insertion); the wrist joints keep the tool pointing down.
OUTER_JOINTS = 3


#: The task files' ``blocked_moves`` values, each adding its rule to those before it.
BLOCKED_MOVES = ("stop", "slide", "climb", "climb_ahead", "settle")


@dataclass(frozen=True)
class MoveRules:
    """Which of this module's rules one arm's moves follow (:meth:`of` a ``blocked_moves`` value): the one place
    that says so, for the batched core and the single env alike."""

    slide: bool = False  # blocked moves slide (:func:`resolve_blocked`, :func:`wall_slide`)
    climb: bool = False  # a descent without headway gives up its descent
    ahead: bool = False  # headway counted the way the move heads
    settle: bool = False  # the suction's descent still without headway slides down the bowl

    @classmethod
    def of(cls, blocked_moves: str, agent: str) -> MoveRules:
        if blocked_moves not in BLOCKED_MOVES:
            raise ValueError(f"blocked_moves must be one of {', '.join(BLOCKED_MOVES)}, got {blocked_moves!r}")
        level = BLOCKED_MOVES.index(blocked_moves)
        # a grasper pressing down onto a pin must stay over it: the settle is the suction's alone
        return cls(slide=level >= 1, climb=level >= 2, ahead=level >= 3, settle=level >= 4 and agent == "suction")

    @property
    def descents(self) -> dict:
        """The keyword arguments of :func:`surface_target` and :func:`resolve_blocked` these rules set."""
        return {"climb": self.climb, "ahead": self.ahead, "settle": self.settle}


def wall_slide(cavities, old, delta):
    """``delta`` (N, 3) less its component into the wall of the cavity that ``old`` (N, 3, world) lies over (the
    sphere's inward normal at the tip); unchanged for a tip over no cavity or a move away from the wall."""
    xp = namespace(old, delta)
    cavity = cavities.cavity_at(old[:, 0], old[:, 1])
    over = cavity >= 0
    index = xp.maximum(cavity, 0)
    radius = cavities.per_cavity(cavities.sphere_radius, index)
    centre = columns((cavities.per_cavity(cavities.centre_x, index), cavities.per_cavity(cavities.centre_y, index),
                      cavities.phantom.top_z - cavities.per_cavity(cavities.depth, index) + radius), xp)
    normal = centre - old
    length = xp.sqrt(xp.sum(normal * normal, axis=1))
    normal = normal / xp.maximum(length, 1e-12)[:, None]
    into = xp.minimum(xp.sum(delta * normal, axis=1), 0.0)
    return xp.where(over[:, None], delta - into[:, None] * normal, delta)


_LEVEL = np.array([1.0, 1.0, 0.0])  # keeps a move's level part


def _length(v, xp):
    return xp.sqrt(xp.sum(v * v, axis=1))


def surface_target(cavities, tip_clearance: float, step: float, low, high, old, delta, slide_on_walls: bool = True,
                   climb: bool = False, ahead: bool = False, settle: bool = False):
    """Where a tip at ``old`` (N, 3, world) commanded by ``delta`` goes against the box and the phantom: clamped to
    the box ``[low, high]``; below the surface, up a slope of at most one ``step`` onto it; against a steeper wall
    slid along it (:func:`wall_slide`), then, if the move still enters the wall, only its vertical part (all that
    ``stop`` makes of it: ``slide_on_walls=False``). ``climb``: a descending move of which these rules make less
    than :data:`NO_HEADWAY` of its length gives up its descent (its level part, made by the same rules, instead).
    ``ahead``: for a move with a level part (at least :data:`NO_HEADWAY` of it), the headway is what the made
    part advances the way the move heads, level (a slide back down the wall, away from where it heads, is none), and
    the level part replaces the move only where it advances further that way (a descent pressed into the box's face
    is made as under ``climb``). ``settle``: a descending move that still makes less than :data:`NO_HEADWAY` of its
    length, over a cavity, slides down the bowl where that makes more (its component into the wall taken away,
    :func:`wall_slide`, on the gentle slopes too)."""
    xp = namespace(old, delta)
    target = _surface_target(cavities, tip_clearance, step, low, high, old, delta, slide_on_walls)
    if climb:
        length = _length(delta, xp)
        made = _length(target - old, xp)
        level = delta * _LEVEL if xp is np else delta * xp.asarray(_LEVEL, dtype=delta.dtype)
        heading = xp.zeros(delta.shape[:1], dtype=xp.bool)
        if ahead:  # a move with a level part: the made part's advance the way it heads
            level_length = _length(level, xp)
            heading = level_length >= NO_HEADWAY * length
            advance = xp.sum((target - old) * level, axis=1) / xp.maximum(level_length, 1e-300)
            made = xp.where(heading, advance, made)
        stalled = (delta[:, 2] < 0.0) & (made < NO_HEADWAY * length)
        if needed(stalled):
            climbed = _surface_target(cavities, tip_clearance, step, low, high, old, level, slide_on_walls)
            if ahead:  # only where the level part gets further that way (not into the box's face, say)
                further = xp.sum((climbed - old) * level, axis=1) / xp.maximum(level_length, 1e-300) > made
                stalled = stalled & (~heading | further)
            target = xp.where(stalled[:, None], climbed, target)
    if settle:
        length = _length(delta, xp)
        made = _length(target - old, xp)
        resting = (delta[:, 2] < 0.0) & (made < NO_HEADWAY * length)
        if needed(resting):  # (the cavity lookup only then: most steps make headway)
            resting = resting & (cavities.cavity_at(old[:, 0], old[:, 1]) >= 0)
            settled = _surface_target(cavities, tip_clearance, step, low, high, old, wall_slide(cavities, old, delta),
                                      slide_on_walls)
            resting = resting & (_length(settled - old, xp) > made)  # never less than ``ahead`` makes
            target = xp.where(resting[:, None], settled, target)
    return target


def _surface_target(cavities, tip_clearance, step, low, high, old, delta, slide_on_walls):
    """:func:`surface_target` without ``climb``."""
    xp = namespace(old, delta)

    def floor(x, y):
        return cavities.surface_height(x, y) + tip_clearance

    target = xp.minimum(xp.maximum(old + delta, low), high)
    ground = floor(target[:, 0], target[:, 1])
    into_wall = (target[:, 2] < ground) & (ground - old[:, 2] > step + 1e-12)
    if slide_on_walls and needed(into_wall):
        slid = xp.minimum(xp.maximum(old + wall_slide(cavities, old, target - old), low), high)
        target = xp.where(into_wall[:, None], slid, target)
        ground = floor(target[:, 0], target[:, 1])
    x, y, z = target[:, 0], target[:, 1], target[:, 2]
    below = z < ground
    if needed(below):
        gentle = below & (ground - old[:, 2] <= step + 1e-12)
        wall = below & ~gentle
        x = xp.where(wall, old[:, 0], x)
        y = xp.where(wall, old[:, 1], y)
        z = xp.where(gentle, ground, xp.where(wall, xp.maximum(z, floor(old[:, 0], old[:, 1])), z))
        target = columns((x, y, z), xp)
    return target


def fallback_moves(delta) -> list:
    """The moves a blocked ``delta`` (N, 3) falls back to, in order: without its smallest component, without its
    middle one, without its largest; then its largest alone, its middle one alone, its smallest alone (ties: x
    before y before z). A zero row stays zero."""
    xp = namespace(delta)
    order = xp.argsort(xp.abs(delta), axis=1, stable=True)  # smallest first
    axes = xp.arange(3)[None, :]
    keep_sets = ([1, 2], [0, 2], [0, 1], [2], [1], [0])  # positions in ``order`` kept
    moves = []
    for keep in keep_sets:
        kept = (axes == order[:, keep[0]][:, None])
        for position in keep[1:]:
            kept = kept | (axes == order[:, position][:, None])
        moves.append(delta * xp.astype(kept, delta.dtype))
    return moves


def _clamped_to_joint_limits(tool, base, target):
    """Where ``target`` (M, 3, world) goes with the outer joints clamped to their limits: the wrist where the clamped
    joints put it, the tip at the same offset from it as the unclamped solution's."""
    xp = namespace(target)
    q, _ = kinematics.inverse_kinematics_batch(tool, target - base)
    lower = xp.asarray(tool.lower[:OUTER_JOINTS], dtype=q.dtype)
    upper = xp.asarray(tool.upper[:OUTER_JOINTS], dtype=q.dtype)
    clamped = xp.concat([xp.minimum(xp.maximum(q[:, :OUTER_JOINTS], lower), upper), q[:, OUTER_JOINTS:]], axis=1)
    offset = target - base - kinematics.wrist_position_batch(tool, q)  # wrist to tip, kept
    return kinematics.wrist_position_batch(tool, clamped) + offset + base


def resolve_blocked(arm: dict, other: dict, is_suction: bool, delta, cavities, tip_clearance: float, step: float,
                    low, high, climb: bool = False, ahead: bool = False, settle: bool = False):
    """The slide of M blocked moves: ``arm`` and ``other`` ``{"tool", "base" (3,), "tip" (M, 3)}`` (world, before
    the move; the other instrument's shaft follows from its tip, as the joints do), ``delta`` (M, 3) the commanded
    move. Returns ``(made (M,), tip (M, 3) world, q (M, n), clearance (M,))`` for the first candidate of each row
    that can be made (rows not made: unchanged, clearance NaN). ``climb``, ``ahead``, ``settle``:
    :func:`surface_target`'s (``climb``, ``ahead``, ``settle``)."""
    tool, base, start = arm["tool"], arm["base"], arm["tip"]
    xp = namespace(start, delta)

    def segment(tool, base, tip):
        joints, reachable = kinematics.inverse_kinematics_batch(tool, tip - base)
        return (base, kinematics.wrist_position_batch(tool, joints) + base, tip), joints, reachable

    # Joints from the tips by the batched IK, not the arms' stored joints: the single env solves its joints with
    # scalar math, and the last bits of the shafts must not make one world slide otherwise than its batched twin.
    own_start, start_q, _ = segment(tool, base, start)
    partner, _, _ = segment(other["tool"], other["base"], other["tip"])
    normal = contact_normal(*own_start, *partner) if is_suction else contact_normal(*partner, *own_start)
    into = xp.minimum(xp.sum(delta * normal, axis=1), 0.0)
    along = delta - into[:, None] * normal
    # A step along a round shaft in contact enters it by about step^2 / (2 x radius) (0.06 mm for 1 mm on the
    # 8.5 mm shaft): the same step lifted off the contact by a tenth of its length clears that.
    lifted = along + (CONTACT_LIFT * _length(delta, xp) * xp.astype(into < 0.0, delta.dtype))[:, None] * normal
    candidates = [delta, along, lifted, *fallback_moves(delta)]

    def evaluate(start, partner, move, first, live):
        """Each row's candidate ``move`` from ``start``: ``(accept, target, joints, gap)``, accepted where it can be
        made (``live`` rows only; ``first``: the blocked move itself, which only a slide along the limits changes)."""
        target = surface_target(cavities, tip_clearance, step, low, high, start, move, climb=climb, ahead=ahead,
                                settle=settle)
        own, joints, reachable = segment(tool, base, target)
        live = xp.where(first, live & ~reachable, live)
        if not needed(live):
            return live, target, joints, None
        if needed(live & ~reachable):
            slid = _clamped_to_joint_limits(tool, base, target)
            slid = xp.minimum(xp.maximum(slid, low), high)
            above = slid[:, 2] >= cavities.surface_height(slid[:, 0], slid[:, 1]) + tip_clearance
            target = xp.where((~reachable & above)[:, None], slid, target)
            own, joints, reachable = segment(tool, base, target)
        moved = xp.any(target != start, axis=1)
        gap = instrument_clearance(*own, *partner) if is_suction else instrument_clearance(*partner, *own)
        return live & moved & reachable & (gap >= 0.0), target, joints, gap

    if xp is np and len(delta) * len(candidates) <= ALL_AT_ONCE_ROWS:
        # numpy, few rows (one world, or a few stuck ones): every candidate of every row in one call (a call costs
        # what a row does here), then each row's first that can be made: the loop's choice, row by row
        count, rows = len(candidates), len(delta)
        moves = np.concatenate(candidates)
        first = np.repeat(np.arange(count) == 0, rows)
        tiled = (partner[0], np.tile(partner[1], (count, 1)), np.tile(partner[2], (count, 1)))
        accept, target, joints, gap = evaluate(np.tile(start, (count, 1)), tiled, moves, first,
                                               np.any(moves != 0.0, axis=1))
        accept = accept.reshape(count, rows)
        made = accept.any(axis=0)
        pick = np.argmax(accept, axis=0) * rows + np.arange(rows)  # the first accepted candidate's row
        tip = np.where(made[:, None], target[pick], start)
        q = np.where(made[:, None], joints[pick], start_q)
        clearance = np.where(made, gap[pick] if gap is not None else np.nan, np.nan)
        return made, tip, q, clearance

    def attempt(carry, item):
        made, tip, q, clearance = carry
        move, first = item
        live = ~made & xp.any(move != 0.0, axis=1)
        if not needed(live):
            return carry
        accept, target, joints, gap = evaluate(start, partner, move, first, live)
        if gap is None:  # (nothing left to try in this candidate)
            return carry
        return (made | accept, xp.where(accept[:, None], target, tip), xp.where(accept[:, None], joints, q),
                xp.where(accept, gap, clearance))

    # one candidate after another (numpy: stopping once every row has made one; JAX: lax.scan, compiled once)
    first = np.arange(len(candidates)) == 0
    if xp is not np:
        first = xp.asarray(first)
    made, tip, q, clearance = scan(attempt, (xp.zeros(delta.shape[:1], dtype=xp.bool), start, start_q,
                                             xp.full(delta.shape[:1], float("nan"), dtype=delta.dtype)),
                                   (xp.stack(candidates), first), until=lambda carry: bool(np.all(carry[0]))
                                   if isinstance(carry[0], np.ndarray) else False)
    return made, tip, q, clearance
