"""Suction & debris removal v4: a held pin is observed where the hand-off judges it.

```python
from dvrl_marl.envs import suction_debris_v4
env = suction_debris_v4.parallel_env()                       # as v3, a held pin shown at the jaws' grip
env = suction_debris_v4.parallel_env(surgeon="scripted")     # the scripted surgeon in the LND seat
env = suction_debris_v4.batched_env(num_envs=4096)           # N worlds as arrays
```

## Description
The collaborative scene of :mod:`dvrl_marl.envs.suction_debris_v3` (agents, spaces, rewards, surgeon seat, batched
form, arguments, the learning options, v1's falling pins and graded suction, v2's hand-off at the grip and dropped
pins in view, v3's sliding moves are the same; see the v0 to v3 pages) with one change, set in
``tasks/suction_debris_v4.toml`` (``held_pin_at_grip = true``):

- **A held pin is shown where the jaws hold it.** Since v2 the hand-off is judged at the grip, the point of the
  pin's axis nearest the tip when the jaw closed, carried with the tip (at most the jaw's 3 mm sensor range from
  it); a pin held by its end can be delivered. v2 and v3 still showed a held pin's *centre* (up to 14 mm from the
  grip) in the observations' and the state's ``position~`` and measured the dense reward's carry (-10 x distance to
  the hand-off point) from it. v4 shows the judged point there, in the observations, the state (and so in the
  observation features' carry and the guided reward's terms, computed from them) and the carry. A pin not held is
  shown at its centre, as before; the scene, the rendering and the rules are unchanged.

Why: the reward, the features and the observation pointed a carrying policy at a point the hand-off does not judge.
Measured (issue 37): of the test episodes a learnt IPPO team (v3, 4M frames) failed by its mean action, 27 of 63
(seed 2) and 36 of 47 (seed 0) ended with the grasper holding a pin at the hand-off, motionless, pushing the tip
into the workspace's +x face (the hand-off point lies 2 mm inside it) while the judged point stayed 3-4 mm off;
its exploration noise had brought the grip within 3 mm in training. Showing the same policies the grip instead of
the centre, untrained, raised seed 0's test success from 0.53 to 0.82.

The scripted surgeon carries the pin it sees to the hand-off point: in v4 the grip, what is judged (it closes over
a pin's centre, so the two lie within the jaw's sensor range of each other).

## Version History
- v4: a held pin observed at its grip (this page). The benchmark ran it until v5.
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
TASK = "suction_debris_v4"

parallel_env, raw_env, batched_env, env = entry_points(TASK)
