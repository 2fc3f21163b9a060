"""Suction & debris removal v5: a descending move the wall leaves no headway climbs instead.

```python
from dvrl_marl.envs import suction_debris_v5
env = suction_debris_v5.parallel_env()                       # as v4, a move stopped by a wall rides up it
env = suction_debris_v5.parallel_env(surgeon="scripted")     # the scripted surgeon in the LND seat
env = suction_debris_v5.batched_env(num_envs=4096)           # N worlds as arrays
```

## Description
The collaborative scene of :mod:`dvrl_marl.envs.suction_debris_v4` (agents, spaces, observations, rewards, surgeon
seat, batched form, arguments, the learning options and every earlier version's change are the same; see the v0 to
v4 pages) with one change, set in ``tasks/suction_debris_v5.toml`` (``blocked_moves = "climb"``; the rule is
:mod:`dvrl_marl.core.sliding`):

- **A descending move that the wall leaves no headway gives up its descent.** v3's wall is frictionless: a move's
  component into the bowl is taken away and the rest slides along it. A move out of a cavity and down, pressed
  along the wall's normal, keeps nothing and the tip stays. In v5, when less than a tenth of a descending move is
  made, its level part is made instead (by the same rules: slid along the wall), so the tip rides up the wall the
  way it was heading and over the rim. A move that makes headway is made as in v4; the tips still stay in the
  workspace, above every surface, within the joint limits and clear of the other instrument.

Why: a policy acting by its mean action (what a robot is driven by) that heads for the other cavity presses down
and outward against the wall it is in, and sends the same command for the rest of the episode. Measured (issue 37;
``python benchmarks/mean_action_failures.py <run>``): the commonest end of the test episodes that learnt v4 teams
failed by their mean action, for the suction (87 of 95 failures of one IPPO seed) and the grasper. The same v4
policies, untrained, in v5's scene: MAPPO 0.39 -> 0.91 (seed 2), IPPO 0.05 -> 0.39 (seed 4) test success, the
seeds that succeeded already unchanged or better (0.87 -> 0.87, 0.72 -> 0.93, 0.93 -> 0.95).

The scripted experts plan over the rims and never press into a wall, so the scripted team's episodes are v4's.

## Version History
- v7: :mod:`dvrl_marl.envs.suction_debris_v7`, the suction's descent pressed into the bowl slides down it (the benchmark's task
  files run it).
- v6: :mod:`dvrl_marl.envs.suction_debris_v6`, a descent's headway counted along the move.
- v5: a descent the wall stops climbs (this page).
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
TASK = "suction_debris_v5"

parallel_env, raw_env, batched_env, env = entry_points(TASK)
