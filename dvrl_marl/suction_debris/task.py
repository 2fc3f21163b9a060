"""The collaborative task's parameters: read from its task file, checked, one frozen record.

``tasks/suction_debris_v8.toml`` holds every value with its source; keyword arguments of the environments override
them one by one and are checked by its schema (:func:`task_schema`, made from the parameters' fields: a misspelt key names itself).
"""

from __future__ import annotations

import dataclasses
import functools
import typing
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np

from dvrl_marl import assets
from dvrl_marl.task import load_task_table

if TYPE_CHECKING:  # (the fields' checked types, named for readers and IDEs; task_schema resolves them)
    from dvrl_marl.schemas import (Flag, Fraction, NonNegative, Positive, PositiveInt, StepCount, Text,
                                   UnitInterval, Vector3)

__all__ = ["SuctionDebrisParams", "TASK", "env_name", "PIN_SLOTS", "task_schema"]

#: The task file of the current version (``tasks/suction_debris_v8.toml``); the environment takes its name from it.
TASK = "suction_debris_v8"
#: The slots pins lie in across a cavity floor (offsets from its centre line, m); at most two pins per slot.
PIN_SLOTS = (0.0, -0.004, 0.004, -0.008, 0.008)


@dataclass(frozen=True)
class SuctionDebrisParams:
    """The task's parameters (see ``tasks/suction_debris_v8.toml`` for defaults and sources). Each field's type says
    its range (the names are :mod:`dvrl_marl.schemas`' checked types): the task file's schema is made from these
    fields (:func:`task_schema`), so a parameter and its range are written here once."""

    scene: Text
    workspace_centre: Vector3
    workspace_range: Positive
    step_size: Positive
    distance_threshold: Positive
    grasp_threshold: UnitInterval
    control_dt: Positive
    tip_clearance: NonNegative
    blood_ml: tuple[NonNegative, ...]
    blood_threshold_ml: NonNegative
    suction_rate_ml_s: Positive
    debris_count: PositiveInt
    contact_penalty: NonNegative
    max_cycles: StepCount
    # The scene's rules; the task file sets the current ones, the defaults here are the simple rules each one
    # replaces (docs/deviations.md: the keyword that gives each back).
    pins_fall: Flag = False  # a released pin falls under gravity (simple: it appears on the surface below at once)
    suction_reach: NonNegative = 0.0  # flow falls linearly to none this far above the surface (m; 0: on/off there)
    bleeding_ml_s: NonNegative = 0.0  # largest bleeding rate per cavity (0: no bleeding)
    bleeding_onset_s: NonNegative = 0.0  # each cavity starts bleeding at a seeded time in [0, this] (s)
    clotting_ml_s: NonNegative = 0.0  # liquid blood clots at this rate per cavity (ml/s); suction draws no clot
    # Irrigation (the S&I valve's other half; suction_debris.rules, the irrigation rule): off by default.
    irrigation_ml_s: NonNegative = 0.0  # saline flow while the valve irrigates (ml/s; 0: a negative command shuts it)
    clot_share: Fraction = 0.0  # share of each cavity's starting blood that is clotted (suction draws no clot)
    clot_per_saline_ml: NonNegative = 0.0  # clot broken up (made liquid) per ml of saline irrigated onto it (ml)
    spill_s: NonNegative = 0.0  # how long an overflow's spill covers the phantom around its cavity (s)
    waste_penalty: NonNegative = 0.0  # per ml of saline wasted (irrigated but into no cavity), off every agent's reward
    deliver_at_grip: Flag = False  # hand-off judged where the jaws hold the pin (simple: at the pin's centre)
    pins_stay_on_phantom: Flag = False  # a pin released beyond the phantom lands on its nearest edge (simple: table)
    blocked_moves: Literal["stop", "slide", "climb", "climb_ahead", "settle"] = "stop"  # how it slides (suction_debris.sliding)
    held_pin_at_grip: Flag = False  # a held pin is observed (and carried, in the dense reward) at the point judged
    # Options that help learning (default: the paper's instant tool and jaw):
    tool_speed: UnitInterval = 1.0  # fraction of the jaw's / valve's stroke per control step (dvrl_marl.core.tools)
    jaw_command: Literal["proportional", "switch"] = "proportional"  # "switch": the jaw's target by the command's sign
    hold_until_handoff: Flag = False  # a held pin's jaw stays shut, whatever the command, until the hand-off

    @property
    def fluids(self) -> bool:
        """The cavities hold more than liquid blood: clots, or saline from the irrigating valve (observations, the
        state and the endoscope then show the fluids: :data:`dvrl_marl.suction_debris.layout.FLUID_FIELDS`)."""
        return self.irrigation_ml_s > 0.0 or self.clot_share > 0.0 or self.clotting_ml_s > 0.0

    @classmethod
    def from_task(cls, task: str = TASK, **overrides) -> "SuctionDebrisParams":
        """The task file's values (checked against :func:`task_schema`: a misspelt key in
        the file is an error naming it), keyword by keyword overridden, then checked as :meth:`validated`."""
        from dvrl_marl.schemas import validated

        task_name, table = load_task_table(task)
        owner = env_name(task_name)
        names = {f.name for f in fields(cls)}
        unknown = set(overrides) - names
        if unknown:
            raise TypeError(f"{owner}() got an unexpected keyword argument {sorted(unknown)[0]!r}")
        path = task if str(task).endswith(".toml") else f"tasks/{task_name}.toml"
        values = validated(task_schema(), table, path, table="task").model_dump(exclude={"description"})
        values.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**values).validated(owner)

    def validated(self, owner: str = TASK) -> "SuctionDebrisParams":
        """Every parameter checked against :func:`task_schema` (finite numbers in range,
        true/false flags), one blood volume per cavity, at most two pins per slot; a copy with the checked values.
        (Each cavity's capacity is checked by BloodState, which knows the cavities.)"""
        from dvrl_marl.schemas import validated

        values = {f.name: getattr(self, f.name) for f in fields(self)}
        for key in ("workspace_centre", "blood_ml"):  # any sequence (a numpy array too) of numbers
            if isinstance(values[key], np.ndarray) or (hasattr(values[key], "__iter__")
                                                       and not isinstance(values[key], (str, bytes, dict))):
                values[key] = tuple(values[key])
        checked = validated(task_schema(), values, owner)
        if len(checked.blood_ml) != len(assets.CAVITY_CENTRES):
            raise ValueError(f"{owner}: blood_ml needs {len(assets.CAVITY_CENTRES)} values (one per cavity), "
                             f"got {self.blood_ml!r}")
        if checked.debris_count > 2 * len(PIN_SLOTS):
            raise ValueError(f"{owner}: debris_count must be <= {2 * len(PIN_SLOTS)} (the cavities' slots), "
                             f"got {self.debris_count!r}")
        return replace(self, **{key: getattr(checked, key) for key in values})


@functools.cache
def task_schema():
    """The ``[task]`` table's schema (a strict pydantic model: unknown keys are errors), made from
    :class:`SuctionDebrisParams`' fields and their types (resolved here: importing the core imports no pydantic)."""
    import pydantic

    from dvrl_marl import schemas

    hints = typing.get_type_hints(SuctionDebrisParams, localns={**vars(schemas), "Literal": typing.Literal},
                                  include_extras=True)
    fields_ = {f.name: (hints[f.name], ... if f.default is dataclasses.MISSING else f.default)
               for f in fields(SuctionDebrisParams)}
    return pydantic.create_model("CollaborativeTask", __config__=schemas.STRICT,
                                 __doc__="The collaborative scene's task file (its [task] table).",
                                 description=(schemas.Text, ""), **fields_)


def env_name(task: str) -> str:
    """The environment's name for a task file (a path or a name): the file's stem."""
    return Path(str(task)).stem
