"""A link for a dry run: nothing is sent; the arm it pretends to be is enabled and homed, and its ``measured_cp`` is
the last ``servo_cp`` goal it was given (a perfect kinematic arm), so a policy's commands can be read before a robot
takes them."""

from __future__ import annotations

import time

import numpy as np

from dvrl_marl.dvrk.link import DatagramLog, encode

__all__ = ["EchoLink"]


class EchoLink:
    """Keeps what would be sent (:attr:`outbox`, and the log) and answers as an arm at ``start`` (4x4 pose, the arm's
    base frame) that goes wherever ``servo_cp`` says, at once."""

    def __init__(self, name: str, start, *, log: DatagramLog | None = None, clock=time.monotonic):
        start = np.asarray(start, dtype=np.float64)
        if start.shape != (4, 4):
            raise ValueError(f"{name}: the dry run's start is a 4x4 pose, got shape {start.shape}")
        self.name, self.clock = name, clock
        self.log = log or DatagramLog()
        self.outbox: list[tuple[float, dict]] = []
        self.sent = self.received = self.unreadable = 0
        self._pose = {"Translation": start[:3, 3].tolist(), "Rotation": start[:3, :3].tolist()}
        self.latest: dict = {}

    def send(self, payload: dict) -> None:
        encode(payload, self.name)
        now = self.clock()
        self.sent += 1
        self.outbox.append((now, payload))
        self.log.write(now, self.name, "out", payload)
        if "servo_cp" in payload:
            self._pose = payload["servo_cp"]["Goal"]

    def receive(self) -> int:
        now = self.clock()
        self.latest["operating_state"] = (now, {"State": "ENABLED", "IsHomed": True, "IsBusy": False})
        self.latest["measured_cp"] = (now, {"Position": self._pose, "Valid": True, "Timestamp": now})
        return 2

    def close(self) -> None:
        pass
