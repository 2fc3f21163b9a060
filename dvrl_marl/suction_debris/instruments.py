"""The two instruments as segments, for contact: an RCM-to-wrist shaft and a wrist-to-tip segment per arm.

Shared by the collaborative scene's batched core (contact and the refusal of intersecting moves) and the sliding rules
(:mod:`dvrl_marl.suction_debris.sliding`: the contact's normal), batched over leading axes. Written against the Python array API
standard (``array_api_compat.array_namespace``): the same functions take numpy arrays (the default), torch tensors
on a CPU or a GPU, or JAX arrays (under ``jax.jit`` too), and give each the same floating-point results
(``benchmarks/backend_prototype.py`` measures them on each).
"""

from __future__ import annotations

import numpy as np
import array_api_compat.numpy  # noqa: F401  (numpy's namespace, loaded now rather than on the first step)

from dvrl_marl import assets
from dvrl_marl.core.backend import namespace
from dvrl_marl.suction_debris.layout import MOVE

__all__ = ["SHAFT_RADIUS", "WRIST_RADIUS", "segment_distance", "segment_offset", "instrument_clearance",
           "contact_normal", "withheld_moves", "keep_clear"]

#: Radii used for instrument-instrument contact: the 8.5 mm shaft and the wrist/tube segment beyond it.
SHAFT_RADIUS = assets.SHAFT_RADIUS
WRIST_RADIUS = {"suction": assets.SUCTION_TUBE_RADIUS, "grasper": 0.0025}




def _dot(u, v):
    return u[..., 0] * v[..., 0] + u[..., 1] * v[..., 1] + u[..., 2] * v[..., 2]


def _clip01(x, xp):
    if xp is np:
        return np.minimum(np.maximum(x, 0.0), 1.0)
    return xp.clip(x, 0.0, 1.0)  # (the same values; a scalar bound is what every array_api_compat release takes)


def _divide(numerator, denominator, safe, xp):
    """``numerator / denominator`` where ``safe`` (elsewhere any value: the caller discards it), never dividing by
    zero on any backend (numpy divides only where it may; the others by 1 elsewhere)."""
    if xp is np:
        return np.divide(numerator, denominator, out=np.zeros_like(numerator), where=safe)
    return numerator / xp.where(safe, denominator, 1.0)


def segment_distance(p1, q1, p2, q2, xp=None):
    """Shortest distances between segments p1-q1 and p2-q2, batched over leading axes (..., 3)."""
    xp = xp or namespace(p1, q1, p2, q2)
    difference = segment_offset(p1, q1, p2, q2, xp)
    return xp.sqrt(_dot(difference, difference))


def withheld_moves(tip, step, other, own_centre, other_centre, keep: float):
    """The moves a seat that waits does not make: moving its tip by ``step`` would bring its instrument (the axis from
    its remote centre of motion to its tip) within ``keep`` of the other's and nearer than it is now; ``(...,)``
    bools. The scripted yielding suction's rule, and a policy's ``keep_clear`` (:mod:`dvrl_marl.policies`)."""
    now = segment_distance(tip, own_centre, other, other_centre)
    after = segment_distance(tip + step, own_centre, other, other_centre)
    return (after < keep) & (after < now)


def keep_clear(action, observation, rule: dict):
    """``action`` ``(..., A)`` with its motion (the first three values) withheld by :func:`withheld_moves` where
    ``rule`` (a policy's ``keep_clear`` table: :func:`dvrl_marl.suction_debris.scripted_team.keep_clear_rule`) says so, the
    tips read from ``observation`` ``(..., d)``; numpy, a new array."""
    tip, other = observation[..., slice(*rule["own_tip"])], observation[..., slice(*rule["other_tip"])]
    withheld = withheld_moves(tip, action[..., MOVE] / rule["gain"], other, np.asarray(rule["own_centre"]),
                              np.asarray(rule["other_centre"]), rule["keep"])
    action = np.array(action, copy=True)
    action[..., MOVE] = np.where(withheld[..., None], 0.0, action[..., MOVE])
    return action


def segment_offset(p1, q1, p2, q2, xp=None):
    """From the point of segment p2-q2 nearest segment p1-q1 to the point of p1-q1 nearest it, (..., 3)."""
    xp = xp or namespace(p1, q1, p2, q2)
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f, c, b = _dot(d1, d1), _dot(d2, d2), _dot(d2, r), _dot(d1, r), _dot(d1, d2)
    denominator = a * e - b * b
    general, e_ok, a_ok = denominator > 1e-18, e > 1e-18, a > 1e-18
    s = xp.where(general, _clip01(_divide(b * f - c * e, denominator, general, xp), xp), 0.0)
    t = xp.where(e_ok, _divide(b * s + f, e, e_ok, xp), 0.0)
    below, above = t < 0.0, t > 1.0
    s = xp.where(below, xp.where(a_ok, _clip01(_divide(-c, a, a_ok, xp), xp), 0.0), s)
    s = xp.where(above, xp.where(a_ok, _clip01(_divide(b - c, a, a_ok, xp), xp), 0.0), s)
    t = xp.where(below, 0.0, xp.where(above, 1.0, t))
    return r + d1 * s[..., None] - d2 * t[..., None]


def contact_normal(rcm_a, wrist_a, tip_a, rcm_b, wrist_b, tip_b):
    """The unit normal between the suction (a) and the grasper (b) where they come closest (the pair of segments
    with the least clearance), pointing from b to a: ``(M, 3)``."""
    xp = namespace(rcm_a, wrist_a, tip_a, rcm_b, wrist_b, tip_b)
    ra, rb = WRIST_RADIUS["suction"], WRIST_RADIUS["grasper"]
    pairs = ((rcm_a, wrist_a, rcm_b, wrist_b, 2 * SHAFT_RADIUS), (rcm_a, wrist_a, wrist_b, tip_b, SHAFT_RADIUS + rb),
             (wrist_a, tip_a, rcm_b, wrist_b, ra + SHAFT_RADIUS), (wrist_a, tip_a, wrist_b, tip_b, ra + rb))
    offsets = xp.stack([xp.broadcast_to(segment_offset(*pair[:4], xp=xp), tip_a.shape) for pair in pairs])
    lengths = xp.sqrt(_dot(offsets, offsets))  # (4, M)
    nearest = xp.argmin(lengths - xp.asarray([[pair[4]] for pair in pairs], dtype=lengths.dtype), axis=0)
    chosen = xp.arange(4)[:, None] == nearest[None, :]  # (4, M): the nearest pair of each row
    offset = xp.sum(xp.where(chosen[..., None], offsets, 0.0), axis=0)
    length = xp.sum(xp.where(chosen, lengths, 0.0), axis=0)
    return offset / xp.maximum(length, 1e-12)[:, None]


#: Batches up to this many points take the four pairs of segments in one call (numpy's per-call cost dominates
#: there); larger ones take them one by one (copying them into one array would cost more than it saves).
_STACKED_BELOW = 64


def instrument_clearance(rcm_a, wrist_a, tip_a, rcm_b, wrist_b, tip_b):
    """Clearance between the suction (a) and the grasper (b), each a shaft RCM-wrist and a wrist-tip segment
    (negative when they intersect). Both ways of computing it give the same floating-point results."""
    xp = namespace(rcm_a, wrist_a, tip_a, rcm_b, wrist_b, tip_b)  # (one backend for all six)
    ra, rb = WRIST_RADIUS["suction"], WRIST_RADIUS["grasper"]
    pairs = ((rcm_a, wrist_a, rcm_b, wrist_b), (rcm_a, wrist_a, wrist_b, tip_b), (wrist_a, tip_a, rcm_b, wrist_b),
             (wrist_a, tip_a, wrist_b, tip_b))
    first, second = (2 * SHAFT_RADIUS, SHAFT_RADIUS, ra, ra), (0.0, rb, SHAFT_RADIUS, rb)
    shape = tuple(np.broadcast_shapes(tuple(tip_a.shape), tuple(tip_b.shape)))
    if xp is np and int(np.prod(shape[:-1])) < _STACKED_BELOW:
        ends = [np.empty((4,) + shape) for _ in range(4)]
        for row, pair in enumerate(pairs):
            for end, point in zip(ends, pair):
                end[row] = point
        column = (4,) + (1,) * (len(shape) - 1)
        gaps = segment_distance(*ends, xp=np) - np.array(first).reshape(column) - np.array(second).reshape(column)
    else:
        gaps = [segment_distance(*pair, xp=xp) - a - b for pair, a, b in zip(pairs, first, second)]
    return xp.minimum(xp.minimum(gaps[0], gaps[1]), xp.minimum(gaps[2], gaps[3]))
