"""The compiled trainer's speed per number of worlds, as Isaac Lab reports it: env-steps/s of the core stepped inside
one compiled loop (``sim``: fixed actions through ``jax.lax.scan``, no Python between steps), and of whole update
cycles of :mod:`dvrl_marl.training.jax_mappo` (``train``: the rollout with the actors' samples, GAE, the PPO epochs),
compilation excluded (timed apart), no validation.

    python benchmarks/jax_trainer_speed.py --device cuda --sizes 4096 16384 65536 --json out.jsonl

A configuration (``--config``; default the large-batch one) with its minibatches scaled to keep their rows
(``--rows``) as the worlds grow; one JSON line per size and part.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--config", type=Path,
                        default=HERE / "baselines" / "configs" / "suction_debris_mappo_large_batch.toml")
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 512])
    parser.add_argument("--rows", type=int, default=16384, help="rows per minibatch (the minibatches scale with N)")
    parser.add_argument("--cycles", type=int, default=5, help="timed cycles (after one that compiles)")
    parser.add_argument("--parts", nargs="+", choices=("sim", "train"), default=["sim", "train"])
    parser.add_argument("--json", default=None)
    args = parser.parse_args()

    import jax
    import numpy as np

    from dvrl_marl.envs import suction_debris_v8
    from dvrl_marl.training import jax_mappo
    from dvrl_marl.training.mappo_config import load_config

    base = load_config(args.config)
    for worlds in args.sizes:
        rows = worlds * base.rollout_steps
        config = replace(base, num_envs=worlds, minibatches=max(1, rows // args.rows))
        env = suction_debris_v8.batched_env(num_envs=worlds, device=args.device, arrays="jax", check_actions=False,
                                            **dict(config.env))
        carry = jax_mappo.start(env, config, seed=0)
        figures = {}
        if "sim" in args.parts:
            step = env.step_function
            zeros = {agent: jax.device_put(np.zeros((worlds, 4)), env.device) for agent in env.possible_agents}

            @jax.jit
            def steps(world):
                return jax.lax.scan(lambda state, _: (step(state, zeros)[0], None), world, None,
                                    length=config.rollout_steps)[0]

            figures["sim"] = _timed(lambda world: (steps(world),), (carry[0],), args.cycles,
                                    worlds * config.rollout_steps)
        if "train" in args.parts:
            cycle = jax.jit(jax_mappo.make_cycle(env, config), donate_argnums=(0,))
            rate = np.float32(config.learning_rate)
            figures["train"] = _timed(lambda *state: cycle(state, rate, None)[0], carry, args.cycles,
                                      worlds * config.rollout_steps)
        name = jax.devices(str(env.device.platform))[0].device_kind
        for part, (compile_seconds, seconds) in figures.items():
            row = {"what": "jax_trainer_speed", "part": part, "device": name, "worlds": worlds,
                   "rollout": config.rollout_steps, "minibatches": config.minibatches, "epochs": config.epochs,
                   "compile_seconds": compile_seconds, "cycle_seconds": seconds,
                   "env_steps_per_s": worlds * config.rollout_steps / seconds}
            print(json.dumps(row), flush=True)
            if args.json:
                with open(args.json, "a") as handle:
                    handle.write(json.dumps(row) + "\n")


def _timed(function, carry, cycles: int, steps: int):
    """(seconds of the first call, compilation included; median seconds of the next ``cycles``)."""
    import jax
    import numpy as np

    began = time.perf_counter()
    carry = jax.block_until_ready(function(*carry))
    first = time.perf_counter() - began
    times = []
    for _ in range(cycles):
        began = time.perf_counter()
        carry = jax.block_until_ready(function(*carry))
        times.append(time.perf_counter() - began)
    return first, float(np.median(times))


if __name__ == "__main__":
    main()
