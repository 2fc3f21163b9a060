"""The collaborative scene's vectors by name: an arm's action, a pin's slot, an agent's observation and the global
state. Every reader takes positions from here (a new field changes this file, not its readers' literals).

An action is ``[move x, move y, move z, tool]`` (the tool: the suction's valve or the LND's jaw); a pin's slot in
an observation is its position then whether it is visible, held, delivered."""

from __future__ import annotations

__all__ = ["ACTION_WIDTH", "MOVE", "TOOL", "PIN_WIDTH", "PIN_POSITION", "PIN_VISIBLE", "PIN_HELD", "PIN_DELIVERED",
           "observation_layout", "state_layout"]

#: An action: the tip's move (three values), then the tool's command.
MOVE, TOOL, ACTION_WIDTH = slice(0, 3), 3, 4
#: A pin's slot in an observation: its position, then its flags (1 or 0).
PIN_POSITION, PIN_VISIBLE, PIN_HELD, PIN_DELIVERED, PIN_WIDTH = slice(0, 3), 3, 4, 5, 6


def observation_layout(cavities: int, pins: int) -> dict[str, slice]:
    """Slices of an agent's observation: its tip and tool, the other tip, each cavity's blood (the share of its
    start), every pin's slot, the hand-off point."""
    return _layout((("own_tip", 3), ("own_tool", 1), ("other_tip", 3), ("blood", cavities),
                    ("debris", PIN_WIDTH * pins), ("handoff", 3)))


def state_layout(cavities: int, pins: int) -> dict[str, slice]:
    """Slices of the global state: both tips and tools, the blood, every pin (hidden ones too), the hand-off point."""
    return _layout((("suction_tip", 3), ("valve", 1), ("grasper_tip", 3), ("jaw", 1), ("blood", cavities),
                    ("debris", PIN_WIDTH * pins), ("handoff", 3)))


def _layout(fields) -> dict[str, slice]:
    out, start = {}, 0
    for name, width in fields:
        out[name] = slice(start, start + width)
        start += width
    return out
