"""Image observations' speed: frames/s of the endoscope's view through the batched env (step, draw, read back), per
image size and number of worlds, beside a bare ``mujoco.Renderer`` of the same scene drawing one world's state again and
again (no shadows, reflections or multisampling; no state written, no step: its best case) in the same run.

A frame is one world's image. The env's figure is a step of every world with random actions plus their images
(``observations()``), minus nothing: the step is counted in. Each figure is the best of ``--repeats`` timed blocks.

    python benchmarks/endoscope_speed.py                       # 84 px, 1 ... 256 worlds
    python benchmarks/endoscope_speed.py --sizes 64 84 128 --worlds 64 --json out.jsonl
    python benchmarks/endoscope_speed.py --worlds 4096 --contexts 1 4 16   # GL contexts in threads (image_contexts)
    python benchmarks/endoscope_speed.py --worlds 64 --stereo               # the stereo pair beside one eye

A stereo frame is one world's pair (two images).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE / "benchmarks"))
import provenance  # noqa: E402


def env_frames_per_second(size: int, worlds: int, repeats: int, steps: int, contexts: int = 1,
                          stereo: bool = False) -> float:
    from dvrl_marl.envs import suction_debris_v8

    env = suction_debris_v8.batched_env(num_envs=worlds, image_size=size, image_contexts=contexts,
                                        image_stereo=stereo)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = [{agent: rng.uniform(-1, 1, (worlds, 4)) for agent in env.possible_agents} for _ in range(steps)]
    env.step(actions[0])  # (the renderer is made on the first observation)
    best = 0.0
    for _ in range(repeats):
        began = time.perf_counter()
        for step in range(steps):
            env.step(actions[step])
        best = max(best, steps * worlds / (time.perf_counter() - began))
    env.close()
    return best


def bare_frames_per_second(size: int, repeats: int, frames: int) -> float:
    # dvrl_marl first: importing it sets MUJOCO_GL=egl on a headless machine, before mujoco loads
    from dvrl_marl.envs import suction_debris_v8

    import mujoco  # noqa: I001

    env = suction_debris_v8.batched_env(num_envs=1)
    env.reset(seed=0)
    mirror = env.mirror()
    model, data = mirror.model, mirror.data
    model.vis.quality.offsamples = 0
    renderer = mujoco.Renderer(model, size, size)
    renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
    renderer.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
    mirror.show(env.core.world_state(0))
    mujoco.mj_forward(model, data)
    best = 0.0
    for _ in range(repeats):  # (the same state drawn again and again: no state written, no step)
        began = time.perf_counter()
        for _ in range(frames):
            renderer.update_scene(data, camera="endoscope")
            renderer.render()
        best = max(best, frames / (time.perf_counter() - began))
    renderer.close()
    return best


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[84])
    parser.add_argument("--worlds", type=int, nargs="+", default=[1, 16, 64, 256])
    parser.add_argument("--contexts", type=int, nargs="+", default=[1],
                        help="GL contexts drawing the images, each in a thread of its own (the env's image_contexts)")
    parser.add_argument("--stereo", action="store_true", help="each figure again with the stereo pair (image_stereo)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--frames", type=int, default=512, help="frames per timed block (about)")
    parser.add_argument("--json", help="append one JSON line per figure to this file")
    args = parser.parse_args(argv)
    if min(args.sizes) < 1 or min(args.worlds) < 1 or min(args.contexts) < 1 or args.repeats < 1 or args.frames < 1:
        parser.error("--sizes, --worlds, --contexts, --repeats and --frames must be positive")
    machine = f"{platform.processor() or platform.machine()}, {__import__('os').cpu_count()} cores"
    rows = []
    for size in args.sizes:
        bare = bare_frames_per_second(size, args.repeats, min(args.frames, 300))
        rows.append({"what": "bare mujoco.Renderer, one world at a time", "size": size, "worlds": 1,
                     "frames_per_second": round(bare, 1)})
        print(f"{size} px, bare renderer: {bare:,.0f} frames/s", flush=True)
        for worlds in args.worlds:
            for contexts in args.contexts:
                for stereo in (False, True) if args.stereo else (False,):
                    steps = max(2, args.frames // worlds)
                    fps = env_frames_per_second(size, worlds, args.repeats, steps, contexts, stereo)
                    what = "batched env step + " + ("the stereo pair" if stereo else "image observations")
                    rows.append({"what": what, "size": size, "worlds": worlds, "contexts": contexts,
                                 "frames_per_second": round(fps, 1), "versus_bare": round(fps / bare, 2)})
                    print(f"{size} px, {worlds} worlds, {contexts} GL context(s), step + "
                          f"{'stereo pairs' if stereo else 'images'}: {fps:,.0f} frames/s "
                          f"({fps / bare:.2f}x the bare renderer)", flush=True)
    if args.json:
        with open(args.json, "a") as handle:
            for row in rows:
                handle.write(json.dumps({**row, "machine": machine, "commit": provenance.commit(),
                                         "command": "python benchmarks/endoscope_speed.py " +
                                                    " ".join(argv or __import__("sys").argv[1:])}) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
