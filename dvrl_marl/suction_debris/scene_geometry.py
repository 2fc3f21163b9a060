"""What the collaborative core needs of a scene file, read from its MJCF text: no MuJoCo inside.

The core steps worlds without a physics engine, so it takes the few fixed facts it needs from the scene file itself:
the phantom (its height field's extent and height, the cavities cut into it: :mod:`dvrl_marl.assets` writes both),
the table's top, each PSM's remote centre of motion (the frame its arm is attached in) and the hand-off point. The
MuJoCo mirror that renders a world compiles the same file; a test holds the two readings equal.
"""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass

import numpy as np

from dvrl_marl import assets
from dvrl_marl.suction_debris.phantom import Cavity, Phantom

__all__ = ["SceneGeometry", "ARM_PREFIXES"]

#: The prefix each arm's names carry in the collaborative scene (its ``<attach prefix=...>``).
ARM_PREFIXES = {"suction": "suction/", "grasper": "grasper/"}


def _vector(element, attribute: str, default: str, where: str) -> np.ndarray:
    text = element.get(attribute, default)
    try:
        return np.array([float(v) for v in text.split()], dtype=np.float64)
    except ValueError:
        raise ValueError(f"{where}: {attribute}={text!r} is not a list of numbers") from None


def _named(root, tag: str, name: str, where: str):
    for element in root.iter(tag):
        if element.get("name") == name:
            return element
    raise ValueError(f"{where}: the scene has no <{tag} name={name!r}>")


def _upright(element, where: str) -> None:
    quat = _vector(element, "quat", "1 0 0 0", where)
    if any(a in element.attrib for a in ("euler", "axisangle", "xyaxes", "zaxis")) or not np.allclose(quat, (1, 0, 0, 0)):
        raise ValueError(f"{where}: the collaborative scene needs upright, unrotated PSM bases "
                         f"(<{element.tag} name={element.get('name')!r}> is rotated)")


@dataclass(frozen=True)
class SceneGeometry:
    """The fixed geometry of a collaborative scene, in world coordinates (metres)."""

    phantom: Phantom
    base_positions: dict  # agent -> (3,) RCM position
    handoff: tuple[float, float, float]

    @classmethod
    def from_scene(cls, scene: str) -> "SceneGeometry":
        """Read scene ``scene`` (a name under ``scenes/``) without compiling it."""
        path = assets.scene_path(scene)
        where = f"scene {path.name}"
        root = ElementTree.parse(path).getroot()
        geom = _named(root, "geom", "phantom", where)
        field = _named(root, "hfield", geom.get("hfield", ""), where)
        size = _vector(field, "size", "", f"{where}: hfield {field.get('name')!r}")
        centre = _vector(geom, "pos", "0 0 0", f"{where}: geom 'phantom'")
        top = float(centre[2] + size[2])
        table = _named(root, "geom", "table", where)
        table_top = float(_vector(table, "pos", "0 0 0", where)[2] + _vector(table, "size", "", where)[2])
        cavities = tuple(Cavity(float(centre[0] + cx), float(centre[1] + cy), top, assets.CAVITY_MOUTH_RADIUS,
                                assets.CAVITY_DEPTH) for cx, cy in assets.CAVITY_CENTRES)
        phantom = Phantom(float(centre[0]), float(centre[1]), float(size[0]), float(size[1]), top, table_top, cavities)
        models = {model.get("name"): model.get("file") for model in root.iter("model")}
        bases = {}
        for frame in root.iter("frame"):
            for attach in frame.iter("attach"):
                agent = next((a for a, prefix in ARM_PREFIXES.items() if attach.get("prefix") == prefix), None)
                if agent is None:
                    continue
                _upright(frame, where)
                robot = ElementTree.parse(path.parent / models[attach.get("model")]).getroot()
                body = _named(robot, "body", attach.get("body", ""), f"scene {models[attach.get('model')]}")
                _upright(body, where)
                bases[agent] = _vector(frame, "pos", "0 0 0", where) + _vector(body, "pos", "0 0 0", where)
        missing = [agent for agent in ARM_PREFIXES if agent not in bases]
        if missing:
            raise ValueError(f"{where}: no arm attached with prefix {ARM_PREFIXES[missing[0]]!r}")
        handoff = _vector(_named(root, "site", "handoff", where), "pos", "0 0 0", where)
        return cls(phantom, bases, tuple(float(v) for v in handoff))
