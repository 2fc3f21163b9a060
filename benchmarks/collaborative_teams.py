"""Success of the collaborative teams (target: the learned pipeline team completes >= 90 % of 50 seeds).

Reports success, mean steps, blood removed and instrument contacts for the scripted team, the scripted-stage
pipeline team, the learned Reach + Pick pipeline team (the shipped policies), and a PPO team if a trained model is
given.

    python benchmarks/collaborative_teams.py [--episodes 50] [--ppo runs/baselines/suction_debris_ppo-seed0]
    python benchmarks/collaborative_teams.py --episodes 50 --json baselines/results/collaborative_teams_v8.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import provenance  # noqa: E402

from dvrl_marl import policies
from dvrl_marl.agents import ScriptedSuction, ScriptedSurgeon
from dvrl_marl.envs import suction_debris_v8
from dvrl_marl.pipeline import ArmPipeline, pipeline_policies
from dvrl_marl.training.marl import TeamPolicy, evaluate_team


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--ppo", help="a suction_debris_ppo run folder (with final_model.zip)")
    parser.add_argument("--json", help="write the figures to this JSON record (with the command and the code)")
    args = parser.parse_args()
    code = provenance.code_state()  # (as the run starts)
    env = suction_debris_v8.parallel_env()
    suction, surgeon = ScriptedSuction.for_env(env), ScriptedSurgeon.for_env(env)
    teams = {"scripted team": lambda o: {"suction": suction(o["suction"]), "grasper": surgeon(o["grasper"])}}
    names = ["scripted_team"]
    if pipeline_policies("learned_team") <= set(policies.available()):
        names.append("learned_team")
    results = {}
    for label, act in teams.items():
        results[label] = evaluate_team(act, args.episodes)
    for name in names:
        env = suction_debris_v8.parallel_env()
        start = time.perf_counter()
        pipes = {agent: ArmPipeline.from_file(name, agent, env) for agent in ("suction", "grasper")}
        result = evaluate_team(lambda o, p=pipes: {agent: p[agent](o[agent]) for agent in p}, args.episodes,
                               on_reset=lambda p=pipes: [pipe.reset() for pipe in p.values()])
        result["wall_seconds"] = round(time.perf_counter() - start, 1)
        results[f"pipeline {name}"] = result
    if args.ppo:
        from stable_baselines3 import PPO

        model = PPO.load(Path(args.ppo) / "final_model.zip")
        results["PPO team"] = evaluate_team(TeamPolicy(model, ["suction", "grasper"]), args.episodes, reward_type="dense")
    print(f"{'team':32s} {'success':>8s} {'steps':>7s} {'blood ml':>9s} {'contacts':>9s}")
    for label, r in results.items():
        print(f"{label:32s} {r['success_rate']:8.0%} {r['mean_steps']:7.0f} {r['mean_blood_removed_ml']:9.2f} "
              f"{r['mean_contacts']:9.2f}")
    print(json.dumps(results, indent=1))
    if args.json:
        Path(args.json).write_text(json.dumps({
            "episodes": args.episodes, "teams": results,
            "command": "python benchmarks/collaborative_teams.py " + " ".join(sys.argv[1:]),
            "code": code}, indent=1) + "\n")


if __name__ == "__main__":
    main()
