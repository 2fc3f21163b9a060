"""Counter-based random streams for resets: a world's draws are a function of (its seed, its episode, the draw).

A generator object per world (``numpy.random.Generator``) makes world i's episodes depend on how many numbers it
drew before, on the library that holds it and on a Python loop over the worlds. Here a draw is a pure function of
four integers, ``(key, episode, stream, index)``: the world's seed, how many episodes it started since it was
seeded, which quantity is drawn (a fixed number per purpose, :data:`STREAMS`) and which of them. So world i is the
same world on every backend (the hash below uses only integer additions, multiplications, shifts and xors, which
numpy, torch and JAX compute alike), in a batch of any size, and whatever the other worlds do; all worlds reset in
a step draw together, as arrays.

The hash is ``lowbias32`` (Wellons, "Hash function prospector", 2018) chained over the four inputs; two 32-bit
outputs make one double in [0, 1) with 53 random bits. Its arithmetic runs in int64 with 32-bit masks (torch has
no unsigned 64-bit multiply), every product below 2^63.
"""

from __future__ import annotations

import numpy as np

from dvrl_marl.core.backend import namespace

__all__ = ["STREAMS", "ResetStreams", "uniforms"]

#: One stream per quantity a reset draws (changing a number changes what every seed draws).
STREAMS = {"tips": 1, "pin_slots": 2, "pin_yaws": 3, "pin_cavities": 4, "pin_turns": 5, "bleeding": 6,
           "level": 7, "level_blood": 8, "level_empty": 9, "level_debris": 10, "level_pin": 11, "level_aside": 12,
           "level_reach": 13, "appearance": 14}

_MASK = 0xFFFFFFFF


def _times(x, constant: int):
    """``x * constant`` modulo 2^32, for ``x`` in [0, 2^32) held in int64 (the halves keep every product < 2^48)."""
    low, high = x & 0xFFFF, x >> 16
    return (low * constant + ((high * constant) & 0xFFFF) * 65536) & _MASK


def _mix(x):
    """lowbias32: a bijection of [0, 2^32) that spreads every input bit over the output."""
    x = x ^ (x >> 16)
    x = _times(x, 0x7FEB352D)
    x = x ^ (x >> 15)
    x = _times(x, 0x846CA68B)
    return x ^ (x >> 16)


def uniforms(key_low, key_high, episode, stream: int, count: int):
    """``(M, count)`` doubles in [0, 1): draws ``0 .. count - 1`` of ``stream`` for M worlds, each given by its
    key's two 32-bit halves and its episode (``(M,)`` int64 arrays of any array library)."""
    xp = namespace(key_low)
    index = xp.arange(2 * count, dtype=xp.int64)[None, :]
    h = _mix(key_low[:, None] ^ _mix(key_high[:, None] ^ _mix((episode[:, None] & _MASK) ^ _mix(
        (index + (stream << 20)) & _MASK))))
    high, low = h[:, 0::2] >> 5, h[:, 1::2] >> 6  # 27 + 26 bits, as numpy's own random doubles take them
    return xp.astype(high * 67108864 + low, xp.float64) / 9007199254740992.0


class ResetStreams:
    """The reset draws of N worlds. ``seed(s)`` gives world i the key ``s + i`` (a list of seeds: one per world),
    so world i of a batch draws what a single env reset with ``seed=s + i`` draws, episode after episode;
    ``seed(None)`` takes fresh entropy. ``uniforms(worlds, stream, count)`` draws for the episode each of ``worlds``
    is starting; :meth:`next_episode` then moves those worlds on."""

    def __init__(self, num_worlds: int):
        self.num_worlds = int(num_worlds)
        #: each world's key as two 32-bit halves, and the episode it starts next (int64 arrays of the core's library)
        self.key_low = self.key_high = self.episode = np.zeros(self.num_worlds, dtype=np.int64)
        self.seed(None)

    def seed(self, seed) -> None:
        if seed is None or isinstance(seed, (str, bytes)) or not hasattr(seed, "__iter__"):  # one seed (or none)
            if seed is None:
                first = int(np.random.SeedSequence().generate_state(1, np.uint64)[0])
            else:
                from dvrl_marl.schemas import Seed, validated

                first = validated(Seed, seed, "reset(seed=...)")
                if first + self.num_worlds - 1 >= 2**64:  # (a world's key would wrap round to seed 0's)
                    raise ValueError(f"reset(seed={first}): world i plays seed + i, which must stay below 2**64 for "
                                     f"the {self.num_worlds} worlds; give a seed up to {2**64 - self.num_worlds}")
            # world i: seed + i (below 2^64: the seed's check; fresh entropy may wrap, as numpy's uint64 addition does)
            keys = np.uint64(first) + np.arange(self.num_worlds, dtype=np.uint64)
        else:
            from dvrl_marl.schemas import Seeds, validated

            seeds = validated(Seeds, list(seed), "reset(seed=[...]): one seed per world")
            if len(seeds) != self.num_worlds:
                raise ValueError(f"seed: expected an int or {self.num_worlds} seeds, got {len(seeds)}")
            keys = np.array(seeds, dtype=np.uint64)
        self.key_low = (keys & np.uint64(_MASK)).astype(np.int64)
        self.key_high = (keys >> np.uint64(32)).astype(np.int64)
        self.episode = np.zeros(self.num_worlds, dtype=np.int64)

    def uniforms(self, worlds, stream: str, count: int):
        """``(M, count)`` doubles in [0, 1) of ``stream`` (a name of :data:`STREAMS`) for the episode each world
        of ``worlds`` (indices, or None for every world) is starting."""
        pick = (lambda x: x) if worlds is None else (lambda x: x[worlds])
        return uniforms(pick(self.key_low), pick(self.key_high), pick(self.episode), STREAMS[stream], int(count))

    def next_episode(self, mask) -> None:
        """The worlds where ``mask`` (N,) holds have started their episode: their next draws are the next one's."""
        self.episode = self.episode + (mask * 1)

    def state(self) -> dict:
        return {"stream_key_low": self.key_low, "stream_key_high": self.key_high, "stream_episode": self.episode}

    def restore(self, state: dict) -> None:
        self.key_low, self.key_high = state["stream_key_low"], state["stream_key_high"]
        self.episode = state["stream_episode"]
