"""``jax.jit(jax.vmap(env.step))`` of ``suction_debris_v8.jax_env`` over N worlds for T steps (issue 77's target: 4,096
worlds, 1,000 steps): finite, the same for the same key, world i equal to the numpy batched env's world seeded
``seed_of(key_i)`` (a sample of worlds compared step by step), and the speed, inside one ``lax.scan``.

    python benchmarks/jax_env_scale.py --worlds 4096 --steps 1000 --json benchmarks/results/jax_env_cpu_2026-12-01.jsonl
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import provenance  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--worlds", type=int, default=4096)
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--compare", type=int, default=8, help="worlds compared with the numpy env")
    parser.add_argument("--json", help="append the figures to this JSON-lines record")
    parser.add_argument("--memory-worlds", type=int, default=65536,
                        help="compile one vmapped step for this many worlds and read XLA's memory figures (0: skip)")
    args = parser.parse_args(argv)
    code = provenance.code_state()  # (as the run starts: what it imports)
    import jax
    import jax.numpy as jnp

    from dvrl_marl.envs import suction_debris_v8
    from dvrl_marl.envs.suction_debris_jax import seed_of
    from dvrl_marl.suction_debris import scene_state

    env = suction_debris_v8.jax_env()
    agents = env.agents
    keys = jax.random.split(jax.random.key(0), args.worlds)
    # the actions a function of the step and the world: the numpy env can be given the same ones
    table = jax.random.uniform(jax.random.key(1), (args.steps, len(agents), 4), jnp.float64, -1.0, 1.0)
    wobble = jnp.linspace(-0.2, 0.2, args.worlds)[:, None]

    def actions_at(t):
        return {agent: jnp.clip(table[t, index][None, :] + wobble, -1.0, 1.0) for index, agent in enumerate(agents)}

    step = jax.vmap(env.step)

    @jax.jit
    def run(keys):
        observations, states = jax.vmap(env.reset)(keys)

        def body(carry, t):
            states = carry
            observations, states, rewards, dones, _ = step(keys, states, actions_at(t))
            picked = {agent: observations[agent][: args.compare] for agent in agents}
            finite = jnp.all(jnp.stack([jnp.all(jnp.isfinite(observations[agent])) & jnp.all(jnp.isfinite(rewards[agent]))
                                        for agent in agents]))
            return states, (picked, dones["__all__"].sum(), finite)

        states, (picked, ended, finite) = jax.lax.scan(body, states, jnp.arange(args.steps))
        return states, picked, ended, finite

    began = time.perf_counter()
    states, picked, ended, finite = jax.block_until_ready(run(keys))
    first = time.perf_counter() - began
    began = time.perf_counter()
    again, _, _, _ = jax.block_until_ready(run(keys))
    seconds = time.perf_counter() - began
    finite = bool(jnp.all(finite))  # every observation and reward of every world and step
    # (the state holds NaN and inf by design: a pin not falling, a cavity that never bleeds)
    same = all(bool(jnp.array_equal(a, b, equal_nan=True))
               for a, b in zip(jax.tree_util.tree_leaves(states), jax.tree_util.tree_leaves(again)))
    host = suction_debris_v8.batched_env(num_envs=args.compare)
    host.reset(seed=[int(seed_of(key)) for key in keys[: args.compare]])
    worst = 0.0
    for t in range(args.steps):
        given = {agent: np.asarray(value)[: args.compare] for agent, value in actions_at(t).items()}
        observations = host.step(given)[0]
        worst = max(worst, max(float(np.abs(np.asarray(picked[agent][t]) - observations[agent]).max()) for agent in agents))
    leaves = jax.tree_util.tree_leaves(states)
    state_bytes = sum(value[0].nbytes for value in leaves)  # one world's
    state_bytes_float32 = state_bytes - scene_state.bytes_per_world(states.scene) + scene_state.bytes_per_world(
        states.scene, float_bytes=4) - sum(value[0].nbytes // 2 for value in jax.tree_util.tree_leaves(states.potential))
    memory = step_memory(env, args.memory_worlds) if args.memory_worlds else {}
    row = {"what": "jax_env: jit(vmap(step)) in one lax.scan", "worlds": args.worlds, "steps": args.steps,
           "state_bytes_per_world": state_bytes, "state_bytes_per_world_float32": state_bytes_float32,
           "state_arrays": len(leaves), **memory,
           "finite": finite, "same_for_the_same_key": same, "worlds_compared": args.compare,
           "max_difference_from_numpy": worst, "episodes_ended": int(np.asarray(ended).sum()),
           "compile_and_first_run_seconds": round(first, 1), "run_seconds": round(seconds, 2),
           "env_steps_per_s": round(args.worlds * args.steps / seconds), "device": str(jax.devices()[0]),
           "command": "python benchmarks/jax_env_scale.py " + " ".join(sys.argv[1:]), "code": code}
    print(json.dumps({k: v for k, v in row.items() if k != "code"}, indent=1))
    if args.json:
        with open(args.json, "a") as handle:
            handle.write(json.dumps(row) + "\n")
    return 0 if finite and same and worst <= 1e-9 else 1


def step_memory(env, worlds: int) -> dict:
    """XLA's figures for one ``jit(vmap(step))`` over ``worlds`` worlds (compiled, not run: the state, the actions and
    the step's temporaries), and a million worlds scaled from them."""
    import jax
    import jax.numpy as jnp

    keys = jax.random.split(jax.random.key(0), worlds)
    states = jax.eval_shape(jax.vmap(env.reset), keys)[1]
    actions = {agent: jax.ShapeDtypeStruct((worlds, env.action_width), jnp.float64) for agent in env.agents}
    compiled = jax.jit(jax.vmap(env.step)).lower(keys, states, actions).compile()
    analysis = compiled.memory_analysis()
    if analysis is None:  # (a backend without the figures)
        return {"memory_worlds": worlds, "memory_analysis": "not given by this backend"}
    used = analysis.argument_size_in_bytes + analysis.output_size_in_bytes + analysis.temp_size_in_bytes
    return {"memory_worlds": worlds, "step_arguments_bytes": int(analysis.argument_size_in_bytes),
            "step_outputs_bytes": int(analysis.output_size_in_bytes),
            "step_temporaries_bytes": int(analysis.temp_size_in_bytes),
            "step_bytes_per_world": round(used / worlds, 1),
            "million_worlds_step_gb": round(used / worlds * 1e6 / 1e9, 2)}


if __name__ == "__main__":
    sys.exit(main())
