"""Teleoperation devices: the protocol, a keyboard through MuJoCo's viewer, replay of recordings, a recorder."""

from __future__ import annotations

import json
import threading
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

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
    """Keys pressed in MuJoCo's viewer drive the seat: each press moves the tip for ``repeat`` steps.

    ``A``/``D``: -x/+x, ``S``/``W``: -y/+y, ``F``/``R``: down/up, ``SPACE``: toggle the jaw (LND) or the suction valve.
    Pass :meth:`key_callback` to ``mujoco.viewer.launch_passive`` (the environment does this for ``render_mode="human"``).
    """

    KEYS = {65: (0, -1.0), 68: (0, 1.0), 83: (1, -1.0), 87: (1, 1.0), 70: (2, -1.0), 82: (2, 1.0)}
    TOGGLE = 32

    def __init__(self, repeat: int = 5, action_dim: int = 4):
        self.repeat = int(repeat)
        self.action_dim = int(action_dim)
        self._lock = threading.Lock()
        self.reset()

    def reset(self) -> None:
        with self._lock:
            self._pending = np.zeros(3)
            self._remaining = 0
            self._last = 1.0  # jaw open / valve ... set by the first toggle

    def key_callback(self, keycode: int) -> None:
        with self._lock:
            if keycode in self.KEYS:
                axis, sign = self.KEYS[keycode]
                self._pending[:] = 0.0
                self._pending[axis] = sign
                self._remaining = self.repeat
            elif keycode == self.TOGGLE:
                self._last = -self._last

    def action(self, observation) -> np.ndarray:
        with self._lock:
            move = self._pending.copy() if self._remaining > 0 else np.zeros(3)
            self._remaining = max(self._remaining - 1, 0)
            return np.append(move, self._last)[: self.action_dim].astype(np.float32)

    def close(self) -> None:
        pass


class ReplayDevice:
    """Plays back recorded actions (an array, or a demonstration file); then holds still with the last jaw/valve."""

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
