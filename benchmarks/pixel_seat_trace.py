"""Why a pixel seat fails: its blood estimates against the truth, world by world, beside the scripted surgeon.

The pixel suction (``--pixel``, a seat that fills its teacher's observation from the image and keeps each cavity's
blood estimate at its lowest) plays ``--episodes`` test seeds on one look; at every step its raw estimates of the
blood left, the lowest it keeps (what its teacher reads) and the truth are recorded. Both estimates carry the margin
the seat was exported with (it is in the read-out's bias), and ``--raise-blood``'s.

    python benchmarks/pixel_seat_trace.py --pixel FOLDER [--look held_out] [--episodes 20] [--raise-blood 0.02]

Prints per world: success and steps; the truth and the kept estimate per cavity at its end; the kept estimate's
least and greatest error over its episode, and the raw estimate's 1st and 99th percentile of error. A seat that left
a cavity early shows a kept estimate under the task's threshold beside a truth above it.
"""

from __future__ import annotations

import argparse

import numpy as np
from pixel_seat import raised

from dvrl_marl import policies
from dvrl_marl.envs.endoscope import APPEARANCES
from dvrl_marl.training import teams


class Traced:
    """The pixel seat, recording its raw and kept blood estimates and the truth at every call."""

    def __init__(self, policy):
        self.policy = policy
        self.image_options = policy.image_options
        _, estimates_at = policy.encoder.fills
        self.blood = policy.encoder.keep_lowest  # over the read-out's outputs
        self.truth_at = np.asarray(estimates_at)[self.blood]  # the observation's indices of the blood left
        self.raw, self.kept, self.truth = [], [], []

    def reset(self, worlds=None):
        self.policy.reset(worlds)

    def __call__(self, observation):
        action = self.policy(observation)
        # encoded a second time: the policy keeps only the lowest (a diagnostic, not a seat's step)
        self.raw.append(self.policy.encoder(observation["image"])[:, self.blood])
        self.kept.append(self.policy.encoder._lowest[:, self.blood].copy())
        self.truth.append(np.asarray(observation["observation"])[:, self.truth_at])
        return action


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--pixel", required=True, help="the pixel seat's policy folder")
    parser.add_argument("--look", default="held_out", choices=sorted(APPEARANCES))
    parser.add_argument("--episodes", type=int, default=20, help="test seeds")
    parser.add_argument("--raise-blood", type=float, default=0.0,
                        help="add this to the seat's blood estimates, beyond the margin it was exported with")
    args = parser.parse_args()
    policy = policies.load(args.pixel)
    if policy.encoder is None or policy.encoder.keep_lowest is None:
        parser.error(f"--pixel {args.pixel}: the seat keeps no blood estimate at its lowest (image.fills.keep_lowest)")
    seat = Traced(raised(policy, args.raise_blood))
    result = teams.evaluate_team_batched({"suction": seat, "grasper": teams.seat("scripted", "grasper")},
                                         args.episodes, max_cycles=6000, image_appearance=args.look)
    raw, kept, truth = (np.stack(part) for part in (seat.raw, seat.kept, seat.truth))
    print(f"success {result['success_rate']:.2f} ({args.look} looks, {args.episodes} episodes)")
    for world in range(args.episodes):
        end = result["steps"][world]
        error, raw_error = kept[:end, world] - truth[:end, world], raw[:end, world] - truth[:end, world]
        print(f"world {world:3d} {'ok  ' if result['success'][world] else 'FAIL'} steps {end:5d}  "
              f"end: truth {np.round(truth[end - 1, world], 3)} kept {np.round(kept[end - 1, world], 3)}  "
              f"kept - truth: least {np.round(error.min(0), 3)} most {np.round(error.max(0), 3)}  "
              f"raw - truth: 1st / 99th pct {np.round(np.percentile(raw_error, 1, axis=0), 3)} "
              f"{np.round(np.percentile(raw_error, 99, axis=0), 3)}")


if __name__ == "__main__":
    main()
