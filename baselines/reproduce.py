"""Reproduce the baselines: train every configuration x seed, ship the best policies, plot the learning curves.

    python baselines/reproduce.py --seeds 0 1 2 --jobs 2                 # everything (hours of CPU)
    python baselines/reproduce.py --configs reach_lnd_ddpg_her --seeds 0  # one configuration
    python baselines/reproduce.py --configs pick_lnd_ppo_scratch --seeds 0 1 2 --held-out pick-lnd-scratch
                                                                          # + each seed on 100 held-out episodes

Run folders go to ``runs/baselines/<config>-seed<N>``; the figure and its CSV to ``baselines/results/``; shipped
policies (``--ship``) to ``baselines/policies/<name>`` with their evaluation and the command that made them.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

HERE = Path(__file__).resolve().parent
RUNS = Path("runs") / "baselines"
#: Shipped policy name -> (configuration, evaluation keyword arguments)
SHIPPED = {
    "reach-lnd": ("reach_lnd_ddpg_her", {}),
    "reach-suction-irrigation": ("reach_suction_irrigation_ddpg_her", {"tool": "suction_irrigation"}),
    "pick-lnd": ("pick_lnd_ddpg_her_bc", {}),
    "pick-lnd-scratch": ("pick_lnd_ppo_scratch", {}),
}


#: The figures of record (results/learning_curves<suffix>.png, summary<suffix>.csv) and the configurations in each.
#: ("" was recorded on the first single-arm envs, whose p was the jaw's control point (commit 36a42a0 reproduces it);
#: "_v1" on the current ones: the same configurations.)
FIGURES = {
    "_v1": ("pick_lnd_ddpg_her_bc", "reach_lnd_ddpg_her", "reach_suction_irrigation_ddpg_her"),
}


def run(config: str, seed: int) -> Path:
    out = RUNS / f"{config}-seed{seed}"
    command = [sys.executable, "-m", "dvrl_marl.cli", "train", str(HERE / "configs" / f"{config}.toml"),
               "--seed", str(seed), "--out", str(out), "--no-progress"]
    if (out / "checkpoint.zip").is_file():
        command.append("--resume")
    env = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")  # one core per job
    subprocess.run(command, check=True, env=env)
    return out


def export_run(name: str, seed: int, target: Path) -> Path:
    """Export seed ``seed``'s run of ``name``'s configuration (its evaluation-selected checkpoint) to ``target``."""
    import gymnasium as gym

    from dvrl_marl.training.export import export_policy
    from dvrl_marl.training.runner import load_config, sb3_algorithms

    config_name, eval_kwargs = SHIPPED[name]
    config = load_config(HERE / "configs" / f"{config_name}.toml")
    out = RUNS / f"{config_name}-seed{seed}"
    # The evaluation-selected checkpoint (off-policy learners can degrade late in a run).
    checkpoint = out / "best_model.zip" if (out / "best_model.zip").is_file() else out / "final_model.zip"
    model = sb3_algorithms()[config.algorithm].load(checkpoint)
    unwrapped = gym.make(config.env_id, **config.env).unwrapped
    # The frame the policy was trained in: pipelines re-centre it but keep its range and step.
    return export_policy(model, target, name=name, env_id=config.env_id, workspace_range=unwrapped.workspace_range,
                         step_size=unwrapped.step_size, **config.export_metadata(), **eval_kwargs)


def ship(name: str, seed: int, episodes: int = 50) -> dict:
    """Export a trained run as a shipped policy, with its evaluation and the commands behind it."""
    from dvrl_marl import policies
    from dvrl_marl.training.runner import evaluate_policy, load_config

    config_name, eval_kwargs = SHIPPED[name]
    config = load_config(HERE / "configs" / f"{config_name}.toml")
    target = export_run(name, seed, HERE / "policies" / name)
    result = evaluate_policy(policies.load(target), config.env_id, episodes, seed=1_000_000, env_kwargs=eval_kwargs)
    spec = json.loads((target / "policy.json").read_text())
    spec["evaluation"] = {**result, "seed": 1_000_000,
                          "command": f"dvrl-marl evaluate {name} --episodes {episodes}"
                          + (f" --tool {eval_kwargs['tool']}" if "tool" in eval_kwargs else "")}
    spec["training"] = {"config": f"baselines/configs/{config_name}.toml", "seed": seed,
                        "command": f"python baselines/reproduce.py --configs {config_name} --seeds {seed} --ship {name}"}
    (target / "policy.json").write_text(json.dumps(spec, indent=2) + "\n")
    return spec["evaluation"]


def held_out(name: str, seeds: list[int], episodes: int = 100) -> Path:
    """Every seed's run of ``name``'s configuration, exported and played by its default call (the mean action) on
    ``episodes`` held-out episodes of the registered task (``dvrl-marl evaluate``'s seeds): one row per seed in
    ``results/<configuration>_held_out.json``."""
    import subprocess as sp

    from dvrl_marl import policies
    from dvrl_marl.training.runner import evaluate_policy, load_config

    config_name, eval_kwargs = SHIPPED[name]
    config = load_config(HERE / "configs" / f"{config_name}.toml")
    rows = []
    for seed in seeds:
        target = export_run(name, seed, RUNS / f"{config_name}-seed{seed}" / "exported")
        result = evaluate_policy(policies.load(target), config.env_id, episodes, seed=1_000_000, env_kwargs=eval_kwargs)
        progress = (RUNS / f"{config_name}-seed{seed}" / "progress.csv").read_text().splitlines()
        last = dict(zip(progress[0].split(","), progress[-1].split(",")))
        rows.append({"seed": seed, **result, "training_steps": int(float(last["timesteps"])),
                     "training_wall_seconds": round(float(last["wall_seconds"]), 1)})
        print(config_name, rows[-1])
    commit = sp.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    record = {"config": f"baselines/configs/{config_name}.toml", "env_id": config.env_id, "commit": commit,
              "evaluation": f"{episodes} held-out episodes per seed (seeds from 1,000,000), the mean action",
              "command": f"python baselines/reproduce.py --configs {config_name} --seeds "
                         f"{' '.join(map(str, seeds))} --held-out {name}",
              "seeds": rows}
    path = HERE / "results" / f"{config_name}_held_out.json"
    path.write_text(json.dumps(record, indent=2) + "\n")
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--configs", nargs="*", default=sorted(p.stem for p in (HERE / "configs").glob("*.toml")))
    parser.add_argument("--seeds", nargs="*", type=int, default=[0, 1, 2])
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--ship", nargs="*", default=[], help=f"export these from the first seed: {sorted(SHIPPED)}")
    parser.add_argument("--held-out", nargs="*", default=[],
                        help=f"play every seed of these on 100 held-out episodes: {sorted(SHIPPED)}")
    parser.add_argument("--no-train", action="store_true", help="only ship and plot existing runs")
    args = parser.parse_args()
    unknown = [name for name in args.ship + args.held_out if name not in SHIPPED]
    if unknown:
        parser.error(f"unknown policy name(s) {unknown}; known: {sorted(SHIPPED)}")
    if not args.no_train:
        with ThreadPoolExecutor(args.jobs) as pool:
            list(pool.map(lambda job: run(*job), [(c, s) for c in args.configs for s in args.seeds]))
    for name in args.held_out:
        print(name, held_out(name, args.seeds))
    for name in args.ship:
        print(name, ship(name, args.seeds[0]))
    from dvrl_marl.training.plots import plot_learning_curves, summary_table

    for suffix, configs in FIGURES.items():
        # A figure of record is redrawn only from all of its runs: a partial set would overwrite it with less.
        runs = [RUNS / f"{config}-seed{seed}" for config in configs for seed in args.seeds]
        missing = [str(run) for run in runs if not (run / "progress.csv").is_file()]
        if missing:
            print(f"results/learning_curves{suffix}: not redrawn, {len(missing)} of {len(runs)} runs missing "
                  f"(e.g. {missing[0]})")
            continue
        print(plot_learning_curves([str(run) for run in runs], HERE / "results" / f"learning_curves{suffix}"))
        print(summary_table([str(run) for run in runs], HERE / "results" / f"summary{suffix}"))


if __name__ == "__main__":
    main()
