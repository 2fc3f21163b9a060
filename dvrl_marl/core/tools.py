"""The instruments' tools (the LND's jaw, the suction's valve) as the commands move them.

The paper sets the jaw to the command at once: ``j = (phi + 1) / 2``, and the valve is open while the command
is positive. ``tool_speed`` (a task parameter, 1 by default: the paper's) gives the tool a finite speed: each
control step it moves at most that fraction of its stroke towards what the command asks. A policy's exploration
noise on the tool then averages out over the steps of a stroke instead of opening the jaw on one unlucky sample
(a tanh-Gaussian of scale 1 around a closed command opens it every few steps: the scripted team, which never
fails without noise, delivered nothing with it; ``benchmarks/tool_noise.py``), and the mean action and the
sampled one drive the tool to the same place.

Two more options (off by default, the paper's behaviour) make the grasp a decision a Gaussian policy can
take, as the valve already is: ``jaw_command = "switch"`` sets the jaw's target by the command's sign (closed when it is
not positive, open when it is: the valve's rule) instead of the paper's proportional ``j = (phi + 1) / 2``, and
``hold_until_handoff`` (applied by the scenes, which know what is held) keeps a held pin's jaw shut, whatever the
command, until the pin is handed off.
"""

from __future__ import annotations

import numpy as np

from dvrl_marl.core.backend import namespace

#: Fraction of the valve's stroke above which it is open (it draws): the command's own threshold (open when > 0),
#: ``(0 + 1) / 2``.
VALVE_OPEN_ABOVE = 0.5


#: The Suction & Irrigation valve is signed when the scene irrigates (``irrigation_ml_s > 0``): a command above 0
#: sucks (as ever), one below ``-IRRIGATE_BELOW`` irrigates, and between them the valve is shut (a script's "shut"
#: is 0). Without irrigation every command not above 0 shuts it, as before. The band keeps a policy's "shut" near 0
#: from spraying on noise, as the jaw's and valve's stroke speed does.
IRRIGATE_BELOW = 0.5
#: The command a script sends for a shut valve (neither sucking nor irrigating).
SHUT = 0.0


#: How the command sets the jaw's target: the paper's proportional mapping, or a switch (the valve's rule).
JAW_COMMANDS = ("proportional", "switch")


def jaw_target(command, rule: str = "proportional"):
    """The jaw's target opening (0 closed, 1 open): the paper's ``j = (phi + 1) / 2``, or with ``rule="switch"``
    open when the command is positive, else closed."""
    if rule == "switch":
        return valve_target(command)
    return (command + 1.0) * 0.5


def valve_target(command):
    """The valve's stroke the command asks for: fully open (1) when it is positive, else closed (0)."""
    return (command > 0.0) * 1.0  # (a float for a scalar command, an array for an array)


def shut_command(irrigates: bool) -> float:
    """The command a script or a device sends for a shut suction valve: -1 as ever, but :data:`SHUT` (0) in a scene
    whose valve irrigates, where -1 irrigates."""
    return SHUT if irrigates else -1.0


def irrigation_target(command):
    """The irrigating side's stroke the command asks for: fully open (1) below ``-IRRIGATE_BELOW``, else shut (0)."""
    return (command < -IRRIGATE_BELOW) * 1.0


def moved_towards(current, target, speed: float):
    """``current`` moved towards ``target`` by at most ``speed`` (scalars or arrays alike); ``speed >= 1`` is
    the paper's instant tool (the target itself, exactly)."""
    if speed >= 1.0:
        return target
    if isinstance(current, (float, int, np.ndarray, np.generic)):
        return current + np.minimum(np.maximum(target - current, -speed), speed)  # (np.clip's values, faster)
    return current + namespace(current).clip(target - current, -speed, speed)
