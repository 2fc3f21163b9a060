"""Teleoperation devices: the protocol, a keyboard (held keys, in the scene's window), replay of recordings, a
recorder."""

from __future__ import annotations

import json
import threading
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from dvrl_marl.core import tools
from dvrl_marl.suction_debris.layout import ACTION_WIDTH

__all__ = [
    "Device",
    "KeyboardDevice",
    "ReplayDevice",
    "Recorder",
    "save_demonstration",
    "load_demonstration",
    "DEMONSTRATION_FORMAT",
]

#: The demonstration file: a NumPy ``.npz`` archive with ``observations`` (T, obs_dim) float64, ``actions``
#: (T, act_dim) float32 and ``metadata``, a JSON string (``format``, ``seat``, free-form fields).
DEMONSTRATION_FORMAT = "dvrl-marl-demonstration-v1"


@runtime_checkable
class Device(Protocol):
    """What the surgeon seat needs from a teleoperation device."""

    def reset(self) -> None: ...

    def action(self, observation: np.ndarray) -> np.ndarray: ...

    def close(self) -> None: ...


def save_demonstration(path, observations, actions, **metadata) -> Path:
    """Write a demonstration file (see :data:`DEMONSTRATION_FORMAT`)."""
    observations = np.asarray(observations, dtype=np.float64)
    actions = np.asarray(actions, dtype=np.float32)
    if len(observations) != len(actions):
        raise ValueError(f"{len(observations)} observations but {len(actions)} actions")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    meta = json.dumps({"format": DEMONSTRATION_FORMAT, **metadata})
    with path.open("wb") as handle:
        np.savez(handle, observations=observations, actions=actions, metadata=np.array(meta))
    return path


def load_demonstration(path) -> tuple[np.ndarray, np.ndarray, dict]:
    """Read a demonstration file: (observations, actions, metadata)."""
    from dvrl_marl.files import read_metadata, read_npz

    data = read_npz(path)
    metadata = read_metadata(data, path, DEMONSTRATION_FORMAT)
    for key in ("observations", "actions"):
        if key not in data:
            raise ValueError(f"{path}: missing array {key!r}")
    observations, actions = data["observations"], data["actions"]
    if len(observations) != len(actions) or actions.ndim != 2 or actions.shape[1] != 4:
        raise ValueError(f"{path}: arrays 'observations' {observations.shape} and 'actions' {actions.shape} do not "
                         "form a recording (one 4-vector action per observation)")
    if not (np.all(np.isfinite(observations)) and np.all(np.isfinite(actions))):
        raise ValueError(f"{path}: arrays 'observations' / 'actions' hold NaN or inf")
    return observations, actions, metadata


class KeyboardDevice:
    """A person at the keyboard: a held key moves the tip, releasing it stops it.

    ``A``/``D``: -x/+x, ``S``/``W``: -y/+y, ``F``/``R``: down/up (keys held together combine; opposite keys cancel),
    ``SPACE``: toggle the jaw (LND: open <-> closed) or the suction valve, ``SHIFT`` held: move at
    ``precision_speed`` for fine work near a pin. The seat moves ``eta * speed`` per 20 ms step along each held axis
    (50 mm/s at full speed with eta = 1 mm). The jaw (or valve) starts at ``initial_tool``: +1, open (the LND's jaw
    at reset), by default; -1 closed for the suction valve, which a seat must not open by itself.

    ``irrigate=True`` (the Suction & Irrigation seat of a scene that irrigates): ``I`` held irrigates (the command -1,
    as the instrument's irrigation trumpet is held down), and the valve's shut state is 0 (-1 irrigates there); on
    release the valve goes back to what SPACE last set. Without it ``I`` does nothing.

    In ``render_mode="human"`` the environment opens its window (:mod:`dvrl_marl.viewer`) and feeds
    :meth:`key_event` every key down, repeat and up; because the device is ``human_operated`` the environment waits
    for ENTER before each episode and paces steps to the 50 Hz control rate. Outside that window, call
    :meth:`key_event` with GLFW's codes yourself. :meth:`key_callback` takes MuJoCo's passive viewer, which reports
    presses only: there each press moves the tip for ``repeat`` steps.
    """

    human_operated = True  # a person drives it: real time, and the episode starts when they say so
    label = "keyboard"
    KEYS = {65: (0, -1.0), 68: (0, 1.0), 83: (1, -1.0), 87: (1, 1.0), 70: (2, -1.0), 82: (2, 1.0)}
    TOGGLE = 32
    IRRIGATE_KEY = 73  # GLFW's I
    SHIFT_KEYS = (340, 344)  # GLFW's left and right SHIFT
    _PRESS, _RELEASE, _REPEAT = 1, 0, 2
    #: The key map as the window's overlay shows it.
    KEY_HELP = (("A / D", "-x / +x"), ("S / W", "-y / +y"), ("F / R", "down / up"), ("SPACE", "jaw / valve"),
                ("SHIFT", "slow, precise"), ("TAB", "free camera"), ("ESC", "quit"))

    def __init__(self, repeat: int = 5, action_dim: int = ACTION_WIDTH, speed: float = 1.0, precision_speed: float = 0.25,
                 initial_tool: float = 1.0, irrigate: bool = False):
        for name, value in (("speed", speed), ("precision_speed", precision_speed)):
            if not 0.0 < value <= 1.0:
                raise ValueError(f"KeyboardDevice: {name} must be in (0, 1] (a fraction of the action range), "
                                 f"got {value!r}")
        if initial_tool not in (-1.0, 1.0):
            raise ValueError(f"KeyboardDevice: initial_tool must be 1 (open) or -1 (closed), got {initial_tool!r}")
        if not isinstance(irrigate, bool):
            raise ValueError(f"KeyboardDevice: irrigate must be true or false, got {irrigate!r}")
        #: ``I`` held irrigates (the S&I valve's other half); the shut valve is then 0
        self.irrigate = irrigate
        self.initial_tool = float(initial_tool)
        self._shut = tools.shut_command(irrigate)
        #: the key map as the window's overlay shows it (with irrigation, the ``I`` key too)
        self.key_help = self.KEY_HELP if not irrigate else (*self.KEY_HELP[:4], ("I (held)", "irrigate"),
                                                            *self.KEY_HELP[4:])
        self.repeat = int(repeat)
        self.action_dim = int(action_dim)
        self.speed, self.precision_speed = float(speed), float(precision_speed)
        self._lock = threading.Lock()
        self.reset()

    def reset(self) -> None:
        with self._lock:
            self._held: set[int] = set()
            self._precise = False
            self._pending = np.zeros(3)
            self._remaining = 0
            self._last = self.initial_tool if self.initial_tool > 0.0 else self._shut
            self._irrigating = False

    def key_event(self, key: int, action: int, mods: int = 0) -> None:
        """One key event in GLFW's terms: ``action`` 1 press, 2 auto-repeat, 0 release; ``mods`` bit 1 = SHIFT."""
        with self._lock:
            if key in self.SHIFT_KEYS:
                self._precise = action != self._RELEASE
            elif key in self.KEYS:
                if action == self._RELEASE:
                    self._held.discard(key)
                else:
                    self._held.add(key)
            elif key == self.TOGGLE and action == self._PRESS:
                self._last = self._shut if self._last > 0.0 else 1.0
            elif key == self.IRRIGATE_KEY and self.irrigate:
                self._irrigating = action != self._RELEASE

    @property
    def irrigating(self) -> bool:
        """True while ``I`` is held on an irrigating seat."""
        with self._lock:
            return self._irrigating

    def key_callback(self, keycode: int) -> None:
        """A key press from MuJoCo's passive viewer (no releases there): a move key moves for ``repeat`` steps."""
        with self._lock:
            if keycode in self.KEYS:
                axis, sign = self.KEYS[keycode]
                self._pending[:] = 0.0
                self._pending[axis] = sign
                self._remaining = self.repeat
            elif keycode == self.TOGGLE:
                self._last = self._shut if self._last > 0.0 else 1.0

    @property
    def moving(self) -> bool:
        """True while a move key is held."""
        with self._lock:
            return bool(self._held)

    def action(self, observation) -> np.ndarray:
        with self._lock:
            move = np.zeros(3)
            for key in self._held:
                axis, sign = self.KEYS[key]
                move[axis] += sign
            move *= self.precision_speed if self._precise else self.speed
            if self._remaining > 0:
                move += self._pending
                self._remaining -= 1
            np.clip(move, -1.0, 1.0, out=move)
            return np.append(move, -1.0 if self._irrigating else self._last)[: self.action_dim].astype(np.float32)

    def close(self) -> None:
        pass


class ReplayDevice:
    """Plays back recorded actions (an array, or a demonstration file); then holds still with the last jaw/valve."""

    label = "replay"

    def __init__(self, actions_or_path):
        if isinstance(actions_or_path, (str, Path)):
            _, actions, _ = load_demonstration(actions_or_path)
        else:
            actions = np.asarray(actions_or_path, dtype=np.float32)
        if actions.ndim != 2 or len(actions) == 0:
            raise ValueError(f"ReplayDevice needs a (T, action_dim) array of actions, got shape {actions.shape}")
        self.actions = actions
        self.index = 0

    def reset(self) -> None:
        self.index = 0

    def action(self, observation) -> np.ndarray:
        if self.index < len(self.actions):
            action = self.actions[self.index]
            self.index += 1
            return action.copy()
        held = np.zeros_like(self.actions[-1])
        held[3:] = self.actions[-1][3:]
        return held

    def close(self) -> None:
        pass


class Recorder:
    """Wraps a device (or any ``policy(observation) -> action``) and records what it did."""

    def __init__(self, device, **metadata):
        self.device = device
        self.metadata = metadata
        self.observations: list[np.ndarray] = []
        self.actions: list[np.ndarray] = []

    def reset(self) -> None:
        if hasattr(self.device, "reset"):
            self.device.reset()

    def action(self, observation) -> np.ndarray:
        act = self.device.action(observation) if hasattr(self.device, "action") else self.device(observation)
        self.observations.append(np.array(observation, dtype=np.float64))
        self.actions.append(np.array(act, dtype=np.float32))
        return act

    def __call__(self, observation) -> np.ndarray:
        return self.action(observation)

    def save(self, path) -> Path:
        """Write what was recorded as a demonstration file."""
        if not self.actions:
            raise ValueError("nothing recorded yet")
        return save_demonstration(path, self.observations, self.actions, **self.metadata)

    def close(self) -> None:
        if hasattr(self.device, "close"):
            self.device.close()

    def __getattr__(self, name):
        # The rest is the wrapped device's (key_event, human_operated, KEY_HELP...): a recorded keyboard still
        # gets its keys and its pacing.
        if name.startswith("__") or name in ("device", "metadata", "observations", "actions"):
            raise AttributeError(name)
        return getattr(self.device, name)
