"""The browser as a teleoperation device: key and gamepad messages from a web page drive the seat.

:class:`BrowserDevice` is a :class:`~dvrl_marl.teleop.Device` like the keyboard: ``reset()``, ``action(observation)``,
``close()``. It knows nothing of HTTP; the web app (:mod:`dvrl_marl.teleop.web`) hands it the controlling page's
messages (:meth:`BrowserDevice.handle`) and tells it when that page connects and leaves. While no page controls
it, or the page has been silent for ``silence_timeout`` seconds, :meth:`~BrowserDevice.action` raises
:class:`TeleopLost`, so the seat holds still with ``teleop_lost`` set and the episode goes on; it resumes with the
next message.

Messages are JSON objects (the page sends them; anything else is refused with a reason and counted by the app):

- ``{"type": "key", "code": "KeyD", "down": true}``: a key of :class:`~dvrl_marl.teleop.KeyboardDevice`'s map by its
  browser ``KeyboardEvent.code`` (``KeyA``/``KeyD`` x, ``KeyS``/``KeyW`` y, ``KeyF``/``KeyR`` z, ``Space`` jaw or
  valve, ``ShiftLeft``/``ShiftRight`` precise);
- ``{"type": "gamepad", "axes": [x, y, z], "toggle": false}``: a gamepad's sticks, each in [-1, 1] after the page's
  dead zone, added to the keys; ``toggle`` true once per press of the jaw button;
- ``{"type": "ping"}``: the page is alive (it sends one every 200 ms).

Every message may carry ``"seq"``, an increasing integer; :attr:`BrowserDevice.applied_seq` is the newest one that an
action has used, which lets the page time key press to frame.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable

import numpy as np

from dvrl_marl.suction_debris.layout import ACTION_WIDTH
from dvrl_marl.teleop.devices import KeyboardDevice

__all__ = ["BrowserDevice", "TeleopLost", "BadMessage", "BROWSER_KEYS"]

#: Browser ``KeyboardEvent.code`` -> the GLFW key code :class:`KeyboardDevice` understands.
BROWSER_KEYS = {"KeyA": 65, "KeyD": 68, "KeyS": 83, "KeyW": 87, "KeyF": 70, "KeyR": 82, "Space": 32,
                "ShiftLeft": 340, "ShiftRight": 344, "KeyI": 73}
_PRESS, _RELEASE = 1, 0


class TeleopLost(RuntimeError):
    """No page is driving the seat (none connected, or it went silent)."""


class BadMessage(ValueError):
    """A message the device cannot use; the reason says what was wrong."""


class BrowserDevice:
    """A person in a web browser (see the module documentation).

    ``silence_timeout``: seconds without a message after which the page counts as gone. ``speed`` and
    ``precision_speed`` as for :class:`KeyboardDevice`, whose key semantics (held keys, SHIFT, SPACE toggles) this
    device shares; gamepad sticks add to the keys and are clipped with them to [-1, 1]. ``initial_tool``: the jaw or
    valve at each reset (+1 open: the LND's jaw; -1 closed: the suction valve). ``irrigate``: ``KeyI`` held
    irrigates (:class:`KeyboardDevice`'s), for the suction seat of a scene that irrigates.
    """

    human_operated = True
    label = "browser"
    KEY_HELP = tuple(row for row in KeyboardDevice.KEY_HELP if row[0] not in ("TAB", "ESC"))

    def __init__(self, silence_timeout: float = 1.0, action_dim: int = ACTION_WIDTH, speed: float = 1.0,
                 precision_speed: float = 0.25, clock: Callable[[], float] = time.monotonic,
                 initial_tool: float = 1.0, irrigate: bool = False):
        if not silence_timeout > 0:
            raise ValueError(f"BrowserDevice: silence_timeout must be positive, got {silence_timeout!r}")
        self.silence_timeout = float(silence_timeout)
        self._keyboard = KeyboardDevice(action_dim=action_dim, speed=speed, precision_speed=precision_speed,
                                        initial_tool=initial_tool, irrigate=irrigate)
        #: ``KeyI`` held irrigates (the suction seat of a scene that irrigates)
        self.irrigate = irrigate
        self.key_help = tuple(row for row in self._keyboard.key_help if row[0] not in ("TAB", "ESC"))
        self._clock = clock
        self._lock = threading.Lock()
        self._connected = False
        self._heard = -math.inf
        self._axes = np.zeros(3)
        self._seq = 0
        self.applied_seq = 0

    # --- what the web app calls -----------------------------------------------------------------------------
    def connect(self) -> None:
        """A page took the seat."""
        with self._lock:
            self._connected = True
            self._heard = self._clock()

    def disconnect(self) -> None:
        """The page left: every key counts as released and the sticks as centred (the jaw stays as it was)."""
        with self._lock:
            self._connected = False
            self._release_all()

    def handle(self, message) -> None:
        """Apply one message from the controlling page; :class:`BadMessage` says why one cannot be used."""
        if not isinstance(message, dict):
            raise BadMessage(f"a message must be a JSON object, got {type(message).__name__}")
        kind = message.get("type")
        seq = message.get("seq", None)
        if seq is not None and (not isinstance(seq, int) or isinstance(seq, bool) or seq < 0):
            raise BadMessage(f"'seq' must be a non-negative integer, got {seq!r}")
        if kind == "key":
            code, down = message.get("code"), message.get("down")
            if not isinstance(code, str) or code not in BROWSER_KEYS:
                raise BadMessage(f"unknown key code {code!r}; known: {sorted(BROWSER_KEYS)}")
            if not isinstance(down, bool):
                raise BadMessage(f"'down' must be true or false, got {down!r}")
            self._keyboard.key_event(BROWSER_KEYS[code], _PRESS if down else _RELEASE)
        elif kind == "gamepad":
            axes, toggle = message.get("axes"), message.get("toggle", False)
            if (not isinstance(axes, list) or len(axes) != 3
                    or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                               and -1.0 <= v <= 1.0 for v in axes)):
                raise BadMessage(f"'axes' must be three finite numbers in [-1, 1], got {axes!r}")
            if not isinstance(toggle, bool):
                raise BadMessage(f"'toggle' must be true or false, got {toggle!r}")
            with self._lock:
                self._axes[:] = axes
            if toggle:
                self._keyboard.key_event(BROWSER_KEYS["Space"], _PRESS)
                self._keyboard.key_event(BROWSER_KEYS["Space"], _RELEASE)
        elif kind != "ping":
            raise BadMessage(f"unknown message type {kind!r}; known: 'key', 'gamepad', 'ping'")
        with self._lock:
            self._heard = self._clock()
            if seq is not None:
                self._seq = max(self._seq, seq)

    @property
    def lost(self) -> bool:
        """True while no page drives the seat: none connected, or silent for ``silence_timeout``."""
        with self._lock:
            return not self._connected or self._clock() - self._heard > self.silence_timeout

    # --- the Device protocol --------------------------------------------------------------------------------
    def reset(self) -> None:
        """A new episode: keys released, sticks centred, jaw open (as :class:`KeyboardDevice`)."""
        self._keyboard.reset()
        with self._lock:
            self._axes[:] = 0.0

    def action(self, observation) -> np.ndarray:
        if self.lost:
            raise TeleopLost("no browser is driving the seat (none connected, or it went silent)")
        with self._lock:
            seq, axes = self._seq, self._axes.copy()
        action = self._keyboard.action(observation)
        action[:3] = np.clip(action[:3] + axes, -1.0, 1.0)
        self.applied_seq = seq
        return action

    def close(self) -> None:
        self.disconnect()

    def _release_all(self) -> None:
        for code in BROWSER_KEYS.values():
            if code != BROWSER_KEYS["Space"]:
                self._keyboard.key_event(code, _RELEASE)
        self._axes[:] = 0.0
