"""A population in one seat: several partners, a share of the batch's worlds each (:class:`Partners`), their
settings drawn from ranges (:func:`draw_within`)."""

from __future__ import annotations

from dataclasses import fields

import numpy as np

from dvrl_marl.envs.suction_debris_batched import takes_worlds

__all__ = ["Partners", "draw_within"]


def draw_within(kind, ranges: dict, rng: np.random.Generator):
    """One ``kind`` (a dataclass) whose every field is drawn uniformly from ``ranges[field]`` (low, high): whole
    numbers for the integer fields (both ends included), real numbers for the others."""
    values = {}
    for item in fields(kind):
        low, high = ranges[item.name]
        values[item.name] = (int(rng.integers(low, high + 1)) if item.type in (int, "int")
                             else float(rng.uniform(low, high)))
    return kind(**values)


class Partners:
    """Several partners filling one seat of a batch of worlds, a share each: world ``i`` is played by
    ``members[i % len(members)]`` (a fixed assignment, so each partner keeps the same worlds across resets)."""

    def __init__(self, members, names):
        if not members:
            raise ValueError("Partners: no partner given")
        self.members, self.names = list(members), [str(name) for name in names]
        self._resets = [(getattr(member, "reset", None), takes_worlds(getattr(member, "reset", None)))
                        for member in self.members]

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        observations = np.asarray(observations)
        actions = np.empty((len(observations), 4), dtype=np.float64)
        count = len(self.members)
        for index, member in enumerate(self.members):
            if index < len(observations):
                actions[index::count] = member(observations[index::count])
        return actions

    def reset(self, worlds=None) -> None:
        """Every member starts again (``worlds`` None), or only in those worlds (a member that keeps state world by
        world is told which of its own worlds; one that cannot is left as it is)."""
        count = len(self.members)
        if worlds is not None:
            worlds = np.asarray(worlds)
            worlds = np.flatnonzero(worlds) if worlds.dtype == bool else worlds
        for index, (reset, resets_worlds) in enumerate(self._resets):
            if reset is None:
                continue
            if worlds is None:
                reset()
            elif resets_worlds:
                mine = worlds[worlds % count == index] // count  # this member's own rows (world i is member i % n's)
                if len(mine):
                    reset(mine)

    def __repr__(self) -> str:
        return f"Partners({self.names})"
