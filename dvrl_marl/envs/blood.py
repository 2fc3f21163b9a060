"""The phantom's cavities and the fake blood in them: plain state, no MuJoCo inside.

Each cavity is a spherical cap (mouth radius ``a``, depth ``D``, sphere radius ``R = (a^2 + D^2) / (2 D)``). Blood of
volume V fills it to the depth h with ``V = pi h^2 (3R - h) / 3``; its surface is a disc of radius
``sqrt(h (2R - h))``. Suction removes blood while the valve is open and the tube tip is inside the cavity's mouth:
at the full rate with the tip under the surface, and (``reach > 0``) at a rate falling linearly to nothing
``reach`` above it, as a suction tip draws air instead of fluid once it leaves the surface. A bleeding source adds
blood (:meth:`BloodState.bleed`). Volumes are kept in millilitres; removed + remaining == initial + added, exactly,
by construction (removed is derived from the others, remaining is clamped to [0, capacity]).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["Cavity", "Phantom", "BloodState"]

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


class BloodState:
    """Blood volume in each cavity, drained by suction."""

    def __init__(self, phantom: Phantom, initial_ml, suction_rate_ml_s: float):
        if len(initial_ml) != len(phantom.cavities):
            raise ValueError(f"blood_ml needs one volume per cavity ({len(phantom.cavities)}), got {list(initial_ml)}")
        for cavity, volume in zip(phantom.cavities, initial_ml):
            if not 0.0 <= volume <= cavity.capacity_ml:
                raise ValueError(
                    f"blood volume {volume} ml is outside [0, {cavity.capacity_ml:.2f}] ml (the cavity's capacity)"
                )
        if not suction_rate_ml_s > 0.0:
            raise ValueError(f"suction_rate_ml_s must be positive, got {suction_rate_ml_s}")
        self.phantom = phantom
        self.initial_ml = tuple(float(v) for v in initial_ml)
        self.suction_rate_ml_s = float(suction_rate_ml_s)
        self.remaining_ml = list(self.initial_ml)
        self.added_ml = [0.0] * len(self.initial_ml)
        self.surface_z = [0.0] * len(self.initial_ml)
        self.surface_radius = [0.0] * len(self.initial_ml)
        self.reset()

    def reset(self) -> None:
        self.remaining_ml = list(self.initial_ml)
        self.added_ml = [0.0] * len(self.initial_ml)
        for index in range(len(self.remaining_ml)):
            self._update_surface(index)

    def set_remaining(self, volumes_ml) -> None:
        """Set the blood left in each cavity (ml), e.g. to mirror a batched world; surfaces follow."""
        self.remaining_ml = [min(max(float(v), 0.0), c.capacity_ml) for v, c in zip(volumes_ml, self.phantom.cavities)]
        for index in range(len(self.remaining_ml)):
            self._update_surface(index)

    @property
    def removed_ml(self) -> tuple[float, ...]:
        """Blood removed from each cavity so far (ml)."""
        return tuple(initial + added - remaining
                     for initial, added, remaining in zip(self.initial_ml, self.added_ml, self.remaining_ml))

    def fraction(self, index: int) -> float:
        """Fraction of the cavity's initial blood still in it (above 1 when a bleed added more); a cavity that
        started empty reports its blood as a fraction of its capacity."""
        initial = self.initial_ml[index]
        if initial > 0.0:
            return self.remaining_ml[index] / initial
        return self.remaining_ml[index] / self.phantom.cavities[index].capacity_ml

    def _update_surface(self, index: int) -> None:
        cavity = self.phantom.cavities[index]
        depth = cavity.fill_depth(self.remaining_ml[index])
        self.surface_z[index] = cavity.floor_z + depth
        self.surface_radius[index] = cavity.surface_radius(depth)

    def suck(self, x: float, y: float, z: float, dt: float, reach: float = 0.0) -> tuple[int, float]:
        """Suction at tip (x, y, z) for dt seconds. Returns (cavity index or -1, ml removed).

        ``reach`` 0: full flow below the surface, none at or above it. ``reach`` > 0: full flow at or below the
        surface, falling linearly to none ``reach`` above it."""
        index = self.phantom.cavity_at(x, y)
        if index < 0 or self.remaining_ml[index] <= 0.0:
            return index, 0.0
        height = z - self.surface_z[index]
        if reach <= 0.0:
            if height >= 0.0:
                return index, 0.0
            flow = 1.0
        elif height >= reach:
            return index, 0.0
        else:
            flow = 1.0 if height <= 0.0 else 1.0 - height / reach
        removed = min(flow * self.suction_rate_ml_s * dt, self.remaining_ml[index])
        self.remaining_ml[index] = max(self.remaining_ml[index] - removed, 0.0)
        self._update_surface(index)
        return index, removed

    def bleed(self, index: int, volume_ml: float) -> float:
        """Add up to ``volume_ml`` of blood to cavity ``index`` (no more than it holds); returns what was added."""
        capacity = self.phantom.cavities[index].capacity_ml
        added = min(volume_ml, capacity - self.remaining_ml[index])
        if added <= 0.0:
            return 0.0
        self.remaining_ml[index] += added
        self.added_ml[index] += added
        self._update_surface(index)
        return added
