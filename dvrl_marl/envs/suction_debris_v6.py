"""Suction & debris removal v6: a descent's headway is what it advances the way it heads.

```python
from dvrl_marl.envs import suction_debris_v6
env = suction_debris_v6.parallel_env()                       # as v5, a tip pressed out of a cavity climbs out
env = suction_debris_v6.parallel_env(surgeon="scripted")     # the scripted surgeon in the LND seat
env = suction_debris_v6.batched_env(num_envs=4096)           # N worlds as arrays
```

## Description
The collaborative scene of :mod:`dvrl_marl.envs.suction_debris_v5` (agents, spaces, observations, rewards, surgeon
seat, batched form, arguments, the learning options and every earlier version's change are the same; see the v0 to
v5 pages) with one change, set in ``tasks/suction_debris_v6.toml`` (``blocked_moves = "climb_ahead"``; the rule is
:mod:`dvrl_marl.core.sliding`):

- **A descent's headway is what it advances the way it heads.** v5 gives up a descending move of which the wall
  leaves less than a tenth, and makes its level part instead, so a tip pressed out of a cavity climbs the wall. It
  counted any made part as headway: a tip pressed almost along the wall's normal climbed one step, and on the next
  steps the frictionless wall let the small rest of the move slip it back down the bowl (made, though away from where
  the move heads), then it climbed again: a cycle of five steps, in place. In v6 a descending move with a level part
  (at least a tenth of it) whose made part advances less than a tenth of the move's length the way its level part
  heads gives up its descent where its level part gets further that way, so the tip keeps climbing the way it heads
  and over the rim. A move that advances, a move (almost) straight down, and a descent whose level part gets no
  further (pressed into the workspace's face, say) are made as in v5.

Why: measured (issue 37; ``python benchmarks/mean_action_failures.py <run>``), the commonest end of the test episodes
that learnt BenchMARL MAPPO teams failed by their mean action on v5 (63 of 72 failures of seed 0: the suction in
cavity 0 heading for cavity 1, the grasper in cavity 1 heading for cavity 0, each in that cycle at its cavity's rim).
The same policies, untrained, in v6's scene: 0.28 -> 0.92 and 0.81 -> 0.95 test success by the mean action
(seeds 0 and 1; 0.74 -> 0.92 and 0.35 -> 0.95 for seeds 2 and 3).

The scripted experts plan over the rims and never press into a wall, so the scripted team's episodes are v5's.

## Version History
- v7: :mod:`dvrl_marl.envs.suction_debris_v7` (the suction's descent pressed into the bowl slides down it); the benchmark's
  task files run it.
- v6: a descent's headway counted along the move (this page).
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
TASK = "suction_debris_v6"

parallel_env, raw_env, batched_env, env = entry_points(TASK)
