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

The level's draws come from a stream of their own, seeded with the env's ``reset(seed=...)`` (world ``i`` of the
batched env draws what a single env reset with ``seed + i`` draws), so the default task's random stream is never
touched and single and batched envs start the same episodes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["EASY", "DEFAULT", "NAMED_LEVELS", "EasyEpisodes", "EASY_EPISODES", "StartDraw", "checked_level",
           "checked_schedule", "scheduled_level", "draw", "grasper_start", "level_generator"]

EASY = 0.0
DEFAULT = 1.0
NAMED_LEVELS = {"easy": EASY, "default": DEFAULT}
#: Entropy that separates the levels' stream from the episode's own (any fixed number; changing it changes the
#: easy episodes a seed draws).
_LEVEL_STREAM = 0x5EED_1E7E


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
class StartDraw:
    """One episode's start at a level: ``easy``, the blood (ml per cavity), the debris in play and how far back
    from its pin the grasper starts (a fraction of the way to its ordinary start)."""

    easy: bool
    blood_ml: np.ndarray
    debris_count: int
    reach: float


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


def level_generator(seed: int | None) -> np.random.Generator:
    """The levels' random stream of an env reset with ``seed`` (fresh entropy for None)."""
    return np.random.default_rng(None if seed is None else (_LEVEL_STREAM, int(seed)))


def draw(rng: np.random.Generator, level: float, blood_ml, debris_count: int,
         easy: EasyEpisodes = EASY_EPISODES) -> StartDraw:
    """The start of one episode at ``level`` (< 1; level 1 draws nothing), given the task's blood and debris."""
    blood_ml = np.asarray(blood_ml, dtype=np.float64)
    if not rng.random() < 1.0 - level:
        return StartDraw(False, blood_ml.copy(), int(debris_count), 0.0)
    blood = rng.random(len(blood_ml)) * blood_ml
    if easy.empty_cavity_probability > 0:
        blood[rng.random(len(blood)) < easy.empty_cavity_probability] = 0.0
    count = int(rng.integers(1, debris_count + 1))
    return StartDraw(True, blood, count, min(1.0, 2.0 * level))


def grasper_start(rng: np.random.Generator, pins, pending, ordinary_tip, reach: float, rims,
                  easy: EasyEpisodes = EASY_EPISODES):
    """Where an easy episode's grasper starts (world metres, (3,)), or None when no pin is in view: above one of the
    ``pending`` pins (``pins``: (D, 3) world positions), moved back toward ``ordinary_tip`` by a uniform share of at
    most ``reach`` of the way :meth:`OverRims.point_along` measures (``rims``)."""
    candidates = np.flatnonzero(pending)
    if len(candidates) == 0:
        return None
    pin = np.asarray(pins[candidates[int(rng.integers(len(candidates)))]], dtype=np.float64)
    target = pin + np.array([0.0, 0.0, easy.above_pin]) + rng.uniform(-easy.aside, easy.aside, 3) * [1, 1, 0.25]
    if reach > 0:
        target = rims.point_along(target, np.asarray(ordinary_tip, dtype=np.float64), rng.uniform(0.0, reach))
    return target
