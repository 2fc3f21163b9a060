"""Human-in-the-loop devices for the surgeon seat, and real-time pacing for the person using them.

A device follows :class:`Device`: ``reset()``, ``action(observation) -> array`` in the seat's action space, and
``close()``. The environment calls it inside ``step()``; a device that raises, returns something unusable or does
not answer within the environment's ``teleop_timeout`` makes the seat hold still that step (zero Delta, jaw or
valve unchanged) with ``infos[agent]["teleop_lost"] = True``; the episode goes on. A device with
``human_operated = True`` (the keyboard) is driven by a person: in ``render_mode="human"`` the environment waits
for ENTER before an episode and runs it in real time (:mod:`dvrl_marl.pacing`).

In a web browser (``dvrl-marl teleop``): :class:`~dvrl_marl.teleop.browser.BrowserDevice` is the device,
:mod:`dvrl_marl.teleop.session` runs a person's episodes in real time and records them as Minari datasets, and
:mod:`dvrl_marl.teleop.web` serves the page (``pip install "dvrl-marl[teleop]"``).
"""

from dvrl_marl.teleop import devices as _devices
from dvrl_marl.teleop.devices import *  # noqa: F403 (the public names are devices.__all__)
from dvrl_marl.teleop.browser import BrowserDevice, TeleopLost
from dvrl_marl.pacing import PacedDisplay, RealTimePacer

__all__ = [*_devices.__all__, "RealTimePacer", "PacedDisplay", "BrowserDevice", "TeleopLost"]
