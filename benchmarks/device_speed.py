"""The collaborative scene's batched env on a device, in Isaac Lab's terms: env-steps/s of the sim alone and of the sim
with a policy's inference, per number of worlds, with the numpy env beside it in the same run.

An env-step is one world's parallel step (both arms act). The sim alone steps with uniform random actions drawn where
the env runs, fresh each step; the sim with inference runs a torch MLP (two layers of 64, the trainer's actor size) on
each arm's observations on the same device first. Each figure is the best of ``--repeats`` timed blocks (at most 200
steps each) after one untimed step (the compile: one per N). Figures go to stdout as they are made and, with
``--json``, one JSON line per figure to that file (the device probe reads them).

    python benchmarks/device_speed.py --device cpu --sizes 1 64 4096
    python benchmarks/device_speed.py --device cuda --sizes 1024 16384 262144 1048576 --numpy-up-to 4096 --json out.jsonl
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE / "benchmarks"))
import provenance  # noqa: E402


def _device_name(device: str) -> str:
    if device.startswith("cuda"):
        import torch

        return torch.cuda.get_device_name(int(device.partition(":")[2] or 0))
    return f"{platform.processor() or platform.machine()} ({os.cpu_count()} cores)"


def measure(kind: str, worlds: int, device: str, preset: str | None, steps: int, repeats: int) -> tuple:
    """(sim env-steps/s, sim + inference env-steps/s) of one env (one compile on a device)."""
    import torch

    from dvrl_marl.envs import suction_debris_v8

    options = {"preset": preset} if preset else {}
    if kind == "numpy":
        env = suction_debris_v8.batched_env(num_envs=worlds, **options)
        torch_device = "cpu"
    else:
        env = suction_debris_v8.batched_env(num_envs=worlds, device=device, **options)
        torch_device = device
    observations, _ = env.reset(seed=0)
    agents = list(env.possible_agents)
    obs_dim = env.observation_space(agents[0]).shape[0]
    actor = torch.nn.Sequential(torch.nn.Linear(obs_dim, 64), torch.nn.Tanh(), torch.nn.Linear(64, 64),
                                torch.nn.Tanh(), torch.nn.Linear(64, 4), torch.nn.Tanh()).double().to(torch_device)
    # fresh uniform random actions every step, drawn where the env runs (the same walk as versus_commit.py's)
    generator = torch.Generator(device=torch_device).manual_seed(0)

    def random_actions(observations):
        drawn = {agent: torch.rand((worlds, 4), generator=generator, device=torch_device, dtype=torch.float64) * 2 - 1
                 for agent in agents}
        return {agent: value.numpy() for agent, value in drawn.items()} if kind == "numpy" else drawn

    def policy(observations):
        with torch.no_grad():
            if kind == "numpy":
                return {agent: actor(torch.from_numpy(observations[agent])).numpy() for agent in agents}
            return {agent: actor(observations[agent]) for agent in agents}

    def sync():
        if kind != "numpy" and torch_device.startswith("cuda"):
            torch.cuda.synchronize()

    figures = []
    for act in (random_actions, policy):
        observations = env.step(act(observations))[0]  # (the compile, on a device: the first call only)
        sync()
        best = 0.0
        for _ in range(repeats):
            start = time.perf_counter()
            for _ in range(steps):
                observations = env.step(act(observations))[0]
            sync()
            best = max(best, steps * worlds / (time.perf_counter() - start))
        figures.append(best)
    env.close()
    return tuple(figures)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu", help="cpu, cuda, cuda:1")
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 64, 4096])
    parser.add_argument("--numpy-up-to", type=int, default=4096, help="the numpy env beside it up to this N")
    parser.add_argument("--preset", default=None, help="benchmark: the benchmark's setting (guided reward, features)")
    parser.add_argument("--seconds", type=float, default=1.0, help="roughly how long each timed block runs")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", default=None, help="append one JSON line per figure to this file")
    args = parser.parse_args()
    os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")  # (torch shares the GPU)
    commit, name = provenance.commit(), _device_name(args.device)
    print(f"device {args.device}: {name}; commit {commit}; setting {args.preset or 'default'}", flush=True)
    print(f"{'N':>9} {'form':<8} {'sim env-steps/s':>16} {'sim + inference':>16}", flush=True)
    for worlds in args.sizes:
        for kind in (["numpy"] if worlds <= args.numpy_up_to else []) + ["device"]:
            # steps per block: about --seconds at a first guess of the rate, at least 3
            steps = max(3, min(200, int(args.seconds * (2e5 if kind == "numpy" else 1e7) / worlds)))
            row = {"worlds": worlds, "form": kind, "device": "cpu (numpy)" if kind == "numpy" else args.device,
                   "device_name": name, "commit": commit, "setting": args.preset or "default"}
            try:
                row["sim"], row["sim_inference"] = measure(kind, worlds, args.device, args.preset, steps, args.repeats)
            except Exception as error:  # noqa: BLE001  (out of memory at a size: the figure says so, the rest go on)
                row["error"] = f"{type(error).__name__}: {str(error)[:200]}"
            shown = ("failed: " + row["error"]) if "error" in row else f"{row['sim']:16,.0f} {row['sim_inference']:16,.0f}"
            print(f"{worlds:>9} {kind:<8} {shown}", flush=True)
            if args.json:
                with open(args.json, "a") as handle:
                    handle.write(json.dumps(row) + "\n")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
