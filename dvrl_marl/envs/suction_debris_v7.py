"""Suction & debris removal v7: the suction pressed down into a cavity's bowl slides down it.

```python
from dvrl_marl.envs import suction_debris_v7
env = suction_debris_v7.parallel_env()                       # as v6; the suction pressed down a slope slides down
env = suction_debris_v7.parallel_env(surgeon="scripted")     # the scripted surgeon in the LND seat
env = suction_debris_v7.batched_env(num_envs=4096)           # N worlds as arrays
```

## Description
The collaborative scene of :mod:`dvrl_marl.envs.suction_debris_v6` (agents, spaces, observations, rewards, surgeon
seat, batched form, arguments, the learning options and every earlier version's change are the same; see the v0 to
v6 pages) with one change, set in ``tasks/suction_debris_v7.toml`` (``blocked_moves = "settle"``; the rule is
:mod:`dvrl_marl.core.sliding`):

- **The suction pressed down into a cavity's bowl slides down it.** From v3 on a move into a cavity's steep wall
  slides along it (a frictionless constraint), but on the bowl's gentler slopes, which a tip climbs by up to a step, a
  move into the surface keeps its horizontal part and rises onto the surface: a command (almost) straight down was
  made as nothing there, and the tip stayed where it was. In v7 a descending move of the suction that the rules up to
  v6 leave with less than a tenth of its length, over a cavity, has its component into the bowl taken away and slides
  down the slope with the rest, as on the steep walls (where that makes more than v6 does). The grasper's moves are
  v6's: a grasper pressing down onto a pin stays over it (with the slide, a tip coming down onto a pin on the slope
  slid away from it: measured, ``baselines/README.md``, a frictionless slope for both arms broke the learnt graspers
  of v4). Every move those rules make is made as in v6.

Why: measured (issue 37; ``python benchmarks/mean_action_failures.py <run>``), the commonest end of the test episodes
that a learnt BenchMARL MAPPO team failed by its mean action on v6 (16 of 34 failures of seed 0): the suction pressed
straight down on the slope a few millimetres above the last half millilitre of a cavity, above the pool and so
drawing none, for the rest of the episode. The same policies, untrained, in v7's scene
(``--option task=suction_debris_v7``): 0.66 -> 0.80 test success by the mean action (seed 0; the others as they were:
0.99 -> 1.00, 0.93 -> 0.98, 0.99 -> 0.99, and seed 3, which never learnt the carry, 0.00).

The scripted experts plan their descents onto the cavities' floors from above them, so the scripted team's episodes
are v6's.

## Version History
- v7: the suction's descent pressed into the bowl slides down it (this page). The benchmark's task files
  (``dvrl_marl.integrations.benchmarl``) run it.
- v6: :mod:`dvrl_marl.envs.suction_debris_v6`, unchanged.
- v5: :mod:`dvrl_marl.envs.suction_debris_v5`, unchanged.
- v4: :mod:`dvrl_marl.envs.suction_debris_v4`, unchanged.
- v3: :mod:`dvrl_marl.envs.suction_debris_v3`, unchanged.
- v2: :mod:`dvrl_marl.envs.suction_debris_v2`, unchanged; the demo and the seats a person uses run it.
- v1: :mod:`dvrl_marl.envs.suction_debris_v1`, unchanged.
- v0: :mod:`dvrl_marl.envs.suction_debris_v0`, unchanged.
"""

from __future__ import annotations

from dvrl_marl.envs.suction_debris_v0 import AGENTS
from dvrl_marl.envs.versions import entry_points

__all__ = ["parallel_env", "env", "raw_env", "batched_env", "AGENTS", "TASK"]

#: The task file of this version (the environment takes its name from it).
TASK = "suction_debris_v7"

parallel_env, raw_env, batched_env, env = entry_points(TASK)
