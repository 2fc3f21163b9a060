"""Whether a window can open here: what ``render_mode="human"`` needs, said before MuJoCo's viewer is asked."""

from __future__ import annotations

import os
import sys

__all__ = ["DisplayUnavailableError", "display_available", "render_modes_here", "require_display"]


class DisplayUnavailableError(RuntimeError):
    """``render_mode="human"`` was asked for where no window can open."""


def display_available() -> bool:
    """Whether a window can open here (always off Linux; on Linux, with DISPLAY or WAYLAND_DISPLAY set)."""
    return not sys.platform.startswith("linux") or bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def render_modes_here(modes) -> list[str]:
    """The render modes an environment advertises on this machine: ``"human"`` only where a window can open, so
    that the ecosystem's checkers (Gymnasium's ``check_env``, PettingZoo's ``render_test``), which try every
    advertised mode, pass with their defaults on a headless server. Asking for ``"human"`` there still says why it
    cannot be (:class:`DisplayUnavailableError`)."""
    return [mode for mode in modes if mode != "human" or display_available()]


def require_display() -> None:
    """Raise :class:`DisplayUnavailableError` where MuJoCo's viewer cannot open a window (it would end the Python
    process from C, leaving ``MUJOCO_LOG.TXT`` behind)."""
    if not display_available():
        raise DisplayUnavailableError(
            'render_mode="human" needs a display (no DISPLAY or WAYLAND_DISPLAY is set). On a headless machine use '
            'render_mode="rgb_array" (MUJOCO_GL=egl, which importing dvrl_marl sets for you), or run under a display '
            "(e.g. xvfb-run).")
