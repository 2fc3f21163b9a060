"""Where a grasper loses its pins: grasps, grasps that can never be delivered, drops and deliveries per episode.

The jaw takes a pin wherever its axis passes within 3 mm of the tip, anywhere along the pin's 25 mm, and the
hand-off point lies 2 mm inside the workspace's +x face: a pin held more than about 5 mm toward -x of the tip can
never reach it (``GraspPathShaping(centred=True)`` in ``dvrl_marl.suction_debris.guidance`` charges such grasps). This
script counts them, from the grasper's own observation, on the held-out evaluation seeds, with the pins of the
cavity on the grasper's own side (near, x > 0) apart from those of the far one (a grasper can learn one and not
the other):

    python baselines/grasp_audit.py --grasper marl-grasper --noise
    python baselines/grasp_audit.py --grasper runs/<run>/policies_best/marl-grasper --suction scripted --noise
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from dvrl_marl.envs import suction_debris_v8
from dvrl_marl.training import teams

#: A pin held further than this (m) toward -x of the tip cannot come within 3 mm of the hand-off point.
UNDELIVERABLE_OFFSET_X = -0.005


def audit(suction: str, grasper: str, episodes: int, seed: int, noise: bool) -> dict:
    team = teams.seats(suction, grasper, noise_from=seed if noise else None)
    env = suction_debris_v8.batched_env(num_envs=episodes, autoreset_mode="disabled")
    debris_slice = env.observation_layout["debris"]
    count = env.params.debris_count
    observations, _ = env.reset(seed=seed)

    def slots(observation):
        return observation[:, debris_slice].reshape(episodes, count, 6)

    held_before = slots(observations["grasper"])[:, :, 4] > 0.5
    # which cavity each pin lies in, from the grasper's side: near (over the grasper's own side, x > 0) or far
    first = slots(observations["grasper"])
    near = first[:, :, 0] > 0.0
    hidden = first[:, :, 3] < 0.5  # a hidden pin reads 0: learn its side once it shows
    grasped_ever = np.zeros((episodes, count), dtype=bool)
    grasps, drops, carry_steps = np.zeros(episodes), np.zeros(episodes), np.zeros(episodes)
    delivered, success, done = np.zeros(episodes), np.zeros(episodes, dtype=bool), np.zeros(episodes, dtype=bool)
    offsets = []
    while not done.all():
        actions = {agent: np.asarray(team[agent](observations[agent]), dtype=np.float64) for agent in env.agents}
        observations, _, terminations, truncations, infos = env.step(actions)
        live = ~done
        own = observations["grasper"]
        pins = slots(own)
        held, gone = pins[:, :, 4] > 0.5, pins[:, :, 5] > 0.5
        new = live[:, None] & held & ~held_before
        shown = hidden & (pins[:, :, 3] > 0.5)
        near = np.where(shown, pins[:, :, 0] > 0.0, near)
        hidden &= ~shown
        grasped_ever |= new
        for world, pin in zip(*np.nonzero(new)):
            offsets.append((pins[world, pin, :3] - own[world, :3]) * env.workspace_range)
        grasps += new.sum(axis=1)
        drops += (live[:, None] & held_before & ~held & ~gone).sum(axis=1)
        carry_steps += live & held.any(axis=1)
        info = infos["grasper"]
        delivered = np.where(live, info["debris_delivered"], delivered)
        success |= live & info["is_success"]
        done |= terminations["grasper"] | truncations["grasper"]
        held_before = held
    env.close()
    offsets = np.asarray(offsets).reshape(-1, 3)
    gone = slots(observations["grasper"])[:, :, 5] > 0.5
    by_side = {side: {"pins": int(mask.sum()), "grasped": int((grasped_ever & mask).sum()),
                      "delivered": int((gone & mask).sum())}
               for side, mask in (("near", near & ~hidden), ("far", ~near & ~hidden))}
    undeliverable = offsets[:, 0] < UNDELIVERABLE_OFFSET_X
    return {"suction": suction, "grasper": grasper, "episodes": episodes, "seed": seed, "noise": noise,
            "success_rate": float(success.mean()), "mean_debris_delivered": float(delivered.mean()),
            "mean_grasps": float(grasps.mean()), "undeliverable_grasp_fraction": float(undeliverable.mean())
            if len(offsets) else 0.0, "mean_drops": float(drops.mean()), "mean_carry_steps": float(carry_steps.mean()),
            "grasp_offset_x_mm_percentiles_5_25_50_75_95": np.percentile(offsets[:, 0] * 1000, [5, 25, 50, 75, 95])
            .round(1).tolist() if len(offsets) else [],
            "episodes_by_debris_delivered": np.bincount(delivered.astype(int), minlength=count + 1).tolist(),
            "pins_by_cavity": by_side}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grasper", required=True, help="scripted, a shipped policy name or a policy folder")
    parser.add_argument("--suction", default="scripted")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=teams.EVAL_SEED)
    parser.add_argument("--noise", action="store_true", help="learned seats act with their exploration noise")
    args = parser.parse_args()
    print(json.dumps(audit(args.suction, args.grasper, args.episodes, args.seed, args.noise), indent=1))


if __name__ == "__main__":
    main()
