"""Why a pixel seat fails: its blood estimates against the truth, world by world, beside a partner.

The pixel suction (``--pixel``, a seat that fills its teacher's observation from the image and keeps each cavity's
blood estimate at its lowest) plays ``--episodes`` test seeds on one look beside ``--partner`` (the scripted surgeon
unless named); at every step its raw estimates of the blood left, the lowest it keeps (what its teacher reads) and
the truth are recorded. Both estimates carry the margin the seat was exported with (it is in the read-out's bias),
and ``--raise-blood``'s.

    python benchmarks/pixel_seat_trace.py --pixel FOLDER [--look held_out] [--episodes 20] [--first 0]
                                          [--partner in-the-way]
                                          [--raise-blood 0.02] [--near-mm 15]
                                          [--keep-clear-mm 14] [--full-above 0.85]
                                          [--felt-contact 30 2 100 0.3]

Prints per world: success and steps; the truth and the kept estimate per cavity at its end; the kept estimate's
least and greatest error over its episode, and the raw estimate's 1st and 99th percentile of error. A seat that left
a cavity early shows a kept estimate under the task's threshold beside a truth above it. Then the other estimates'
error (the other arm's tip: the largest of its coordinates' errors, in the observation's units) and how far the
seat's action is from its teacher's given the truth in the estimates' place: a seat that goes elsewhere than its
teacher would, its blood estimates right, was led there by the rest (and the distance again given the true
blood alone, the rest as estimated: small where the rest made the seat's action). Where the two tips came within
``--near-mm`` of each other (where it must wait for the other instrument): the world's contact steps, the other tip's
error there, how far its action was from its teacher's given the truth, and in how many of those steps its own tip
moved 0.3 mm or more short of its command (stopped by the other instrument, a wall or a joint limit: what a seat's
joints feel).
"""

from __future__ import annotations

import argparse

import numpy as np
from partner_zoo import PARTNERS, partner_seat
from pixel_seat import exactly_filled, feeling_contact, keeping_clear, raised, reading_full_above

from dvrl_marl import policies
from dvrl_marl.envs import suction_debris_v8
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
        self.other_at = np.asarray(estimates_at)[~self.blood]  # the rest it estimates (the other arm's tip)
        self.teacher = policies.load(policy.spec["teacher"])
        self.raw, self.kept, self.truth, self.other_error, self.action_gap = [], [], [], [], []
        self.blood_only_gap, self.apart_mm, self.short_mm = [], [], []
        self._last = None  # the own tip and the move sent at the last call
        env = suction_debris_v8.parallel_env()  # where the tips are in the observation, and its unit
        self.own_tip, self.other_tip = env.observation_layout["own_tip"], env.observation_layout["other_tip"]
        self.mm_per_unit = 1000.0 * env.workspace_range
        self.step = env.layout().gain ** -1  # an action of 1 moves the tip this far (observation units)
        env.close()

    def reset(self, worlds=None):
        self.policy.reset(worlds)

    def __call__(self, observation):
        action = self.policy(observation)
        # encoded a second time: the policy keeps only the lowest (a diagnostic, not a seat's step); an offset read
        # (fills.relative) is in the observation's terms here
        state = np.asarray(observation["observation"], dtype=np.float64)
        self.apart_mm.append(self.mm_per_unit * np.linalg.norm(state[:, self.own_tip] - state[:, self.other_tip],
                                                               axis=1))
        estimates = self.policy.encoder.estimates(self.policy.encoder.image(observation),
                                                  state[:, self.policy.encoder.proprioception])
        # how far short of its last command the own tip moved (mm): a move the other instrument or a wall stopped
        tip = state[:, self.own_tip]
        self.short_mm.append(np.zeros(len(state)) if self._last is None else self.mm_per_unit * np.linalg.norm(
            self._last[1] - (tip - self._last[0]), axis=1))
        self._last = (tip.copy(), np.asarray(action, dtype=np.float64)[:, :3] * self.step)
        self.raw.append(estimates[:, self.blood])
        self.kept.append(self.policy.encoder._lowest[:, self.blood].copy())
        self.truth.append(state[:, self.truth_at])
        self.other_error.append(np.abs(estimates[:, ~self.blood] - state[:, self.other_at]).max(axis=1)
                                if self.other_at.size else np.zeros(len(state)))
        # what its teacher does given the truth where the seat has estimates (the rest as the seat fills it): where
        # the two part, the estimates led the seat elsewhere
        exact = exactly_filled(self.policy, state)
        self.action_gap.append(np.abs(action - self.teacher(exact)).max(axis=1))
        # the same with the true blood alone (the rest as estimated): small where the rest made the seat's action
        exact[:, self.other_at] = estimates[:, ~self.blood]
        self.blood_only_gap.append(np.abs(action - self.teacher(exact)).max(axis=1))
        return action


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--pixel", required=True, help="the pixel seat's policy folder")
    parser.add_argument("--look", default="held_out", choices=[*sorted(APPEARANCES), "scene"],
                        help="scene: the scene's own look (no image_appearance), as a person's view draws it")
    parser.add_argument("--episodes", type=int, default=20, help="test seeds")
    parser.add_argument("--first", type=int, default=0,
                        help="the first test seed (world j plays seed first + j; a partner kind drawn per world, such "
                             "as in-the-way, fills world j with its member j, so only the scripted and pipeline "
                             "partners replay a world of a longer run)")
    parser.add_argument("--partner", default="scripted", choices=PARTNERS, help="the partner kind at the LND")
    parser.add_argument("--raise-blood", type=float, default=0.0,
                        help="add this to the seat's blood estimates, beyond the margin it was exported with")
    parser.add_argument("--keep-clear-mm", type=float,
                        help="the seat keeps this clear of the other instrument (benchmarks/pixel_seat.py's)")
    parser.add_argument("--full-above", type=float,
                        help="its blood estimates at this or more read as full (benchmarks/pixel_seat.py's)")
    parser.add_argument("--felt-contact", type=float, nargs=4, metavar=("NEAR_MM", "RETREAT_MM", "HOLD", "MM"),
                        help="the felt-contact rule (benchmarks/pixel_seat.py's)")
    parser.add_argument("--near-mm", type=float, default=15.0,
                        help="the steps where the two tips are within this: the other tip's error and the action's "
                             "gap from the teacher's there")
    args = parser.parse_args()
    policy = policies.load(args.pixel)
    if policy.encoder is None or policy.encoder.keep_lowest is None:
        parser.error(f"--pixel {args.pixel}: the seat keeps no blood estimate at its lowest (image.fills.keep_lowest)")
    if args.keep_clear_mm:
        policy = keeping_clear(policy, args.keep_clear_mm)
    if args.full_above:
        policy = reading_full_above(policy, args.full_above)
    if args.felt_contact:
        policy = feeling_contact(policy, args.felt_contact)
    seat = Traced(raised(policy, args.raise_blood))
    result = teams.evaluate_team_batched({"suction": seat, "grasper": partner_seat(args.partner, "grasper")},
                                         args.episodes, seed=teams.EVAL_SEED + args.first, max_cycles=6000,
                                         **({} if args.look == "scene" else {"image_appearance": args.look}))
    raw, kept, truth, other_error, gap, blood_only_gap, apart, short = (
        np.stack(part) for part in (seat.raw, seat.kept, seat.truth, seat.other_error, seat.action_gap,
                                    seat.blood_only_gap, seat.apart_mm, seat.short_mm))
    print(f"success {result['success_rate']:.2f} ({args.look} looks, beside {args.partner}, {args.episodes} episodes), "
          f"contact steps {result['mean_contact_steps']:.1f}")
    for world in range(args.episodes):
        end = result["steps"][world]
        error, raw_error = kept[:end, world] - truth[:end, world], raw[:end, world] - truth[:end, world]
        print(f"world {args.first + world:3d} {'ok  ' if result['success'][world] else 'FAIL'} steps {end:5d}  "
              f"end: truth {np.round(truth[end - 1, world], 3)} kept {np.round(kept[end - 1, world], 3)}  "
              f"kept - truth: least {np.round(error.min(0), 3)} most {np.round(error.max(0), 3)}  "
              f"raw - truth: 1st / 99th pct {np.round(np.percentile(raw_error, 1, axis=0), 3)} "
              f"{np.round(np.percentile(raw_error, 99, axis=0), 3)}  "
              f"other tip's error: median {np.median(other_error[:end, world]):.3f} "
              f"99th pct {np.percentile(other_error[:end, world], 99):.3f}  "
              f"|action - teacher's|: mean {gap[:end, world].mean():.2f} > 0.5 in "
              f"{(gap[:end, world] > 0.5).mean():.0%} of steps, given the true blood alone: mean "
              f"{blood_only_gap[:end, world].mean():.2f}")
        near = apart[:end, world] < args.near_mm
        if near.any():  # where it must wait for the other instrument: what it read and did there
            print(f"          contact steps {result['contact_steps'][world]:4d}; tips within {args.near_mm:g} mm in "
                  f"{near.sum():4d} steps: other tip's error median {np.median(other_error[:end, world][near]):.3f}, "
                  f"|action - teacher's| mean {gap[:end, world][near].mean():.2f} (> 0.5 in "
                  f"{(gap[:end, world][near] > 0.5).mean():.0%}); its own move 0.3 mm or more short of its command "
                  f"in {(short[:end, world][near] >= 0.3).sum()} of them")


if __name__ == "__main__":
    main()
