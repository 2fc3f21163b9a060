"""The MAPPO trainer's throughput with its collectors here, on Ray (1 and 2 collectors) and on a two-node cluster.

    python benchmarks/ray_scaling.py [--iterations 6] [--num-envs 256] [--out benchmarks/ray_scaling.txt]

Each configuration trains the same small run (``--num-envs`` worlds x 32 steps per iteration, 2 x 128 networks)
from scratch and reads ``result.json``'s timing: env steps per second overall, while collecting (the collectors'
throughput, all of them together) and while updating (the learner's). "two nodes" is ``ray.cluster_utils.Cluster``
with two Ray nodes of one CPU each on this machine (a collector on each, the learner in this process): it shows the
work spread over nodes, not extra hardware. On a cluster of real machines each collector adds its machine's cores.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

CONFIG = """
[run]
algorithm = "mappo"
total_steps = {total}
num_envs = {num_envs}
rollout_steps = 32
eval_every = {total}
eval_episodes = 4
checkpoint_every = {total}
torch_threads = 1
[env]
reward_type = "dense"
[model]
hidden = [128, 128]
"""


def run(label: str, num_envs: int, iterations: int, **ray_options) -> dict:
    from dvrl_marl.training import mappo

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "bench.toml"
        path.write_text(CONFIG.format(total=num_envs * 32 * iterations, num_envs=num_envs))
        messages = []
        began = time.perf_counter()
        mappo.train(mappo.load_config(path), 0, Path(folder) / "run", progress=False, tensorboard=False,
                    log=messages.append, **ray_options)
        wall = time.perf_counter() - began
        timing = json.loads((Path(folder) / "run" / "result.json").read_text())["timing"]
    spread = next((m for m in messages if m.startswith("collecting on Ray")), "local")
    steps = timing["steps"]
    return {"configuration": label, "steps": steps, "wall_s": wall,
            "steps_per_s": steps / (timing["collect_seconds"] + timing["learn_seconds"]),
            "collect_steps_per_s": steps / timing["collect_seconds"],
            "learn_samples_per_s": steps / timing["learn_seconds"], "where": spread}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--iterations", type=int, default=6)
    parser.add_argument("--num-envs", type=int, default=256)
    parser.add_argument("--out", help="also write the table to this file")
    args = parser.parse_args()
    import ray
    from ray.cluster_utils import Cluster

    rows = [run("local (no Ray)", args.num_envs, args.iterations)]
    ray.init(include_dashboard=False, log_to_driver=False)
    for collectors in (1, 2):
        rows.append(run(f"Ray, this machine, {collectors} collector(s)", args.num_envs, args.iterations,
                        ray_address="local", num_collectors=collectors))
    ray.shutdown()
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    cluster.add_node(num_cpus=1)
    cluster.wait_for_nodes()
    ray.init(address=cluster.address, log_to_driver=False)
    rows.append(run("Ray, two nodes (local cluster), 2 collectors", args.num_envs, args.iterations,
                    ray_address="auto", num_collectors=2))
    ray.shutdown()
    cluster.shutdown()

    lines = [f"MAPPO trainer throughput, {args.num_envs} worlds x 32 steps per iteration, {args.iterations} "
             "iterations, "
             f"{os.cpu_count()} CPU cores (python benchmarks/ray_scaling.py)",
             f"{'configuration':<46} {'env steps/s':>12} {'collecting':>12} {'updating':>12}  where",
             ]
    for row in rows:
        lines.append(f"{row['configuration']:<46} {row['steps_per_s']:>12,.0f} {row['collect_steps_per_s']:>12,.0f} "
                     f"{row['learn_samples_per_s']:>12,.0f}  {row['where']}")
    print("\n".join(lines))
    if args.out:
        Path(args.out).write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
