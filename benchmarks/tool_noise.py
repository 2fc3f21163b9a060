"""What exploration noise on the tool dimension does to the collaborative task, with and without ``tool_speed``.

The scripted team (``ScriptedSuction`` + ``ScriptedSurgeon``, which never fails without noise) drives the motion
exactly; only its tool command (valve, jaw) is replaced by a tanh-Gaussian sample around a decided command
(pre-tanh mean +/-1.5 for open / closed, scale ``sigma``), as a library's Gaussian policy explores it (BenchMARL's
and RLlib's start at scale 1). With the paper's instant tool (``tool_speed = 1``) one sample above the jaw's
threshold drops the held pin; with a finite speed the noise averages out over a stroke. ``--jaw-command switch``
and ``--hold-until-handoff`` run the scene's other tool options (a jaw set by the command's sign; a held pin kept
until the hand-off).

    python benchmarks/tool_noise.py [--worlds 64] [--task suction_debris_v8]
    python benchmarks/tool_noise.py --task suction_debris_v8 --jaw-command switch --hold-until-handoff
"""

from __future__ import annotations

import argparse
import importlib

import numpy as np

from dvrl_marl.agents import ScriptedSuction, ScriptedSurgeon

#: The decided command's pre-tanh magnitude (tanh 1.5 = 0.91: well past either threshold without noise).
DECIDED = 1.5


def success_rate(task: str, tool_speed: float, sigma: float, worlds: int, seed: int = 0, **options) -> float:
    """Fraction of ``worlds`` first episodes the scripted team completes with noise ``sigma`` on its tool
    (``options``: more keyword arguments of the env, e.g. ``jaw_command="switch"``)."""
    env = importlib.import_module(f"dvrl_marl.envs.{task}").batched_env(num_envs=worlds, tool_speed=tool_speed,
                                                                        **options)
    observations, _ = env.reset(seed=seed)
    experts = {"suction": ScriptedSuction.for_env(env), "grasper": ScriptedSurgeon.for_env(env)}
    rng = np.random.default_rng(seed)
    ended, succeeded = np.zeros(worlds, dtype=bool), np.zeros(worlds, dtype=bool)
    while not ended.all():
        actions = {}
        for agent in env.agents:
            action = np.array(experts[agent](observations[agent]), dtype=np.float64)
            decided = np.where(action[:, 3] > 0.0 if agent == "suction" else action[:, 3] > -0.5, DECIDED, -DECIDED)
            action[:, 3] = np.tanh(decided + sigma * rng.standard_normal(worlds))
            actions[agent] = action
        observations, _, terminations, truncations, _ = env.step(actions)
        done = terminations[env.agents[0]] | truncations[env.agents[0]]
        succeeded |= ~ended & terminations[env.agents[0]]
        ended |= done
    env.close()
    return float(succeeded.mean())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worlds", type=int, default=64)
    parser.add_argument("--task", default="suction_debris_v8")
    parser.add_argument("--sigmas", type=float, nargs="+", default=[0.0, 0.3, 0.6, 1.0])
    parser.add_argument("--speeds", type=float, nargs="+", default=[1.0, 0.1, 0.05])
    parser.add_argument("--jaw-command", choices=("proportional", "switch"), default="proportional")
    parser.add_argument("--hold-until-handoff", action="store_true")
    args = parser.parse_args()
    options = {"jaw_command": args.jaw_command, "hold_until_handoff": args.hold_until_handoff}
    print(f"{args.task} ({options}): the scripted team's success ({args.worlds} episodes) with tanh-Gaussian noise "
          "on its tool")
    print(f"  {'sigma':>6s}" + "".join(f"  speed {speed:<5g}" for speed in args.speeds))
    for sigma in args.sigmas:
        rates = [success_rate(args.task, speed, sigma, args.worlds, **options) for speed in args.speeds]
        print(f"  {sigma:6.2f}" + "".join(f"  {rate:11.2f}" for rate in rates), flush=True)


if __name__ == "__main__":
    main()
