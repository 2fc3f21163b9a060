"""Suction & debris removal v2: every valid grasp can be delivered, and a dropped pin stays in view.

```python
from dvrl_marl.envs import suction_debris_v2
env = suction_debris_v2.parallel_env()                       # as v1, without the scene's traps
env = suction_debris_v2.parallel_env(surgeon="scripted")     # the scripted surgeon in the LND seat
env = suction_debris_v2.batched_env(num_envs=4096)           # N worlds as arrays
```

## Description
The collaborative scene of :mod:`dvrl_marl.envs.suction_debris_v1` (agents, spaces, observations, rewards, surgeon
seat, batched form, arguments, v1's falling pins, graded suction and optional bleeding are the same; see the v0 and
v1 pages) with two changes a person in the surgeon seat needed, set in ``tasks/suction_debris_v2.toml``:

- **The hand-off is judged where the jaws hold the pin** (``deliver_at_grip``). When the grasp rule takes a pin, the
  point of its axis nearest the jaw's control point is where the jaws hold it; that point, carried with the tip, must
  come within ``distance_threshold`` (delta, 3 mm) of the hand-off point. In v0 and v1 the pin's centre was judged,
  and since the hand-off point lies 2 mm inside the workspace's +x face, a pin gripped more than 5 mm off its centre
  on the assistant's side could never be delivered although on screen it touched the marker.
- **A dropped pin stays in view** (``pins_stay_on_phantom``). A pin released beyond the phantom lands 5 mm inside the
  nearest edge of the phantom's top (then falls as in v1), where the endoscope sees it and the grasper can take it
  again; in v1 it fell to the table behind the phantom, out of view and out of reach.

Everything a person sees in the seat (a drop line from each tip to the surface below it, the hand-off marker's
beacon, and the cues of :meth:`~dvrl_marl.envs.suction_debris_v0.SuctionDebrisEnv.cues`) is drawn for every
version; only these two rules change trajectories.

## Version History
- v2: hand-off judged at the grip, dropped pins stay on the phantom (this page). The demo, the browser and desktop
  seats (``dvrl_marl/SurgeonSeat-v2``) run it.
- v1: :mod:`dvrl_marl.envs.suction_debris_v1`, unchanged.
- v0: :mod:`dvrl_marl.envs.suction_debris_v0`, unchanged.
"""

from __future__ import annotations

from dvrl_marl.envs.suction_debris_v0 import AGENTS
from dvrl_marl.envs.versions import entry_points

__all__ = ["parallel_env", "env", "raw_env", "batched_env", "AGENTS", "TASK"]

#: The task file of this version (the environment takes its name from it).
TASK = "suction_debris_v2"

parallel_env, raw_env, batched_env, env = entry_points(TASK)
