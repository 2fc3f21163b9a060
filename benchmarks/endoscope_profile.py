"""Where an image step's time goes: microseconds per world of each part of the endoscope's drawing (one GL context),
best of ``--repeats``. GL calls return before the GPU is done: ``drawing calls`` is their CPU side, ``read back``
waits for the GPU and copies the framebuffer.

    python benchmarks/endoscope_profile.py --worlds 1024 --size 84
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np


def _best(function, repeats: int, count: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        began = time.perf_counter()
        function()
        best = min(best, time.perf_counter() - began)
    return best / count * 1e6


def profile(worlds: int, size: int, repeats: int) -> dict:
    from dvrl_marl.envs import suction_debris_v8
    from dvrl_marl.envs.endoscope import _MOVING, _STILL, EndoscopeRenderer

    import mujoco  # noqa: I001  (after dvrl_marl: it sets MUJOCO_GL on a headless machine)

    env = suction_debris_v8.batched_env(num_envs=worlds, image_size=size)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = {agent: rng.uniform(-1, 1, (worlds, 4)) for agent in env.possible_agents}
    env.step(actions)
    renderer, core = env._endoscope, env.core
    model, data = renderer.mirror.model, renderer.mirror.data
    states = core.world_states(range(worlds))
    poses = renderer.mirror.poses(states)
    other = EndoscopeRenderer(env.params, size, layers=not renderer.layers)  # (the other way, for its render())
    bare = suction_debris_v8.batched_env(num_envs=worlds)
    bare.reset(seed=0)
    chunks = [range(start, min(worlds, start + renderer.tiles)) for start in range(0, worlds, renderer.tiles)]

    drawing = _MOVING if renderer.layers else (_STILL, _MOVING)  # (what the renderer draws per world)

    def drawing_calls():
        for chunk in chunks:
            for tile, _ in enumerate(chunk):
                renderer._draw(drawing, tile)

    def draw_and_read():
        for chunk in chunks:
            for tile, _ in enumerate(chunk):
                renderer._draw(drawing, tile)
            renderer._read(len(chunk), renderer.layers)

    def read_back():
        for chunk in chunks:
            renderer._read(len(chunk), renderer.layers)

    renderer._bind()
    option, scene = renderer._options[drawing], renderer._scene
    way = "layers" if renderer.layers else "whole scenes"
    parts = {
        "the step without images": _best(lambda: bare.step(actions), repeats, worlds),
        "world_states (every world at once)": _best(lambda: core.world_states(range(worlds)), repeats, worlds),
        "poses (every world at once)": _best(lambda: renderer.mirror.poses(states), repeats, worlds),
        "put (a world's pose into the model)": _best(lambda: [renderer.mirror.put(poses, world)
                                                              for world in range(worlds)], repeats, worlds),
        "mj_kinematics": _best(lambda: [mujoco.mj_kinematics(model, data) for _ in range(worlds)], repeats, worlds),
        "mjv_updateScene": _best(lambda: [mujoco.mjv_updateScene(model, data, option, renderer._perturb,
                                                                 renderer._camera, mujoco.mjtCatBit.mjCAT_ALL, scene)
                                          for _ in range(worlds)], repeats, worlds),
        f"drawing calls ({way}: mjv_updateScene + mjr_render, CPU side)": _best(drawing_calls, repeats, worlds),
        "read back (after the drawings of the call before)": _best(read_back, repeats, worlds),
        "drawing + read back": _best(draw_and_read, repeats, worlds),
        f"render() of every world ({way}, this renderer's way)": _best(lambda: renderer.render(states), repeats,
                                                                       worlds),
        f"render() of every world ({'whole scenes' if renderer.layers else 'layers'})": _best(
            lambda: other.render(states), repeats, worlds),
        "step + images": _best(lambda: env.step(actions), repeats, worlds),
    }
    other.close()
    env.close()
    return parts


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worlds", type=int, default=1024)
    parser.add_argument("--size", type=int, default=84)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", help="append one JSON line to this file")
    args = parser.parse_args(argv)
    if args.worlds < 1 or args.repeats < 1:
        parser.error("--worlds and --repeats must be positive")
    parts = profile(args.worlds, args.size, args.repeats)
    for name, micro in parts.items():
        print(f"{name}: {micro:,.1f} us per world", flush=True)
    if args.json:
        with open(args.json, "a") as handle:
            handle.write(json.dumps({"what": "endoscope profile", "worlds": args.worlds, "size": args.size,
                                     "us_per_world": {name: round(value, 2) for name, value in parts.items()}}) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
