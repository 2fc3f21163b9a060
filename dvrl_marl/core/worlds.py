"""What every batched core shares: one random stream per world, and validation of action batches."""

from __future__ import annotations

import numpy as np

from dvrl_marl import kinematics

__all__ = ["WorldRandom", "check_action_batch", "world_indices", "sample_reachable_batch"]

#: How many candidate positions to draw at once when sampling the reachable workspace.
_SAMPLE_BATCH = 16


class WorldRandom:
    """One ``numpy.random.Generator`` per world.

    ``seed(s)`` gives world ``i`` the generator ``default_rng(s + i)``: exactly what a single environment gets from
    ``reset(seed=s + i)`` (Gymnasium seeds ``np_random`` the same way), so world ``i`` draws the same numbers as
    that environment, episode after episode. A list of seeds gives each world its own. ``seed(None)`` draws fresh
    entropy for every world.
    """

    def __init__(self, num_worlds: int):
        self.num_worlds = int(num_worlds)
        self.generators = [np.random.default_rng() for _ in range(self.num_worlds)]

    def seed(self, seed) -> None:
        if seed is None:
            self.generators = [np.random.default_rng() for _ in range(self.num_worlds)]
            return
        from dvrl_marl.schemas import Seed, Seeds, validated

        if isinstance(seed, (str, bytes)) or not hasattr(seed, "__iter__"):  # one seed (a string is no seed list)
            seeds = [validated(Seed, seed, "reset(seed=...)") + i for i in range(self.num_worlds)]
        else:
            seeds = validated(Seeds, list(seed), "reset(seed=[...]): one seed per world")
            if len(seeds) != self.num_worlds:
                raise ValueError(f"seed: expected an int or {self.num_worlds} seeds, got {len(seeds)}")
        self.generators = [np.random.default_rng(s) for s in seeds]

    def __getitem__(self, world: int) -> np.random.Generator:
        return self.generators[world]


def world_indices(worlds, num_worlds: int, who: str) -> np.ndarray:
    """Indices of the worlds to reset: all (None), a boolean mask of shape (num_worlds,), or indices."""
    if worlds is None:
        return np.arange(num_worlds)
    worlds = np.asarray(worlds)
    if worlds.dtype == bool:
        if worlds.shape != (num_worlds,):
            raise ValueError(f"{who}: reset mask must have shape ({num_worlds},), got {worlds.shape}")
        return np.flatnonzero(worlds)
    if worlds.size == 0:
        return np.zeros(0, dtype=np.int64)
    if not np.issubdtype(worlds.dtype, np.integer):  # 1.5 is no world, and 1.0 is likely a mistaken mask
        raise ValueError(f"{who}: reset mask must be booleans of shape ({num_worlds},) or world indices "
                         f"(integers), got {worlds.dtype} values {worlds.reshape(-1)[:5].tolist()}")
    indices = worlds.astype(np.int64).reshape(-1)
    outside = (indices < 0) | (indices >= num_worlds)
    if outside.any():  # a negative index would wrap to another world, a large one raise IndexError later
        raise ValueError(f"{who}: world index {int(indices[outside][0])} is outside [0, {num_worlds})")
    return indices


def check_action_batch(actions, num_worlds: int, width: int, who: str) -> np.ndarray:
    """Validate an action batch and return it as float64, clipped to [-1, 1].

    Raises ``ValueError`` naming ``who`` (the agent or env) and, for NaN/inf, the first bad world index.
    """
    try:
        array = np.asarray(actions, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{who}: actions are not numeric: {actions!r}") from error
    if array.shape != (num_worlds, width):
        raise ValueError(f"{who}: actions must have shape ({num_worlds}, {width}), got {array.shape}")
    finite = np.isfinite(array).all(axis=1)
    if not finite.all():
        world = int(np.argmin(finite))
        raise ValueError(f"{who}: action of world {world} contains NaN or inf: {array[world].tolist()}")
    return np.clip(array, -1.0, 1.0)


def sample_reachable_batch(generators, tool, low, high, tool_point_drop: float = 0.0) -> np.ndarray:
    """One uniform draw per generator from the box [low, high], restricted to positions ``tool`` can reach (rejection
    sampling; positions are tips whose tool point lies ``tool_point_drop`` below them): ``(len(generators), 3)``.

    Each generator draws exactly what it would alone (16 candidates at a time, the first reachable one kept;
    ``low + (high - low) * u`` is how NumPy's ``uniform`` computes its samples), so the single-arm environments and
    the batched cores, which both sample resets through this, draw the same positions from the same seeds.
    """
    low, high = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
    span = high - low
    result = np.empty((len(generators), 3))
    pending = list(range(len(generators)))
    for _ in range(1000):
        candidates = low + span * np.stack([generators[i].random((_SAMPLE_BATCH, 3)) for i in pending])
        ok = kinematics.inverse_kinematics_batch(tool, candidates - np.array([0.0, 0.0, tool_point_drop]))[1]
        found = ok.any(axis=1)
        rows = np.flatnonzero(found)
        result[np.asarray(pending)[rows]] = candidates[rows, np.argmax(ok[rows], axis=1)]
        pending = [i for i, hit in zip(pending, found.tolist()) if not hit]
        if not pending:
            return result
    raise RuntimeError(f"no reachable position in the box {low} .. {high}")
