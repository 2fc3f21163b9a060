"""Named configurations of the collaborative scene: one argument, ``preset="benchmark"``, gives a whole setting.

``"default"`` is the task file as it is (the paper's instant tool, the sparse reward, plain observations).
``"benchmark"`` is the setting the benchmark table, the configurations of record and the reference team use: the
guided reward, the observation features the learned seats read, both arms' observations in the state (for
centralised critics), a lower contact penalty, a tool with a finite speed, the jaw a switch and a held pin kept
until the hand-off (each option is documented on the environment's page). Keyword arguments given beside a preset
win over its values.
"""

from __future__ import annotations

from types import MappingProxyType

from dvrl_marl.suction_debris.task import TASK

__all__ = ["PRESETS", "LEARNING_OPTIONS", "with_preset", "evaluation_options"]

#: Options that shape learning only (the reward, what is appended to or done to observations): a learned seat is
#: evaluated without them, since an exported policy computes its own features and normalisation from the plain
#: observation.
LEARNING_OPTIONS = ("reward_type", "guidance", "observation_features", "normalize_observations")

#: preset name -> the keyword arguments it sets
PRESETS = MappingProxyType({
    "default": MappingProxyType({}),
    "benchmark": MappingProxyType({
        "reward_type": "guided",
        "observation_features": "suction_debris_cleared_pins_zoom",
        "state_observations": True,
        "contact_penalty": 0.1,
        "tool_speed": 0.1,  # jaw / valve move 0.1 of their stroke per step: a Gaussian tool dimension's noise averages out
        "jaw_command": "switch",  # the jaw's target by the command's sign: a grasp is one decision
        "hold_until_handoff": True,  # a held pin stays in the jaws until the hand-off: noise cannot drop it
    }),
})
#: ``"irrigation"``: the benchmark's setting on a clotted field (the benchmark's irrigation level): half of each
#: cavity's blood starts clotted, which suction cannot draw until the valve's irrigating side (a negative command)
#: has broken it up. The rate: clinical irrigators deliver a litre a minute or more, which would fill a cavity of this
#: 11 ml phantom at once (as the suction's clinical rate would empty it: the task file); 1 ml/s is scaled to the
#: phantom as the suction's 2.5 ml/s is, and kept below it, as an S&I instrument's suction outdraws its irrigation.
#: A burst of a second adds 9 % of a cavity. The clotted share is the level's choice (CRESSim's contaminant has no
#: clotted share to take). The scripted irrigating team needs about 1,500 steps (benchmarks/irrigation_field.py):
#: the level's horizon is 2,500.
PRESETS = MappingProxyType({**PRESETS, "irrigation": MappingProxyType({
    **PRESETS["benchmark"],
    "irrigation_ml_s": 1.0,
    "clot_share": 0.5,
    "max_cycles": 2500,
})})


def with_preset(kwargs: dict, owner: str = TASK) -> dict:
    """``kwargs`` with its ``preset`` (if any) replaced by the preset's values; the explicit keywords win."""
    kwargs = dict(kwargs)
    name = kwargs.pop("preset", "default")
    if not isinstance(name, str) or name not in PRESETS:
        raise ValueError(f"{owner}: preset must be one of {sorted(PRESETS)}, got {name!r}")
    return {**PRESETS[name], **kwargs}


def evaluation_options(preset: str = "default", **kwargs) -> dict:
    """The keyword arguments of ``preset`` (and ``kwargs``, which win) that make the scene, without the learning
    options (:data:`LEARNING_OPTIONS`): what an exported team is evaluated on."""
    return {key: value for key, value in with_preset({"preset": preset, **kwargs}).items()
            if key not in LEARNING_OPTIONS}
