"""A seat that keeps state per world, called across episodes without ``reset()``: how many of its second episodes
finish (the trap of issue 80: ``marl-suction-pixels`` keeps its lowest blood estimates per world; a caller that never
resets it once left it reading the last episode's emptied cavities).

    python benchmarks/pixel_seat_without_reset.py --json baselines/results/pixel_seat_without_reset_v8.json
    python benchmarks/pixel_seat_without_reset.py --no-new-episodes   # the seat as it was: no new episode seen

N worlds beside the scripted surgeon, held-out seeds, automatic resets (the seat is reset once, before the first
episodes); every world plays two episodes, and the second episodes' completions are counted."""

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


def second_episodes(policy_name: str, worlds: int, detect: bool) -> dict:
    from dvrl_marl import policies
    from dvrl_marl.envs import suction_debris_v8
    from dvrl_marl.policies import image_encoder
    from dvrl_marl.training import teams

    if not detect:
        image_encoder.NEW_EPISODE_JUMP = float("inf")
    policy = policies.load(policy_name)
    env = suction_debris_v8.batched_env(num_envs=worlds, **(policy.image_options or {}))
    surgeon = teams.seat("scripted", "grasper", env)
    observations, _ = env.reset(seed=teams.EVAL_SEED)
    policy.reset()
    episodes, second = np.zeros(worlds, dtype=int), np.zeros(worlds, dtype=bool)
    began = time.perf_counter()
    while (episodes < 2).any():
        grasper = observations["grasper"]
        actions = {"suction": policy(observations["suction"]),
                   "grasper": surgeon(grasper["observation"] if isinstance(grasper, dict) else grasper)}
        observations, _, terminations, truncations, infos = env.step(actions)
        for world in np.flatnonzero(terminations["suction"] | truncations["suction"]):
            if episodes[world] == 1:
                second[world] = bool(infos["suction"]["is_success"][world])
            episodes[world] += 1
    return {"policy": policy_name, "worlds": worlds, "new_episodes_seen": detect,
            "second_episodes_completed": int(second.sum()), "seconds": round(time.perf_counter() - began, 1)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--policy", default="marl-suction-pixels")
    parser.add_argument("--worlds", type=int, default=20)
    parser.add_argument("--no-new-episodes", action="store_true",
                        help="the seat as it was: a tip's jump starts no new episode")
    parser.add_argument("--json", help="append the row to this JSON record")
    args = parser.parse_args(argv)
    code = provenance.code_state()  # (as the run starts)
    row = {**second_episodes(args.policy, args.worlds, not args.no_new_episodes),
           "command": "python benchmarks/pixel_seat_without_reset.py " + " ".join(sys.argv[1:]),
           "code": code}
    print(f"{row['policy']}, {'a new episode seen where the tip jumps' if row['new_episodes_seen'] else 'no new episode seen'}: "
          f"{row['second_episodes_completed']} of {row['worlds']} second episodes completed ({row['seconds']:.0f} s)")
    if args.json:
        path = Path(args.json)
        rows = json.loads(path.read_text())["rows"] if path.is_file() else []
        path.write_text(json.dumps({"rows": rows + [row]}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
