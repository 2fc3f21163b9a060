"""Take docs/irrigation.png: the irrigation level (``preset="irrigation"``) as the scripted irrigating team clears it,
four moments of one episode side by side: the clotted field, the first cavity's clot under saline (a pink mix),
that cavity drawn clear and the second under saline, and the field cleared with a pin on its way to the hand-off.

    MUJOCO_GL=egl python docs/irrigation_picture.py
"""

from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio
import numpy as np

from dvrl_marl.agents.collaborative import ScriptedSuction, ScriptedSurgeon
from dvrl_marl.envs import suction_debris_v8

#: The steps shown (seed 3; the episode ends at step 1,237): the start, the mix in the first cavity the suction works,
#: the other cavity under saline, the field cleared with the last pin on its way.
MOMENTS = (1, 350, 850, 1200)


def main(out: Path = Path(__file__).with_name("irrigation.png")) -> Path:
    env = suction_debris_v8.parallel_env(preset="irrigation", render_mode="rgb_array", width=480, height=360)
    suction, surgeon = ScriptedSuction.for_env(env), ScriptedSurgeon.for_env(env)
    env.reset(seed=3)
    frames = []
    for step in range(1, max(MOMENTS) + 1):
        env.step({"suction": suction(env.seat_observation("suction")),
                  "grasper": surgeon(env.seat_observation("grasper"))})
        if step in MOMENTS:
            frames.append(env.render())
    iio.imwrite(out, np.concatenate(frames, axis=1))
    return out


if __name__ == "__main__":
    print(main())
