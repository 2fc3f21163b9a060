"""Rendering a scene from its endoscope camera: RGB, depth, or a MuJoCo viewer window."""

from __future__ import annotations

import os
import sys

import mujoco
import numpy as np

__all__ = ["SceneRenderer", "RENDER_MODES", "DisplayUnavailableError", "require_display"]

RENDER_MODES = ("human", "rgb_array", "depth_array")


class DisplayUnavailableError(RuntimeError):
    """``render_mode="human"`` was asked for where no window can open."""


def require_display() -> None:
    """Raise :class:`DisplayUnavailableError` where MuJoCo's viewer cannot open a window (it would end the Python
    process from C, leaving ``MUJOCO_LOG.TXT`` behind)."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise DisplayUnavailableError(
            'render_mode="human" needs a display (no DISPLAY or WAYLAND_DISPLAY is set). On a headless machine use '
            'render_mode="rgb_array" (MUJOCO_GL=egl, which importing dvrl_marl sets for you), or run under a display '
            "(e.g. xvfb-run).")


class SceneRenderer:
    """Lazily creates MuJoCo's offscreen renderer (or a passive viewer for ``"human"``)."""

    def __init__(self, model, data, render_mode: str | None, camera: str = "endoscope", width: int = 640,
                 height: int = 480, key_callback=None):
        if render_mode is not None and render_mode not in RENDER_MODES:
            raise ValueError(f"render_mode must be one of {RENDER_MODES} or None, got {render_mode!r}")
        if render_mode == "human":
            require_display()  # fail here, in Python, not later in GLFW
        self.model, self.data, self.render_mode = model, data, render_mode
        self.camera, self.width, self.height = camera, width, height
        self.key_callback = key_callback  # keys pressed in the "human" viewer (e.g. a KeyboardDevice)
        self._renderer = None
        self._viewer = None

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            return None
        mujoco.mj_forward(self.model, self.data)  # only when drawing: the step path keeps kinematics lazy
        if self.render_mode == "human":
            if self._viewer is None:
                from mujoco import viewer

                self._viewer = viewer.launch_passive(self.model, self.data, key_callback=self.key_callback)
            self._viewer.sync()
            return None
        if self._renderer is None:
            try:
                self._renderer = mujoco.Renderer(self.model, self.height, self.width)
            except Exception as error:  # MuJoCo raises FatalError when no OpenGL context could be made
                raise RuntimeError(
                    "could not create an OpenGL context for offscreen rendering; on a machine without a display set "
                    "MUJOCO_GL=egl before anything imports mujoco (importing dvrl_marl first does this for you)"
                ) from error
            if self.render_mode == "depth_array":
                self._renderer.enable_depth_rendering()
        self._renderer.update_scene(self.data, camera=self.camera)
        return self._renderer.render()

    def __getstate__(self):
        # OpenGL contexts and viewer windows do not travel (pickle, deepcopy, Ray): drop them, rebuild on render().
        state = self.__dict__.copy()
        state["_renderer"] = None
        state["_viewer"] = None
        return state

    @property
    def viewer(self):
        """The passive viewer in ``"human"`` mode (None until the first render)."""
        return self._viewer

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None
