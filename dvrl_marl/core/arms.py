"""N kinematic PSMs with one tool each: the batched form of :class:`dvrl_marl.arm.Arm`'s motion.

Each step is the paper's ``p <- p + eta * Delta`` clamped to a box, solved by the closed-form IK, and, where the
clamped target leaves the joint limits, cut short along the move by bisection, exactly as ``Arm.move`` does for
one arm (the same floating-point operations in the same order, so world ``i`` matches the single arm).
"""

from __future__ import annotations

import numpy as np

from dvrl_marl import kinematics
from dvrl_marl.core.backend import namespace, needed, put, repeat, rows_of, take

__all__ = ["ArmBatch"]

#: Bisection steps when a move leaves the joint limits (the same count as ``Arm.move``).
_PROJECTION_ITERATIONS = 20


class ArmBatch:
    """Tips ``(N, 3)`` (base frame, metres), joints ``q`` ``(N, n_joints)`` and jaw ``(N,)`` of N arms."""

    def __init__(self, tool: kinematics.Tool | str, num_worlds: int, base_position=(0.0, 0.0, 0.0),
                 tool_point_drop: float = 0.0):
        self.tool = kinematics.get_tool(tool)
        #: How far the tool point lies below the tip (``Arm.tool_point_drop``: 0, or 10.2 mm for measured_cp tips).
        self.tool_point_drop = float(tool_point_drop)
        self._to_tool_point = np.array([0.0, 0.0, self.tool_point_drop])
        self.num_worlds = int(num_worlds)
        #: The base (RCM) position in the world; bases are axis-aligned in every scene the cores support.
        self.base_position = np.asarray(base_position, dtype=np.float64)
        self.tip = np.zeros((self.num_worlds, 3))
        self.q = np.zeros((self.num_worlds, self.tool.n_joints))
        self.jaw = np.ones(self.num_worlds)

    def _tool_points(self, tips: np.ndarray) -> np.ndarray:
        """Where the tool points of ``tips`` lie (what IK solves for); ``tips`` itself, no copy, when they coincide."""
        return tips - self._to_tool_point if self.tool_point_drop else tips

    def tip_world(self) -> np.ndarray:
        """Tip positions in world coordinates (a new array)."""
        return self.tip + self.base_position

    def set_tips(self, worlds, positions) -> None:
        """Put the tips of ``worlds`` (indices or mask) at ``positions`` (base frame); they must be reachable."""
        positions = np.asarray(positions, dtype=np.float64)
        q, reachable = kinematics.inverse_kinematics_batch(self.tool, self._tool_points(positions))
        if not np.all(reachable):
            raise kinematics.UnreachableError(self.tool.name, positions[np.argmin(reachable)] if positions.ndim > 1
                                              else positions, "geometry", np.nan, (np.nan, np.nan))
        self.tip[worlds] = positions
        self.q[worlds] = q

    def move(self, delta, low, high):
        """Move every tip by ``delta`` ``(N, 3)``, clamped to ``[low, high]`` (per axis, ``(3,)`` or ``(N, 3)``).

        Returns the mask of worlds whose move was cut short by the joint limits.
        """
        xp = namespace(self.tip, delta)
        start = self.tip
        target = xp.minimum(xp.maximum(start + delta, low), high)
        q, reachable = kinematics.inverse_kinematics_batch(self.tool, self._tool_points(target))
        blocked = ~reachable
        if needed(blocked):  # cut short along the move by bisection, where the target leaves the joint limits
            rows = rows_of(blocked)
            origin, goal = take(start, rows), take(target, rows)
            span = goal - origin

            def halve(carry):
                good, bad = carry
                mid = 0.5 * (good + bad)
                _, ok = kinematics.inverse_kinematics_batch(self.tool, self._tool_points(origin + mid[:, None] * span))
                return xp.where(ok, mid, good), xp.where(ok, bad, mid)

            good, _ = repeat(_PROJECTION_ITERATIONS, halve, (xp.zeros(origin.shape[:1], dtype=origin.dtype),
                                                             xp.ones(origin.shape[:1], dtype=origin.dtype)))
            reached = origin + good[:, None] * span
            target = put(target, rows, blocked, reached)
            q = put(q, rows, blocked, kinematics.inverse_kinematics_batch(self.tool, self._tool_points(reached))[0])
        self.tip = target
        self.q = q
        return blocked

    def tool_point_world(self) -> np.ndarray:
        """Where each tool acts (jaw control point / tube tip), world coordinates (a new array)."""
        return self._tool_points(self.tip + self.base_position)

    def wrist_world(self) -> np.ndarray:
        """The wrist pitch point (where the straight shaft ends) of every arm, world frame: ``(N, 3)``.

        The batched form of :func:`dvrl_marl.kinematics.wrist_position_point`.
        """
        return kinematics.wrist_position_batch(self.tool, self.q) + self.base_position
