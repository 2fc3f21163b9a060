"""Take docs/keyboard_seat.png: the keyboard seat's window, mid-episode, with its overlay.

Run it at a desktop, or headless under a virtual screen: ``xvfb-run -s "-screen 0 1024x768x24" python
docs/keyboard_seat_screenshot.py``. The scripted suction clears blood; the LND is driven by key events sent to a
KeyboardDevice the way the window sends them (this script is not a person, so it does not wait for ENTER).
"""

from __future__ import annotations

import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from dvrl_marl.agents.collaborative import ScriptedSuction
from dvrl_marl.envs import suction_debris_v8
from dvrl_marl.teleop import KeyboardDevice

PRESS, RELEASE = 1, 0


class _ScriptKeys(KeyboardDevice):
    human_operated = False  # no person to press ENTER; keys come from the script below

#: (step, key, GLFW action): S held for 40 steps (-y), then F for 20 (down).
KEY_EVENTS = ((0, "S", PRESS), (40, "S", RELEASE), (41, "F", PRESS), (60, "F", RELEASE))


def main(out: Path = Path(__file__).with_name("keyboard_seat.png")) -> Path:
    keys = _ScriptKeys()
    env = suction_debris_v8.parallel_env(surgeon=keys, render_mode="human")
    suction = ScriptedSuction.for_env(env)
    observations, _ = env.reset(seed=0)
    for step in range(420):
        for at, key, action in KEY_EVENTS:
            if at == step:
                keys.key_event(ord(key), action)
        observations, *_ = env.step({"suction": suction(observations["suction"])})
    env.render()
    frame = env.window.screenshot()
    env.close()
    iio.imwrite(out, np.ascontiguousarray(frame))
    return out


if __name__ == "__main__":
    print(main(*[Path(arg) for arg in sys.argv[1:]]))
