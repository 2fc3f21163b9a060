"""dvrl-marl: dVRK reinforcement-learning environments on MuJoCo.

Importing the package registers the Gymnasium environments ``dvrl_marl/PSMReach-v1``, ``dvrl_marl/PSMPick-v1``
and their dense-reward twins ``dvrl_marl/PSMReachDense-v1``, ``dvrl_marl/PSMPickDense-v1``.
"""

from __future__ import annotations

import os
import sys

# Headless machines: MuJoCo picks its OpenGL backend when it is imported, so choose EGL before that happens.
if sys.platform.startswith("linux") and not os.environ.get("DISPLAY") and "MUJOCO_GL" not in os.environ:
    os.environ["MUJOCO_GL"] = "egl"

from dvrl_marl.registration import register_envs  # noqa: E402

__version__ = "0.2.0"
__all__ = ["register_envs", "__version__"]

register_envs()
