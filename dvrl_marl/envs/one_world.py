"""One world of the collaborative core seen as one scene: its arms, blood and pins as the parallel env shows them.

The core keeps every world in arrays; these read (and, for an arm, move) world 0 of it, for code and tests that set up
or inspect one scene (``env.arms["grasper"].tip_world()``, ``env.blood.remaining_ml``, ``env.debris[0].held``).
"""

from __future__ import annotations

import math

import numpy as np

from dvrl_marl.suction_debris.rules import PIN_HALF_LENGTH

__all__ = ["WorldArm", "WorldBlood", "WorldPin"]


class WorldArm:
    """World 0 of an :class:`~dvrl_marl.core.arms.ArmBatch` as one arm (the single env's ``arms[agent]``)."""

    def __init__(self, batch):
        self._batch = batch
        self.tool = batch.tool
        self.base_position = batch.base_position
        self.base_rotation = np.eye(3)  # (the collaborative scene's bases are upright: SceneGeometry checks)

    @property
    def tip(self) -> list[float]:
        """The tip (base frame, m)."""
        return self._batch.tip[0].tolist()

    @property
    def q(self) -> tuple:
        return tuple(self._batch.q[0].tolist())

    @property
    def jaw(self) -> float:
        return float(self._batch.jaw[0])

    def tip_world(self) -> tuple[float, float, float]:
        return tuple((self._batch.tip[0] + self.base_position).tolist())

    def to_base(self, position_world) -> np.ndarray:
        return np.asarray(position_world, dtype=np.float64) - self.base_position

    def to_world(self, position_base) -> np.ndarray:
        return np.asarray(position_base, dtype=np.float64) + self.base_position

    def set_tip(self, x: float, y: float, z: float) -> None:
        """Put the tip at (x, y, z) (base frame) by inverse kinematics (UnreachableError where it cannot be)."""
        self._batch.set_tips(np.array([0]), np.array([[x, y, z]], dtype=np.float64))

    def set_jaw(self, jaw: float) -> None:
        self._batch.jaw[0] = float(jaw)


class WorldBlood:
    """World 0's blood (the single env's ``blood``, a record): volumes per cavity in ml, surfaces in m."""

    def __init__(self, core):
        cavities = core.phantom.cavities
        self.initial_ml = tuple(core.initial_ml[0].tolist())
        self.added_ml = core.added_ml[0].tolist()
        self.remaining_ml = core.remaining_ml[0].tolist()
        self.removed_ml = tuple(core.removed_ml[0].tolist())
        self.surface_z = tuple(core.surface_z[0].tolist())
        self.surface_radius = tuple(c.surface_radius(z - c.floor_z) for c, z in zip(cavities, self.surface_z))
        self._capacity_ml = tuple(c.capacity_ml for c in cavities)
        self.suction_rate_ml_s = core.params.suction_rate_ml_s

    def fraction(self, index: int) -> float:
        """Fraction of the cavity's initial blood still in it (above 1 when a bleed added more); a cavity that
        started empty reports its blood as a fraction of its capacity."""
        initial = self.initial_ml[index]
        return self.remaining_ml[index] / (initial if initial > 0.0 else self._capacity_ml[index])


def _pin_field(name: str, kind):
    """A property reading pin ``index``'s ``name`` of world 0 from the core, as ``kind``."""
    return property(lambda pin: kind(getattr(pin._core, name)[0, pin._index]))


def _fall_speed(value) -> float | None:
    return None if math.isnan(value) else float(value)  # (m/s while it falls, None at rest)


class WorldPin:
    """Pin ``index`` of world 0, read live from the core (the single env's ``debris[index]``)."""

    def __init__(self, core, index: int):
        self._core, self._index = core, index

    position = property(lambda pin: pin._core.debris_position[0, pin._index].tolist())
    yaw = _pin_field("debris_yaw", float)
    cavity = _pin_field("debris_cavity", int)
    visible = _pin_field("visible", bool)
    held = _pin_field("held", bool)
    delivered = _pin_field("delivered", bool)
    lifted = _pin_field("lifted", bool)
    fall_speed = _pin_field("fall_speed", _fall_speed)

    def axis_ends(self):
        dx, dy = PIN_HALF_LENGTH * math.cos(self.yaw), PIN_HALF_LENGTH * math.sin(self.yaw)
        x, y, z = self.position
        return (x - dx, y - dy, z), (x + dx, y + dy, z)
