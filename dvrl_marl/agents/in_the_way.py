"""Surgeons that get in the suction's way: they rest their instrument where the suction must pass and move off only
once the suction has waited close to them for a while.

A person in the surgeon seat does not keep out of the other arm's way as the scripted surgeon does: they rest over
the cavity they mean to work in, stop on the other arm's route, reach into its cavity. Beside such a partner a seat
that pushes on (the scripted suction does, and so does everything cloned from it) finishes only by pushing into the
other instrument until it gives way; a person beside a robot expects it to wait, or to go round.

:class:`InTheWayPartner` fills the LND seat: at each episode's start it takes its instrument to a resting point
``along`` the way from the suction's start to the cavity the suction clears first (0: over that cavity, 1: at the
suction's start), ``height_mm`` above the phantom's top (below 0: into the cavity), and holds it there with the jaw
open (it stops short wherever the suction is already beside it: it never pushes). Once the suction has stayed within
``near_mm`` of it for ``patience_steps`` steps in a row (the distance between the instruments' axes, each a line from
its remote centre of motion to its tip: a suction that went past the tip and stopped against the shaft is close too),
it yields: from then on it is the scripted surgeon (it goes to its waiting place over its own side and picks the pins
as they are uncovered). A suction that keeps farther away is never let through.

Obstructions are drawn from ranges with a seed, like the person-like profiles (:mod:`dvrl_marl.agents.partners`):
:data:`TRAINING_RANGES` for the partners a trainer may use (the seat name ``"in-the-way"``: half rest on the route,
half in the cavity), and the held-out kind :data:`HELD_OUT` (the partner zoo's ``"in-the-way"``), which waits longer
before it yields than any met in training.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dvrl_marl.agents.population import Partners, draw_within
from dvrl_marl.suction_debris.instruments import segment_distance
from dvrl_marl.suction_debris.layout import ACTION_WIDTH, MOVE, TOOL

__all__ = ["Obstruction", "InTheWayPartner", "TRAINING_RANGES", "HELD_OUT", "draw_obstructions",
           "training_obstructors", "held_out_obstructors", "TRAINING_SEED", "ZOO_SEED"]


@dataclass(frozen=True)
class Obstruction:
    """Where an :class:`InTheWayPartner` rests and how long it makes the suction wait (module documentation)."""

    along: float = 0.3
    height_mm: float = 10.0
    near_mm: float = 20.0
    patience_steps: int = 50

    def __post_init__(self):
        if isinstance(self.patience_steps, bool) or not isinstance(self.patience_steps, (int, np.integer)):
            raise ValueError(f"Obstruction: patience_steps must be a whole number of steps, got {self.patience_steps!r}")
        if not (0.0 <= self.along <= 1.0 and -10.0 <= self.height_mm <= 40.0 and self.near_mm > 0.0
                and self.patience_steps >= 1):
            raise ValueError(f"Obstruction: a value is out of range: {self}")


#: Where a trainer's obstructing partners rest, drawn uniformly from these ranges (patience_steps inclusive), half
#: of them at each place: on the suction's route at about its travelling height (the scripted suction travels 10 mm
#: above the phantom), or in the mouth of the cavity the suction clears first.
TRAINING_RANGES = {
    "route": {"along": (0.15, 0.6), "height_mm": (7.0, 13.0), "near_mm": (15.0, 25.0), "patience_steps": (25, 200)},
    "cavity": {"along": (0.0, 0.05), "height_mm": (-4.0, 2.0), "near_mm": (15.0, 25.0), "patience_steps": (25, 200)},
}
#: The held-out kind leaves the training ranges in one way: it makes the suction wait longer before it yields.
HELD_OUT = {place: {**ranges, "patience_steps": (250, 350)} for place, ranges in TRAINING_RANGES.items()}
#: Obstructions for training are drawn from this seed, the held-out ones from ZOO_SEED (documented, reproducible).
TRAINING_SEED = 55_000
ZOO_SEED = 535_353


def draw_obstructions(places: dict, count: int, seed: int) -> list[Obstruction]:
    """``count`` obstructions, the places taken in turn (``places``: name -> ranges), each drawn uniformly from its
    place's ranges, reproducibly from ``seed``."""
    rng, ranges = np.random.default_rng(seed), list(places.values())
    return [draw_within(Obstruction, ranges[index % len(ranges)], rng) for index in range(count)]


class InTheWayPartner:
    """The LND seat's obstructing surgeon (module documentation). ``env``: the scene it plays in (its layout and
    observation slices). Takes one observation ``(d,)`` or a batch ``(N, d)`` and keeps per-world state."""

    def __init__(self, agent: str, env, obstruction: Obstruction):
        from dvrl_marl.agents.collaborative import ScriptedSuction, ScriptedSurgeon

        if agent != "grasper":
            raise ValueError(f"InTheWayPartner: it fills the LND seat ('grasper'), got {agent!r}")
        if not isinstance(obstruction, Obstruction):
            raise ValueError(f"InTheWayPartner: obstruction must be an Obstruction, got {type(obstruction).__name__}")
        self.agent, self.obstruction = agent, obstruction
        self.expert = ScriptedSurgeon.for_env(env)
        unwrapped = getattr(env, "unwrapped", env)
        layout, scale = unwrapped.layout(), float(unwrapped.workspace_range)
        self.first_cavity = np.asarray(layout.cavity_centres[ScriptedSuction.for_env(env).order[0]])
        self.rest_z = layout.phantom_top + obstruction.height_mm / 1000.0 / scale
        self.near = obstruction.near_mm / 1000.0 / scale
        self.slices = unwrapped.observation_layout
        self.centres = {agent: np.asarray(layout.base_positions[agent], dtype=np.float64)
                        for agent in ("suction", "grasper")}  # the remote centres of motion, normalised
        self._rest = None  # (N, 3), set at each world's first step

    def reset(self, worlds=None) -> None:
        """Start again in every world (``worlds`` None) or in those worlds only."""
        if worlds is None or self._rest is None:
            self._rest = None
            return
        self._fresh[worlds], self._yielded[worlds], self._waited[worlds] = True, False, 0

    def __call__(self, observation) -> np.ndarray:
        observations = np.asarray(observation, dtype=np.float64)
        single = observations.ndim == 1
        batch = observations[None] if single else observations
        n = len(batch)
        own, other = batch[:, self.slices["own_tip"]], batch[:, self.slices["other_tip"]]
        if self._rest is None or len(self._rest) != n:
            self._rest, self._fresh = np.zeros((n, 3)), np.ones(n, dtype=bool)
            self._yielded, self._waited = np.zeros(n, dtype=bool), np.zeros(n, dtype=np.int64)
        if self._fresh.any():  # where the suction starts decides the route it takes, and so where to rest
            start = other[self._fresh, :2]
            self._rest[self._fresh, :2] = self.first_cavity + self.obstruction.along * (start - self.first_cavity)
            self._rest[self._fresh, 2] = self.rest_z
            self._fresh[:] = False
        close = segment_distance(own, self.centres["grasper"], other, self.centres["suction"]) < self.near
        self._waited = np.where(close & ~self._yielded, self._waited + 1, 0)
        self._yielded |= self._waited >= self.obstruction.patience_steps
        actions = np.empty((n, ACTION_WIDTH))
        yielded, resting = self._yielded, ~self._yielded
        if yielded.any():
            actions[yielded] = self.expert(batch[yielded])
        if resting.any():
            expert = self.expert
            way = expert._via_safe_height(own[resting], self._rest[resting], 2 * expert.near)
            actions[resting, MOVE] = expert._towards(own[resting], way)
            actions[resting & close, MOVE] = 0.0  # with the suction beside it, it stops where it is (it never pushes)
            actions[resting, TOOL] = 1.0  # the jaw open, as a surgeon waiting to work
        return actions[0].astype(np.float32) if single else actions

    def __repr__(self) -> str:
        return f"InTheWayPartner({self.agent!r}, {self.obstruction})"


def _partners(ranges: dict, count: int, seed: int, env, prefix: str):
    members = [InTheWayPartner("grasper", env, obstruction) for obstruction in draw_obstructions(ranges, count, seed)]
    return Partners(members, [f"{prefix}-{index}" for index in range(count)])


def training_obstructors(agent: str, env, members: int = 8):
    """The obstructing partners a trainer may use (the seat name ``"in-the-way"``): ``members`` obstructions from
    :data:`TRAINING_RANGES` drawn with :data:`TRAINING_SEED`, a share of the worlds each."""
    if agent != "grasper":
        raise ValueError(f"'in-the-way' partners fill the LND seat ('grasper'), not {agent!r}")
    return _partners(TRAINING_RANGES, members, TRAINING_SEED, env, "in-the-way")


def held_out_obstructors(agent: str, env, members: int = 4):
    """The partner zoo's held-out ``"in-the-way"`` kind: ``members`` obstructions from :data:`HELD_OUT`, drawn with
    :data:`ZOO_SEED`."""
    if agent != "grasper":
        raise ValueError(f"the held-out 'in-the-way' partners fill the LND seat ('grasper'), not {agent!r}")
    return _partners(HELD_OUT, members, ZOO_SEED, env, "in-the-way")
