"""A dVRK arm's CRTK commands over a socket-streamer link, and the system's power and homing.

What the arm's streamer must carry (its configuration file's ``read-commands``, ``write-commands``,
``void-commands`` and ``write-events``; ``docs/robot.md`` gives the files): it reads ``measured_cp``
(``prmPositionCartesianGet``), ``measured_js`` and ``jaw/measured_js`` (``prmStateJoint``) and ``operating_state``
(``prmOperatingState``, and its event); it writes ``servo_cp`` and ``move_cp`` (``prmPositionCartesianSet``) and ``jaw/servo_jp``
(``prmPositionJointSet``); ``hold`` is a void command. The system's streamer carries the void
commands ``power_on`` and ``home`` (an arm's ``state_command`` takes a string, which the streamer cannot carry).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ArmLink", "SystemLink", "Measured", "cartesian_goal"]


@dataclass(frozen=True)
class Measured:
    """A ``measured_cp``: the pose's position (m) and rotation in the arm's base frame, whether the dVRK said it was
    valid, its timestamp (the dVRK's clock, s) and when it arrived (the link's clock, s)."""

    position: np.ndarray
    rotation: np.ndarray
    valid: bool
    timestamp: float
    received: float


def cartesian_goal(pose) -> dict:
    """A 4x4 pose as ``prmPositionCartesianSet``'s ``Goal`` (a ``vctFrm3``: translation in metres, rotation rows)."""
    pose = np.asarray(pose, dtype=np.float64)
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        raise ValueError(f"servo_cp: a goal is a finite 4x4 pose, got shape {pose.shape}")
    rotation = pose[:3, :3]
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6) or np.linalg.det(rotation) < 0:
        raise ValueError("servo_cp: the goal's rotation is not a proper rotation matrix")
    return {"Translation": [round(float(v), 9) for v in pose[:3, 3]],
            "Rotation": [[round(float(v), 9) for v in row] for row in rotation]}


class ArmLink:
    """One arm (``PSM1``, ...) through its streamer's link (:class:`~dvrl_marl.dvrk.link.StreamerLink`)."""

    def __init__(self, name: str, link):
        self.name = name
        self.link = link

    def update(self) -> int:
        """Read what the streamer sent since the last call."""
        return self.link.receive()

    def measured_cp(self) -> Measured | None:
        """The latest ``measured_cp``, or None before the first (or if it cannot be read: a malformed one is
        treated as none)."""
        entry = self.link.latest.get("measured_cp")
        if entry is None:
            return None
        received, value = entry
        try:
            pose = value["Position"]
            position = np.asarray(pose["Translation"], dtype=np.float64)
            rotation = np.asarray(pose["Rotation"], dtype=np.float64)
            if position.shape != (3,) or rotation.shape != (3, 3):
                return None
            valid = bool(value.get("Valid", True)) and bool(np.all(np.isfinite(position)))
            return Measured(position, rotation, valid, float(value.get("Timestamp", float("nan"))), received)
        except (KeyError, TypeError, ValueError):
            return None

    def joints(self, key: str = "measured_js") -> np.ndarray | None:
        """The latest ``measured_js`` (or ``jaw/measured_js``) positions."""
        entry = self.link.latest.get(key)
        try:
            return None if entry is None else np.asarray(entry[1]["Position"], dtype=np.float64)
        except (KeyError, TypeError, ValueError):
            return None

    @property
    def operating_state(self) -> dict | None:
        entry = self.link.latest.get("operating_state")
        return entry[1] if entry is not None and isinstance(entry[1], dict) else None

    def ready(self) -> tuple[bool, str]:
        """Whether the arm takes servo commands: enabled and homed (and why not)."""
        state = self.operating_state
        if state is None:
            return False, f"{self.name}: no operating_state received (is its streamer running and sending to us?)"
        if state.get("State") != "ENABLED":
            return False, f"{self.name}: operating state is {state.get('State')!r}, not 'ENABLED' (power it on)"
        if not state.get("IsHomed", False):
            return False, f"{self.name}: not homed (home it first)"
        return True, ""

    def servo_cp(self, pose) -> None:
        self.link.send({"servo_cp": {"Goal": cartesian_goal(pose)}})

    def move_cp(self, pose) -> None:
        """Go to ``pose`` by the dVRK's own trajectory generator (``move_cp``): a start pose, reached safely; the
        operating state's ``IsBusy`` says when it is done."""
        self.link.send({"move_cp": {"Goal": cartesian_goal(pose)}})

    def jaw_servo_jp(self, angle: float) -> None:
        if not np.isfinite(angle):
            raise ValueError(f"{self.name}: jaw angle must be finite, got {angle!r}")
        self.link.send({"jaw/servo_jp": {"Goal": [round(float(angle), 9)]}})

    def hold(self) -> None:
        """Stop where it is (the arm's ``hold``)."""
        self.link.send({"hold": ""})



class SystemLink:
    """The dVRK system's void commands through its own streamer."""

    def __init__(self, link):
        self.link = link

    def power_on(self) -> None:
        self.link.send({"power_on": ""})

    def home(self) -> None:
        self.link.send({"home": ""})

    def update(self) -> int:
        return self.link.receive()

    def wait_heard(self, timeout_s: float = 5.0, sleep=None) -> None:
        """Read until the system's streamer has been heard (its address is learnt from its datagrams)."""
        import time

        sleep = sleep or time.sleep
        deadline = self.link.clock() + timeout_s
        while not self.link.latest:
            self.link.receive()
            if self.link.latest:
                return
            if self.link.clock() >= deadline:
                raise RuntimeError(f"system: nothing heard from its streamer in {timeout_s:.0f} s (is the dVRK's system "
                                   "program running with the streamers' files, sending to this machine?)")
            sleep(0.01)
