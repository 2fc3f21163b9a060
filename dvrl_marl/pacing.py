"""Real time for a person in the loop: a pacer on the monotonic clock, and the paced window loop built on it.

A person reacts to what they see, so an episode with a human seat must advance at the control rate (50 Hz: one
20 ms step per period), neither faster (1,500 steps in 3 s leave no time to act) nor in bursts after a stall
(the arm would jump). Learning and evaluation never come here: they step as fast as the machine allows.
"""

from __future__ import annotations

import time
from collections.abc import Callable

__all__ = ["RealTimePacer", "PacedDisplay", "LATE_TOLERANCE"]

#: A step counts as late when it ends more than this fraction of a period after its deadline (sleep jitter of a
#: millisecond or so is not lateness a person can see).
LATE_TOLERANCE = 0.1


class RealTimePacer:
    """Holds a loop to one iteration per ``period`` seconds of the monotonic clock.

    Call :meth:`start` when the first step begins and :meth:`wait` after each step. Step ``k`` never ends before
    ``start + k * period``, so wall time is never less than simulated time. A step that ends late is counted
    (``steps_late``, ``worst_lag_ms``); one that fell behind by more than a period does not make the following steps
    rush to catch up (the schedule restarts from now), because a person would see the arm jump.
    """

    def __init__(self, period: float, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep):
        if not period > 0:
            raise ValueError(f"RealTimePacer: period must be positive, got {period!r}")
        self.period = float(period)
        self._clock, self._sleep = clock, sleep
        self.start()

    def start(self) -> None:
        now = self._clock()
        self._started = now
        self._deadline = now + self.period
        self.steps = 0
        self.steps_late = 0
        self.worst_lag = 0.0
        self.resyncs = 0

    def time_left(self) -> float:
        """Seconds until the current step's deadline (negative when already late)."""
        return self._deadline - self._clock()

    def wait(self) -> float:
        """Sleep until the current step's deadline; returns how late the step was (0 when on time)."""
        now = self._clock()
        lag = now - self._deadline
        if lag < 0:
            self._sleep(-lag)
            lag = 0.0
        elif lag > LATE_TOLERANCE * self.period:
            self.steps_late += 1
            self.worst_lag = max(self.worst_lag, lag)
        self.steps += 1
        if lag > self.period:
            self._deadline = now + self.period
            self.resyncs += 1
        else:
            self._deadline += self.period
        return lag

    def stats(self) -> dict:
        """What the run's metrics report: steps, steps late, worst lag, wall and simulated seconds."""
        return {
            "paced_steps": self.steps,
            "steps_late": self.steps_late,
            "worst_lag_ms": round(1000.0 * self.worst_lag, 1),
            "resyncs": self.resyncs,
            "period_ms": round(1000.0 * self.period, 3),
            "paced_wall_seconds": round(self._clock() - self._started, 3),
            "paced_sim_seconds": round(self.steps * self.period, 3),
        }


class PacedDisplay:
    """The window side of an episode with a person in a seat: waits for ENTER, keeps the window live, paces steps.

    ``renderer`` is a :class:`dvrl_marl.rendering.SceneRenderer` in ``"human"`` mode. After each step
    :meth:`after_step` delivers key events, draws a frame when the time left in the period allows it (frames are
    dropped before steps are: at least one every ``max_frame_gap`` steps) and sleeps until the period ends.
    """

    START_KEYS = (257, 335)  # GLFW's ENTER and keypad ENTER

    def __init__(self, renderer, period: float, max_frame_gap: int = 5):
        self.renderer = renderer
        self.pacer = RealTimePacer(period)
        self.max_frame_gap = int(max_frame_gap)
        self.waiting = False
        self.frames_dropped = 0
        self._since_frame = 0

    @property
    def window(self):
        return self.renderer.viewer

    @property
    def closed(self) -> bool:
        return self.renderer.window_closed

    def start_episode(self, wait_for_enter: bool) -> bool:
        """Show the first frame; with ``wait_for_enter``, hold until the person presses ENTER. False if the window
        was closed instead."""
        window = self.window
        self.renderer.forward()  # the waiting screen shows the scene lit and posed, not dark
        if wait_for_enter and not window.closed:
            self.waiting = True
            try:
                window.wait_for_key(self.START_KEYS, self.renderer.overlay or (lambda: ()))
            finally:
                self.waiting = False
        self.renderer.render()
        window.poll()
        self.pacer.start()
        self.frames_dropped = 0
        self._since_frame = 0
        return not window.closed

    def before_step(self) -> None:
        """Deliver the key events that arrived since the last step (the seat reads them this step)."""
        self.window.poll()

    def after_step(self) -> None:
        window = self.window
        self._since_frame += 1
        if self.pacer.time_left() > window.frame_seconds or self._since_frame >= self.max_frame_gap:
            self.renderer.render()
            self._since_frame = 0
        else:
            self.frames_dropped += 1
        window.poll()
        self.pacer.wait()

    def stats(self) -> dict:
        return {**self.pacer.stats(), "frames_dropped": self.frames_dropped}
