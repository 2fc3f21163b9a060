"""One world's move in Python floats: the parallel env's fast path for the common case of :meth:`_move`.

The core's step is written once, over arrays; with one world numpy's per-call cost makes an arm's move (the phantom's
surface, the box, inverse kinematics, the instruments' clearance: some 200 calls on arrays of one row) most of a
step. Most moves need none of the rare rules (a move into a wall or below the surface, past a joint limit, into the
other instrument, a descent without headway): :class:`LeanMove` makes those with the same floating-point operations
in the same order on floats (numpy's own ``arctan2``, ``sin`` and ``cos`` on scalars, which give what its array loops
give), so the result is bit for bit the array path's; any move that needs a rare rule returns None and the array
path makes it. ``tests/test_lean_move.py`` holds the two equal, bit for bit, over random moves.
"""

from __future__ import annotations

import math

import numpy as np

from dvrl_marl.suction_debris.instruments import SHAFT_RADIUS, WRIST_RADIUS
from dvrl_marl.suction_debris.sliding import NO_HEADWAY

__all__ = ["LeanMove"]

_sqrt, _atan2, _sin, _cos = math.sqrt, np.arctan2, np.sin, np.cos


def _clip01(x):
    return min(max(x, 0.0), 1.0)


def _segment_distance(p1, q1, p2, q2):
    """:func:`dvrl_marl.suction_debris.instruments.segment_offset`'s length, on 3-tuples."""
    d10, d11, d12 = q1[0] - p1[0], q1[1] - p1[1], q1[2] - p1[2]
    d20, d21, d22 = q2[0] - p2[0], q2[1] - p2[1], q2[2] - p2[2]
    r0, r1, r2 = p1[0] - p2[0], p1[1] - p2[1], p1[2] - p2[2]
    a = d10 * d10 + d11 * d11 + d12 * d12
    e = d20 * d20 + d21 * d21 + d22 * d22
    f = d20 * r0 + d21 * r1 + d22 * r2
    c = d10 * r0 + d11 * r1 + d12 * r2
    b = d10 * d20 + d11 * d21 + d12 * d22
    denominator = a * e - b * b
    s = _clip01((b * f - c * e) / denominator) if denominator > 1e-18 else 0.0
    t = (b * s + f) / e if e > 1e-18 else 0.0
    if t < 0.0:
        s, t = (_clip01(-c / a) if a > 1e-18 else 0.0), 0.0
    elif t > 1.0:
        s, t = (_clip01((b - c) / a) if a > 1e-18 else 0.0), 1.0
    o0, o1, o2 = r0 + d10 * s - d20 * t, r1 + d11 * s - d21 * t, r2 + d12 * s - d22 * t
    return _sqrt(o0 * o0 + o1 * o1 + o2 * o2)


class _Arm:
    """One arm's constants as floats: its base, its tool's closed form and limits."""

    def __init__(self, arm):
        tool = arm.tool
        self.base = tuple(float(v) for v in arm.base_position)
        self.tip_drop, self.wrist_link = float(tool.tip_drop), float(tool.wrist_link)
        self.insertion_offset, self.has_jaw = float(tool.insertion_offset), tool.has_jaw
        self.limits = tuple(zip((float(v) for v in tool.lower), (float(v) for v in tool.upper)))

    def joints(self, x, y, z):
        """:func:`dvrl_marl.kinematics.inverse_kinematics_batch` of one tool point: the joints, or None where the
        point is out of reach (past a limit: the array path's bisection)."""
        z_link = z + self.tip_drop
        outer_yaw = float(_atan2(x, -z_link))
        radial = _sqrt(x * x + z_link * z_link) - self.wrist_link
        outer_pitch = float(_atan2(-y, radial))
        insertion = _sqrt(radial * radial + y * y) + self.insertion_offset
        if self.has_jaw:
            q = (outer_yaw, outer_pitch, insertion, 0.0 * outer_yaw, -outer_pitch, -outer_yaw)
        else:
            q = (outer_yaw, outer_pitch, insertion, -outer_pitch, -outer_yaw)
        if not radial > 0.0:
            return None
        for value, (lower, upper) in zip(q, self.limits):
            if not (value >= lower and value <= upper):
                return None
        return q

    def wrist(self, q):
        """:func:`dvrl_marl.kinematics.wrist_position_batch` plus the base: the wrist in the world."""
        s1, c1 = float(_sin(q[0])), float(_cos(q[0]))
        s2, c2 = float(_sin(q[1])), float(_cos(q[1]))
        length = q[2] - self.insertion_offset
        b = self.base
        return (length * s1 * c2 + b[0], -length * s2 + b[1], -length * c1 * c2 + b[2])


class LeanMove:
    """The common case of :meth:`CollaborativeCore._move` for a core of one numpy world."""

    def __init__(self, core):
        p, c = core.params, core.cavities
        self.clearance_of_tip, self.step = float(p.tip_clearance), float(p.step_size)
        self.low = tuple(float(v) for v in core.low)
        self.high = tuple(float(v) for v in core.high)
        self.rules = core.move_rules
        self.cavities = tuple(zip(*(tuple(float(v) for v in values) for values in
                                    (c.centre_x, c.centre_y, c.sphere_radius, c.depth, c.mouth_radius ** 2))))
        ph = c.phantom
        self.phantom = tuple(float(v) for v in (ph.centre_x, ph.centre_y, ph.half_x, ph.half_y, ph.top_z, ph.table_z))
        self.arms = {agent: _Arm(arm) for agent, arm in core.arms.items()}
        ra, rb = WRIST_RADIUS["suction"], WRIST_RADIUS["grasper"]
        self.radii = ((2 * SHAFT_RADIUS, 0.0), (SHAFT_RADIUS, rb), (ra, SHAFT_RADIUS), (ra, rb))

    def floor(self, x, y):
        """:meth:`dvrl_marl.suction_debris.phantom.Cavities.surface_height` plus the tip's clearance."""
        cx, cy, half_x, half_y, top_z, table_z = self.phantom
        deepest = 0.0
        for centre_x, centre_y, radius, depth, mouth2 in self.cavities:
            dx, dy = x - centre_x, y - centre_y
            r2 = dx * dx + dy * dy
            if not r2 >= mouth2:
                bowl = depth - (radius - _sqrt(max(radius * radius - r2, 0.0)))
                deepest = max(deepest, bowl)
        surface = table_z if abs(x - cx) > half_x or abs(y - cy) > half_y else top_z - deepest
        return surface + self.clearance_of_tip

    def target(self, agent, old, delta):
        """:func:`dvrl_marl.suction_debris.sliding.surface_target` where no rule of a blocked move applies, else None."""
        low, high = self.low, self.high
        target = tuple(min(max(o + d, lo), hi) for o, d, lo, hi in zip(old, delta, low, high))
        if target[2] < self.floor(target[0], target[1]):  # into a wall or below the surface: the array path
            return None
        rules = self.rules[agent]
        if rules.climb or rules.settle:
            d0, d1, d2 = delta
            made0, made1, made2 = target[0] - old[0], target[1] - old[1], target[2] - old[2]
            length = _sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            made = _sqrt(made0 * made0 + made1 * made1 + made2 * made2)
            if rules.climb:
                heading_made = made
                if rules.ahead:
                    level2 = d2 * 0.0
                    level_length = _sqrt(d0 * d0 + d1 * d1 + level2 * level2)
                    if level_length >= NO_HEADWAY * length:
                        heading_made = (made0 * d0 + made1 * d1 + made2 * level2) / max(level_length, 1e-300)
                if d2 < 0.0 and heading_made < NO_HEADWAY * length:
                    return None
            if rules.settle and d2 < 0.0 and made < NO_HEADWAY * length:
                return None
        return target

    def move(self, agent, other, tip, q_other, tip_other, delta):
        """``agent``'s arm at ``tip`` (base frame) moved by ``delta`` (world), the ``other`` arm at ``tip_other``
        with joints ``q_other``: ``(tip, q, clearance)`` as the array path makes them, or None where a rare rule is
        needed (nothing is changed: the caller's array path takes the move from the start)."""
        arm = self.arms[agent]
        base = arm.base
        old = (tip[0] + base[0], tip[1] + base[1], tip[2] + base[2])
        target = self.target(agent, old, delta)
        if target is None:
            return None
        moved = tuple(min(max(t + (w - o), -1.0), 1.0) for t, w, o in zip(tip, target, old))  # ArmBatch.move
        q = arm.joints(*moved)
        if q is None:
            return None
        own = (base, arm.wrist(q), (moved[0] + base[0], moved[1] + base[1], moved[2] + base[2]))
        partner_arm = self.arms[other]
        pb = partner_arm.base
        partner = (pb, partner_arm.wrist(q_other), (tip_other[0] + pb[0], tip_other[1] + pb[1], tip_other[2] + pb[2]))
        a, b = (own, partner) if agent == "suction" else (partner, own)
        pairs = ((a[0], a[1], b[0], b[1]), (a[0], a[1], b[1], b[2]), (a[1], a[2], b[0], b[1]), (a[1], a[2], b[1], b[2]))
        gaps = [_segment_distance(*pair) - first - second for pair, (first, second) in zip(pairs, self.radii)]
        clearance = min(min(gaps[0], gaps[1]), min(gaps[2], gaps[3]))
        if not clearance >= 0.0:  # refused: the instruments would intersect (the array path slides or keeps it)
            return None
        return moved, q, clearance
