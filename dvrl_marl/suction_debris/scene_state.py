"""The collaborative scene's state as data: one frozen record of arrays, every world's row of each.

:class:`SceneState` names everything the next step depends on (and the cues a step leaves for a person), one field
each, with its shape per world and how an episode starts it (:data:`SPECS`). It is a pytree for JAX
(:func:`register_with_jax`: ``jit``, ``vmap`` and ``lax.scan`` carry it); with numpy arrays it is the same record.
Nothing converts it by hand: choosing, writing and stacking worlds, checking a record's shapes and dtypes and counting
its bytes are written once here, over its fields.

The rules that advance it are :class:`~dvrl_marl.suction_debris.rules.CollaborativeCore`'s; ``core.step_state(state,
commands)`` and ``core.reset_state(state, mask)`` are them as pure functions of the record.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

__all__ = ["SceneState", "EnvState", "FieldSpec", "SPECS", "register_with_jax", "take_worlds", "write_worlds",
           "stack_worlds", "one_world", "check_state", "bytes_per_world", "map_arrays"]


@dataclass(frozen=True)
class FieldSpec:
    """A field's shape in one world (``"C"``: cavities, ``"D"``: pins, ``"J:<agent>"``: that arm's joints, or a
    length), its kind (``"float"``, ``"int"``, ``"bool"``) and what a new episode sets it to (None: a rule draws or
    computes it)."""

    shape: tuple = ()
    kind: str = "float"
    start: object = None


_F, _I, _B = "float", "int", "bool"

#: Every field of :class:`SceneState`, in its order. Adding a field here and to the record is all a new rule's state
#: needs: the core makes it, starts it with each episode (``start``) and carries it through every conversion.
SPECS = {
    # the arms: tips (base frame, m), joints, the grasper's jaw (0 shut .. 1 open)
    "suction_tip": FieldSpec((3,)), "suction_q": FieldSpec(("J:suction",)),
    "grasper_tip": FieldSpec((3,)), "grasper_q": FieldSpec(("J:grasper",)), "jaw": FieldSpec((), _F, 1.0),
    # the suction's valve stroke (0 closed .. 1 open: core.tools)
    "valve_opening": FieldSpec((), _F, 0.0),
    # blood per cavity (ml): at the episode's start, now, and the level of its surface (m)
    "initial_ml": FieldSpec(("C",)), "remaining_ml": FieldSpec(("C",)), "surface_z": FieldSpec(("C",)),
    # the pins: centre (m, world), yaw, cavity, and their flags
    "debris_position": FieldSpec(("D", 3)), "debris_yaw": FieldSpec(("D",)), "debris_cavity": FieldSpec(("D",), _I),
    "visible": FieldSpec(("D",), _B), "held": FieldSpec(("D",), _B, False), "delivered": FieldSpec(("D",), _B, False),
    "lifted": FieldSpec(("D",), _B, False),
    "fall_speed": FieldSpec(("D",), _F, float("nan")),  # m/s while a released pin falls, NaN at rest
    # bleeding: blood added this episode (ml), each cavity's onset (s; inf: none) and rate (ml/s)
    "added_ml": FieldSpec(("C",), _F, 0.0), "bleed_onset": FieldSpec(("C",)), "bleed_rate": FieldSpec(("C",)),
    # clotted blood per cavity (ml; part of remaining_ml, which suction cannot draw)
    "clot_ml": FieldSpec(("C",), _F, 0.0),
    # irrigation (suction_debris.rules's irrigation rule): the valve's irrigating stroke (0 shut .. 1 open), saline in
    # each cavity (ml; with the liquid blood, the mix suction draws), seconds each cavity's spill still covers the
    # phantom, whether it overflowed this step; the episode's saline used and wasted, spilt (ml), overflows begun and
    # steps with a cavity overflowing
    "irrigation_opening": FieldSpec((), _F, 0.0), "saline_ml": FieldSpec(("C",), _F, 0.0),
    "spill_s": FieldSpec(("C",), _F, 0.0), "spilling": FieldSpec(("C",), _B, False),
    "saline_used_ml": FieldSpec((), _F, 0.0), "saline_wasted_ml": FieldSpec((), _F, 0.0),
    "overflow_ml": FieldSpec((), _F, 0.0), "overflow_events": FieldSpec((), _I, 0),
    "overflow_steps": FieldSpec((), _I, 0),
    # the held pin (-1: none), its offset from the tip and where the jaws hold it
    "holding": FieldSpec((), _I, -1), "hold_offset": FieldSpec((3,), _F, 0.0), "grip_offset": FieldSpec((3,)),
    # the episode's clock and end
    "elapsed": FieldSpec((), _I, 0), "limit": FieldSpec((), _I), "contact": FieldSpec((), _B, False),
    "complete": FieldSpec((), _B, False),
    # the dense reward's shaping distances (m)
    "suction_work_distance": FieldSpec(()), "grasper_work_distance": FieldSpec(()),
    # a person's cues from the last step: a move refused, the blood the suction drew (ml)
    "suction_blocked": FieldSpec((), _B, False), "grasper_blocked": FieldSpec((), _B, False),
    "drawn_ml": FieldSpec((), _F, 0.0),
    # each world's counter-based random stream (core.streams): its 64-bit key as two halves, its episode count
    "stream_key_low": FieldSpec((), _I), "stream_key_high": FieldSpec((), _I), "stream_episode": FieldSpec((), _I),
}

_DTYPES = {_F: np.float64, _I: np.int64, _B: np.bool_}


@dataclass(frozen=True)
class SceneState:
    """Every world's state, one array per field with the worlds along its first axis (see :data:`SPECS`)."""

    suction_tip: object
    suction_q: object
    grasper_tip: object
    grasper_q: object
    jaw: object
    valve_opening: object
    initial_ml: object
    remaining_ml: object
    surface_z: object
    debris_position: object
    debris_yaw: object
    debris_cavity: object
    visible: object
    held: object
    delivered: object
    lifted: object
    fall_speed: object
    added_ml: object
    bleed_onset: object
    bleed_rate: object
    clot_ml: object
    irrigation_opening: object
    saline_ml: object
    spill_s: object
    spilling: object
    saline_used_ml: object
    saline_wasted_ml: object
    overflow_ml: object
    overflow_events: object
    overflow_steps: object
    holding: object
    hold_offset: object
    grip_offset: object
    elapsed: object
    limit: object
    contact: object
    complete: object
    suction_work_distance: object
    grasper_work_distance: object
    suction_blocked: object
    grasper_blocked: object
    drawn_ml: object
    stream_key_low: object
    stream_key_high: object
    stream_episode: object

    replace = dataclasses.replace

    @property
    def num_worlds(self) -> int:
        return int(np.shape(self.elapsed)[0]) if np.ndim(self.elapsed) else 1

    def as_dict(self) -> dict:
        """``{field: array}``, in the record's order (no copies)."""
        return {name: getattr(self, name) for name in SPECS}


@dataclass(frozen=True)
class EnvState:
    """What a compiled env carries between steps: the scene's state, each world's start level and (with the guided
    reward) each rewarded agent's potential at the last step."""

    scene: SceneState
    levels: object
    potential: dict

    replace = dataclasses.replace


if tuple(f.name for f in dataclasses.fields(SceneState)) != tuple(SPECS):  # (one list: the record's and the specs')
    raise RuntimeError("SceneState's fields and SPECS differ")

_registered = False


def register_with_jax() -> None:
    """Make the records JAX pytrees (once; a no-op where JAX is not installed). The env forms that trace the step
    call it; a caller's own ``jit`` over a record needs it too."""
    global _registered
    if _registered:
        return
    try:
        import jax
    except ImportError:
        return
    jax.tree_util.register_dataclass(SceneState, data_fields=list(SPECS), meta_fields=[])
    jax.tree_util.register_dataclass(EnvState, data_fields=["scene", "levels", "potential"], meta_fields=[])
    _registered = True


def map_arrays(function, state: SceneState) -> SceneState:
    """A record of ``function(array)`` for each field's array."""
    return SceneState(**{name: function(value) for name, value in state.as_dict().items()})


def take_worlds(state: SceneState, worlds) -> SceneState:
    """The worlds ``worlds`` (indices or a mask) of a record, as a record of their own (copies, for numpy)."""
    return map_arrays(lambda value: value[worlds], state)


def one_world(state: SceneState, world: int) -> SceneState:
    """World ``world``'s fields without the worlds' axis (a vmapped function's view of it)."""
    return map_arrays(lambda value: value[world], state)


def write_worlds(state: SceneState, worlds, part: SceneState) -> SceneState:
    """A record equal to ``state`` but for the worlds ``worlds``, which are ``part``'s (numpy: copies; the record
    given is not changed)."""

    def written(value, new):
        if isinstance(value, np.ndarray):
            out = value.copy()
            out[worlds] = new
            return out
        return value.at[worlds].set(new)  # (JAX)

    return SceneState(**{name: written(value, getattr(part, name)) for name, value in state.as_dict().items()})


def stack_worlds(states) -> SceneState:
    """One record of the worlds of several, in order (each a record of one or more worlds)."""
    states = list(states)
    return SceneState(**{name: np.concatenate([np.asarray(getattr(s, name)) for s in states]) for name in SPECS})


def world_shapes(num_cavities: int, num_debris: int, joints: dict) -> dict:
    """``{field: shape in one world}`` for a scene of this many cavities, pins and arm joints."""
    sizes = {"C": num_cavities, "D": num_debris, **{f"J:{agent}": count for agent, count in joints.items()}}
    return {name: tuple(sizes.get(axis, axis) for axis in spec.shape) for name, spec in SPECS.items()}


def dtype_of(name: str):
    """The numpy dtype of a field."""
    return _DTYPES[SPECS[name].kind]


def check_state(state, shapes: dict, num_worlds, who: str) -> None:
    """``ValueError`` naming the first field of ``state`` not of the dtype and shape the scene's record has
    (``shapes``: :func:`world_shapes`; ``num_worlds``: the leading axis, or None for one world's record). Runs on
    shapes and dtypes alone, so it names a wrong record at trace time."""
    if not isinstance(state, SceneState):
        raise ValueError(f"{who}: the state must be a SceneState record, got {type(state).__name__}")
    lead = () if num_worlds is None else (int(num_worlds),)
    for name, shape in shapes.items():
        value = getattr(state, name)
        want, got_shape = lead + shape, tuple(getattr(value, "shape", np.shape(value)))
        kind = SPECS[name].kind
        dtype = str(getattr(value, "dtype", ""))
        fits = {_F: dtype.startswith("float"), _I: dtype.startswith("int"), _B: dtype == "bool"}[kind]
        if got_shape != want or not fits:
            raise ValueError(f"{who}: state.{name} must be {kind} of shape {want}, got {dtype or type(value).__name__} "
                             f"of shape {got_shape}")


def bytes_per_world(state: SceneState, float_bytes: int | None = None) -> int:
    """The bytes one world's fields take (with ``float_bytes``: as if floats were that wide, e.g. 4)."""
    total = 0
    for name, value in state.as_dict().items():
        array = np.asarray(value)
        per_world = array.nbytes // max(array.shape[0], 1) if array.ndim else array.nbytes
        if float_bytes is not None and SPECS[name].kind == _F:
            per_world = per_world // array.dtype.itemsize * float_bytes
        total += per_world
    return total
