"""The collaborative scene's options, one checked record per concern, made from ``preset`` plus keywords in one place.

Every form of the scene (``parallel_env``, ``env``, ``batched_env``, ``jax_env``, the seat) takes the same keywords;
:meth:`SceneOptions.of` sorts them into their records and checks each value once, before anything is made:

- :class:`~dvrl_marl.suction_debris.task.SuctionDebrisParams`, **the scene's rules** (the task file's values,
  overridden keyword by keyword);
- :class:`ObservationOptions`, **what is observed** beyond the plain observation (features, the state, scaling);
- :class:`ImageOptions`, **the endoscope's images** in the observations;
- :class:`LearningAids`, **what helps learning** without changing the scene (the reward, start levels).

Each record's fields carry their type and range (``schemas``), their default and, in a ``#:`` comment, what they do:
the environment page's options table is generated from them (``docs/build_docs.py``), and
:mod:`dvrl_marl.envs.scene_keywords` writes them into every form's signature. A value out of its range is named with
its keyword (``suction_debris_v8: image_size: must be 0 (no images) or 32..256 px, got 8``).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Literal

from pydantic.dataclasses import dataclass

from dvrl_marl.schemas import STRICT, EasyEpisodeSteps, Flag, NonNegativeInt, PositiveInt, validated
from dvrl_marl.suction_debris import features, start_levels
from dvrl_marl.suction_debris.appearance import APPEARANCES, Appearance
from dvrl_marl.suction_debris.guidance import Guidance
from dvrl_marl.suction_debris.presets import with_preset
from dvrl_marl.suction_debris.task import TASK, SuctionDebrisParams

__all__ = ["SceneOptions", "ObservationOptions", "ImageOptions", "LearningAids", "RECORDS", "REWARD_TYPES",
           "IMAGE_SIZES"]

#: The rewards the scene computes: the paper's sparse one, the env's dense shaping, and the guided reward.
REWARD_TYPES = ("sparse", "dense", "guided")
#: The endoscope's image sizes (px, square), beside 0 for none: what its renderer draws (endoscope.EndoscopeRenderer).
IMAGE_SIZES = (32, 256)


@dataclass(frozen=True, config=STRICT)
class ObservationOptions:
    """What each arm observes beyond the plain observation (the environment page's Observation Space)."""

    #: a feature set appended to every observation (``features.SCENE_FEATURE_SETS``; "" for none)
    observation_features: Literal[("",) + features.SCENE_FEATURE_SETS] = ""
    #: ``state()`` carries every arm's observation after it (for centralised critics)
    state_observations: Flag = False
    #: observations and the state mapped by fixed, measured centres and spreads (``observation_scaling``)
    normalize_observations: Flag = False


@dataclass(frozen=True, config=STRICT)
class ImageOptions:
    """The endoscope's images in every arm's observation (``observation["image"]`` and its companions)."""

    #: the images' side in pixels, 0 (no images) or 32..256
    image_size: NonNegativeInt = 0
    #: the left eye's depth (metres) beside its image
    image_depth: Flag = False
    #: the left eye's segmentation mask beside its image
    image_segmentation: Flag = False
    #: the stereo pair's right eye beside the left
    image_stereo: Flag = False
    #: the range each world's look is drawn from per episode (a name of ``appearance.APPEARANCES`` or an
    #: ``Appearance``; None: the scene's own look)
    image_appearance: Any = None
    #: GL contexts that draw the images, each in a thread of its own
    image_contexts: PositiveInt = 1

    def __post_init__(self):
        size = self.image_size
        if size and not IMAGE_SIZES[0] <= size <= IMAGE_SIZES[1]:
            raise ValueError(f"image_size must be 0 (no images) or {IMAGE_SIZES[0]}..{IMAGE_SIZES[1]} px, got {size}")
        if not (self.image_appearance is None or isinstance(self.image_appearance, Appearance)
                or (isinstance(self.image_appearance, str) and self.image_appearance in APPEARANCES)):
            raise ValueError(f"image_appearance must be None (the scene's own look), one of {sorted(APPEARANCES)} "
                             f"or an endoscope.Appearance, got {self.image_appearance!r}")
        if not size:
            for name in ("image_depth", "image_segmentation", "image_stereo", "image_appearance"):
                if getattr(self, name) not in (False, None):
                    raise ValueError(f"{name} needs image_size (it is the image's)")
            if self.image_contexts > 1:
                raise ValueError("image_contexts needs image_size (they draw the images)")


@dataclass(frozen=True, config=STRICT)
class LearningAids:
    """What helps learning without changing the scene: an exported policy is evaluated without them
    (:data:`dvrl_marl.suction_debris.presets.LEARNING_OPTIONS`)."""

    #: the reward: the paper's sparse one, the env's dense shaping, or the guided reward
    reward_type: Literal[REWARD_TYPES] = "sparse"
    #: the guided reward's settings (a dict of ``guidance.Guidance`` fields; only with ``reward_type="guided"``)
    guidance: Any = None
    #: how easy each episode's start is: 0 (easy) .. 1 (the task), or "easy" / "default" (``start_levels``)
    start_level: Any = 1.0
    #: an easy episode's time limit in steps (None or 0: the task's ``max_cycles``)
    easy_episode_steps: EasyEpisodeSteps | None = start_levels.EASY_EPISODES.episode_steps

    def __post_init__(self):
        start_levels.checked_level(self.start_level, "start_level")  # (raises naming it)
        if self.guidance is not None:
            if self.reward_type != "guided":
                raise ValueError(f"guidance settings need reward_type='guided', got {self.reward_type!r}")
            if not isinstance(self.guidance, (dict, Guidance)):
                raise ValueError(f"guidance must be a dict of Guidance settings, got {type(self.guidance).__name__}")
            if isinstance(self.guidance, dict):  # (each setting checked now, before anything is made)
                validated(Guidance, self.guidance, "guidance")

    @property
    def level(self) -> float:
        """:attr:`start_level` as a number in [0, 1]."""
        return start_levels.checked_level(self.start_level, "start_level")

    @property
    def easy_steps(self) -> int | None:
        """An easy episode's time limit (None: the task's)."""
        return self.easy_episode_steps or None

    def guidance_settings(self, owner: str) -> Guidance | None:
        """The guided reward's settings, checked (None unless the reward is guided)."""
        if self.reward_type != "guided":
            return None
        if self.guidance is None or isinstance(self.guidance, Guidance):
            return self.guidance or Guidance()
        return validated(Guidance, self.guidance, f"{owner}: guidance")


#: The option records by concern, in the order the environment page lists them.
RECORDS = {"observation": ObservationOptions, "images": ImageOptions, "learning": LearningAids}


def record_fields(record) -> tuple[str, ...]:
    return tuple(item.name for item in dataclasses.fields(record))


@dataclasses.dataclass(frozen=True)
class SceneOptions:
    """Every option of a scene, by concern: ``rules`` (the task's parameters), ``observation``, ``images`` and
    ``learning``, and the ``preset`` they started from."""

    preset: str
    rules: SuctionDebrisParams
    observation: ObservationOptions
    images: ImageOptions
    learning: LearningAids

    @classmethod
    def of(cls, owner: str = TASK, *, preset: str = "default", task: str = TASK, max_cycles: int | None = None,
           **keywords) -> SceneOptions:
        """``preset``'s values with ``keywords`` over them (the keywords win), sorted into their records and each
        checked; an unknown keyword or a value out of its range raises naming it (``owner: keyword: ...``)."""
        values = with_preset({"preset": preset, **keywords}, owner)
        if "max_cycles" in values and max_cycles is None:  # (a preset's horizon, unless the caller gives one)
            max_cycles = values["max_cycles"]
        values.pop("max_cycles", None)
        parts = {}
        for concern, record in RECORDS.items():
            names = record_fields(record)
            given = {name: values.pop(name) for name in names if name in values}
            parts[concern] = _checked(record, given, owner)
        rules = SuctionDebrisParams.from_task(task, max_cycles=max_cycles, **values)  # (the rest: the task's own)
        return cls(preset=preset, rules=rules, **parts)

    def keywords(self) -> dict:
        """The option records' keywords and values (not the rules'), as the env's constructor takes them."""
        return {name: getattr(part, name) for part in (self.observation, self.images, self.learning)
                for name in record_fields(type(part))}


def _checked(record, values: dict, owner: str):
    """``record(**values)`` with pydantic's checks; a ``ValueError`` naming ``owner`` and the keyword otherwise."""
    try:
        return validated(record, values, owner)
    except ValueError as error:
        message = str(error)
        if message.startswith(owner):
            raise
        raise ValueError(f"{owner}: {message}") from None
