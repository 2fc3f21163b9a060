"""Which array backend for the collaborative core: one piece of its step on each, at N = 1 and N = 4,096 worlds.

The piece is the instruments' clearance (:func:`dvrl_marl.suction_debris.instruments.instrument_clearance`: the four pairs of
segments between the two instruments, about a third of the step's arithmetic), written once against the array API
standard and run here on numpy, on torch (CPU, and CUDA where there is a GPU) and on JAX (``jax.jit``; where JAX is
installed). Each figure is the median of several timed rounds of calls on one core's worth of work; a line per
backend and N gives microseconds per call and world-evaluations per second. The whole step of the core at the same N
(random commands) follows: on numpy, and on JAX under ``jax.jit`` (where JAX is installed), which traces every rule
for every world (the rare ones too: a blocked move's nine slides, the joint-limit bisection), where numpy skips
those no world needs.

    taskset -c 1 python benchmarks/backend_prototype.py [--sizes 1 4096] [--rounds 5]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from dvrl_marl.suction_debris.instruments import instrument_clearance


def _points(n: int, rng) -> list[np.ndarray]:
    points = [rng.normal(size=(n, 3)) * 0.03 + np.array([0.0, 0.0, 0.05]) for _ in range(6)]
    points[0], points[3] = np.array([-0.07, -0.03, 0.14]), np.array([0.07, -0.03, 0.14])  # the two RCMs
    return points


def _time(call, calls: int, rounds: int, sync=lambda value: value) -> float:
    """Median seconds per call."""
    sync(call())  # warm up (and compile, for JAX)
    times = []
    for _ in range(rounds):
        start = time.perf_counter()
        for _ in range(calls):
            value = call()
        sync(value)
        times.append((time.perf_counter() - start) / calls)
    return statistics.median(times)


def backends():
    """(name, convert, wrap, sync) for each backend available here."""
    yield "numpy", (lambda a: a), instrument_clearance, (lambda v: v)
    try:
        import torch
    except ImportError:
        torch = None
    if torch is not None:
        yield "torch-cpu", (lambda a: torch.as_tensor(a)), instrument_clearance, (lambda v: v)
        if torch.cuda.is_available():
            yield ("torch-cuda", (lambda a: torch.as_tensor(a, device="cuda")), instrument_clearance,
                   (lambda v: torch.cuda.synchronize()))
    try:
        import jax
    except ImportError:
        return
    jax.config.update("jax_enable_x64", True)  # the core is float64
    import jax.numpy as jnp

    for jax_device in jax.devices():
        yield (f"jax-jit-{jax_device.platform}", (lambda a, d=jax_device: jax.device_put(jnp.asarray(a), d)),
               jax.jit(instrument_clearance), (lambda v: v.block_until_ready()))


def core_step_seconds(n: int, rounds: int) -> float:
    from dvrl_marl.suction_debris.rules import CollaborativeCore
    from dvrl_marl.suction_debris.task import SuctionDebrisParams

    core = CollaborativeCore(SuctionDebrisParams.from_task(), n)
    core.reset(seed=0)
    rng = np.random.default_rng(1)
    rounds_of_commands = [{agent: rng.uniform(-1, 1, (n, 4)) for agent in ("suction", "grasper")} for _ in range(64)]
    turn = iter(range(10**9))
    return _time(lambda: core.step(rounds_of_commands[next(turn) % 64]), max(1, 2000 // n), rounds)


def jax_step_seconds(n: int, rounds: int) -> float | None:
    """The whole step under ``jax.jit``: the core's state in and out as one record of arrays."""
    try:
        import jax
    except ImportError:
        return None
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    from dvrl_marl.suction_debris import scene_state
    from dvrl_marl.suction_debris.rules import CollaborativeCore
    from dvrl_marl.suction_debris.task import SuctionDebrisParams

    core = CollaborativeCore(SuctionDebrisParams.from_task(), n)
    core.reset(seed=0)

    scene_state.register_with_jax()
    compiled = jax.jit(lambda state, commands: core.step_state(state, commands)[0])
    state = scene_state.map_arrays(jnp.asarray, core.get_state())
    rng = np.random.default_rng(1)
    rounds_of_commands = [{agent: jnp.asarray(rng.uniform(-1, 1, (n, 4))) for agent in ("suction", "grasper")}
                          for _ in range(8)]
    turn = iter(range(10**9))
    holder = {"state": state}

    def call():
        holder["state"] = compiled(holder["state"], rounds_of_commands[next(turn) % 8])
        return holder["state"]

    return _time(call, max(1, 200 // n), rounds, lambda value: jax.block_until_ready(value))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 4096])
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    print(f"{'backend':<16} {'N':>9} {'us/call':>10} {'worlds/s':>14}")
    for n in args.sizes:
        points = _points(n, rng)
        expected = instrument_clearance(*points)
        calls = max(1, 4000 // n)
        for name, convert, function, sync in backends():
            inputs = [convert(p) for p in points]
            got = np.asarray(function(*inputs).tolist() if name.startswith("torch-cuda") else function(*inputs))
            assert np.allclose(got, expected, rtol=0, atol=1e-12), name  # the same numbers on every backend
            seconds = _time(lambda: function(*inputs), calls, args.rounds, sync)
            print(f"{name:<16} {n:>9,} {seconds * 1e6:>10.1f} {n / seconds:>14,.0f}")
        step = core_step_seconds(n, args.rounds)
        print(f"{'step, numpy':<16} {n:>9,} {step * 1e6:>10.1f} {n / step:>14,.0f}")
        step = jax_step_seconds(n, args.rounds)
        if step is not None:
            print(f"{'step, jax-jit':<16} {n:>9,} {step * 1e6:>10.1f} {n / step:>14,.0f}")


if __name__ == "__main__":
    main()
