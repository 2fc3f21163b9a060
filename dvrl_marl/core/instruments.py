"""The two instruments as segments, for contact: an RCM-to-wrist shaft and a wrist-to-tip segment per arm.

Shared by the collaborative scene's batched core (contact and the refusal of intersecting moves) and the sliding rules
(:mod:`dvrl_marl.core.sliding`: the contact's normal), batched over leading axes.
"""

from __future__ import annotations

import numpy as np

from dvrl_marl import assets

__all__ = ["SHAFT_RADIUS", "WRIST_RADIUS", "segment_distance", "segment_offset", "instrument_clearance",
           "contact_normal"]

#: Radii used for instrument-instrument contact: the 8.5 mm shaft and the wrist/tube segment beyond it.
SHAFT_RADIUS = assets.SHAFT_RADIUS
WRIST_RADIUS = {"suction": assets.SUCTION_TUBE_RADIUS, "grasper": 0.0025}


def _dot(u, v):
    return u[..., 0] * v[..., 0] + u[..., 1] * v[..., 1] + u[..., 2] * v[..., 2]


def segment_distance(p1, q1, p2, q2) -> np.ndarray:
    """Shortest distances between segments p1-q1 and p2-q2, batched over leading axes (..., 3)."""
    difference = segment_offset(p1, q1, p2, q2)
    return np.sqrt(_dot(difference, difference))


def segment_offset(p1, q1, p2, q2) -> np.ndarray:
    """From the point of segment p2-q2 nearest segment p1-q1 to the point of p1-q1 nearest it, (..., 3)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f, c, b = _dot(d1, d1), _dot(d2, d2), _dot(d2, r), _dot(d1, r), _dot(d1, d2)
    denominator = a * e - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(denominator > 1e-18, np.minimum(np.maximum((b * f - c * e) / denominator, 0.0), 1.0), 0.0)
        t = np.where(e > 1e-18, (b * s + f) / e, 0.0)
        a_ok = a > 1e-18
        below, above = t < 0.0, t > 1.0
        s = np.where(below, np.where(a_ok, np.minimum(np.maximum(-c / a, 0.0), 1.0), 0.0), s)
        s = np.where(above, np.where(a_ok, np.minimum(np.maximum((b - c) / a, 0.0), 1.0), 0.0), s)
    t = np.where(below, 0.0, np.where(above, 1.0, t))
    return r + d1 * s[..., None] - d2 * t[..., None]


def contact_normal(rcm_a, wrist_a, tip_a, rcm_b, wrist_b, tip_b) -> np.ndarray:
    """The unit normal between the suction (a) and the grasper (b) where they come closest (the pair of segments
    with the least clearance), pointing from b to a: ``(M, 3)``."""
    ra, rb = WRIST_RADIUS["suction"], WRIST_RADIUS["grasper"]
    pairs = ((rcm_a, wrist_a, rcm_b, wrist_b, 2 * SHAFT_RADIUS), (rcm_a, wrist_a, wrist_b, tip_b, SHAFT_RADIUS + rb),
             (wrist_a, tip_a, rcm_b, wrist_b, ra + SHAFT_RADIUS), (wrist_a, tip_a, wrist_b, tip_b, ra + rb))
    offsets = np.stack([np.broadcast_to(segment_offset(*pair[:4]), np.shape(tip_a)) for pair in pairs])
    lengths = np.sqrt(_dot(offsets, offsets))
    nearest = np.argmin(lengths - np.array([pair[4] for pair in pairs])[:, None], axis=0)
    rows = np.arange(lengths.shape[1])
    return offsets[nearest, rows] / np.maximum(lengths[nearest, rows], 1e-12)[:, None]


#: Batches up to this many points take the four pairs of segments in one call (numpy's per-call cost dominates
#: there); larger ones take them one by one (copying them into one array would cost more than it saves).
_STACKED_BELOW = 64


def instrument_clearance(rcm_a, wrist_a, tip_a, rcm_b, wrist_b, tip_b) -> np.ndarray:
    """Clearance between the suction (a) and the grasper (b), each a shaft RCM-wrist and a wrist-tip segment
    (negative when they intersect). Both ways of computing it give the same floating-point results."""
    ra, rb = WRIST_RADIUS["suction"], WRIST_RADIUS["grasper"]
    pairs = ((rcm_a, wrist_a, rcm_b, wrist_b), (rcm_a, wrist_a, wrist_b, tip_b), (wrist_a, tip_a, rcm_b, wrist_b),
             (wrist_a, tip_a, wrist_b, tip_b))
    first, second = (2 * SHAFT_RADIUS, SHAFT_RADIUS, ra, ra), (0.0, rb, SHAFT_RADIUS, rb)
    shape = np.broadcast_shapes(np.shape(tip_a), np.shape(tip_b))
    if int(np.prod(shape[:-1])) < _STACKED_BELOW:
        ends = [np.empty((4,) + shape) for _ in range(4)]
        for row, pair in enumerate(pairs):
            for end, point in zip(ends, pair):
                end[row] = point
        column = (4,) + (1,) * (len(shape) - 1)
        gaps = segment_distance(*ends) - np.array(first).reshape(column) - np.array(second).reshape(column)
    else:
        gaps = [segment_distance(*pair) - a - b for pair, a, b in zip(pairs, first, second)]
    return np.minimum(np.minimum(gaps[0], gaps[1]), np.minimum(gaps[2], gaps[3]))
