"""Where the scenes and tasks live, and how the PSM models and their meshes are built.

``scenes/`` and ``tasks/`` sit at the repository root and are shipped inside the wheel as ``dvrl_marl/scenes``
and ``dvrl_marl/tasks``; :func:`scenes_dir` and :func:`tasks_dir` find either layout.

The robot files ``scenes/psm_lnd.xml`` and ``scenes/psm_suction_irrigation.xml`` are *written* from the DH tables
in :mod:`dvrl_marl.kinematics` by :func:`robot_xml`, so the MuJoCo chain reproduces the DH forward kinematics
exactly. Meshes (and the phantom's height field) are generated procedurally with trimesh by
:func:`write_generated_assets`; ``python -m dvrl_marl.assets`` (or ``scripts/build_assets.py``) rewrites them all,
byte for byte the same each time. Nothing here runs when an environment steps.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from dvrl_marl import kinematics
from dvrl_marl.kinematics import Tool

_PACKAGE_DIR = Path(__file__).resolve().parent

#: Shaft diameter of the 8 mm EndoWrists as modelled in the original dVRL scene (psm_facts.md).
SHAFT_RADIUS = 0.0085 / 2
#: Each LND jaw finger turns this many radians times the jaw value j in [0, 1] (original dVRL scene).
JAW_FINGER_OPEN_ANGLE = 0.4106
#: Jaw finger length from the yaw axis (the control point sits at 10.2 mm, inside the jaws).
JAW_FINGER_LENGTH = 0.0125
#: Half extents (tip frame x, y, z) of the proximity sensor volume between the jaws, for the paper's grasp rule.
GRASP_ZONE_HALF_EXTENTS = (0.002, 0.0025, 0.003)
#: Radius of the S&I tube.
SUCTION_TUBE_RADIUS = 0.0025


def _resolve(name: str) -> Path:
    installed = _PACKAGE_DIR / name
    if installed.is_dir():
        return installed
    source = _PACKAGE_DIR.parent / name
    if source.is_dir():
        return source
    raise FileNotFoundError(f"cannot find the {name!r} folder next to {_PACKAGE_DIR} (is the package installed?)")


def configs_dir() -> Path:
    """The training configurations of record (``baselines/configs`` in a clone, ``dvrl_marl/configs`` in a wheel)."""
    installed = _PACKAGE_DIR / "configs"
    if installed.is_dir():
        return installed
    source = _PACKAGE_DIR.parent / "baselines" / "configs"
    if source.is_dir():
        return source
    raise FileNotFoundError(f"cannot find the training configurations next to {_PACKAGE_DIR}")


def scenes_dir() -> Path:
    """The folder of MJCF scenes and their meshes."""
    return _resolve("scenes")


def tasks_dir() -> Path:
    """The folder of task definitions (TOML)."""
    return _resolve("tasks")


def scene_path(name: str) -> Path:
    """Path of a scene file by name (``"pick_lnd"`` or ``"pick_lnd.xml"``)."""
    filename = name if name.endswith(".xml") else f"{name}.xml"
    path = scenes_dir() / filename
    if not path.is_file():
        available = sorted(p.stem for p in scenes_dir().glob("*.xml"))
        raise FileNotFoundError(f"no scene {name!r}; available: {available}")
    return path


# --- MJCF writing -----------------------------------------------------------------------------------------


def _fmt(values) -> str:
    return " ".join(repr(float(v)) if v != 0 else "0" for v in values)


def _rotation_quat(alpha: float, theta: float) -> tuple[float, float, float, float]:
    """Quaternion (w, x, y, z) of Rx(alpha) Rz(theta)."""
    ca, sa = math.cos(alpha / 2), math.sin(alpha / 2)
    ct, st = math.cos(theta / 2), math.sin(theta / 2)
    return (ca * ct, sa * ct, -sa * st, ca * st)


def _row_frame(row: kinematics.DHRow) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
    """Body position and orientation for a modified-DH row: Rx(alpha) Tx(a) Rz(theta0) Tz(d0)."""
    sa, ca = math.sin(row.alpha), math.cos(row.alpha)
    return (row.a, -sa * row.d, ca * row.d), _rotation_quat(row.alpha, row.theta)


# Geometry placement per tool: for each body (joint) name, a list of (mesh, pos, quat, material). Frames follow
# the DH rows: on the LND the shaft rolls (tool_roll body), on the S&I the insertion body carries it.
_QUAT_SHAFT_IN_PITCH = _rotation_quat(math.pi / 2, 0.0)  # frame 2 -> frame 3 orientation (shaft along z)
_IDENTITY = (1.0, 0.0, 0.0, 0.0)


def _geometry(tool: Tool) -> dict[str, list[tuple[str, tuple, tuple, str]]]:
    common = {
        "outer_pitch": [
            ("cannula", (0, 0, 0), _QUAT_SHAFT_IN_PITCH, "cannula"),
            ("instrument_rail", (0, 0, 0), _QUAT_SHAFT_IN_PITCH, "arm_white"),
        ],
    }
    if tool.has_jaw:
        # Frame 3's origin is the shaft's back end, frame 4's the wrist pitch axis; the shaft rolls with frame 4.
        return common | {
            "insertion": [("tool_housing", (0, 0, 0), _IDENTITY, "arm_blue")],
            "tool_roll": [("shaft_lnd", (0, 0, -kinematics.L_TOOL), _IDENTITY, "shaft")],
            "wrist_pitch": [("wrist_clevis", (0, 0, 0), _IDENTITY, "metal")],
            "wrist_yaw": [("yaw_hub", (0, 0, 0), _IDENTITY, "metal")],
        }
    # No roll joint: frame 3's origin is already the wrist pitch axis and carries the shaft.
    back_end = -_suction_shaft_length()
    return common | {
        "insertion": [
            ("tool_housing", (0, 0, back_end), _IDENTITY, "arm_blue"),
            ("shaft_suction_irrigation", (0, 0, back_end), _IDENTITY, "shaft"),
        ],
        "wrist_pitch": [("suction_tube", (0, 0, 0), _IDENTITY, "metal")],
    }


def _suction_shaft_length() -> float:
    """The S&I shaft starts where the LND's does (l_RCC behind the RCM at zero insertion)."""
    return kinematics.L_RCC - kinematics.SUCTION_IRRIGATION_PITCH_OFFSET


def robot_xml(tool: Tool | str) -> str:
    """MJCF text for one PSM with ``tool``, written from its DH rows (the generated ``scenes/psm_*.xml``)."""
    tool = kinematics.get_tool(tool)
    geometry = _geometry(tool)
    moving = [row for row in tool.rows if row.joint is not None]
    tip_row = tool.rows[-1]
    lines = [
        f'<mujoco model="psm_{tool.name}">',
        "  <!-- Generated by `python -m dvrl_marl.assets` from dvrl_marl/kinematics.py; do not edit by hand. -->",
        '  <compiler angle="radian" meshdir="meshes"/>',
        "  <default>",
        '    <default class="psm">',
        '      <geom type="mesh" contype="0" conaffinity="0" group="1" density="0"/>',
        '      <joint armature="0.01" damping="1"/>',
        '      <site group="4" rgba="0.2 0.9 0.2 0.4"/>',
        "    </default>",
        "  </default>",
        "  <asset>",
        '    <material name="shaft" rgba="0.12 0.12 0.13 1" specular="0.6" shininess="0.6"/>',
        '    <material name="metal" rgba="0.72 0.73 0.76 1" specular="0.9" shininess="0.9"/>',
        '    <material name="arm_white" rgba="0.9 0.9 0.88 1" specular="0.3"/>',
        '    <material name="arm_blue" rgba="0.25 0.45 0.75 1" specular="0.3"/>',
        '    <material name="cannula" rgba="0.55 0.57 0.6 1" specular="0.7"/>',
    ]
    mesh_names = sorted({g[0] for parts in geometry.values() for g in parts} | ({"jaw_finger"} if tool.has_jaw else set()))
    lines += [f'    <mesh name="{m}" file="{m}.stl"/>' for m in mesh_names]
    lines += ["  </asset>", "  <worldbody>", '    <body name="rcm" childclass="psm">', '      <site name="rcm" size="0.002"/>']
    indent = "      "
    for row in moving:
        name = tool.joint_names[row.joint]
        pos, quat = _row_frame(row)
        lower, upper = tool.lower[row.joint], tool.upper[row.joint]
        joint_type = "slide" if row.prismatic else "hinge"
        # gravcomp: the arm is kinematic; physics steps (for free objects) must not let it sag.
        lines.append(f'{indent}<body name="{name}" pos="{_fmt(pos)}" quat="{_fmt(quat)}" gravcomp="1">')
        lines.append(f'{indent}  <joint name="{name}" type="{joint_type}" axis="0 0 1" range="{_fmt((lower, upper))}"/>')
        lines.append(f'{indent}  <inertial pos="0 0 0" mass="0.05" diaginertia="1e-5 1e-5 1e-5"/>')
        for mesh, gpos, gquat, material in geometry.get(name, []):
            lines.append(f'{indent}  <geom name="{name}_{mesh}" mesh="{mesh}" pos="{_fmt(gpos)}" quat="{_fmt(gquat)}" material="{material}"/>')
        indent += "  "
    tip_pos, tip_quat = _row_frame(tip_row)
    lines.append(f'{indent}<site name="tip" pos="{_fmt(tip_pos)}" quat="{_fmt(tip_quat)}" size="0.0008"/>')
    if tool.has_jaw:
        zone = GRASP_ZONE_HALF_EXTENTS
        lines.append(
            f'{indent}<site name="grasp_zone" type="box" pos="{_fmt(tip_pos)}" quat="{_fmt(tip_quat)}" size="{_fmt(zone)}"/>'
        )
        # Fingers turn about the yaw axis (frame z); they extend along the tip direction (frame y).
        # The left finger lies on the frame's +x side and opens towards +x, i.e. turns about -z.
        for side, sign in (("left", -1.0), ("right", 1.0)):
            lines.append(f'{indent}<body name="jaw_{side}" gravcomp="1">')
            lines.append(
                f'{indent}  <joint name="jaw_{side}" type="hinge" axis="0 0 {sign:g}" range="-0.349 0.698"/>'
            )
            lines.append(f'{indent}  <inertial pos="0 0.006 0" mass="0.002" diaginertia="1e-7 1e-7 1e-7"/>')
            mirror = "1 0 0 0" if side == "left" else "0 0 1 0"
            lines.append(f'{indent}  <geom name="jaw_{side}" mesh="jaw_finger" quat="{mirror}" material="metal"/>')
            lines.append(f"{indent}</body>")
    for _ in moving:
        indent = indent[:-2]
        lines.append(f"{indent}</body>")
    lines += ["    </body>", "  </worldbody>", "</mujoco>", ""]
    return "\n".join(lines)


# --- Procedural meshes ------------------------------------------------------------------------------------


def build_meshes() -> dict:
    """Every mesh of the PSM models, as trimesh objects keyed by file stem. Deterministic."""
    import trimesh
    from trimesh.creation import box, cylinder

    def along_z(mesh, z0: float, z1: float):
        mesh.apply_translation((0, 0, (z0 + z1) / 2))
        return mesh

    def tube(radius: float, z0: float, z1: float, sections: int = 24):
        return along_z(cylinder(radius=radius, height=z1 - z0, sections=sections), z0, z1)

    meshes = {}
    # Shaft: 8.5 mm, from the tool housing to the wrist (mesh frame: z from 0 to l_tool).
    meshes["shaft_lnd"] = tube(SHAFT_RADIUS, 0.0, kinematics.L_TOOL, sections=32)
    meshes["shaft_suction_irrigation"] = tube(SHAFT_RADIUS, 0.0, _suction_shaft_length(), sections=32)
    # Cannula around the shaft through the RCM (in the shaft frame: z along the tool, RCM at 0).
    meshes["cannula"] = trimesh.util.concatenate(
        [tube(0.0058, -0.12, 0.015, sections=32), tube(0.011, -0.16, -0.12, sections=32)]
    )
    # Instrument rail of the insertion stage, beside the shaft, behind the cannula.
    rail = box(extents=(0.012, 0.03, 0.33))
    rail.apply_translation((0.0, 0.03, -0.16 - 0.165))
    meshes["instrument_rail"] = rail
    # Tool housing (the instrument's back end, seated on the sterile adapter), at the shaft's back end.
    housing = box(extents=(0.045, 0.06, 0.03))
    housing.apply_translation((0.0, 0.015, -0.015))
    disc = tube(0.009, -0.005, 0.004)
    meshes["tool_housing"] = trimesh.util.concatenate([housing, disc])
    # LND wrist (frame 5: z the pitch axis, x the link to the yaw axis): a hub on the pitch pin and the link.
    hub = tube(SHAFT_RADIUS, -0.004, 0.004, sections=24)
    link = box(extents=(kinematics.L_PITCH2YAW, 0.004, 0.0035))
    link.apply_translation((kinematics.L_PITCH2YAW / 2, 0.0, 0.0))
    meshes["wrist_clevis"] = trimesh.util.concatenate([hub, link])
    meshes["yaw_hub"] = tube(0.0022, -0.0024, 0.0024, sections=20)
    # Jaw finger in the yaw frame: from the yaw axis along +y, tapering, lying on the +x side of the gap.
    # A unit box whose eight corners are moved onto a tapered prism (1.8 mm wide at the axis, 1.1 mm at the tip).
    finger = box(extents=(1.0, 1.0, 1.0))
    corners = finger.vertices
    along = corners[:, 1] > 0  # tip end
    outer = corners[:, 0] > 0
    x_inner = np.where(along, 0.0005, 0.0002)
    x_outer = np.where(along, 0.0016, 0.002)
    finger.vertices = np.column_stack(
        [np.where(outer, x_outer, x_inner), np.where(along, JAW_FINGER_LENGTH, 0.0), corners[:, 2] * 0.0024]
    )
    meshes["jaw_finger"] = finger
    # S&I tube: from the pitch axis along frame x for l_5, with a hub on the pitch axis and a lip at the tip.
    tube_len = kinematics.SUCTION_IRRIGATION_TUBE_LENGTH
    stem = cylinder(radius=SUCTION_TUBE_RADIUS, height=tube_len, sections=24)
    stem.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, (0, 1, 0)))
    stem.apply_translation((tube_len / 2, 0, 0))
    lip = cylinder(radius=SUCTION_TUBE_RADIUS + 0.0006, height=0.0015, sections=24)
    lip.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, (0, 1, 0)))
    lip.apply_translation((tube_len - 0.00075, 0, 0))
    meshes["suction_tube"] = trimesh.util.concatenate([tube(0.0042, -0.004, 0.002), stem, lip])
    return meshes


#: Phantom: a gelatin block with two spherical-cap cavities, as a height field (collision and visual).
PHANTOM_SIZE = (0.07, 0.045)  # half extents x, y of the height field (m)
PHANTOM_HEIGHT = 0.03  # top surface above the table (m)
PHANTOM_BASE = 0.004  # thickness below the lowest point of the height field (m)
#: Cavity centres (x, y) in the phantom frame, mouth radius and depth (m).
CAVITY_CENTRES = ((-0.03, 0.0), (0.03, 0.0))
CAVITY_MOUTH_RADIUS = 0.022
CAVITY_DEPTH = 0.013
PHANTOM_GRID = 141


def cavity_sphere_radius() -> float:
    """Radius of the sphere whose cap forms each cavity."""
    return (CAVITY_MOUTH_RADIUS**2 + CAVITY_DEPTH**2) / (2 * CAVITY_DEPTH)


def phantom_surface_depth(x, y) -> np.ndarray:
    """Depth below the phantom's top surface at (x, y) in the phantom frame (0 outside the cavities)."""
    radius = cavity_sphere_radius()
    x, y = np.asarray(x, float), np.asarray(y, float)
    depth = np.zeros(np.broadcast(x, y).shape)
    for cx, cy in CAVITY_CENTRES:
        r2 = (x - cx) ** 2 + (y - cy) ** 2
        inside = r2 < CAVITY_MOUTH_RADIUS**2
        bowl = CAVITY_DEPTH - (radius - np.sqrt(np.maximum(radius**2 - r2, 0.0)))
        depth = np.where(inside, np.maximum(depth, bowl), depth)
    return depth


def phantom_heightfield() -> np.ndarray:
    """Elevation grid in [0, 1] (row = y, from -y to +y), as MuJoCo's height field expects."""
    xs = np.linspace(-PHANTOM_SIZE[0], PHANTOM_SIZE[0], PHANTOM_GRID)
    ys = np.linspace(-PHANTOM_SIZE[1], PHANTOM_SIZE[1], PHANTOM_GRID)
    gx, gy = np.meshgrid(xs, ys)
    depth = phantom_surface_depth(gx, gy)
    return 1.0 - depth / CAVITY_DEPTH


def write_generated_assets(root: Path | None = None) -> list[Path]:
    """Write the robot MJCF files, meshes (binary STL) and phantom height field under ``root`` (scenes/)."""
    root = Path(root) if root is not None else scenes_dir()
    (root / "meshes").mkdir(parents=True, exist_ok=True)
    written = []
    for tool in kinematics.TOOLS.values():
        path = root / f"psm_{tool.name}.xml"
        path.write_text(robot_xml(tool))
        written.append(path)
    for name, mesh in sorted(build_meshes().items()):
        path = root / "meshes" / f"{name}.stl"
        # Round vertices so the bytes do not depend on floating-point noise across platforms.
        mesh = mesh.copy()
        mesh.vertices = np.round(mesh.vertices, 7)
        path.write_bytes(mesh.export(file_type="stl"))
        written.append(path)
    elevation = phantom_heightfield().astype("<f4")
    path = root / "meshes" / "phantom.bin"
    header = np.array(elevation.shape, dtype="<i4")
    path.write_bytes(header.tobytes() + elevation.tobytes())
    written.append(path)
    return written


if __name__ == "__main__":
    for written_path in write_generated_assets():
        print(written_path)
