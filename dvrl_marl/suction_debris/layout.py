"""The collaborative scene's vectors by name: an arm's action, a pin's slot, an agent's observation and the global
state. Every reader takes positions from here (a new field changes this file, not its readers' literals).

An action is ``[move x, move y, move z, tool]`` (the tool: the suction's valve or the LND's jaw); a pin's slot in
an observation is its position then whether it is visible, held, delivered."""

from __future__ import annotations

__all__ = ["ACTION_WIDTH", "MOVE", "TOOL", "PIN_WIDTH", "PIN_POSITION", "PIN_VISIBLE", "PIN_HELD", "PIN_DELIVERED",
           "FLUID_FIELDS", "observation_layout", "state_layout", "plain_width"]

#: An action: the tip's move (three values), then the tool's command.
MOVE, TOOL, ACTION_WIDTH = slice(0, 3), 3, 4
#: A pin's slot in an observation: its position, then its flags (1 or 0).
PIN_POSITION, PIN_VISIBLE, PIN_HELD, PIN_DELIVERED, PIN_WIDTH = slice(0, 3), 3, 4, 5, 6


#: What a scene with fluids (irrigation or clots) appends to observations and the state: the valve's irrigating side
#: (-1 shut .. 1 open; one value), then one value per cavity of each: its liquid (blood not clotted and saline, a share of its
#: capacity), the blood's share of that liquid (its concentration), its clot (a share of its capacity), and the
#: share of its spill's time still to run.
FLUID_FIELDS = (("irrigation", 1), ("liquid", "C"), ("concentration", "C"), ("clot", "C"), ("spill", "C"))


def observation_layout(cavities: int, pins: int, fluids: bool = False) -> dict[str, slice]:
    """Slices of an agent's observation: its tip and tool, the other tip, each cavity's blood (the share of its
    start), every pin's slot, the hand-off point; with ``fluids``, then :data:`FLUID_FIELDS`."""
    return _layout((("own_tip", 3), ("own_tool", 1), ("other_tip", 3), ("blood", cavities),
                    ("debris", PIN_WIDTH * pins), ("handoff", 3), *_fluids(cavities, fluids)))


def state_layout(cavities: int, pins: int, fluids: bool = False) -> dict[str, slice]:
    """Slices of the global state: both tips and tools, the blood, every pin (hidden ones too), the hand-off point;
    with ``fluids``, then :data:`FLUID_FIELDS`."""
    return _layout((("suction_tip", 3), ("valve", 1), ("grasper_tip", 3), ("jaw", 1), ("blood", cavities),
                    ("debris", PIN_WIDTH * pins), ("handoff", 3), *_fluids(cavities, fluids)))


def plain_width(fields: dict[str, slice]) -> int:
    """The width of the plain part of an observation or state whose slices are ``fields`` (what follows it,
    appended by an env's options: ``features``, the arms' observations in the state, is not counted)."""
    return (fields["spill"] if "spill" in fields else fields["handoff"]).stop


def _fluids(cavities: int, on: bool):
    return tuple((name, cavities if width == "C" else width) for name, width in FLUID_FIELDS) if on else ()


def _layout(fields) -> dict[str, slice]:
    out, start = {}, 0
    for name, width in fields:
        out[name] = slice(start, start + width)
        start += width
    return out
