"""Where the device trainer's time goes: one update cycle of ``dvrl_marl.training.device_mappo`` taken apart, each
part timed alone (the device synchronised around it), medians over ``--repeats`` cycles after one to warm up.

Parts: the env's steps alone (fixed actions, ``rollout`` steps), the policy's sampling alone, a whole
``step_worlds`` (env, policy and bookkeeping), the critic's values, the return scaling, GAE, PPO's update, the
normalisers' update. A row per part goes to ``--json``.

    python benchmarks/device_trainer_profile.py --device cuda --worlds 4096
    python benchmarks/device_trainer_profile.py --device cpu --worlds 64 --repeats 2
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from dataclasses import replace
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--backend", choices=("numpy", "jax"), default=None, help="default: jax on a GPU, else numpy")
    parser.add_argument("--config", type=Path,
                        default=HERE / "baselines" / "configs" / "suction_debris_mappo_large_batch.toml")
    parser.add_argument("--worlds", type=int, default=4096)
    parser.add_argument("--minibatches", type=int, default=None, help="default: the configuration's")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--json", default=None)
    args = parser.parse_args()

    import torch

    from dvrl_marl.envs import suction_debris_v8
    from dvrl_marl.training import device_mappo
    from dvrl_marl.training.mappo_config import load_config
    from dvrl_marl.training.models import update_norms

    config = replace(load_config(args.config), num_envs=args.worlds, torch_threads=0)
    if args.minibatches:
        config = replace(config, minibatches=args.minibatches)
    backend = args.backend or ("jax" if args.device.startswith("cuda") else "numpy")
    device = torch.device(args.device)
    if backend == "jax":
        env = host = suction_debris_v8.batched_env(num_envs=config.num_envs, device=args.device, **dict(config.env))
    else:
        host = suction_debris_v8.batched_env(num_envs=config.num_envs, **dict(config.env))
        env = device_mappo._TorchView(host, torch)
    models = device_mappo.build_learner(config, host, device, torch)
    agents = models["agents"]
    optimiser = torch.optim.Adam(models["parameters"], lr=config.learning_rate)
    scale = device_mappo._ReturnScale(len(agents), config.gamma, torch, device)
    env.set_start_level(config.level(0.5))
    observations, _ = env.reset(seed=1)
    observations = device_mappo._stack(observations, agents, torch).to(device, torch.float32)
    state = env.state().to(device, torch.float32)
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    times: dict[str, list[float]] = {}

    def timed(name, call):
        sync()
        start = time.perf_counter()
        out = call()
        sync()
        times.setdefault(name, []).append(time.perf_counter() - start)
        return out

    fixed = {agent: torch.zeros((config.num_envs, 4), device=device) for agent in agents}

    def env_alone():
        for _ in range(config.rollout_steps):
            env.step(fixed)
            env.state()

    def sampling_alone():
        with torch.no_grad():
            for _ in range(config.rollout_steps):
                loc, scale_ = models["head"](observations)
                models["distribution"](loc, scale_).sample()

    for repeat in range(args.repeats + 1):
        if repeat == 1:
            times.clear()  # (the first cycle compiles and warms up)
        timed("env steps alone", env_alone)
        observations, _ = env.reset(seed=repeat + 2)
        observations = device_mappo._stack(observations, agents, torch).to(device, torch.float32)
        state = env.state().to(device, torch.float32)
        timed("policy sampling alone", sampling_alone)
        taken = timed("step_worlds (env + policy + bookkeeping)", lambda: device_mappo.step_worlds(
            env, models["head"], models["distribution"], agents, observations, state, config.rollout_steps, torch,
            device))
        observations, state = taken.observations[-1], taken.states[-1]
        rollout = timed("critic values", lambda: device_mappo.value_rollout(taken, models["critic"], torch))
        rollout.rewards = timed("return scaling", lambda: rollout.rewards / scale.update(rollout.rewards,
                                                                                           rollout.done))
        advantage, returns = timed("GAE", lambda: device_mappo.advantages(rollout, config.gamma, config.gae_lambda,
                                                                          torch))
        timed("PPO update", lambda: device_mappo.update(models, optimiser, rollout, advantage, returns, config,
                                                        torch))
        timed("normalisers", lambda: update_norms(models["norms"], rollout.observations, rollout.states))
    batch = config.num_envs * config.rollout_steps
    name = torch.cuda.get_device_name(0) if device.type == "cuda" else "cpu"
    cycle = sum(statistics.median(v) for key, v in times.items() if "alone" not in key)
    print(f"{name}, {backend} env, {config.num_envs} worlds x {config.rollout_steps} steps, {config.epochs} epochs "
          f"of {config.minibatches} minibatches: a cycle {cycle * 1e3:,.0f} ms = {batch / cycle:,.0f} env-steps/s "
          "(no validation)")
    rows = []
    for key, values in times.items():
        median = statistics.median(values)
        print(f"  {key:42s} {median * 1e3:9.1f} ms")
        rows.append({"what": "device_trainer_profile", "device": name, "backend": backend, "worlds": config.num_envs,
                     "rollout": config.rollout_steps, "epochs": config.epochs, "minibatches": config.minibatches,
                     "part": key, "median_ms": median * 1e3, "repeats": len(values)})
    if args.json:
        with open(args.json, "a") as handle:
            for row in rows:
                handle.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
