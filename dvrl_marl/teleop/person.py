"""A person-like operator for the grasper seat: it reads only what the page shows and presses only the page's keys.

It stands in for a person when a change to the seat must be judged the way a person meets it: can the task be
finished from what the page shows (the status behind the page: tips, visible pins, the cues, the outline of the
top and side views; :func:`dvrl_marl.teleop.session.scene_view`), with the keys the page sends, at a person's pace?

How it acts, after the human-in-the-seat figures in the project's reference notes (a person reacts to what they
saw about 200 ms earlier and moves more slowly than the script):

- **Look, then move.** It sees the page as it was ``reaction_s`` earlier and decides only on a view taken after
  its last move ended (a ballistic move, a look, a correction), never faster than ``decision_s`` (jittered).
- **Keys held for a time.** A move holds the axis keys for distance / speed (``KeyD`` ... ``KeyR``; with
  ``ShiftLeft`` for short moves, at the page's precise speed), each released on its own, with motor noise: every
  hold lasts ``1 + N(0, motor_noise)`` times what was meant. Now and then (``pause_probability`` per decision) it
  pauses for ``pause_s``.
- **The plan a person is told**: wait above the phantom until a pin is uncovered and the suction is not at it;
  go above the pin at a safe height, descend onto it, close the jaw when the page says the pin is in reach, rise,
  carry it to the hand-off point and bring the held pin to it (the page's "mm to the hand-off"). A refused move
  (the page's "blocked") makes it wait and go round above.

:func:`run_episode` seats it in ``dvrl_marl/SurgeonSeat-v8`` through :class:`~dvrl_marl.teleop.browser.BrowserDevice`
(the page's messages, in simulated time); :func:`drive_page` puts it in front of the real page (a Playwright page
in Chromium, in real time): it reads ``window.dvrl.status`` and presses the keys.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

__all__ = ["PersonLikeOperator", "run_episode", "drive_page", "AXIS_KEYS"]

#: Page key codes per axis: (minus, plus).
AXIS_KEYS = (("KeyA", "KeyD"), ("KeyS", "KeyW"), ("KeyF", "KeyR"))
_SAFE_HEIGHT_MM = 10.0  # above the phantom's top while travelling (the scripted surgeon's safe height)
_PRECISE_BELOW_MM = 6.0  # moves shorter than this are made with SHIFT held
_FRAME_S = 0.08  # a view counts as taken after a move once it is this much younger than the move's end (2 frames)
_PARTNER_CLEARANCE_MM = 25.0  # keep away from a pin while the suction tip is this close to it, and low


class PersonLikeOperator:
    """Decides which page keys to press from the page's status (see the module documentation).

    ``act(status, now_s)`` takes the status a person sees at time ``now_s`` (already ``reaction_s`` old: the driver
    delays it) and returns the messages the page would send now (``{"type": "key", "code": ..., "down": ...}``).
    ``speed_mm_s`` / ``precise_mm_s``: how fast the seat moves with a key held without and with SHIFT (the seat's
    50 mm/s and a quarter of it).
    """

    def __init__(self, seed: int = 0, *, reaction_s: float = 0.2, decision_s: float = 0.25, motor_noise: float = 0.1,
                 pause_probability: float = 0.03, pause_s: float = 0.6, speed_mm_s: float = 50.0,
                 precise_mm_s: float = 12.5):
        if not decision_s > 0 or not speed_mm_s > 0 or not precise_mm_s > 0:
            raise ValueError("PersonLikeOperator: decision_s, speed_mm_s and precise_mm_s must be positive")
        if not 0 <= motor_noise < 1 or not 0 <= pause_probability <= 1 or pause_s < 0:
            raise ValueError("PersonLikeOperator: motor_noise in [0, 1), pause_probability in [0, 1], pause_s >= 0")
        self.rng = np.random.default_rng(seed)
        self.reaction_s, self.decision_s, self.motor_noise = float(reaction_s), float(decision_s), float(motor_noise)
        self.pause_probability, self.pause_s = float(pause_probability), float(pause_s)
        self.speed, self.precise = float(speed_mm_s), float(precise_mm_s)
        self.reset()

    def reset(self) -> None:
        self._release_at: dict[str, float] = {}  # held key -> when to let it go
        self._next_decision = 0.0
        self._moved_until = -math.inf  # the end of the last move (its keys released) or jaw press
        self.presses = 0  # key presses made (a person's effort)

    # --- what a driver calls -------------------------------------------------------------------------------------
    def act(self, status: dict, now_s: float) -> list[dict]:
        messages = self._releases(now_s)
        tip = np.asarray(status["tip_mm"], dtype=float)
        # It looks again only at a view taken after its last move ended (the view is reaction_s old, plus a frame).
        settled = now_s - self.reaction_s >= self._moved_until + _FRAME_S
        if self._release_at or now_s < self._next_decision or not settled:
            return messages
        self._next_decision = now_s + self.decision_s * float(self.rng.uniform(0.8, 1.4))
        if self.rng.random() < self.pause_probability:
            self._next_decision += self.pause_s
            return messages
        target, jaw = self._plan(status, tip)
        if jaw is not None:  # the jaw first: one press of Space toggles it
            return messages + self._tap("Space", now_s)
        if target is not None:
            messages += self._move(target - tip, now_s)
        return messages

    # --- the plan --------------------------------------------------------------------------------------------------
    def _plan(self, status: dict, tip: np.ndarray):
        """(target tip in mm or None, "open" / "close" / None for the jaw)."""
        outline, cues = status["outline"], status["cues"]
        safe_z = outline["phantom"]["top"] + _SAFE_HEIGHT_MM
        jaw_open = status["jaw"] > 0.5
        if cues["holding"]:
            if jaw_open:
                return None, "close"
            handoff = np.asarray(outline["handoff"], dtype=float)
            grips = [np.asarray(pin["grip_mm"], dtype=float) for pin in status["pins"] if pin.get("grip_mm")]
            # the hand-off judges where the jaws hold the pin: the tip goes where that puts the grip on the marker
            goal = tip + (handoff - grips[0]) if grips else handoff
            return self._via_safe_height(tip, goal, safe_z), None
        if not jaw_open:
            return None, "open"
        pin = self._choose_pin(status, tip)
        if pin is None:  # wait above the phantom, near the assistant's side
            phantom = outline["phantom"]
            home = np.array([phantom["centre"][0] + 0.5 * phantom["half"][0], phantom["centre"][1], safe_z + 15.0])
            return (home if np.max(np.abs(home - tip)) > 5.0 else None), None
        if cues["in_reach"]:
            return None, "close"
        if cues["blocked"]:  # the other instrument is in the way: go up and round
            return tip + np.array([0.0, 0.0, 10.0]), None
        return self._via_safe_height(tip, pin, safe_z), None

    def _choose_pin(self, status: dict, tip: np.ndarray):
        suction = np.asarray(status["tips_mm"]["suction"], dtype=float)
        low = suction[2] < status["outline"]["phantom"]["top"] + 15.0
        free = [np.asarray(pin["mm"], dtype=float) for pin in status["pins"] if not pin["held"]]
        free = [p for p in free if not (low and np.hypot(*(p[:2] - suction[:2])) < _PARTNER_CLEARANCE_MM)]
        return min(free, key=lambda p: float(np.linalg.norm(p - tip)), default=None)

    @staticmethod
    def _via_safe_height(tip: np.ndarray, goal: np.ndarray, safe_z: float) -> np.ndarray:
        """Rise before crossing, cross at the safe height, then go straight to the goal."""
        far = np.hypot(*(goal[:2] - tip[:2])) > 3.0
        if far and tip[2] < safe_z - 1.0:
            return np.array([tip[0], tip[1], safe_z])
        if far:
            return np.array([goal[0], goal[1], max(goal[2], safe_z)])
        return goal

    # --- keys ------------------------------------------------------------------------------------------------------
    def _move(self, offset: np.ndarray, now_s: float) -> list[dict]:
        distance = float(np.max(np.abs(offset)))
        precise = distance < _PRECISE_BELOW_MM
        speed = self.precise if precise else self.speed
        messages = self._press("ShiftLeft", now_s + distance / speed + 0.05) if precise else []
        for axis, (minus, plus) in enumerate(AXIS_KEYS):
            if abs(offset[axis]) < 0.4:  # within the seat's step (a quarter of eta with SHIFT, 0.25 mm)
                continue
            hold = abs(offset[axis]) / speed * max(0.2, 1.0 + self.rng.normal(0.0, self.motor_noise))
            messages += self._press(plus if offset[axis] > 0 else minus, now_s + hold)
        return messages

    def _press(self, code: str, until_s: float) -> list[dict]:
        self._release_at[code] = until_s
        self._moved_until = max(self._moved_until, until_s)
        self.presses += 1
        return [{"type": "key", "code": code, "down": True}]

    def _tap(self, code: str, now_s: float) -> list[dict]:
        self.presses += 1
        self._moved_until = max(self._moved_until, now_s)
        return [{"type": "key", "code": code, "down": True}, {"type": "key", "code": code, "down": False}]

    def _releases(self, now_s: float) -> list[dict]:
        due = [code for code, until in self._release_at.items() if until <= now_s and code != "ShiftLeft"]
        for code in due:
            del self._release_at[code]
        messages = [{"type": "key", "code": code, "down": False} for code in due]
        if list(self._release_at) == ["ShiftLeft"]:  # SHIFT goes with the last move key
            del self._release_at["ShiftLeft"]
            messages.append({"type": "key", "code": "ShiftLeft", "down": False})
        return messages


def run_episode(seed: int, operator: PersonLikeOperator | None = None, *, partner: str = "scripted",
                reaction_s: float = 0.2, max_seconds: float = 120.0) -> dict:
    """One episode of the grasper seat of ``dvrl_marl/SurgeonSeat-v8`` worked by ``operator`` (default: one seeded
    with ``seed``) through a :class:`~dvrl_marl.teleop.browser.BrowserDevice`, in simulated time: the operator sees
    :func:`~dvrl_marl.teleop.session.scene_view` as it was ``reaction_s`` earlier. Returns the success, the pins
    delivered, the seconds to success (or None) and the key presses."""
    import gymnasium as gym

    import dvrl_marl  # noqa: F401  (registration)
    from dvrl_marl.teleop.browser import BrowserDevice
    from dvrl_marl.teleop.session import TELEOP_ENV_ID, scene_view

    operator = operator or PersonLikeOperator(seed, reaction_s=reaction_s)
    operator.reset()
    from dvrl_marl.suction_debris.task import TASK  # the scene of TELEOP_ENV_ID
    from dvrl_marl.task import load_task_table

    dt = float(load_task_table(TASK)[1]["control_dt"])
    env = gym.make(TELEOP_ENV_ID, seat="grasper", partner=partner, max_cycles=int(round(max_seconds / dt)))
    scene = env.unwrapped.scene
    clock = [0.0]
    device = BrowserDevice(clock=lambda: clock[0])
    device.connect()
    device.reset()
    observation, _ = env.reset(seed=seed)
    view = scene_view(scene, "grasper")
    outline = view["outline"]
    seen = deque([view], maxlen=max(1, int(round(reaction_s / dt))) + 1)
    delivered, success, steps = 0, False, 0
    try:
        while True:
            clock[0] = steps * dt
            for message in operator.act(seen[0], clock[0]) + [{"type": "ping"}]:
                device.handle(message)
            observation, _, terminated, truncated, info = env.step(device.action(observation))
            steps += 1
            delivered, success = int(info["debris_delivered"]), bool(info["is_success"])
            seen.append(scene_view(scene, "grasper", outline))
            if terminated or truncated:
                break
    finally:
        env.close()
    return {"seed": seed, "success": success, "delivered": delivered, "steps": steps,
            "seconds": round(steps * dt, 2) if success else None, "presses": operator.presses}


def drive_page(page, operator: PersonLikeOperator, *, reaction_s: float = 0.2, time_limit_s: float | None = None,
               stall_s: float = 30.0, on_view=None) -> dict:
    """Work the seat in an open page (a Playwright ``Page`` showing ``dvrl-marl teleop``) until the episode is over:
    start it, then look at the status the page drew ``reaction_s`` ago and press the page's keys. ``on_view(status,
    page)`` runs at every look (a test reads the page's cues there). Returns the page's last status.

    It stops early, its keys released, once the episode has run ``time_limit_s`` of the seat's time (the status's
    ``time_s``; a busy machine steps the seat slower than the clock, so a limit on the clock would judge the machine)
    or when the seat has not stepped for ``stall_s`` seconds of the clock (the server stopped); the status it returns
    then says ``running``.
    """
    import time

    if time_limit_s is not None and not time_limit_s > 0:
        raise ValueError(f"drive_page: time_limit_s must be positive, got {time_limit_s!r}")
    if not stall_s > 0:
        raise ValueError(f"drive_page: stall_s must be positive, got {stall_s!r}")
    keyboard = page.keyboard
    page.keyboard.press("Enter")
    seen: deque = deque()
    began = time.monotonic()
    status = page.evaluate("window.dvrl.status")
    last_step, stepped_at = status["step"], 0.0
    while True:
        now = time.monotonic() - began
        status = page.evaluate("window.dvrl.status")
        if status["step"] != last_step:
            last_step, stepped_at = status["step"], now
        if status["state"] == "over" or now - stepped_at > stall_s:
            break
        if time_limit_s is not None and status["time_s"] >= time_limit_s:
            break
        seen.append((now, status))
        while len(seen) > 1 and seen[1][0] <= now - reaction_s:
            seen.popleft()
        if status["state"] != "running":
            time.sleep(0.02)
            continue
        view = seen[0][1]
        if on_view is not None:
            on_view(view, page)
        for message in operator.act(view, now):
            (keyboard.down if message["down"] else keyboard.up)(message["code"])
        time.sleep(0.02)
    for code in ("KeyA", "KeyD", "KeyS", "KeyW", "KeyF", "KeyR", "ShiftLeft"):
        keyboard.up(code)
    return status
