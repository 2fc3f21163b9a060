"""The phantom and its cavities: plain geometry, no MuJoCo inside.

Each cavity is a spherical cap (mouth radius ``a``, depth ``D``, sphere radius ``R = (a^2 + D^2) / (2 D)``). Blood of
volume V fills it to the depth h with ``V = pi h^2 (3R - h) / 3``; its surface is a disc of radius
``sqrt(h (2R - h))``. :class:`Cavity` and :class:`Phantom` answer for one point; :class:`Cavities` holds the same
geometry as arrays and answers for many worlds at once (the collaborative core's step and the sliding rules read it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dvrl_marl.core.backend import namespace, needed, repeat

__all__ = ["Cavity", "Phantom", "Cavities"]

_ML = 1e-6  # m^3 per millilitre


@dataclass(frozen=True)
class Cavity:
    """A spherical-cap cavity; positions in world coordinates (metres)."""

    centre_x: float
    centre_y: float
    top_z: float
    mouth_radius: float
    depth: float

    @property
    def sphere_radius(self) -> float:
        return (self.mouth_radius**2 + self.depth**2) / (2.0 * self.depth)

    @property
    def floor_z(self) -> float:
        return self.top_z - self.depth

    @property
    def capacity_ml(self) -> float:
        return self.volume_ml(self.depth)

    def volume_ml(self, fill_depth: float) -> float:
        """Blood volume (ml) filling the cavity to ``fill_depth`` above its floor."""
        h = min(max(fill_depth, 0.0), self.depth)
        return math.pi * h * h * (3.0 * self.sphere_radius - h) / 3.0 / _ML

    def fill_depth(self, volume_ml: float) -> float:
        """Inverse of :meth:`volume_ml` (Newton's method on the monotonic cubic, then bisection-safe clamp)."""
        if volume_ml <= 0.0:
            return 0.0
        if volume_ml >= self.capacity_ml:
            return self.depth
        radius = self.sphere_radius
        target = volume_ml * _ML * 3.0 / math.pi  # h^2 (3R - h)
        h = min(math.sqrt(target / (3.0 * radius)), self.depth)  # small-h guess
        for _ in range(30):
            f = h * h * (3.0 * radius - h) - target
            slope = 6.0 * radius * h - 3.0 * h * h
            step = f / slope
            h = min(max(h - step, 0.0), self.depth)
            if abs(step) < 1e-13:
                break
        return h

    def surface_radius(self, fill_depth: float) -> float:
        h = min(max(fill_depth, 0.0), self.depth)
        return math.sqrt(max(h * (2.0 * self.sphere_radius - h), 0.0))

    def floor_depth_at(self, x: float, y: float) -> float:
        """Depth of the cavity surface below the phantom top at (x, y); 0 outside the mouth."""
        r2 = (x - self.centre_x) ** 2 + (y - self.centre_y) ** 2
        if r2 >= self.mouth_radius**2:
            return 0.0
        radius = self.sphere_radius
        return self.depth - (radius - math.sqrt(radius * radius - r2))


@dataclass(frozen=True)
class Phantom:
    """The gelatin block: a rectangle (world x/y half extents around a centre) with cavities cut into its top."""

    centre_x: float
    centre_y: float
    half_x: float
    half_y: float
    top_z: float
    table_z: float
    cavities: tuple[Cavity, ...]

    def surface_height(self, x: float, y: float) -> float:
        """Height of the first solid surface below (x, y): cavity floor, phantom top or table."""
        if abs(x - self.centre_x) > self.half_x or abs(y - self.centre_y) > self.half_y:
            return self.table_z
        depth = 0.0
        for cavity in self.cavities:
            depth = max(depth, cavity.floor_depth_at(x, y))
        return self.top_z - depth

    def nearest_on_top(self, x: float, y: float, margin: float) -> tuple[float, float]:
        """(x, y) when it is over the phantom; else the nearest point ``margin`` inside its top's edge."""
        dx, dy = x - self.centre_x, y - self.centre_y
        if abs(dx) <= self.half_x and abs(dy) <= self.half_y:
            return x, y
        reach_x, reach_y = self.half_x - margin, self.half_y - margin
        return (self.centre_x + min(max(dx, -reach_x), reach_x), self.centre_y + min(max(dy, -reach_y), reach_y))

    def cavity_at(self, x: float, y: float) -> int:
        """Index of the cavity whose mouth contains (x, y), or -1."""
        for index, cavity in enumerate(self.cavities):
            if (x - cavity.centre_x) ** 2 + (y - cavity.centre_y) ** 2 < cavity.mouth_radius**2:
                return index
        return -1


#: numpy: points up to this many find their cavity in one call over every cavity (numpy's per-call cost dominates
#: there); more, cavity by cavity (a reduction over the short cavity axis costs more than it saves).
_ONE_CALL_BELOW = 64


class Cavities:
    """The phantom's cavities as arrays, as arrays: :class:`Phantom`'s geometry for many points at once."""

    def __init__(self, phantom):
        cavities = phantom.cavities
        self.count = len(cavities)
        self.centre_x = np.array([c.centre_x for c in cavities])
        self.centre_y = np.array([c.centre_y for c in cavities])
        self.mouth_radius = np.array([c.mouth_radius for c in cavities])
        self.depth = np.array([c.depth for c in cavities])
        self.sphere_radius = np.array([c.sphere_radius for c in cavities])
        self.floor_z = np.array([c.floor_z for c in cavities])
        self.capacity_ml = np.array([c.capacity_ml for c in cavities])
        self._mouth_radius2 = self.mouth_radius ** 2
        self.phantom = phantom

    def _r2(self, x, y):
        return (x[..., None] - self.centre_x) ** 2 + (y[..., None] - self.centre_y) ** 2

    def surface_height(self, x, y):
        """Height of the first solid surface below (x, y): cavity floor, phantom top or table."""
        xp, p = namespace(x), self.phantom
        r2 = self._r2(x, y)
        radius = self.sphere_radius
        # (the root's argument is positive inside every mouth, the only place its value is kept)
        bowl = self.depth - (radius - xp.sqrt(xp.maximum(radius * radius - r2, 0.0)))
        depth = xp.where(r2 >= self.mouth_radius**2, 0.0, bowl)
        depth = xp.maximum(xp.max(depth, axis=-1), 0.0)
        outside = (xp.abs(x - p.centre_x) > p.half_x) | (xp.abs(y - p.centre_y) > p.half_y)
        return xp.where(outside, p.table_z, p.top_z - depth)

    def nearest_on_top(self, x, y, margin: float):
        """:meth:`Phantom.nearest_on_top` element-wise."""
        xp, p = namespace(x), self.phantom
        dx, dy = x - p.centre_x, y - p.centre_y
        over = (xp.abs(dx) <= p.half_x) & (xp.abs(dy) <= p.half_y)
        reach_x, reach_y = p.half_x - margin, p.half_y - margin
        return (xp.where(over, x, p.centre_x + xp.minimum(xp.maximum(dx, -reach_x), reach_x)),
                xp.where(over, y, p.centre_y + xp.minimum(xp.maximum(dy, -reach_y), reach_y)))

    def cavity_at(self, x, y):
        """Index of the first cavity whose mouth contains (x, y), or -1."""
        xp = namespace(x)
        if xp is np and np.size(x) < _ONE_CALL_BELOW:  # (the same arithmetic, element by element, in fewer calls)
            dx, dy = np.asarray(x)[..., None] - self.centre_x, np.asarray(y)[..., None] - self.centre_y
            inside = dx * dx + dy * dy < self._mouth_radius2
            return np.where(inside.any(axis=-1), inside.argmax(axis=-1), -1)
        index = -1
        for cavity in reversed(range(self.count)):  # (a few cavities: no (..., C) array to reduce)
            dx, dy = x - self.centre_x[cavity], y - self.centre_y[cavity]
            index = xp.where(dx * dx + dy * dy < self.mouth_radius[cavity] ** 2, cavity, index)
        return index

    def per_cavity(self, values, cavity):
        """``values`` (one per cavity) of each element of ``cavity`` (indices)."""
        return values[cavity] if isinstance(cavity, np.ndarray) else namespace(cavity).asarray(values)[cavity]

    def fill_depth(self, cavity, volume_ml):
        """:meth:`Cavity.fill_depth` element-wise (the same Newton iterations, each element stopping on its own)."""
        xp = namespace(volume_ml)
        depth, radius = self.per_cavity(self.depth, cavity), self.per_cavity(self.sphere_radius, cavity)
        capacity = self.per_cavity(self.capacity_ml, cavity)
        target = volume_ml * _ML * 3.0 / math.pi
        h = xp.minimum(xp.sqrt(xp.maximum(target, 0.0) / (3.0 * radius)), depth)  # (a negative volume: none)
        active = (volume_ml > 0.0) & (volume_ml < capacity)

        def newton(carry):
            h, active = carry
            f = h * h * (3.0 * radius - h) - target
            slope = 6.0 * radius * h - 3.0 * h * h
            step = f / xp.where(active, slope, 1.0)  # (the inactive keep their depth: never divide by their zero)
            return xp.where(active, xp.minimum(xp.maximum(h - step, 0.0), depth), h), active & ~(xp.abs(step) < 1e-13)

        h, _ = repeat(30, newton, (h, active), until=lambda carry: not needed(carry[1]))
        return xp.where(volume_ml <= 0.0, 0.0, xp.where(volume_ml >= capacity, depth, h))

    def surface_radius(self, cavity, fill_depth):
        xp = namespace(fill_depth)
        h = xp.minimum(xp.maximum(fill_depth, 0.0), self.per_cavity(self.depth, cavity))
        return xp.sqrt(xp.maximum(h * (2.0 * self.per_cavity(self.sphere_radius, cavity) - h), 0.0))
