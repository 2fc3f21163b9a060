"""Suction & debris removal v3: a blocked move slides along what blocks it, so no command can pin a tip in place.

```python
from dvrl_marl.envs import suction_debris_v3
env = suction_debris_v3.parallel_env()                       # as v2, blocked moves slide
env = suction_debris_v3.parallel_env(surgeon="scripted")     # the scripted surgeon in the LND seat
env = suction_debris_v3.batched_env(num_envs=4096)           # N worlds as arrays
```

## Description
The collaborative scene of :mod:`dvrl_marl.envs.suction_debris_v2` (agents, spaces, observations, rewards, surgeon
seat, batched form, arguments, the learning options, v1's falling pins and graded suction, v2's hand-off at the grip
and dropped pins in view are the same; see the v0, v1 and v2 pages) with one change, set in
``tasks/suction_debris_v3.toml`` (``blocked_moves = "slide"``; the rule is :mod:`dvrl_marl.core.sliding`):

- **A move into a cavity's wall slides along it.** The bowl is a sphere; the move's component into it is taken
  away and the rest is made (a frictionless contact: a tip pushed sideways against the wall rides up it and over
  the rim). In v2 the tip kept its horizontal position at a wall and moved only vertically.
- **A move the other instrument or the joint limits block falls back to its free components.** Its components are
  given up one at a time, the smallest first, then all but one, the largest first; the first of these that can be
  made in full is made. In v2 the tip stayed where it was (a joint limit: it went as far as it could along the move).
  The instruments still never pass through each other, the tips stay in the workspace box, above every surface and
  within the joint limits, and ``collision`` and the contact penalty are as in v2.

Why: up to v2 a policy acting by its mean action (what a robot is driven by) that pushed into a wall, the other
instrument or a joint limit saw the same observation again and sent the same action again until the episode ended.
Measured (issue 37): a MAPPO team trained on v2 succeeded in 0.92 of its training episodes, acting with its
exploration noise, and in 0.11 of 100 test episodes by its mean action; in 87 of the 89 failures the suction had
been motionless for 100 or more steps against a blocker. The noise, not the policy, had resolved the contacts.

A scripted expert never pushes into a blocker, so the scripted team's episodes are v2's step for step.

## Version History
- v3: blocked moves slide (this page). The benchmark ran it until v4.
- v2: :mod:`dvrl_marl.envs.suction_debris_v2`, unchanged; the demo and the seats a person uses run it.
- v1: :mod:`dvrl_marl.envs.suction_debris_v1`, unchanged.
- v0: :mod:`dvrl_marl.envs.suction_debris_v0`, unchanged.
"""

from __future__ import annotations

from dvrl_marl.envs.suction_debris_v0 import AGENTS
from dvrl_marl.envs.versions import entry_points

__all__ = ["parallel_env", "env", "raw_env", "batched_env", "AGENTS", "TASK"]

#: The task file of this version (the environment takes its name from it).
TASK = "suction_debris_v3"

parallel_env, raw_env, batched_env, env = entry_points(TASK)
