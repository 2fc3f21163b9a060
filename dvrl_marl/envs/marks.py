"""Marks drawn into a rendered scene for a person in the seat: depth and the hand-off point at a glance.

One oblique endoscope view hides depth: moving a tip forward and moving it up both move it up in the image. A drop
line from each tip to the surface below it, ending in a disc on that surface, shows where over the phantom the tip
is and how high (the line's length); the disc turns green when closing the jaw would take a pin. The hand-off
point keeps a beacon, a thin vertical post above it that the instruments cannot hide all of.

The marks are decoration only (``MjvScene`` geoms added after the scene is updated): nothing in the simulation
changes, and they are drawn in every version of the scene, in the browser's frames and in the desktop window.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

__all__ = ["Mark", "add_marks", "COLOURS"]

#: RGBA of each kind of mark.
COLOURS = {
    "suction": (0.35, 0.85, 1.0, 0.9),
    "grasper": (1.0, 0.85, 0.2, 0.9),
    "in_reach": (0.2, 1.0, 0.35, 1.0),
    "handoff": (0.1, 0.95, 0.35, 0.55),
}
_LINE_RADIUS = 0.0003  # m: a drop line as thin as it can be and still be seen at 640 x 480
_DISC_RADIUS = 0.0025  # m: about a jaw's width
_DISC_HALF_HEIGHT = 0.0002
_BEACON_HEIGHT = 0.05  # m above the hand-off point
_BEACON_RADIUS = 0.0006
_IDENTITY = np.eye(3).ravel()


@dataclass(frozen=True)
class Mark:
    """A drop line from ``tip`` to ``foot`` (world, m), drawn in ``colour``."""

    tip: tuple[float, float, float]
    foot: tuple[float, float, float]
    colour: tuple[float, float, float, float]


def _new_geom(scene):
    if scene.ngeom >= scene.maxgeom:
        return None  # a full scene loses its marks, never its frame
    geom = scene.geoms[scene.ngeom]
    scene.ngeom += 1
    return geom


def _connector(scene, start, end, radius, colour) -> None:
    geom = _new_geom(scene)
    if geom is None:
        return
    mujoco.mjv_initGeom(geom, mujoco.mjtGeom.mjGEOM_CAPSULE, np.zeros(3), np.zeros(3), _IDENTITY,
                        np.asarray(colour, dtype=np.float32))
    mujoco.mjv_connector(geom, mujoco.mjtGeom.mjGEOM_CAPSULE, radius, np.asarray(start, float), np.asarray(end, float))


def add_marks(scene, marks, handoff) -> None:
    """Add the drop lines of ``marks`` and the hand-off beacon at ``handoff`` (world, m) to an updated ``scene``."""
    for mark in marks:
        if mark.tip[2] - mark.foot[2] > 1e-4:
            _connector(scene, mark.tip, mark.foot, _LINE_RADIUS, mark.colour)
        disc = _new_geom(scene)
        if disc is not None:
            mujoco.mjv_initGeom(disc, mujoco.mjtGeom.mjGEOM_CYLINDER,
                                np.array([_DISC_RADIUS, _DISC_RADIUS, _DISC_HALF_HEIGHT]),
                                np.array([mark.foot[0], mark.foot[1], mark.foot[2] + _DISC_HALF_HEIGHT]), _IDENTITY,
                                np.asarray(mark.colour, dtype=np.float32))
    top = (handoff[0], handoff[1], handoff[2] + _BEACON_HEIGHT)
    _connector(scene, handoff, top, _BEACON_RADIUS, COLOURS["handoff"])
