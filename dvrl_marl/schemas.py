"""The declared schemas of what the library reads: task files, training configurations, pipeline specs, policy files
and the command line's numbers, each a pydantic model (or a dataclass pydantic validates) that forbids unknown keys,
checks types strictly (``"0.99"`` is not a number, ``true`` is not 1) and checks ranges.

:func:`validated` is the one way in: it returns the checked values or raises a ``ValueError`` that names the source
(a file, or the object a keyword went to), the table and the field, and says what was wrong, e.g.
``baselines/configs/x.toml: [ppo] gamma: must be <= 1, got 2.0``. Modules declare their own schema beside the code
that uses it when the schema is that code's dataclass (the trainers' configurations); the file kinds that have no
dataclass of their own are declared here.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import (BaseModel, BeforeValidator, ConfigDict, Field, Strict, StrictBool, StrictStr, TypeAdapter,
                      ValidationError, model_validator)

__all__ = ["validated", "describe", "STRICT", "Finite", "Positive", "NonNegative", "Fraction", "PositiveInt",
           "NonNegativeInt", "Vector3", "SingleArmTask", "Sb3PpoRun", "CloneRun", "CloneBc",
           "CloneDagger", "CloneRecord", "CloneEvaluate", "PolicyFile", "PolicyImage", "PolicyImageFill", "cli_number",
           "PolicyFeltContact",
           "Seed", "Seeds",
           "Text", "Flag", "UnitInterval"]

#: Every schema: unknown keys are errors (the types below are strict: no "0.99" for a number, no true for 1).
STRICT = ConfigDict(extra="forbid")



def _plain(value):
    """numpy scalars as the Python numbers they hold (np.int64(3) is an integer; "3" and True are not numbers)."""
    if type(value).__module__ == "numpy" and hasattr(value, "item") and getattr(value, "ndim", 1) == 0:
        item = value.item()
        return item if not isinstance(item, bool) else value
    return value


_NUMBER = BeforeValidator(_plain)
Finite = Annotated[float, _NUMBER, Strict(), Field(allow_inf_nan=False)]
Positive = Annotated[float, _NUMBER, Strict(), Field(gt=0, allow_inf_nan=False)]
NonNegative = Annotated[float, _NUMBER, Strict(), Field(ge=0, allow_inf_nan=False)]
Fraction = Annotated[float, _NUMBER, Strict(), Field(ge=0, le=1, allow_inf_nan=False)]
UnitInterval = Annotated[float, _NUMBER, Strict(), Field(gt=0, le=1, allow_inf_nan=False)]  # (0, 1]
PositiveInt = Annotated[int, _NUMBER, Strict(), Field(ge=1)]
#: A count of steps (an episode's limit): at most a billion (230 days at 50 Hz), which int64 arrays hold.
StepCount = Annotated[int, _NUMBER, Strict(), Field(ge=1, le=10**9)]
#: An easy episode's limit (0: the task's), a count of steps as above.
EasyEpisodeSteps = Annotated[int, _NUMBER, Strict(), Field(ge=0, le=10**9)]
NonNegativeInt = Annotated[int, _NUMBER, Strict(), Field(ge=0)]
#: numpy's generators take seeds >= 0.
#: A seed: a 64-bit key of the counter-based streams (a larger one once wrapped: 2**64 played seed 0).
Seed = Annotated[int, _NUMBER, Strict(), Field(ge=0, le=2**64 - 1)]
Seeds = list[Seed]  # (one object: validated() keeps one adapter per schema)
Vector3 = tuple[Finite, Finite, Finite]
Text = StrictStr
Flag = StrictBool


def describe(error: ValidationError, source: str, table: str | None = None, tables: dict | None = None) -> str:
    """One line per problem: ``source: [table] field: what was wrong, got value``. ``tables`` maps a field to the
    table it came from (flattened configurations)."""
    lines = []
    for problem in error.errors(include_url=False):
        location = list(problem["loc"])
        name = "".join(f"[{part}]" if isinstance(part, int) else (f".{part}" if index else str(part))
                       for index, part in enumerate(location))
        where = (tables or {}).get(location[0], table) if location else table
        prefix = f"[{where}] " if where else ""
        lines.append(f"{source}: {prefix}{name + ': ' if name else ''}{_requirement(problem)}")
    return "\n".join(lines)


def _requirement(problem: dict) -> str:
    kind, context, value = problem["type"], problem.get("ctx") or {}, problem.get("input")
    got = f", got {value!r}"
    if isinstance(value, float) and not math.isfinite(value):  # NaN fails every bound; say what is wrong with it
        return "must be finite" + got
    if kind in ("extra_forbidden", "unexpected_keyword_argument"):
        return "unknown key (a typo?)" + got
    if kind == "missing":
        return "missing"
    if kind in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
        sign = {"greater_than": ">", "greater_than_equal": ">=", "less_than": "<", "less_than_equal": "<="}[kind]
        bound = next(iter(context.values()))
        return f"must be {sign} {bound}{got}"
    if kind == "finite_number":
        return "must be finite" + got
    if kind in ("float_type", "float_parsing"):
        return "must be a number" + got
    if kind in ("int_type", "int_parsing", "int_from_float"):
        return "must be an integer" + got
    if kind == "bool_type":
        return "must be true or false" + got
    if kind in ("string_type",):
        return "must be a string" + got
    if kind == "value_error":  # a rule between fields (a dataclass's __post_init__): its own words
        return str(context.get("error", problem["msg"]))
    if kind == "literal_error":
        return f"must be one of {context.get('expected')}{got}"
    if kind in ("too_short", "too_long"):
        return f"{problem['msg'].lower()}{got}"
    return f"{problem['msg']}{got}"


def validated(schema, data: Any, source: str, table: str | None = None, tables: dict | None = None):
    """``data`` checked against ``schema`` (a model class, or any type pydantic validates: a dataclass, an
    ``Annotated`` number); a ``ValueError`` naming ``source``, the table and the field otherwise."""
    try:
        if isinstance(schema, type) and issubclass(schema, BaseModel):
            return schema.model_validate(data)
        return _adapter(schema).validate_python(data)
    except ValidationError as error:
        raise ValueError(describe(error, source, table, tables)) from None


_ADAPTERS: dict = {}


def _adapter(schema) -> TypeAdapter:
    """One adapter per schema object, built once (schemas are module constants; keyed by identity, the schema kept
    alive beside its adapter so that an identity is never reused)."""
    key = id(schema)
    if key not in _ADAPTERS:
        _ADAPTERS[key] = (schema, TypeAdapter(schema))
    return _ADAPTERS[key][1]


# --- task files (tasks/*.toml, the [task] table) ---------------------------------------------------------------------
class SingleArmTask(BaseModel):
    """A single-arm task (PSM Reach, PSM Pick): the paper's parameters, positions in metres (PSM base frame)."""

    model_config = STRICT
    description: Text
    scenes: dict[Text, Text]
    workspace_centre: Vector3
    workspace_range: Positive
    step_size: Positive
    distance_threshold: Positive
    max_episode_steps: PositiveInt
    control_dt: Positive
    tip_clearance: NonNegative
    grasp_threshold: Annotated[float, _NUMBER, Strict(), Field(gt=0, le=1, allow_inf_nan=False)] | None = None
    initial_jaw: Fraction | None = None
    dense_scale: Positive = 1.0
    workspace_margin: NonNegative = 0.0
    start_distribution: Literal["uniform", "original"] = "uniform"
    goal_distribution: Literal["uniform", "original"] = "uniform"
    original_goal_floor: NonNegative | None = None


# (the collaborative task's schema is made from its parameters' fields: suction_debris.task.task_schema)


# --- training configurations without a dataclass of their own --------------------------------------------------------
class Sb3PpoRun(BaseModel):
    """``[run]`` of the collaborative env's SB3 PPO configurations (``dvrl_marl.training.marl``)."""

    model_config = STRICT
    algorithm: Literal["ppo"] = "ppo"
    total_timesteps: PositiveInt = 100_000
    n_envs: PositiveInt = 4
    eval_episodes: PositiveInt = 10
    surgeon: Literal["none", "scripted"] = "none"


class CloneRun(BaseModel):
    """``[run]`` of a behaviour-cloning configuration (``dvrl_marl.training.clone``)."""

    model_config = STRICT
    algorithm: Literal["bc"]
    dataset: Annotated[str, Strict(), Field(min_length=1)]


class CloneBc(BaseModel):
    """``[bc]``: the network and its fit (defaults: :class:`dvrl_marl.training.clone.CloneConfig`)."""

    model_config = STRICT
    hidden: Annotated[tuple[PositiveInt, ...], Field(min_length=1)] | None = None
    epochs: PositiveInt | None = None
    batch_size: PositiveInt | None = None
    learning_rate: Positive | None = None
    cleared_features: Flag | None = None
    anneal_lr: Flag | None = None
    action_weights: tuple[NonNegative, NonNegative, NonNegative, NonNegative] | None = None


class CloneDagger(BaseModel):
    """``[dagger]``: rounds in which the clone drives and the expert labels."""

    model_config = STRICT
    rounds: PositiveInt
    episodes: PositiveInt
    seed: Seed = 0


class CloneRecord(BaseModel):
    """``[record]``: how the dataset is made when it is not in the local Minari store."""

    model_config = STRICT
    policy: Annotated[str, Strict(), Field(min_length=1)]
    episodes: PositiveInt
    seed: Seed = 0
    action_noise: NonNegative = 0.0
    env_kwargs: dict[Text, Any] | None = None


class CloneEvaluate(BaseModel):
    """``[evaluate]``: the clone beside a partner on held-out seeds."""

    model_config = STRICT
    partner: Annotated[str, Strict(), Field(min_length=1)] = "pipeline"
    episodes: PositiveInt = 100


# --- policy files --------------------------------------------------------------------------------
class PolicyImageFill(BaseModel):
    """How a pixel policy fills the observation of the state policy it acts with: ``template`` (the scene's constants,
    zero for what the image does not give), its proprioception at the same indices as in the env's observation, its
    read-out's estimates at ``estimates_at``; at the indices ``keep_lowest`` names (some of ``estimates_at``), each
    estimate the lowest its episode has seen (the policy then keeps state per world: ``reset`` starts an episode).
    ``relative`` pairs ``[estimated, own]``: the read-out estimates ``observation[estimated] - observation[own]``, an
    index of the proprioception, which is added back (the other arm's tip read as its offset from the own tip).
    ``full_above``: an estimate kept at its lowest that is at least this reads as full (1, a cavity's whole blood)."""

    model_config = STRICT
    template: Annotated[list[Finite], Field(min_length=1)]
    estimates_at: Annotated[list[NonNegativeInt], Field(min_length=1)]
    keep_lowest: list[NonNegativeInt] = []
    relative: list[Annotated[list[NonNegativeInt], Field(min_length=2, max_length=2)]] = []
    full_above: UnitInterval | None = None


class PolicyImage(BaseModel):
    """A pixel policy's image table (:mod:`dvrl_marl.policies.image_encoder`)."""

    model_config = STRICT
    key: Text
    size: Annotated[int, _NUMBER, Strict(), Field(ge=32, le=256)]
    proprioception: Annotated[list[NonNegativeInt], Field(min_length=2, max_length=2)]
    convolutions: Annotated[list[Annotated[list[PositiveInt], Field(min_length=3, max_length=3)]], Field(min_length=1)]
    readout: PositiveInt | None = None
    fills: PolicyImageFill | None = None
    normalise: Literal["none", "per_image", "brightness"] = "none"
    # the read-out reads, after the convolutions' output, two keypoints per channel of the last convolution and the
    # proprioception (dvrl_marl.policies.image_encoder)
    keypoints: StrictBool = False
    # the convolutions read the stereo pair: the left eye's image (key) then the right eye's (key + "_right"), six
    # channels
    stereo: StrictBool = False

    @model_validator(mode="after")
    def _consistent(self):
        start, stop = self.proprioception
        if not start < stop:
            raise ValueError(f"proprioception must be [start, stop) with start < stop, got {self.proprioception}")
        self.encoded_size()
        if self.keypoints and self.readout is None:
            raise ValueError("keypoints are read by the read-out: give a readout size")
        if self.fills is not None:
            size, at = len(self.fills.template), self.fills.estimates_at
            if self.readout != len(at):
                raise ValueError(f"fills.estimates_at names {len(at)} indices for a read-out of {self.readout} outputs")
            if stop > size or max(at) >= size or len(set(at)) != len(at):
                raise ValueError(f"fills: proprioception {self.proprioception} and estimates_at {at} must be distinct "
                                 f"indices of the {size}-long template")
            if any(start <= index < stop for index in at):
                raise ValueError(f"fills.estimates_at {at} overlaps the proprioception {self.proprioception}")
            if not set(self.fills.keep_lowest) <= set(at):
                raise ValueError(f"fills.keep_lowest {self.fills.keep_lowest} names indices that are not estimated "
                                 f"(estimates_at {at})")
            if self.fills.full_above is not None and not self.fills.keep_lowest:
                raise ValueError(f"fills.full_above {self.fills.full_above} reads the estimates kept at their lowest "
                                 f"as full: name them in fills.keep_lowest")
            relative = [estimated for estimated, _ in self.fills.relative]
            if not set(relative) <= set(at) - set(self.fills.keep_lowest) or len(set(relative)) != len(relative):
                raise ValueError(f"fills.relative {self.fills.relative}: each pair's first index must be estimated "
                                 f"(estimates_at {at}), once, and not kept at its lowest")
            if any(not start <= own < stop for _, own in self.fills.relative):
                raise ValueError(f"fills.relative {self.fills.relative}: each pair's second index must be of the "
                                 f"proprioception {self.proprioception}")
        return self

    def policy_input_size(self) -> int:
        """Length of what the policy's layers read from the encoder: the filled observation, or the encoding followed
        by the proprioception."""
        if self.fills is not None:
            return len(self.fills.template)
        start, stop = self.proprioception
        return self.encoded_size() + stop - start

    def convolved_size(self) -> int:
        """Length of the convolutions' flattened output (no padding)."""
        size = self.size
        for _, kernel, stride in self.convolutions:
            size = (size - kernel) // stride + 1
            if size < 1:
                raise ValueError(f"the convolutions {self.convolutions} leave nothing of a {self.size} px image")
        return self.convolutions[-1][0] * size * size

    def encoded_size(self) -> int:
        """Length of what the encoder gives the perceptron: the read-out's, or the convolutions' output."""
        return self.readout or self.convolved_size()

    def readout_input_size(self) -> int:
        """Length of what the read-out reads: the convolutions' output, then (``keypoints``) two keypoints per
        channel of the last convolution and the proprioception."""
        if not self.keypoints:
            return self.convolved_size()
        start, stop = self.proprioception
        return self.convolved_size() + 2 * self.convolutions[-1][0] + stop - start


#: The workspace's span in observation units (positions are normalised to [-1, 1]).
WORKSPACE_SPAN = 2.0
#: The longest episode the collaborative scene runs (a person's seat: 2 minutes at 50 Hz), the bound of a policy's
#: counts of steps.
MAX_EPISODE_STEPS = 6000


class PolicyKeepClear(BaseModel):
    """A policy's ``keep_clear`` (:mod:`dvrl_marl.policies`): its motion withheld where it would bring its instrument
    within ``keep`` of the other's and nearer, in the observation's coordinates (``keep_mm`` as read by a person).
    ``own_tip`` and ``other_tip`` are ``[start, stop)`` of three observation values each; ``gain`` turns an action
    into the tip's move (``move = action / gain``); the centres are the two arms' remote centres of motion."""

    model_config = STRICT
    keep_mm: Positive
    keep: Positive
    gain: Positive
    own_tip: Annotated[list[NonNegativeInt], Field(min_length=2, max_length=2)]
    other_tip: Annotated[list[NonNegativeInt], Field(min_length=2, max_length=2)]
    own_centre: Annotated[list[Finite], Field(min_length=3, max_length=3)]
    other_centre: Annotated[list[Finite], Field(min_length=3, max_length=3)]

    @model_validator(mode="after")
    def _three_values_each(self):
        for name in ("own_tip", "other_tip"):
            start, stop = getattr(self, name)
            if stop - start != 3:
                raise ValueError(f"{name} must span three observation values, [start, start + 3), got "
                                 f"{getattr(self, name)}")
        if self.keep > WORKSPACE_SPAN:  # (a seat that keeps clear of the whole workspace never moves)
            raise ValueError(f"keep {self.keep} (keep_mm {self.keep_mm}) is wider than the workspace "
                             f"({WORKSPACE_SPAN} observation units across)")
        for name in ("own_centre", "other_centre"):
            if max(abs(v) for v in getattr(self, name)) > 10 * WORKSPACE_SPAN:
                raise ValueError(f"{name} {getattr(self, name)} lies far outside the workspace (observation units)")
        return self

    def mm_per_unit(self) -> float:
        """Millimetres per observation unit, as this table reads them (``keep_mm / keep``)."""
        return self.keep_mm / self.keep


class PolicyFeltContact(BaseModel):
    """A policy's ``felt_contact`` (:mod:`dvrl_marl.policies.felt_contact`), in the observation's units (the ``_mm``
    values as read by a person): a move ``threshold`` or more short of its command with the other instrument's axis
    within ``near`` is a touch; the tip then keeps ``retreat`` behind it for ``hold_steps`` steps."""

    model_config = STRICT
    near_mm: Positive
    near: Positive
    retreat_mm: Positive
    retreat: Positive
    threshold_mm: Positive
    threshold: Positive
    hold_steps: Annotated[int, _NUMBER, Strict(), Field(ge=1, le=MAX_EPISODE_STEPS)]

    @model_validator(mode="after")
    def _sizes(self):
        units = {name: getattr(self, f"{name}_mm") / getattr(self, name) for name in ("near", "retreat", "threshold")}
        if max(units.values()) > min(units.values()) * (1 + 1e-6):
            raise ValueError(f"the _mm values and their observation units disagree: {units} mm per unit")
        if self.near > WORKSPACE_SPAN:
            raise ValueError(f"near {self.near} (near_mm {self.near_mm}) is wider than the workspace "
                             f"({WORKSPACE_SPAN} observation units across)")
        for name in ("retreat", "threshold"):
            if not getattr(self, name) < self.near:
                raise ValueError(f"{name}_mm {getattr(self, f'{name}_mm')} must be below near_mm {self.near_mm} (a "
                                 f"touch is felt within near, and the tip keeps within it)")
        return self


class PolicyFile(BaseModel):
    """What ``policy.json`` must hold (:mod:`dvrl_marl.policies`; its other keys record how it was trained): the
    layer sizes, one activation per layer, the observation's keys and finite action bounds, each low below its
    high (bounds the other way round would invert the actions)."""

    model_config = ConfigDict(extra="allow")
    format: Text
    name: Text = "policy"
    env_id: Text
    agent: Literal["suction", "grasper"] | None = None  # (a seat of the collaborative scene names its seat)
    preset: Text | None = None
    layer_sizes: Annotated[list[PositiveInt], Field(min_length=2)]
    activations: Annotated[list[Text], Field(min_length=1)]
    observation_keys: list[Text]
    action_low: list[Finite]
    action_high: list[Finite]
    switch_dimensions: list[NonNegativeInt] = []
    image: PolicyImage | None = None
    keep_clear: PolicyKeepClear | None = None
    felt_contact: PolicyFeltContact | None = None

    @model_validator(mode="after")
    def _consistent(self):
        if self.felt_contact is not None and self.keep_clear is None:
            raise ValueError("felt_contact reads the tips, the arms' centres and the action's gain from keep_clear, "
                             "which the policy lacks")
        if self.felt_contact is not None:
            keep, felt = self.keep_clear.mm_per_unit(), self.felt_contact.near_mm / self.felt_contact.near
            if abs(keep - felt) > 1e-6 * keep:
                raise ValueError(f"keep_clear reads {keep:g} mm per observation unit, felt_contact {felt:g}: the "
                                 "two tables must be of one scene")
        if self.keep_clear is not None:
            if self.image is not None and self.image.fills is None:
                raise ValueError("keep_clear reads the two tips from the observation: a pixel policy has them only "
                                 "with image.fills")
            if self.image is not None and not set(range(*self.keep_clear.other_tip)) <= set(
                    self.image.fills.estimates_at):
                raise ValueError(f"keep_clear.other_tip {self.keep_clear.other_tip} must be estimated from the image "
                                 f"(image.fills.estimates_at {self.image.fills.estimates_at}): the rest of what a "
                                 f"pixel policy fills is constant")
            width = len(self.image.fills.template) if self.image is not None else self.layer_sizes[0]
            for name in ("own_tip", "other_tip"):  # (the features a state policy computes: dvrl_marl.policies)
                if getattr(self.keep_clear, name)[1] > width:
                    raise ValueError(f"keep_clear.{name} {getattr(self.keep_clear, name)} lies beyond the "
                                     f"{width} observation values the policy reads")
            if self.layer_sizes[-1] < 3:
                raise ValueError("keep_clear withholds the first three action values (the motion); the policy has "
                                 f"{self.layer_sizes[-1]}")
        if self.image is not None and self.image.fills is not None:  # (features of its own may follow the fill)
            if self.layer_sizes[0] < len(self.image.fills.template):
                raise ValueError(f"layer_sizes[0] must be at least {len(self.image.fills.template)} (the filled "
                                 f"observation), got {self.layer_sizes[0]}")
        elif self.image is not None:
            start, stop = self.image.proprioception
            expected = self.image.policy_input_size()
            if self.layer_sizes[0] != expected:
                raise ValueError(f"layer_sizes[0] must be {expected} (the image's encoding then "
                                 f"{stop - start} proprioception values), got {self.layer_sizes[0]}")
        for index in self.switch_dimensions:
            if index >= self.layer_sizes[-1]:
                raise ValueError(f"switch_dimensions names action dimension {index}; the policy has "
                                 f"{self.layer_sizes[-1]}")
        if len(self.layer_sizes) != len(self.activations) + 1:
            raise ValueError(f"layer_sizes must list {len(self.activations) + 1} sizes (one per layer boundary for "
                             f"{len(self.activations)} activations), got {self.layer_sizes}")
        for name in ("action_low", "action_high"):
            if len(getattr(self, name)) != self.layer_sizes[-1]:
                raise ValueError(f"{name} needs {self.layer_sizes[-1]} values (the output layer's), got "
                                 f"{getattr(self, name)}")
        for index, (low, high) in enumerate(zip(self.action_low, self.action_high)):
            if not low < high:
                raise ValueError(f"action_low[{index}] = {low} must be below action_high[{index}] = {high}")
        return self


# --- the command line ------------------------------------------------------------------------------------------------
def cli_number(kind: type, *, low=None, high=None, name: str = "value"):
    """An ``argparse`` type: the text as ``kind`` (int or float) in ``[low, high]``, checked by pydantic; argparse
    prints the error with the flag's name."""
    import argparse

    constraints = {k: v for k, v in (("ge", low), ("le", high)) if v is not None}
    schema = Annotated[kind, Field(**constraints, allow_inf_nan=False) if kind is float else Field(**constraints)]
    adapter = TypeAdapter(schema)

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if kind is int else 'a number'}") from None
        if kind is float and not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
        try:
            return adapter.validate_python(value)
        except ValidationError as error:
            raise argparse.ArgumentTypeError(_requirement(error.errors(include_url=False)[0])) from None

    parse.__name__ = name  # argparse names the type in its messages
    return parse
