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

__all__ = ["EASY", "DEFAULT", "NAMED_LEVELS", "EasyEpisodes", "EASY_EPISODES", "StartDraws", "checked_level",
           "checked_schedule", "scheduled_level", "draw", "grasper_uniforms", "grasper_start"]

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


def draw(streams, worlds: np.ndarray, levels: np.ndarray, blood_ml, debris_count: int,
         easy: EasyEpisodes = EASY_EPISODES) -> StartDraws:
    """The starts of the episodes ``worlds`` begin at ``levels`` (M,), given the task's blood and debris, from
    ``streams`` (:class:`~dvrl_marl.core.streams.ResetStreams`, before the core's reset moves them on). A world at
    level 1 is never easy."""
    blood_ml = np.asarray(blood_ml, dtype=np.float64)
    levels = np.asarray(levels, dtype=np.float64)
    is_easy = streams.uniforms(worlds, "level", 1)[:, 0] < 1.0 - levels
    blood = streams.uniforms(worlds, "level_blood", len(blood_ml)) * blood_ml
    if easy.empty_cavity_probability > 0:
        blood = np.where(streams.uniforms(worlds, "level_empty", len(blood_ml)) < easy.empty_cavity_probability,
                         0.0, blood)
    count = 1 + np.minimum((streams.uniforms(worlds, "level_debris", 1)[:, 0] * debris_count).astype(np.int64),
                           debris_count - 1)
    return StartDraws(is_easy, np.where(is_easy[:, None], blood, blood_ml),
                      np.where(is_easy, count, int(debris_count)),
                      np.where(is_easy, np.minimum(1.0, 2.0 * levels), 0.0))


def grasper_uniforms(streams, worlds: np.ndarray) -> np.ndarray:
    """(M, 5): what :func:`grasper_start` draws for each of ``worlds`` (taken with :func:`draw`, before the reset)."""
    return np.concatenate([streams.uniforms(worlds, "level_pin", 1), streams.uniforms(worlds, "level_aside", 3),
                           streams.uniforms(worlds, "level_reach", 1)], axis=1)


def grasper_start(draws: np.ndarray, pins, pending, ordinary_tip, reach: float, rims,
                  easy: EasyEpisodes = EASY_EPISODES):
    """Where an easy episode's grasper starts (world metres, (3,)), or None when no pin is in view: above one of the
    ``pending`` pins (``pins``: (D, 3) world positions), moved back toward ``ordinary_tip`` by a uniform share of at
    most ``reach`` of the way :meth:`OverRims.point_along` measures (``rims``). ``draws``: the world's row of
    :func:`grasper_uniforms`."""
    candidates = np.flatnonzero(pending)
    if len(candidates) == 0:
        return None
    pin = np.asarray(pins[candidates[min(int(draws[0] * len(candidates)), len(candidates) - 1)]], dtype=np.float64)
    aside = -easy.aside + 2.0 * easy.aside * draws[1:4]
    target = pin + np.array([0.0, 0.0, easy.above_pin]) + aside * [1, 1, 0.25]
    if reach > 0:
        target = rims.point_along(target, np.asarray(ordinary_tip, dtype=np.float64), reach * draws[4])
    return target
