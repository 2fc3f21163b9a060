"""Human-in-the-loop devices for the surgeon seat.

A device follows :class:`Device`: ``reset()``, ``action(observation) -> array`` in the seat's action space, and
``close()``. The environment calls it inside ``step()``; a device that raises, returns something unusable or does
not answer within the environment's ``teleop_timeout`` makes the seat hold still that step (zero Delta, jaw or
valve unchanged) with ``infos[agent]["teleop_lost"] = True``; the episode goes on.
"""

from dvrl_marl.teleop import devices as _devices
from dvrl_marl.teleop.devices import *  # noqa: F403 (the public names are devices.__all__)

__all__ = list(_devices.__all__)
