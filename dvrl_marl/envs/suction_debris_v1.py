"""Suction & debris removal v1: pins that fall, suction that needs the surface, and an optional bleeding field.

```python
from dvrl_marl.envs import suction_debris_v1
env = suction_debris_v1.parallel_env()                                        # as v0, with v1's physics
env = suction_debris_v1.parallel_env(surgeon="scripted", bleeding_ml_s=0.3)   # cavities keep bleeding
env = suction_debris_v1.batched_env(num_envs=4096)                            # N worlds as arrays
```

## Description
The collaborative scene of :mod:`dvrl_marl.envs.suction_debris_v0` (agents, spaces, observations, rewards,
surgeon seat, batched form and arguments are the same; see its page) with three changes to the physics, its
defaults in ``tasks/suction_debris_v1.toml`` with their sources:

- **Released pins fall.** A pin the grasper lets go of away from the assistant falls under gravity (9.81 m/s^2,
  one step of 20 ms at a time) onto the surface below it: phantom top, cavity floor or table, never through it.
  In v0 it appeared on that surface in the same step. A falling pin can be caught again.
- **Suction needs the surface** (``suction_reach``, 2 mm). The valve draws the full 2.5 ml/s while the tube's tip
  is at or under the blood surface of the cavity it is in, less the higher it is above the surface (linearly), and
  nothing from ``suction_reach`` up: a suction tip in the air draws gas, not fluid. In v0 the flow was full strictly
  under the surface and nothing at it.
- **A bleeding field** (``bleeding_ml_s``, off by default). Each cavity starts bleeding at a seeded time in
  ``[0, bleeding_onset_s]`` (10 s) at a seeded rate in ``[0.5, 1] x bleeding_ml_s`` ml/s, up to its capacity, for
  the rest of the episode. Success is unchanged: every cavity below ``blood_threshold_ml`` and every pin delivered,
  at the same time; with bleeding the suction must keep the field clear while the grasper works, so cooperation
  rather than sequencing decides success (the suction-then-grasp sequence of the scripted team no longer suffices).
  A cavity that started empty reports its blood as a fraction of its capacity.

## Version History
- v1: released pins fall, graded suction, optional bleeding (this page).
- v0: :mod:`dvrl_marl.envs.suction_debris_v0`, unchanged.
"""

from __future__ import annotations

from dvrl_marl.envs.suction_debris_v0 import AGENTS
from dvrl_marl.envs.versions import entry_points

__all__ = ["parallel_env", "env", "raw_env", "batched_env", "AGENTS", "TASK"]

#: The task file of this version.
TASK = "suction_debris_v1"

parallel_env, raw_env, batched_env, env = entry_points(TASK)
