"""Scripted experts for PSM Reach and PSM Pick. They see only the observation dict, like a learned policy.

Both act in normalised coordinates: a normalised offset d~ is ``d~ * rho / eta`` steps away, so the expert
commands ``clip(d~ * rho / eta)`` per axis (``gain = rho / eta``, 50 for Reach and 25 for Pick with the paper's
values). They generate the demonstrations for behaviour cloning.
"""

from __future__ import annotations

import numpy as np

__all__ = ["ReachExpert", "PickExpert"]


def _gain_of(env) -> float:
    unwrapped = env.unwrapped
    return unwrapped.workspace_range / unwrapped.step_size


class ReachExpert:
    """Moves straight to the goal: ``Delta = clip((g~ - p~) * rho / eta, -1, 1)``."""

    def __init__(self, gain: float = 50.0):
        self.gain = float(gain)

    @classmethod
    def for_env(cls, env) -> "ReachExpert":
        """An expert with the gain of ``env``'s rho and eta."""
        return cls(gain=_gain_of(env))

    def __call__(self, observation: dict) -> np.ndarray:
        offset = np.asarray(observation["desired_goal"]) - np.asarray(observation["achieved_goal"])
        return np.clip(offset * self.gain, -1.0, 1.0).astype(np.float32)


class PickExpert:
    """Three phases, like the authors' demonstrations: go to the object with the jaw open, close on it, carry it.

    Args:
        gain: rho / eta of the environment.
        grasp_tolerance: normalised distance from the jaws to the object under which the jaw closes (1 mm at
            rho = 2.5 cm).
        tool_point_drop: normalised distance from the observed p down to the jaws (0 in the tool-point frame, where p is the jaw
            control point; 10.2 mm / rho in the registered envs, where p is the dVRK's measured_cp).
    """

    def __init__(self, gain: float = 25.0, grasp_tolerance: float = 0.04, tool_point_drop: float = 0.0):
        self.gain = float(gain)
        self.grasp_tolerance = float(grasp_tolerance)
        self.tool_point_drop = float(tool_point_drop)

    @classmethod
    def for_env(cls, env) -> "PickExpert":
        unwrapped = env.unwrapped
        return cls(gain=_gain_of(env), grasp_tolerance=0.001 / unwrapped.workspace_range,
                   tool_point_drop=unwrapped.arm.tool_point_drop / unwrapped.workspace_range)

    def __call__(self, observation: dict) -> np.ndarray:
        state = np.asarray(observation["observation"])
        tip, jaw, obj = state[:3].copy(), state[3], state[4:7]
        tip[2] -= self.tool_point_drop  # where the jaws are
        goal = np.asarray(observation["desired_goal"])
        to_object = obj - tip
        holding = jaw < 0.0 and np.linalg.norm(to_object) < 3 * self.grasp_tolerance + 0.2
        if holding:
            move = np.clip((goal - obj) * self.gain, -1.0, 1.0)
            return np.append(move, -1.0).astype(np.float32)
        if np.linalg.norm(to_object) <= self.grasp_tolerance:
            return np.array([0.0, 0.0, 0.0, -1.0], dtype=np.float32)  # close the jaw on the object
        move = np.clip(to_object * self.gain, -1.0, 1.0)
        return np.append(move, 1.0).astype(np.float32)
