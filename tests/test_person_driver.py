"""How the person-like operator's page driver stops (dvrl_marl.teleop.person.drive_page), with a stand-in page: at
the episode's end, at a limit in the seat's time whatever the clock says, and when the seat stops stepping; its
keys released each time. The real page is driven in tests/test_browser_page.py."""

import pytest

from dvrl_marl.teleop.person import drive_page


class _Operator:
    """Holds D from its first look on (the driver must let it go when it stops)."""

    def act(self, status, now_s):
        return [{"type": "key", "code": "KeyD", "down": True}]


class _Keyboard:
    def __init__(self):
        self.held, self.pressed = set(), []

    def press(self, code):
        self.pressed.append(code)

    def down(self, code):
        self.held.add(code)

    def up(self, code):
        self.held.discard(code)


class _Page:
    """A page whose seat runs ``seconds_per_look`` of its time per status read, up to ``over_at`` (or stalls at
    ``stall_at`` steps); 50 steps a second of the seat's time."""

    def __init__(self, seconds_per_look=0.1, over_at=None, stall_at=None):
        self.keyboard, self.looks = _Keyboard(), 0
        self.seconds_per_look, self.over_at, self.stall_at = seconds_per_look, over_at, stall_at

    def evaluate(self, expression):
        assert expression == "window.dvrl.status"
        assert self.looks < 10_000, "the driver never stopped"  # (a failure, not a hang)
        time_s = self.looks * self.seconds_per_look
        self.looks += 1
        steps = round(time_s * 50)
        if self.stall_at is not None:
            steps = min(steps, self.stall_at)
        over = self.over_at is not None and time_s >= self.over_at
        return {"state": "over" if over else "running", "step": steps, "time_s": steps / 50}


def test_the_driver_stops_at_the_episodes_end_at_its_limit_in_the_seats_time_and_when_the_seat_stalls():
    ended = _Page(over_at=3.0)
    assert drive_page(ended, _Operator(), reaction_s=0.0)["state"] == "over"
    assert ended.keyboard.pressed == ["Enter"] and ended.looks >= 30 and not ended.keyboard.held
    # the limit is the seat's time, which this page runs 100 times faster than the clock
    limited = _Page(seconds_per_look=1.0)
    final = drive_page(limited, _Operator(), reaction_s=0.0, time_limit_s=20.0)
    assert final["state"] == "running" and final["time_s"] == 20.0 and limited.looks <= 22
    assert not limited.keyboard.held
    stalled = _Page(stall_at=10)
    final = drive_page(stalled, _Operator(), reaction_s=0.0, stall_s=0.3)
    assert final["state"] == "running" and final["step"] == 10 and not stalled.keyboard.held
    for wrong in ({"time_limit_s": 0.0}, {"stall_s": -1.0}):
        with pytest.raises(ValueError, match=next(iter(wrong))):
            drive_page(_Page(), _Operator(), **wrong)
