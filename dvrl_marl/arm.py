"""One PSM in a MuJoCo scene, moved kinematically through the closed-form IK.

The paper's argument (Sec. III-A): with eta small enough that the real arm never overshoots, the arm needs no
dynamics; each step sets new joint set points by inverse kinematics. :class:`Arm` keeps the tip position in its
base (RCM) frame as Python floats, writes the joint values into ``data.qpos``, and projects every requested move
back into the allowed region (workspace box, floor, joint limits) instead of failing.
"""

from __future__ import annotations

import mujoco
import numpy as np

from dvrl_marl import kinematics
from dvrl_marl.assets import JAW_FINGER_OPEN_ANGLE
from dvrl_marl.scene import object_id

__all__ = ["Arm"]

# Bisection steps when a move leaves the joint limits: 2**-20 of a 1 mm step is far below any tolerance.
_PROJECTION_ITERATIONS = 20


def _as_slice(addresses):
    """A slice when the addresses are consecutive (cheaper to assign through), else an index array."""
    addresses = [int(a) for a in addresses]
    if addresses == list(range(addresses[0], addresses[0] + len(addresses))):
        return slice(addresses[0], addresses[0] + len(addresses))
    return np.array(addresses)


class Arm:
    """A PSM with ``tool`` whose bodies carry ``prefix`` (e.g. ``"psm/"``) in ``model``.

    ``tip_frame`` says which point of the tool :attr:`tip` is (see :mod:`dvrl_marl.kinematics`):
    ``"tool_point"`` (the jaw control point / tube tip) or ``"measured_cp"`` (the dVRK's frame, 10.2 mm behind it).

    Attributes:
        tool: the :class:`~dvrl_marl.kinematics.Tool`.
        tip: current tip position p (base frame, metres) as a list of 3 floats; read it, move it with
            :meth:`set_tip` or :meth:`move`.
        q: the joint vector that puts it there.
        jaw: current jaw value j in [0, 1] (LND only; 0 closed, 1 open).
        base_position, base_rotation: the base (RCM) frame in world coordinates.
    """

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, prefix: str, tool: kinematics.Tool | str,
                 tip_frame: str = "tool_point"):
        self.tool = kinematics.get_tool(tool)
        if tip_frame not in kinematics.TIP_FRAMES:
            raise ValueError(f"tip_frame must be one of {kinematics.TIP_FRAMES}, got {tip_frame!r}")
        self.tip_frame = tip_frame
        #: How far the tool point lies below :attr:`tip` (the tool points down): 0 when tip is the tool point.
        self.tool_point_drop = self.tool.measured_cp_to_tool_point if tip_frame == "measured_cp" else 0.0
        self.model = model
        self.data = data
        self.prefix = prefix
        base = object_id(model, "body", f"{prefix}rcm")
        mujoco.mj_kinematics(model, data)
        self.base_position = data.xpos[base].copy()
        self.base_rotation = data.xmat[base].reshape(3, 3).copy()
        self._axis_aligned = bool(np.allclose(self.base_rotation, np.eye(3)))
        self._joint_qpos = _as_slice(
            [model.jnt_qposadr[object_id(model, "joint", f"{prefix}{n}")] for n in self.tool.joint_names]
        )
        self.tip_site = object_id(model, "site", f"{prefix}tip")
        if self.tool.has_jaw:
            self._jaw_qpos = _as_slice(
                [model.jnt_qposadr[object_id(model, "joint", f"{prefix}jaw_{side}")] for side in ("left", "right")]
            )
            zone = object_id(model, "site", f"{prefix}grasp_zone")
            # Tip frame (fixed orientation): x along base y, y along base x, z along -base z.
            hx, hy, hz = (float(v) for v in model.site_size[zone])
            self.grasp_zone_half_extents_base = (hy, hx, hz)
        self.tip = [0.0, 0.0, 0.0]
        self.jaw = 1.0
        self.q = (0.0,) * self.tool.n_joints

    @property
    def joint_qpos_addresses(self):
        """Where this arm's joints live in ``qpos`` (a slice or an index array)."""
        return self._joint_qpos

    @property
    def jaw_qpos_addresses(self):
        """Where the two jaw fingers live in ``qpos`` (LND only)."""
        return self._jaw_qpos

    # --- frames -----------------------------------------------------------------------------------------
    def to_world(self, position_base) -> np.ndarray:
        """Base-frame position(s) (..., 3) to world coordinates."""
        return np.asarray(position_base, float) @ self.base_rotation.T + self.base_position

    def to_base(self, position_world) -> np.ndarray:
        """World position(s) (..., 3) to this arm's base frame."""
        return (np.asarray(position_world, float) - self.base_position) @ self.base_rotation

    # --- motion -----------------------------------------------------------------------------------------
    def set_tip(self, x: float, y: float, z: float) -> None:
        """Put the tip at (x, y, z) (base frame); raises :class:`~dvrl_marl.kinematics.UnreachableError`."""
        self._place(x, y, z, kinematics.inverse_kinematics_point(self.tool, x, y, z - self.tool_point_drop))

    def set_solved_tip(self, x: float, y: float, z: float, q) -> None:
        """Put the tip at (x, y, z) (base frame) with the joints ``q`` that the batched IK solved for it, within the
        limits. Why: the scalar IK of :meth:`set_tip` can judge a point the batched IK put exactly on a joint limit
        (a move slid along it) a last bit outside; the batched core keeps the batched solution, and so does the
        single env that mirrors it."""
        if self.tool_point_drop:
            raise ValueError("set_solved_tip: the batched IK solves for the tool point, this arm's tip is the measured_cp")
        self._place(x, y, z, tuple(float(v) for v in q))

    def _place(self, x: float, y: float, z: float, q: tuple) -> None:
        self.data.qpos[self._joint_qpos] = q
        self.q = q
        self.tip[0], self.tip[1], self.tip[2] = x, y, z

    def reachable(self, x: float, y: float, z: float) -> bool:
        """Whether IK can reach (x, y, z) within the joint limits."""
        try:
            kinematics.inverse_kinematics_point(self.tool, x, y, z - self.tool_point_drop)
        except kinematics.UnreachableError:
            return False
        return True

    def move(self, dx: float, dy: float, dz: float, low, high) -> bool:
        """Move the tip by (dx, dy, dz), clamped to the box [low, high] (per axis, base frame).

        If the clamped target lies outside the joint limits, the tip goes as far as it can along the move
        (bisection). Returns True if the move was cut short by the joint limits.
        """
        x0, y0, z0 = self.tip
        x = min(max(x0 + dx, low[0]), high[0])
        y = min(max(y0 + dy, low[1]), high[1])
        z = min(max(z0 + dz, low[2]), high[2])
        try:
            self.set_tip(x, y, z)
            return False
        except kinematics.UnreachableError:
            pass
        good, bad = 0.0, 1.0
        for _ in range(_PROJECTION_ITERATIONS):
            mid = 0.5 * (good + bad)
            if self.reachable(x0 + mid * (x - x0), y0 + mid * (y - y0), z0 + mid * (z - z0)):
                good = mid
            else:
                bad = mid
        if good == 0.0:  # none of the move can be made: the tip and its joints stay as they are (set_solved_tip's
            return True  # tip on a limit may be one the scalar IK judges a last bit outside)
        self.set_tip(x0 + good * (x - x0), y0 + good * (y - y0), z0 + good * (z - z0))
        return True

    def set_jaw(self, jaw: float) -> None:
        """Set the jaw value j in [0, 1]; each finger turns ``JAW_FINGER_OPEN_ANGLE * j``."""
        self.jaw = jaw
        angle = JAW_FINGER_OPEN_ANGLE * jaw
        self.data.qpos[self._jaw_qpos] = angle

    # --- sensing ----------------------------------------------------------------------------------------
    def tip_world(self) -> tuple[float, float, float]:
        """Tip position in world coordinates (floats, no MuJoCo call)."""
        x, y, z = self.tip
        if self._axis_aligned:
            p = self.base_position
            return (x + p[0], y + p[1], z + p[2])
        world = self.to_world((x, y, z))
        return (float(world[0]), float(world[1]), float(world[2]))

    def tool_point_world(self) -> tuple[float, float, float]:
        """Where the tool acts (jaw control point / tube tip), world coordinates: :attr:`tool_point_drop` below the
        tip."""
        x, y, z = self.tip_world()
        if self._axis_aligned:
            return (x, y, z - self.tool_point_drop)
        world = np.array((x, y, z)) - self.tool_point_drop * self.base_rotation[:, 2]
        return (float(world[0]), float(world[1]), float(world[2]))

    def base_point(self, x: float, y: float, z: float) -> tuple[float, float, float]:
        """A world point in this arm's base frame (floats, no MuJoCo call): :meth:`to_base` for one point."""
        if self._axis_aligned:
            p = self.base_position
            return (x - p[0], y - p[1], z - p[2])
        base = self.to_base((x, y, z))
        return (float(base[0]), float(base[1]), float(base[2]))

    def grasp_sensor(self, point_world) -> bool:
        """The proximity sensor between the jaws: is ``point_world`` inside its volume (the grasp_zone site)?"""
        tx, ty, tz = self.tool_point_world()
        hx, hy, hz = self.grasp_zone_half_extents_base
        if self._axis_aligned:
            rx, ry, rz = point_world[0] - tx, point_world[1] - ty, point_world[2] - tz
        else:
            rx, ry, rz = (np.asarray(point_world, float) - (tx, ty, tz)) @ self.base_rotation
        return abs(rx) <= hx and abs(ry) <= hy and abs(rz) <= hz

