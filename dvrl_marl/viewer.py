"""A desktop window on a scene: MuJoCo's renderer in a GLFW window of our own, with an overlay and every key event.

MuJoCo's passive viewer reports key presses only (never releases) and shows "LOADING..." until its own thread has
drawn, so a person cannot hold a key to move an arm, nor see the scene before an episode starts. This window is
drawn by the thread that steps the environment, when it asks: the first frame is on screen before the episode
starts, key-down and key-up both reach the listeners, and closing it is something the caller can see (``closed``).

Keys the window keeps for itself: ``TAB`` switches between the scene's camera and a free camera (left drag
rotates, right drag pans, the wheel zooms), ``ESC`` closes the window. GLFW comes with the ``mujoco`` package.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable

import mujoco
import numpy as np

from dvrl_marl.display import DisplayUnavailableError, require_display

__all__ = ["ViewerWindow", "KeyListener"]

#: ``listener(key, action, mods)`` with GLFW's codes: ``key`` is ``glfw.KEY_*`` (letters are their upper-case
#: ASCII code), ``action`` is 1 press, 0 release, 2 auto-repeat, ``mods`` a bit mask (``glfw.MOD_SHIFT`` = 1).
KeyListener = Callable[[int, int, int], None]

_GRID = {
    "top left": mujoco.mjtGridPos.mjGRID_TOPLEFT, "top right": mujoco.mjtGridPos.mjGRID_TOPRIGHT,
    "bottom left": mujoco.mjtGridPos.mjGRID_BOTTOMLEFT, "bottom right": mujoco.mjtGridPos.mjGRID_BOTTOMRIGHT,
    "top": mujoco.mjtGridPos.mjGRID_TOP, "bottom": mujoco.mjtGridPos.mjGRID_BOTTOM,
}
_COST_SMOOTHING = 0.2  # weight of the newest frame in the running frame cost
#: mjv_moveCamera(m, action, dx, dy, scn, cam) before MuJoCo 4; (m, action, dx, dy, cam) from 4.0 on.
_MOVE_CAMERA_TAKES_SCENE = int(mujoco.__version__.split(".")[0]) < 4


class ViewerWindow:
    """One window showing ``data`` through ``camera`` (a camera name in the model, or None for a free camera).

    ``frame_budget`` (seconds): when a frame costs more than this (software OpenGL draws shadow maps slowly), the
    window turns shadows off for the rest of its life, so that a paced loop can keep its rate.
    """

    def __init__(self, model, data, title: str = "dvrl-marl", camera: str | None = "endoscope", width: int = 640,
                 height: int = 480, frame_budget: float | None = None, decorate=None):
        require_display()
        import glfw

        if not glfw.init():
            raise DisplayUnavailableError("GLFW could not reach the display; check DISPLAY (or run under xvfb-run)")
        window = glfw.create_window(int(width), int(height), title, None, None)
        if not window:
            raise DisplayUnavailableError("the display refused an OpenGL window (is GLX available? try xvfb-run)")
        self._glfw, self._window = glfw, window
        glfw.make_context_current(window)
        glfw.swap_interval(0)  # the caller paces; waiting for vertical sync would add up to a frame of lag
        self.model, self.data, self.title = model, data, title
        self.decorate = decorate  # decorate(scene): marks added to each frame's updated scene
        self._context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_100)
        self._scene = mujoco.MjvScene(model, maxgeom=4000)
        self._option = mujoco.MjvOption()
        self._scene_camera = mujoco.MjvCamera()
        if camera is not None:
            self._scene_camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
            self._scene_camera.fixedcamid = model.camera(camera).id
        else:
            mujoco.mjv_defaultFreeCamera(model, self._scene_camera)
        self._free_camera = mujoco.MjvCamera()
        mujoco.mjv_defaultFreeCamera(model, self._free_camera)
        self._camera = self._scene_camera
        self._listeners: list[KeyListener] = []
        self.listener_errors = 0  # listeners that raised (a failing device never ends the session)
        self.frame_budget = frame_budget
        self.frame_seconds = 0.0  # running cost of one frame
        self.frames = 0
        self.shadows = True
        self._drag = None  # (button, x, y) while a mouse button is held
        glfw.set_key_callback(window, self._on_key)
        glfw.set_mouse_button_callback(window, self._on_mouse_button)
        glfw.set_cursor_pos_callback(window, self._on_cursor)
        glfw.set_scroll_callback(window, self._on_scroll)

    # --- what callers use ------------------------------------------------------------------------------------
    def add_key_listener(self, listener: KeyListener) -> None:
        self._listeners.append(listener)

    @property
    def closed(self) -> bool:
        """True once the person closed the window (or pressed ESC), or after :meth:`close`."""
        return self._window is None or bool(self._glfw.window_should_close(self._window))

    def poll(self) -> None:
        """Deliver pending keyboard, mouse and window events."""
        if self._window is not None:
            self._glfw.poll_events()

    def draw(self, overlays: Iterable[tuple[str, str, str]] = ()) -> None:
        """Draw the scene and ``overlays`` (``(position, left column, right column)``; positions as in
        ``"top left"``, ``"bottom right"``, ``"top"``...) and show it."""
        if self._window is None:
            return
        began = time.perf_counter()
        glfw = self._glfw
        glfw.make_context_current(self._window)
        width, height = glfw.get_framebuffer_size(self._window)
        viewport = mujoco.MjrRect(0, 0, width, height)
        mujoco.mjv_updateScene(self.model, self.data, self._option, None, self._camera,
                               mujoco.mjtCatBit.mjCAT_ALL, self._scene)
        if self.decorate is not None:
            self.decorate(self._scene)
        self._scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = self.shadows
        mujoco.mjr_render(viewport, self._scene, self._context)
        for position, left, right in overlays:
            mujoco.mjr_overlay(mujoco.mjtFont.mjFONT_NORMAL, _GRID[position], viewport, left, right, self._context)
        glfw.swap_buffers(self._window)
        cost = time.perf_counter() - began
        self.frame_seconds = cost if self.frames == 0 else (
            (1 - _COST_SMOOTHING) * self.frame_seconds + _COST_SMOOTHING * cost)
        self.frames += 1
        if self.shadows and self.frame_budget is not None and self.frames >= 3 and self.frame_seconds > self.frame_budget:
            self.shadows = False
            self.frame_seconds = 0.0
            self.frames = 0

    def wait_for_key(self, keys: Iterable[int], overlays: Callable[[], Iterable[tuple[str, str, str]]],
                     fps: float = 30.0) -> bool:
        """Keep the window drawn and responsive until one of ``keys`` is pressed (True) or it is closed (False)."""
        wanted, pressed = set(keys), []

        def listen(key, action, mods):
            if action == 1 and key in wanted:
                pressed.append(key)

        self._listeners.insert(0, listen)
        try:
            while not pressed and not self.closed:
                self.draw(overlays())
                self.poll()
                time.sleep(1.0 / fps)
        finally:
            self._listeners.remove(listen)
        return bool(pressed)

    def screenshot(self) -> np.ndarray:
        """The window's last drawn frame as an (height, width, 3) uint8 array, top row first."""
        if self._window is None:
            raise RuntimeError("the window is closed")
        self._glfw.make_context_current(self._window)
        width, height = self._glfw.get_framebuffer_size(self._window)
        pixels = np.zeros((height, width, 3), dtype=np.uint8)
        mujoco.mjr_readPixels(pixels, None, mujoco.MjrRect(0, 0, width, height), self._context)
        return pixels[::-1].copy()

    def close(self) -> None:
        if self._window is not None:
            self._context.free()
            self._glfw.destroy_window(self._window)
            self._window = None
            self._glfw.poll_events()  # let the window manager see it go

    # --- GLFW callbacks ----------------------------------------------------------------------------------------
    def _on_key(self, window, key, scancode, action, mods) -> None:
        glfw = self._glfw
        if action == glfw.PRESS and key == glfw.KEY_ESCAPE:
            glfw.set_window_should_close(window, True)
        elif action == glfw.PRESS and key == glfw.KEY_TAB:
            self._camera = self._free_camera if self._camera is self._scene_camera else self._scene_camera
        for listener in list(self._listeners):
            try:
                listener(key, action, mods)
            except Exception:  # noqa: BLE001  (GLFW would re-raise it from poll(), inside the caller's step)
                self.listener_errors += 1

    def _on_mouse_button(self, window, button, action, mods) -> None:
        if action == self._glfw.PRESS:
            x, y = self._glfw.get_cursor_pos(window)
            self._drag = (button, x, y)
        else:
            self._drag = None

    def _on_cursor(self, window, x, y) -> None:
        if self._drag is None or self._camera is not self._free_camera:
            return
        button, last_x, last_y = self._drag
        self._drag = (button, x, y)
        height = max(self._glfw.get_window_size(window)[1], 1)
        action = (mujoco.mjtMouse.mjMOUSE_ROTATE_V if button == self._glfw.MOUSE_BUTTON_LEFT
                  else mujoco.mjtMouse.mjMOUSE_MOVE_V)
        self._move_camera(action, (x - last_x) / height, (y - last_y) / height)

    def _on_scroll(self, window, x_offset, y_offset) -> None:
        if self._camera is self._free_camera:
            self._move_camera(mujoco.mjtMouse.mjMOUSE_ZOOM, 0.0, -0.05 * y_offset)

    def _move_camera(self, action, dx: float, dy: float) -> None:
        """Move the free camera; MuJoCo 4 dropped the scene argument that 3.x takes (both are accepted versions)."""
        if _MOVE_CAMERA_TAKES_SCENE:
            mujoco.mjv_moveCamera(self.model, action, dx, dy, self._scene, self._free_camera)
        else:
            mujoco.mjv_moveCamera(self.model, action, dx, dy, self._free_camera)
