"""Loading MJCF scenes and looking up their named parts.

Compiled models are cached per scene file, and every caller gets its own copy (environments change geometry,
e.g. the blood surfaces, in their model).
"""

from __future__ import annotations

import copy
import functools

import mujoco
import numpy as np

from dvrl_marl.assets import scene_path

__all__ = ["load_model", "object_id", "geom_top", "MujocoWarningError", "raise_on_warnings", "has_warnings"]


@functools.lru_cache(maxsize=16)
def _compiled(name: str) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(scene_path(name)))


def load_model(name: str) -> mujoco.MjModel:
    """A fresh copy of the compiled scene ``name`` (e.g. ``"pick_lnd"``)."""
    return copy.copy(_compiled(name))


def object_id(model: mujoco.MjModel, kind: str, name: str) -> int:
    """Id of a named body/geom/site/joint/camera; a clear error naming the scene when it is missing."""
    obj = {"body": mujoco.mjtObj.mjOBJ_BODY, "geom": mujoco.mjtObj.mjOBJ_GEOM, "site": mujoco.mjtObj.mjOBJ_SITE,
           "joint": mujoco.mjtObj.mjOBJ_JOINT, "camera": mujoco.mjtObj.mjOBJ_CAMERA}[kind]
    index = mujoco.mj_name2id(model, obj, name)
    if index < 0:
        raise KeyError(f"scene has no {kind} named {name!r}")
    return index


def geom_top(model: mujoco.MjModel, name: str) -> float:
    """World height of the top face of an axis-aligned box geom on the world body (e.g. the table)."""
    gid = object_id(model, "geom", name)
    if int(model.geom_type[gid]) != int(mujoco.mjtGeom.mjGEOM_BOX) or model.geom_bodyid[gid] != 0:
        raise ValueError(f"geom {name!r} must be a box on the world body")
    return float(model.geom_pos[gid][2] + model.geom_size[gid][2])


class MujocoWarningError(RuntimeError):
    """MuJoCo raised a simulation warning (instability, contact overflow, ...)."""


def raise_on_warnings(data: mujoco.MjData) -> None:
    """Raise :class:`MujocoWarningError` if any MuJoCo warning counter is set."""
    counts = [int(data.warning[i].number) for i in range(len(data.warning))]
    if any(counts):
        names = [mujoco.mjtWarning(i).name for i, n in enumerate(counts) if n]
        raise MujocoWarningError(f"MuJoCo warnings: {names}")


def has_warnings(data: mujoco.MjData) -> bool:
    """True if any MuJoCo warning counter is set (cheap enough for a step path)."""
    return bool(np.any(data.warning.number))
