"""Start-state levels of the collaborative env: from an easy episode (``level=0``) to the default task (``level=1``).

``reset(options={"level": x})`` (or ``start_level=x`` when the env is made; ``"easy"`` is 0, ``"default"`` is 1)
draws each episode at level ``x``:

- with probability ``1 - x`` the episode is **easy**: each cavity starts empty with probability
  :attr:`EasyEpisodes.empty_cavity_probability`, otherwise with a uniform share of the task's blood (no blood shows
  the debris at once, so a grasper meets the grasp long before a suction could clear 16 ml); 1 to all of the debris
  are in play (the others start delivered); the grasper's tip starts a few millimetres above a visible pin, moved
  back along the way to its ordinary start (around the phantom's rims) by a uniform share of at most
  ``min(1, 2 x)`` of that way (starts that recede from the pin as the level rises); and the episode lasts at most
  the env's ``easy_episode_steps`` (default :attr:`EasyEpisodes.episode_steps`, the record's 300: a time limit,
  truncated, not terminated), so that starts and what follows them are a larger share of a learner's data. That
  limit is a training device: an easy episode with two full cavities cannot be completed in 300 steps (the scripted
  team completes 34 % of them), so a benchmark of the easy level sets ``easy_episode_steps=None`` (the task's
  limit; the shipped BenchMARL easy task does);
- otherwise it is the default task, exactly as without the option.

Level 1 draws nothing: the default task is bit-for-bit what the env gives without the option. These are the
start states of the curriculum that made the task learnable (``baselines/README.md``: half of the resets easy,
the near-pin starts receding over the first 30 % of the run, then the easy share falling to nothing), which
lived in the MAPPO trainer until 0.1.0 moved it into the env: a library's own curriculum drives it by setting the level
at each reset; the trainer's ``[curriculum]`` schedule is one such curriculum.

The level's draws come from streams of their own (:mod:`dvrl_marl.core.streams`: a draw is a function of the
world's seed, its episode and the quantity drawn), so the default task's draws are never touched, level 1 is the
default task bit for bit, and single and batched envs start the same episodes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dvrl_marl.core.backend import namespace

__all__ = ["EASY", "DEFAULT", "NAMED_LEVELS", "EasyEpisodes", "EASY_EPISODES", "StartDraws", "checked_level",
           "checked_schedule", "scheduled_level", "draw", "grasper_uniforms", "grasper_starts"]

EASY = 0.0
DEFAULT = 1.0
NAMED_LEVELS = {"easy": EASY, "default": DEFAULT}

@dataclass(frozen=True)
class EasyEpisodes:
    """What an easy episode is; the values are those of the configuration of record
    (``baselines/configs/suction_debris_mappo.toml``'s ``[curriculum]`` before 0.1.0)."""

    #: each cavity of an easy episode starts empty this often (a pin shows only once the level is a few mm deep)
    empty_cavity_probability: float = 0.5
    #: an easy episode is cut (truncated) after this many steps (the env's ``easy_episode_steps`` default)
    episode_steps: int = 300
    #: the grasper's start above a pin: this high above its axis (m), within the jaw's 3 mm sensor range
    above_pin: float = 0.0015
    #: and up to this far aside (m; a quarter of it vertically)
    aside: float = 0.002


EASY_EPISODES = EasyEpisodes()


@dataclass(frozen=True)
class StartDraws:
    """The starts of M episodes at their levels: ``easy`` (M,), the blood (M, C) ml, the debris in play (M,) and
    how far back from its pin the grasper starts (M,), a fraction of the way to its ordinary start."""

    easy: np.ndarray
    blood_ml: np.ndarray
    debris_count: np.ndarray
    reach: np.ndarray


def checked_level(value, owner: str) -> float:
    """A level as a float in [0, 1] (``"easy"``, ``"default"`` or a number), else ``ValueError`` naming it."""
    if isinstance(value, str):
        if value not in NAMED_LEVELS:
            raise ValueError(f"{owner}: level must be a number in [0, 1] or one of {sorted(NAMED_LEVELS)}, "
                             f"got {value!r}")
        return NAMED_LEVELS[value]
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{owner}: level must be a number in [0, 1] or one of {sorted(NAMED_LEVELS)}, "
                         f"got {value!r}")
    level = float(value)
    if not 0.0 <= level <= 1.0:  # NaN fails too
        raise ValueError(f"{owner}: level must lie in [0, 1] (0 easy, 1 the default task), got {value!r}")
    return level


def checked_schedule(levels, owner: str) -> list[tuple[float, float]]:
    """A curriculum's schedule of levels: ``(progress, level)`` pairs in [0, 1], progress increasing (a library's
    curriculum over a run: this project's trainer, the BenchMARL callback); else ``ValueError`` naming ``owner``."""
    points = [(float(p), float(v)) for p, v in levels]
    if any(not (0.0 <= p <= 1.0 and 0.0 <= v <= 1.0) for p, v in points):
        raise ValueError(f"{owner}: levels must be (progress, level) pairs in [0, 1], got {levels!r}")
    progress = [p for p, _ in points]
    if any(b <= a for a, b in zip(progress, progress[1:])):
        raise ValueError(f"{owner}: the progress points must increase (levels are (progress, level) pairs in [0, 1], "
                         f"progress increasing), got {progress}")
    return points


def scheduled_level(levels, progress: float) -> float:
    """The level a schedule (:func:`checked_schedule`) gives at ``progress`` in [0, 1]: piecewise linear."""
    points, values = zip(*levels)
    return float(np.interp(min(max(progress, 0.0), 1.0), points, values))


def draw(streams, worlds, levels, blood_ml, debris_count: int, easy: EasyEpisodes = EASY_EPISODES) -> StartDraws:
    """The starts of the episodes ``worlds`` begin at ``levels`` (M,), given the task's blood and debris, from
    ``streams`` (:class:`~dvrl_marl.core.streams.ResetStreams`, before the core's reset moves them on; ``worlds``:
    indices, or None for every world). A world at level 1 is never easy. Any array library's arrays."""
    xp = namespace(levels)
    task_blood = xp.asarray(np.asarray(blood_ml, dtype=np.float64))
    count = task_blood.shape[0]
    is_easy = streams.uniforms(worlds, "level", 1)[:, 0] < 1.0 - levels
    blood = streams.uniforms(worlds, "level_blood", count) * task_blood
    if easy.empty_cavity_probability > 0:
        blood = xp.where(streams.uniforms(worlds, "level_empty", count) < easy.empty_cavity_probability, 0.0, blood)
    debris = 1 + xp.minimum(xp.astype(streams.uniforms(worlds, "level_debris", 1)[:, 0] * debris_count, xp.int64),
                            debris_count - 1)
    return StartDraws(is_easy, xp.where(is_easy[:, None], blood, task_blood),
                      xp.where(is_easy, debris, int(debris_count)),
                      xp.where(is_easy, xp.minimum(2.0 * levels, 1.0), 0.0))


def grasper_uniforms(streams, worlds):
    """(M, 5): what :func:`grasper_starts` draws for each of ``worlds`` (taken with :func:`draw`, before the reset)."""
    parts = [streams.uniforms(worlds, name, k) for name, k in (("level_pin", 1), ("level_aside", 3), ("level_reach", 1))]
    return namespace(parts[0]).concatenate(parts, axis=1)


def grasper_starts(draws, pins, pending, ordinary_tip, reach, rims, easy: EasyEpisodes = EASY_EPISODES):
    """Where easy episodes' graspers start (world metres, (M, 3)) and whether each has a pin in view to start at
    ((M,); where not, the ordinary start stays): above one of the ``pending`` (M, D) pins (``pins``: (M, D, 3) world
    positions), moved back toward ``ordinary_tip`` (M, 3) by a uniform share of at most ``reach`` (M,) of the way
    :meth:`OverRims.point_along` measures (``rims``). ``draws``: :func:`grasper_uniforms`' rows. Any array library's
    arrays."""
    xp = namespace(pins)
    count = xp.sum(xp.astype(pending, xp.int64), axis=1)
    has = count > 0
    # the k-th pending pin, k drawn uniformly among them
    k = xp.minimum(xp.astype(draws[:, 0] * count, xp.int64), xp.maximum(count - 1, 0))
    order = xp.cumsum(xp.astype(pending, xp.int64), axis=1) - 1  # each pending pin's rank among them
    chosen = pending & (order == k[:, None])
    pin = xp.sum(xp.where(chosen[..., None], pins, 0.0), axis=1)
    aside = -easy.aside + 2.0 * easy.aside * draws[:, 1:4]
    target = pin + xp.asarray([0.0, 0.0, easy.above_pin]) + aside * xp.asarray([1.0, 1.0, 0.25])
    moved = rims.point_along(target, ordinary_tip, reach * draws[:, 4])
    return xp.where((reach > 0.0)[:, None], moved, target), has
