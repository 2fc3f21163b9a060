"""From an environment's positions to a real dVRK arm: its base frame and the point it reports and commands.

A dVRK PSM reports ``measured_cp`` and takes ``servo_cp`` goals (CRTK) as the pose of its wrist-yaw frame in its
base (remote centre of motion) frame. An environment's p is a position in its own frame: the PSM base frame for
Reach and Pick (identity base pose), the world for the collaborative scene (each arm's base at its RCM, see
:func:`base_pose_of`). In the registered single-arm environments p *is* the measured_cp position; with
``tip_frame="tool_point"`` (and in the collaborative scene) p is the tool point, 10.2 mm further along the tool
(:mod:`dvrl_marl.kinematics`).

```python
from dvrl_marl import frames
target = env.unwrapped.denormalise(goal_normalised)                 # metres, env frame
pose = frames.servo_cp_goal(target, tool="lnd", env_tip_frame="measured_cp")   # 4x4 in the arm's base frame
arm.servo_cp(pose)                                                   # e.g. through dvrk's Python CRTK client
```
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dvrl_marl import kinematics

__all__ = ["BasePose", "base_pose_of", "env_to_dvrk", "dvrk_to_env", "servo_cp_goal"]


@dataclass(frozen=True)
class BasePose:
    """Where a dVRK arm's base (RCM) frame sits in the environment's frame: ``x_env = rotation @ x_base +
    position``. The default is the identity (the single-arm environments work in the base frame)."""

    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))

    def __post_init__(self):
        rotation = np.asarray(self.rotation, dtype=np.float64)
        position = np.asarray(self.position, dtype=np.float64)
        if rotation.shape != (3, 3) or position.shape != (3,):
            raise ValueError(f"BasePose needs a (3,) position and a (3, 3) rotation, got {position.shape} and "
                             f"{rotation.shape}")
        if not (np.all(np.isfinite(rotation)) and np.all(np.isfinite(position))):
            raise ValueError("BasePose: position and rotation must be finite")
        if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-9) or np.linalg.det(rotation) < 0:
            raise ValueError("BasePose: rotation must be a proper rotation matrix")
        object.__setattr__(self, "rotation", rotation)
        object.__setattr__(self, "position", tuple(position.tolist()))


def base_pose_of(arm) -> BasePose:
    """The base pose of an environment's :class:`~dvrl_marl.arm.Arm` (e.g. ``env.arms["grasper"]``) in its scene."""
    return BasePose(tuple(np.asarray(arm.base_position, dtype=np.float64).tolist()), arm.base_rotation)


def _check(position) -> np.ndarray:
    array = np.asarray(position, dtype=np.float64)
    if array.ndim == 0 or array.shape[-1] != 3 or not np.all(np.isfinite(array)):
        raise ValueError(f"positions must be finite, shape (..., 3), got {np.asarray(position).tolist()!r}")
    return array


def env_to_dvrk(position, base_pose: BasePose = BasePose(), *, tool="lnd", env_tip_frame: str = "measured_cp"):
    """Environment position(s) p ``(..., 3)`` (metres) to the dVRK's measured_cp / servo_cp position in the arm's
    base frame. ``env_tip_frame``: which point p is ("measured_cp" for the registered single-arm envs, "tool_point" with
    ``tip_frame="tool_point"`` and for the collaborative scene); the tool points down the base's -z, as in every environment."""
    if env_tip_frame not in kinematics.TIP_FRAMES:
        raise ValueError(f"env_tip_frame must be one of {kinematics.TIP_FRAMES}, got {env_tip_frame!r}")
    in_base = (_check(position) - np.asarray(base_pose.position)) @ base_pose.rotation
    if env_tip_frame == "tool_point":
        in_base = kinematics.measured_cp_from_tool_point(tool, in_base)
    return in_base


def dvrk_to_env(position, base_pose: BasePose = BasePose(), *, tool="lnd", env_tip_frame: str = "measured_cp"):
    """Inverse of :func:`env_to_dvrk`: a measured_cp position in the arm's base frame to the environment's p."""
    if env_tip_frame not in kinematics.TIP_FRAMES:
        raise ValueError(f"env_tip_frame must be one of {kinematics.TIP_FRAMES}, got {env_tip_frame!r}")
    in_base = _check(position)
    if env_tip_frame == "tool_point":
        in_base = kinematics.tool_point_from_measured_cp(tool, in_base)
    return in_base @ base_pose.rotation.T + np.asarray(base_pose.position)


def servo_cp_goal(position, base_pose: BasePose = BasePose(), *, tool="lnd",
                  env_tip_frame: str = "measured_cp") -> np.ndarray:
    """A 4x4 ``servo_cp`` goal in the arm's base frame for the environment position p: :func:`env_to_dvrk` with
    the environments' fixed orientation (tool pointing down, :data:`~dvrl_marl.kinematics.TIP_ROTATION_DOWN`, the
    DH chain's convention; a dVRK configured with a ``tooltip-offset`` rotation expects that rotation applied)."""
    pose = np.eye(4)
    pose[:3, :3] = kinematics.TIP_ROTATION_DOWN
    pose[:3, 3] = env_to_dvrk(position, base_pose, tool=tool, env_tip_frame=env_tip_frame)
    return pose
