"""Kinematics of the dVRK Patient Side Manipulator (PSM) with two EndoWrists.

Pure numpy; knows nothing of MuJoCo. All positions are in metres in the PSM base frame, whose origin is the
remote centre of motion (RCM); at the home configuration the instrument points along -z.

Forward kinematics uses the modified Denavit-Hartenberg convention (Craig): each row is
``T_i = Rx(alpha_i) Tx(a_i) Rz(theta_i) Tz(d_i)``.

* Large Needle Driver (LND): the dVRK table (``PSM.json`` + ``LARGE_NEEDLE_DRIVER_400006.json`` of the JHU
  sawIntuitiveResearchKit; the paper's Table I with l_1 = l_RCC, l_3 = l_tool, l_4 = l_pitch2yaw), plus the
  fixed row to the control point between the jaws.
* Suction & Irrigation (S&I): the paper's Table I, the LND's frames without the roll joint. The paper gives no
  lengths; the values chosen are :data:`SUCTION_IRRIGATION_PITCH_OFFSET` and
  :data:`SUCTION_IRRIGATION_TUBE_LENGTH` below, the only place they are set.

**Two points on the tool.** The *tool point* is where the tool acts: the LND's jaw control point (row 7 above) or
the S&I's tube tip. The dVRK itself reports (``measured_cp``) and commands (``servo_cp``) the origin of the last
frame of its tool file, the wrist-yaw frame, :attr:`Tool.measured_cp_to_tool_point` (10.2 mm for both tools) behind
the tool point along the tool's axis; the original dVRL code's end-effector p (and so its p_c) is that frame too.
Version 0 of the single-arm environments moves the tool point; version 1 moves the dVRK's frame
(:func:`measured_cp_from_tool_point`, and :mod:`dvrl_marl.frames` for a dVRK arm's base frame).

Inverse kinematics solves for a tool-tip position with the fixed orientation the environments use (tool
pointing straight down, -z of the base frame, with the home roll). For both tools the solution is closed
form (see :func:`inverse_kinematics`) and batched over any leading axes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "LND",
    "SUCTION_IRRIGATION",
    "TOOLS",
    "Tool",
    "DHRow",
    "UnreachableError",
    "forward_kinematics",
    "inverse_kinematics",
    "inverse_kinematics_point",
    "inverse_kinematics_batch",
    "within_limits",
    "wrist_position_point",
    "get_tool",
    "measured_cp_forward_kinematics",
    "measured_cp_from_tool_point",
    "tool_point_from_measured_cp",
    "TIP_FRAMES",
]

# --- Link lengths (metres) --------------------------------------------------------------------------------
#: Remote centre of motion to the insertion origin (dVRK PSM.json, ``l_RCC``).
L_RCC = 0.4318
#: Length of the LND shaft to the wrist pitch axis (``l_tool``).
L_TOOL = 0.4162
#: LND wrist pitch axis to yaw axis (``l_pitch2yaw``).
L_PITCH2YAW = 0.0091
#: LND yaw axis to the control point between the jaws (``l_yaw2ctrlpnt``; surgical_robotics_challenge psmFK).
L_YAW2CTRLPNT = 0.0102
#: S&I: the paper's l_2 (frame 3 ``d = q3 - l_2``). Chosen from the public CRESSim-Neo model, whose pitch axis
#: sits 0.447 m along the insertion axis: l_2 = l_RCC - 0.447. Not authoritative (the dVRK ships no S&I file).
SUCTION_IRRIGATION_PITCH_OFFSET = L_RCC - 0.447
#: S&I: the paper's l_5 (frame 6 ``a = l_5``), pitch axis to the tube tip. Chosen from CRESSim-Neo: 6 mm pitch
#: to yaw plus 10.2 mm yaw to tip, collapsed onto one tube because the paper's S&I table ends at frame 6.
SUCTION_IRRIGATION_TUBE_LENGTH = 0.006 + 0.0102
#: S&I: its wrist-yaw frame origin (the dVRK's measured_cp by the LND's rule: the last frame of the tool's chain)
#: lies 10.2 mm behind the tube tip (CRESSim-Neo's yaw-to-tip length, the same 10.2 mm as the LND's).
SUCTION_IRRIGATION_YAW2TIP = 0.0102

#: The points a single-arm environment can move (its p): ``"tool_point"`` (the jaw control point / tube tip) or
#: ``"measured_cp"`` (the dVRK's reported and commanded frame; the registered envs').
TIP_FRAMES = ("tool_point", "measured_cp")

_HALF_PI = math.pi / 2


class UnreachableError(ValueError):
    """A tool-tip position has no inverse-kinematics solution within the joint limits.

    Attributes:
        position: the offending position (metres, base frame).
        joint: name of the violated joint limit (or ``"geometry"`` when no solution exists at all).
        value: the joint value the solution would need (``nan`` for ``"geometry"``).
        limits: the ``(lower, upper)`` limits of that joint.
    """

    def __init__(self, tool: str, position, joint: str, value: float, limits: tuple[float, float]):
        self.tool = tool
        self.position = np.array(position, dtype=float)
        self.joint = joint
        self.value = float(value)
        self.limits = (float(limits[0]), float(limits[1]))
        if joint == "geometry":
            reason = "it is too close to the remote centre of motion for the wrist to fit"
        else:
            reason = f"joint {joint!r} would be {value:.6g}, outside its limits [{limits[0]:.6g}, {limits[1]:.6g}]"
        super().__init__(f"{tool}: tip position {self.position.tolist()} (m) is unreachable: {reason}")

    def __reduce__(self):  # copied and pickled with its arguments (Ray copies and ships the errors of its workers)
        return type(self), (self.tool, self.position.tolist(), self.joint, self.value, self.limits)


@dataclass(frozen=True)
class DHRow:
    """One modified-DH row. ``joint`` is the index into q for a moving joint, ``None`` for a fixed row."""

    alpha: float
    a: float
    d: float
    theta: float
    joint: int | None = None
    prismatic: bool = False


@dataclass(frozen=True)
class Tool:
    """A PSM with one EndoWrist: DH rows, joint names and limits, and the closed-form IK parameters.

    The closed form: with the tool pointing down, the wrist bends back by exactly the shaft's tilt, so the
    point at ``tip_drop`` above the tip, the shaft and the in-plane wrist link of length ``wrist_link`` stay in
    one plane through the RCM. ``insertion_offset`` is the insertion at which the wrist pitch axis is at the RCM.
    """

    name: str
    rows: tuple[DHRow, ...]
    joint_names: tuple[str, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    insertion_offset: float
    wrist_link: float
    tip_drop: float
    has_jaw: bool
    #: Distance from the dVRK's measured_cp origin (the wrist-yaw frame) forward along the tool axis to the tool
    #: point (LND: l_yaw2ctrlpnt; S&I: :data:`SUCTION_IRRIGATION_YAW2TIP`).
    measured_cp_to_tool_point: float = 0.0

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @property
    def limits(self) -> np.ndarray:
        """Joint limits as an (n_joints, 2) array of [lower, upper]."""
        return np.stack([self.lower, self.upper], axis=1)

    def __repr__(self) -> str:  # the dataclass repr would print every DH row
        return f"Tool({self.name!r})"


_OUTER_ROWS = (
    DHRow(_HALF_PI, 0.0, 0.0, _HALF_PI, joint=0),
    DHRow(-_HALF_PI, 0.0, 0.0, -_HALF_PI, joint=1),
)
_OUTER_NAMES = ("outer_yaw", "outer_pitch", "insertion")
_OUTER_LOWER = (-1.588, -0.925, 0.0)
_OUTER_UPPER = (1.588, 0.925, 0.24)
_WRIST_LIMIT = 1.396

#: Large Needle Driver: 6 joints (outer yaw, outer pitch, insertion, roll, wrist pitch, wrist yaw) + jaw.
LND = Tool(
    name="lnd",
    rows=_OUTER_ROWS
    + (
        DHRow(_HALF_PI, 0.0, -L_RCC, 0.0, joint=2, prismatic=True),
        DHRow(0.0, 0.0, L_TOOL, 0.0, joint=3),
        DHRow(-_HALF_PI, 0.0, 0.0, -_HALF_PI, joint=4),
        DHRow(-_HALF_PI, L_PITCH2YAW, 0.0, -_HALF_PI, joint=5),
        DHRow(-_HALF_PI, 0.0, L_YAW2CTRLPNT, _HALF_PI),
    ),
    joint_names=_OUTER_NAMES + ("tool_roll", "wrist_pitch", "wrist_yaw"),
    lower=_OUTER_LOWER + (-4.538, -_WRIST_LIMIT, -_WRIST_LIMIT),
    upper=_OUTER_UPPER + (4.538, _WRIST_LIMIT, _WRIST_LIMIT),
    insertion_offset=L_RCC - L_TOOL,
    wrist_link=L_PITCH2YAW,
    tip_drop=L_YAW2CTRLPNT,
    has_jaw=True,
    measured_cp_to_tool_point=L_YAW2CTRLPNT,
)

#: Suction & Irrigation: the LND's frames without the roll joint (paper Table I); 5 joints.
SUCTION_IRRIGATION = Tool(
    name="suction_irrigation",
    rows=_OUTER_ROWS
    + (
        DHRow(_HALF_PI, 0.0, -SUCTION_IRRIGATION_PITCH_OFFSET, 0.0, joint=2, prismatic=True),
        DHRow(-_HALF_PI, 0.0, 0.0, -_HALF_PI, joint=3),
        DHRow(-_HALF_PI, SUCTION_IRRIGATION_TUBE_LENGTH, 0.0, -_HALF_PI, joint=4),
        # Tip frame at the tube end with the LND's tip-frame axes (z along the tool), so both tools share one
        # "pointing down" orientation.
        DHRow(-_HALF_PI, 0.0, 0.0, _HALF_PI),
    ),
    joint_names=_OUTER_NAMES + ("wrist_pitch", "wrist_yaw"),
    lower=_OUTER_LOWER + (-_WRIST_LIMIT, -_WRIST_LIMIT),
    upper=_OUTER_UPPER + (_WRIST_LIMIT, _WRIST_LIMIT),
    insertion_offset=SUCTION_IRRIGATION_PITCH_OFFSET,
    wrist_link=SUCTION_IRRIGATION_TUBE_LENGTH,
    tip_drop=0.0,
    has_jaw=False,
    measured_cp_to_tool_point=SUCTION_IRRIGATION_YAW2TIP,
)

TOOLS = {LND.name: LND, SUCTION_IRRIGATION.name: SUCTION_IRRIGATION}

#: The fixed tip orientation used by the environments (columns: tip x, y, z axes in the base frame). It is the
#: LND's home orientation: tool pointing down (-z), jaws opening about the base y axis.
TIP_ROTATION_DOWN = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def measured_cp_from_tool_point(tool: Tool | str, position) -> np.ndarray:
    """The dVRK's measured_cp position(s) for tool point position(s) ``(..., 3)`` with the tool pointing down
    (base frame, metres): ``measured_cp_to_tool_point`` straight above."""
    tool = get_tool(tool)
    result = np.array(position, dtype=np.float64)
    result[..., 2] += tool.measured_cp_to_tool_point
    return result


def tool_point_from_measured_cp(tool: Tool | str, position) -> np.ndarray:
    """Inverse of :func:`measured_cp_from_tool_point`."""
    tool = get_tool(tool)
    result = np.array(position, dtype=np.float64)
    result[..., 2] -= tool.measured_cp_to_tool_point
    return result


def measured_cp_forward_kinematics(tool: Tool | str, q) -> np.ndarray:
    """The dVRK's measured_cp pose(s) ``(..., 4, 4)``: the tool point's frame moved back along its z axis (the tool
    axis) by ``measured_cp_to_tool_point``. For the LND this is the origin of DH row 6, the end of
    ``LARGE_NEEDLE_DRIVER_400006.json``."""
    tool = get_tool(tool)
    pose = forward_kinematics(tool, q)
    pose[..., :3, 3] -= tool.measured_cp_to_tool_point * pose[..., :3, 2]
    return pose


def get_tool(tool: Tool | str) -> Tool:
    """Return a :class:`Tool` from itself or its name (``"lnd"``, ``"suction_irrigation"``)."""
    if isinstance(tool, Tool):
        return tool
    try:
        return TOOLS[tool]
    except (KeyError, TypeError):
        raise ValueError(f"unknown tool {tool!r}; expected one of {sorted(TOOLS)}") from None


def _dh_matrices(row: DHRow, q: np.ndarray | None, batch_shape: tuple[int, ...]) -> np.ndarray:
    theta = np.full(batch_shape, row.theta)
    d = np.full(batch_shape, row.d)
    if row.joint is not None:
        if row.prismatic:
            d = d + q[..., row.joint]
        else:
            theta = theta + q[..., row.joint]
    ca, sa = math.cos(row.alpha), math.sin(row.alpha)
    ct, st = np.cos(theta), np.sin(theta)
    m = np.zeros(batch_shape + (4, 4))
    m[..., 0, 0] = ct
    m[..., 0, 1] = -st
    m[..., 0, 3] = row.a
    m[..., 1, 0] = st * ca
    m[..., 1, 1] = ct * ca
    m[..., 1, 2] = -sa
    m[..., 1, 3] = -sa * d
    m[..., 2, 0] = st * sa
    m[..., 2, 1] = ct * sa
    m[..., 2, 2] = ca
    m[..., 2, 3] = ca * d
    m[..., 3, 3] = 1.0
    return m


def _as_finite(values, name: str, last: int) -> np.ndarray:
    array = np.asarray(values, dtype=float)
    if array.ndim == 0 or array.shape[-1] != last:
        raise ValueError(f"{name} must have shape (..., {last}), got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be finite, got {array.tolist()}")
    return array


def forward_kinematics(tool: Tool | str, q, *, frames: bool = False) -> np.ndarray:
    """Tool-tip pose(s) as homogeneous 4x4 matrices in the PSM base (RCM) frame.

    Args:
        tool: :data:`LND`, :data:`SUCTION_IRRIGATION` or their names.
        q: joint vector(s), shape ``(..., tool.n_joints)``.
        frames: if True, return every DH frame, shape ``(..., n_rows, 4, 4)``; the last one is the tip.

    Returns:
        ``(..., 4, 4)`` tip poses (or all frames).
    """
    tool = get_tool(tool)
    q = _as_finite(q, "q", tool.n_joints)
    batch = q.shape[:-1]
    pose = np.broadcast_to(np.eye(4), batch + (4, 4)).copy()
    all_frames = []
    for row in tool.rows:
        pose = pose @ _dh_matrices(row, q, batch)
        all_frames.append(pose)
    return np.stack(all_frames, axis=-3) if frames else pose


def _solve(tool: Tool, x, y, z, sqrt, atan2):
    """The closed form shared by both tools; works on floats (math) and arrays (numpy) alike.

    With the tip pointing down, the wrist yaw undoes the outer yaw and the wrist pitch the outer pitch (the LND's
    roll stays 0), so the point ``tip_drop`` above the tip lies at ``wrist_link`` from the shaft's end, in the
    plane of the outer yaw. For the S&I this is the paper's closed form (Sec. IV-C) with v = -z:
    theta_1 from the tip, theta_2 + theta_5 = 0, theta_6 = -theta_1.
    """
    z_link = z + tool.tip_drop
    outer_yaw = atan2(x, -z_link)
    radial = sqrt(x * x + z_link * z_link) - tool.wrist_link  # shaft-end distance from the RCM in that plane
    outer_pitch = atan2(-y, radial)
    insertion = sqrt(radial * radial + y * y) + tool.insertion_offset
    return outer_yaw, outer_pitch, insertion, radial


def _joint_vector(tool: Tool, outer_yaw, outer_pitch, insertion):
    if tool.has_jaw:
        return (outer_yaw, outer_pitch, insertion, 0.0 * outer_yaw, -outer_pitch, -outer_yaw)
    return (outer_yaw, outer_pitch, insertion, -outer_pitch, -outer_yaw)


def inverse_kinematics_point(tool: Tool, x: float, y: float, z: float) -> tuple[float, ...]:
    """Single-position IK on Python floats: the allocation-free path that environment steps use.

    Same solution as :func:`inverse_kinematics`; raises :class:`UnreachableError` likewise. Inputs must be finite
    floats (the environments validate actions before they get here).
    """
    outer_yaw, outer_pitch, insertion, radial = _solve(tool, x, y, z, math.sqrt, math.atan2)
    q = _joint_vector(tool, outer_yaw, outer_pitch, insertion)
    if radial <= 0.0:
        raise UnreachableError(tool.name, (x, y, z), "geometry", math.nan, (math.nan, math.nan))
    for index, value in enumerate(q):
        if value < tool.lower[index] or value > tool.upper[index]:
            raise UnreachableError(
                tool.name, (x, y, z), tool.joint_names[index], value, (tool.lower[index], tool.upper[index])
            )
    return q


def wrist_position_point(tool: Tool, q) -> tuple[float, float, float]:
    """The wrist pitch axis point on the shaft (base frame) for joint vector ``q``: where the straight shaft ends."""
    s1, c1 = math.sin(q[0]), math.cos(q[0])
    s2, c2 = math.sin(q[1]), math.cos(q[1])
    length = q[2] - tool.insertion_offset
    return (length * s1 * c2, -length * s2, -length * c1 * c2)


def wrist_position_batch(tool: Tool, q):
    """:func:`wrist_position_point` for joint vectors ``q`` ``(M, n_joints)``: ``(M, 3)``, base frame (any array
    library's arrays: numpy's, torch's, JAX's)."""
    xp = _namespace(q)
    s1, c1 = xp.sin(q[:, 0]), xp.cos(q[:, 0])
    s2, c2 = xp.sin(q[:, 1]), xp.cos(q[:, 1])
    length = q[:, 2] - tool.insertion_offset
    parts = (length * s1 * c2, -length * s2, -length * c1 * c2)
    if xp is not np:
        return xp.stack(parts, axis=1)
    wrist = np.empty((len(q), 3))  # (numpy: cheaper than stacking, on the step's path)
    wrist[:, 0], wrist[:, 1], wrist[:, 2] = parts
    return wrist


def _solve_batch(tool: Tool, position):
    xp = _namespace(position)
    x, y, z = position[..., 0], position[..., 1], position[..., 2]
    atan2 = np.arctan2 if xp is np else xp.atan2
    outer_yaw, outer_pitch, insertion, radial = _solve(tool, x, y, z, xp.sqrt, atan2)
    q = xp.stack(xp.broadcast_arrays(*_joint_vector(tool, outer_yaw, outer_pitch, insertion)), axis=-1)
    return q, radial


def _namespace(x):
    if isinstance(x, np.ndarray):
        return np
    from array_api_compat import array_namespace

    return array_namespace(x)


def within_limits(tool: Tool | str, position) -> np.ndarray:
    """Boolean mask, shape ``position.shape[:-1]``: which tip positions IK can reach within the joint limits."""
    tool = get_tool(tool)
    position = _as_finite(position, "position", 3)
    q, radial = _solve_batch(tool, position)
    lower, upper = np.asarray(tool.lower), np.asarray(tool.upper)
    return (radial > 0.0) & np.all((q >= lower) & (q <= upper), axis=-1)


def inverse_kinematics_batch(tool: Tool, position):
    """Unchecked batched IK for the batched core: ``(q, reachable)`` for finite positions ``(..., 3)`` (any array
    library's arrays).

    The same closed form and limit test as :func:`inverse_kinematics_point`, over arrays; ``q`` of unreachable
    positions is returned as computed (outside the limits), ``reachable`` says which rows are valid.
    """
    q, radial = _solve_batch(tool, position)
    lower, upper = _limit_arrays(tool)
    xp = _namespace(q)
    if xp is not np:
        lower, upper = xp.asarray(lower, dtype=q.dtype), xp.asarray(upper, dtype=q.dtype)
    return q, (radial > 0.0) & xp.all((q >= lower) & (q <= upper), axis=-1)


#: id(tool) -> (tool, lower, upper): the limits as arrays, made once per tool (keyed by identity: a cache keyed by the
#: tool itself would hash its DH rows on every batched IK call; the entry keeps the tool, so its id is never reused).
_LIMIT_ARRAYS: dict[int, tuple] = {}


def _limit_arrays(tool: Tool) -> tuple[np.ndarray, np.ndarray]:
    entry = _LIMIT_ARRAYS.get(id(tool))
    if entry is None:
        entry = _LIMIT_ARRAYS[id(tool)] = (tool, np.asarray(tool.lower), np.asarray(tool.upper))
    return entry[1], entry[2]


def inverse_kinematics(tool: Tool | str, position) -> np.ndarray:
    """Joint vector(s) that put the tool tip at ``position`` with the tool pointing down.

    Args:
        tool: :data:`LND`, :data:`SUCTION_IRRIGATION` or their names.
        position: tip position(s) in the base (RCM) frame, metres, shape ``(..., 3)``.

    Returns:
        ``(..., tool.n_joints)`` joint vectors (LND: 6, S&I: 5), satisfying ``forward_kinematics(tool, q)[..., :3, 3]
        == position`` and, for the LND, tip rotation :data:`TIP_ROTATION_DOWN`.

    Raises:
        ValueError: ``position`` has the wrong shape or is not finite.
        UnreachableError: a position (the first one, in a batch) needs a joint outside its limits.
    """
    tool = get_tool(tool)
    position = _as_finite(position, "position", 3)
    q, radial = _solve_batch(tool, position)
    lower, upper = np.asarray(tool.lower), np.asarray(tool.upper)
    bad_geometry = radial <= 0.0
    bad_joint = (q < lower) | (q > upper)
    bad = bad_geometry | np.any(bad_joint, axis=-1)
    if np.any(bad):
        index = tuple(np.argwhere(bad)[0]) if bad.ndim else ()
        if bad_geometry[index]:
            raise UnreachableError(tool.name, position[index], "geometry", math.nan, (math.nan, math.nan))
        joint = int(np.argmax(bad_joint[index]))
        raise UnreachableError(
            tool.name, position[index], tool.joint_names[joint], q[index][joint], (tool.lower[joint], tool.upper[joint])
        )
    return q
