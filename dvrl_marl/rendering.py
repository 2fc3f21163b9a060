"""Rendering a scene from its endoscope camera: RGB, depth, or a desktop window (:mod:`dvrl_marl.viewer`)."""

from __future__ import annotations

import gc
import time
from contextlib import contextmanager

import mujoco
import numpy as np

from dvrl_marl.display import DisplayUnavailableError, display_available, render_modes_here, require_display

__all__ = ["SceneRenderer", "RENDER_MODES", "uncollected", "DisplayUnavailableError", "require_display",
           "display_available", "render_modes_here"]

RENDER_MODES = ("human", "rgb_array", "depth_array")


@contextmanager
def uncollected():
    """No automatic garbage collection inside: for drawing with a bound GL context. MuJoCo 3.3's EGL context, when
    freed (say, a dropped env's, collected), releases whichever context the thread holds, and a collection between
    binding ours and reading it back would leave the drawings in between undone: wrong images, no error."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


class SceneRenderer:
    """Lazily creates MuJoCo's offscreen renderer (or a passive viewer for ``"human"``)."""

    def __init__(self, model, data, render_mode: str | None, camera: str = "endoscope", width: int = 640,
                 height: int = 480, key_listener=None, overlay=None, title: str = "dvrl-marl",
                 frame_budget: float | None = None, decorate=None):
        if render_mode is not None and render_mode not in RENDER_MODES:
            raise ValueError(f"render_mode must be one of {RENDER_MODES} or None, got {render_mode!r}")
        from dvrl_marl.schemas import PositiveInt, validated

        # a bad size names itself here, not later as "no OpenGL context"
        width, height = (validated(PositiveInt, value, f"render {name}") for name, value in (("width", width),
                                                                                               ("height", height)))
        self.model, self.data, self.render_mode = model, data, render_mode
        self.camera, self.width, self.height = camera, width, height
        # "human" only: key events in the window go to key_listener (e.g. a KeyboardDevice); overlay() returns
        # the text drawn over the scene; frame_budget lets the window drop shadows when frames cost more.
        self.key_listener, self.overlay, self.title, self.frame_budget = key_listener, overlay, title, frame_budget
        # decorate(scene) adds marks to the updated MjvScene of every frame (e.g. the seat's drop lines)
        self.decorate = decorate
        self._renderer = None
        self._viewer = None
        # With a frame_budget, offscreen frames that cost more give up shadows, then multisampling (look only: the
        # simulation is untouched).
        self.shadows, self.multisampling = True, True
        self._frame_costs: list[float] = []

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            return None
        mujoco.mj_forward(self.model, self.data)  # only when drawing: the step path keeps kinematics lazy
        if self.render_mode == "human":
            self.viewer.draw(self.overlay() if self.overlay is not None else ())
            return None
        if self._renderer is None:
            self._renderer = self._offscreen_renderer()
        began = time.perf_counter()
        self._renderer.update_scene(self.data, camera=self.camera)
        if self.decorate is not None:
            self.decorate(self._renderer.scene)
        if not self.shadows:
            self._renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
        with uncollected():
            frame = self._renderer.render()
        if self.frame_budget is not None:
            self._degrade_if_slow(time.perf_counter() - began)
        return frame

    def _offscreen_renderer(self):
        # Multisampling is read when the context is made: set it for this renderer only, the model stays as it was.
        samples = self.model.vis.quality.offsamples
        if not self.multisampling:
            self.model.vis.quality.offsamples = 0
        try:
            renderer = mujoco.Renderer(self.model, self.height, self.width)
        except ValueError as error:  # larger than the model's offscreen framebuffer
            raise ValueError(f"render size {self.width} x {self.height}: {str(error).splitlines()[0]}") from None
        except Exception as error:  # MuJoCo raises FatalError when no OpenGL context could be made
            if "framebuffer" in str(error):  # a size past what this OpenGL draws offscreen
                raise ValueError(f"render size {self.width} x {self.height} is past what this OpenGL can draw "
                                 f"offscreen ({error})") from None
            raise RuntimeError(
                "could not create an OpenGL context for offscreen rendering; on a machine without a display set "
                "MUJOCO_GL=egl before anything imports mujoco (importing dvrl_marl first does this for you)"
            ) from error
        finally:
            self.model.vis.quality.offsamples = samples
        if self.render_mode == "depth_array":
            renderer.enable_depth_rendering()
        return renderer

    def _degrade_if_slow(self, cost: float) -> None:
        """Offscreen frames over ``frame_budget``: shadows go first, then multisampling (software OpenGL at 640x480:
        59 ms a frame with both, 26 ms without shadows, 12 ms without either, measured here)."""
        self._frame_costs.append(cost)
        if len(self._frame_costs) < 3:
            return
        slow = sorted(self._frame_costs)[1] > self.frame_budget  # the median of the last three
        self._frame_costs.clear()
        if slow and self.shadows:
            self.shadows = False
        elif slow and self.multisampling:
            self.multisampling = False
            self._renderer.close()
            self._renderer = None

    def __getstate__(self):
        # OpenGL contexts and viewer windows do not travel (pickle, deepcopy, Ray): drop them, rebuild on render().
        state = self.__dict__.copy()
        state["_renderer"] = None
        state["_viewer"] = None
        return state

    @property
    def viewer(self):
        """The window in ``"human"`` mode (a :class:`dvrl_marl.viewer.ViewerWindow`, opened on first use)."""
        if self.render_mode != "human":
            return None
        if self._viewer is None:
            # Here, when the window is first needed (reset or render), not at construction: the ecosystem's checkers
            # build every env with render_mode="human" to read its metadata, and must pass on a headless server.
            require_display()  # in Python, with what to do instead, not later in GLFW
            from dvrl_marl.viewer import ViewerWindow

            self._viewer = ViewerWindow(self.model, self.data, title=self.title, camera=self.camera, width=self.width,
                                        height=self.height, frame_budget=self.frame_budget, decorate=self.decorate)
            if self.key_listener is not None:
                self._viewer.add_key_listener(self.key_listener)
        return self._viewer

    def forward(self) -> None:
        """Bring the model's derived quantities (body poses, lights) up to date with ``data`` before a window draws
        it outside :meth:`render` (a window waiting for ENTER): without it the first frame of an episode is dark."""
        mujoco.mj_forward(self.model, self.data)

    @property
    def window_closed(self) -> bool:
        """``"human"``: True once the window that was opened has been closed (by the person, or ESC)."""
        return self._viewer is not None and self._viewer.closed

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None
