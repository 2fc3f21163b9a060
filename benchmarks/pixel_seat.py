"""The seat that sees the endoscope beside every partner kind, on the training looks and on held-out ones.

A pixel suction (``--pixel``, a policy folder that ``dvrl-marl train suction_pixels_dagger`` wrote: the endoscope's
image and its own tip and valve) and the privileged seat it was distilled from (``marl-suction``: blood volumes, pin
and tip positions) play beside the same partners as in ``benchmarks/partner_zoo.py`` (the scripted surgeon, the
Reach + Pick pipeline, the measured person and each held-out kind), by their default call, on test seeds, with a
person's 6,000-step horizon. The pixel seat plays once per look (``image_appearance``: ``"train"``, the range it
trained in; ``"held_out"``, outside it; ``"held_out_light"`` and the like, one quantity outside it); the privileged
seat sees no image, so one row per partner.

    python benchmarks/pixel_seat.py --pixel FOLDER [--episodes 50] [--partners scripted pipeline ...]
                                    [--looks train held_out scene] [--raise-blood 0.02]
                                    [--acting marl-suction-yielding] [--keep-clear-mm 12] [--full-above 0.85]
                                    [--exact]
                                    [--json FILE]

Prints per partner and look: success, median steps, contact steps, tip path; and the pixel seat's gap to the
privileged seat (the target: within 5 points on the training looks, at least 90 % on held-out ones, contacts at most
the privileged seat's + 2).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from partner_zoo import PARTNERS, evaluate

from dvrl_marl import policies
from dvrl_marl.agents.collaborative import YieldingSuction
from dvrl_marl.envs import suction_debris_v8
from dvrl_marl.envs.endoscope import APPEARANCES


def raised(policy, amount: float):
    """``--raise-blood``: the seat's blood estimates (those it keeps at their lowest) raised by ``amount`` more than
    its ``estimate_margin``: a larger margin tried without training again."""
    if policy.encoder is None or policy.encoder.keep_lowest is None:
        raise ValueError("--raise-blood: the pixel seat keeps no estimate at its lowest (no blood estimates named)")
    weights, bias = policy.encoder.readout
    policy.encoder.readout = (weights, bias + np.float32(amount) * policy.encoder.keep_lowest)
    return policy


def acting_as(policy, name: str):
    """``--acting``: the pixel seat's estimates read by another privileged seat (its network in place of the teacher's,
    the image's read-out kept): what a different teacher would make of the same estimates, without training again."""
    acting = policies.load(name)
    if acting.encoder is not None or acting.spec.get("features") != policy.spec.get("features") \
            or [w.shape for w, _ in acting.weights] != [w.shape for w, _ in policy.weights]:
        raise ValueError(f"--acting {name}: not a privileged seat reading the observation the pixel seat fills "
                         f"({policy.spec.get('teacher')}'s)")
    policy.weights = acting.weights
    return policy


def keeping_clear(policy, keep_mm: float):
    """``--keep-clear-mm``: the pixel seat withholding the moves that would bring its instrument within ``keep_mm``
    of the other's, the yielding suction's rule on its own estimate of the other tip, without training again."""
    if policy.encoder is None or policy.encoder.fills is None:
        raise ValueError("--keep-clear-mm: the pixel seat does not fill an observation with the other tip to read")
    env = suction_debris_v8.parallel_env()
    policy.keep_clear = YieldingSuction(env.layout(), env.observation_layout, env.workspace_range, keep_mm).rule
    env.close()
    return policy


def feeling_contact(policy, settings: list[float]):
    """``--felt-contact NEAR_MM RETREAT_MM HOLD_STEPS THRESHOLD_MM``: the pixel seat keeping back from where its own
    moves were stopped near the other instrument (``policy.json``'s ``felt_contact``), without training again."""
    from dvrl_marl.policies.felt_contact import FeltContact
    from dvrl_marl.suction_debris.scripted_team import felt_contact_rule

    if policy.keep_clear is None:
        raise ValueError("--felt-contact reads keep_clear's geometry: give --keep-clear-mm too")
    near_mm, retreat_mm, hold_steps, threshold_mm = settings
    env = suction_debris_v8.parallel_env()
    rule = felt_contact_rule(env.workspace_range, near_mm, retreat_mm, hold_steps, threshold_mm)
    env.close()
    policy.spec["felt_contact"] = rule
    policy.felt_contact = FeltContact(rule, policy.keep_clear)
    return policy


def reading_full_above(policy, threshold: float):
    """``--full-above``: the pixel seat's blood estimates (those it keeps at their lowest) at ``threshold`` or more read
    as full (``image.fills.full_above``), without training again."""
    if policy.encoder is None or policy.encoder.keep_lowest is None:
        raise ValueError("--full-above: the pixel seat keeps no estimate at its lowest (no blood estimates named)")
    if not 0.0 < threshold <= 1.0:
        raise ValueError(f"--full-above: a share of a cavity's blood in (0, 1], got {threshold}")
    policy.encoder.full_above = threshold
    return policy


def exactly_filled(policy, state: np.ndarray) -> np.ndarray:
    """The observation a pixel seat fills for its teacher with the truth from ``state`` where it has estimates."""
    return policy.encoder.filled(state[..., policy.encoder.proprioception], state[..., policy.encoder.fills[1]])


class ExactEstimates:
    """``--exact``: the pixel seat's teacher on what the seat fills, its estimates exact (no image drawn): the most a
    perfect read-out of the image could give that seat."""

    def __init__(self, folder):
        self.pixel = policies.load(folder)
        if self.pixel.encoder is None or self.pixel.encoder.fills is None:
            raise ValueError(f"--exact: {folder} does not fill its teacher's observation from the image")
        self.teacher = policies.load(self.pixel.spec["teacher"])

    def __call__(self, observation) -> np.ndarray:
        return self.teacher(exactly_filled(self.pixel, np.asarray(observation, dtype=np.float64)))


def keeping_lowest(folder):
    """``--keep-lowest``: a pixel seat exported before ``image.fills.keep_lowest`` existed, tried with it (each
    estimate the lowest its episode has seen, world by world; the evaluation starts the episodes)."""
    policy = policies.load(folder)
    if policy.encoder is None or policy.encoder.fills is None:
        raise ValueError(f"--keep-lowest: {folder} does not fill its teacher's observation from the image")
    policy.encoder.keep_lowest = np.ones(len(policy.encoder.fills[1]), dtype=bool)
    return policy


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--episodes", type=int, default=50, help="test seeds per row")
    parser.add_argument("--pixel", required=True,
                        help="the seat that sees the endoscope: a policy folder (runs/<name>-seed<N>/policies/<name>)")
    parser.add_argument("--privileged", default="marl-suction", help="the seat it was distilled from")
    parser.add_argument("--partners", nargs="+", default=list(PARTNERS), choices=PARTNERS)
    parser.add_argument("--looks", nargs="*", default=["train", "held_out"], choices=[*APPEARANCES, "scene"],
                        help="scene: the scene's own look (no image_appearance), as a person's view draws it; "
                             "held_out_light (colour, camera, noise): that quantity alone held out; none: no pixel row")
    parser.add_argument("--keep-lowest", action="store_true",
                        help="the pixel seat keeps the lowest of each estimate in its episode (a policy exported "
                             "without image.fills.keep_lowest, tried with it)")
    parser.add_argument("--raise-blood", type=float, default=0.0,
                        help="add this to the seat's blood estimates, beyond the margin it was exported with")
    parser.add_argument("--acting", help="another privileged seat acting on the pixel seat's estimates (a policy "
                                          "name or folder reading the same observation as its teacher)")
    parser.add_argument("--keep-clear-mm", type=float,
                        help="the pixel seat withholds the moves that would bring its instrument within this of the "
                             "other's (the yielding suction's rule, on its estimate of the other tip)")
    parser.add_argument("--felt-contact", type=float, nargs=4, metavar=("NEAR_MM", "RETREAT_MM", "HOLD", "MM"),
                        help="keep back RETREAT_MM from a touch for HOLD steps: a move MM short of its command with "
                             "the other instrument within NEAR_MM (as estimated)")
    parser.add_argument("--full-above", type=float,
                        help="the seat's blood estimates at this or more read as full (image.fills.full_above)")
    parser.add_argument("--exact", action="store_true",
                        help="also a row of its teacher on what the seat fills, the estimates exact (no image)")
    parser.add_argument("--json", type=Path, help="write the rows here")
    args = parser.parse_args()
    rows = []
    print(f"{'partner':10s} {'player':14s} {'look':16s} {'success':>8s} {'median steps':>13s} {'contacts':>9s} "
          f"{'tip path mm':>12s} {'gap':>6s} {'seconds':>8s}", flush=True)
    for partner in args.partners:
        began = time.perf_counter()
        privileged = evaluate("suction", args.privileged, partner, args.episodes, False)
        privileged.update(look=None, seconds=round(time.perf_counter() - began, 1))
        rows.append(privileged)
        runs = [(privileged, "-")]
        if args.exact:
            began = time.perf_counter()
            exact = evaluate("suction", ExactEstimates(args.pixel), partner, args.episodes, False)
            exact.update(player="exact estimates", look=None, seconds=round(time.perf_counter() - began, 1),
                         gap=round(exact["success_rate"] - privileged["success_rate"], 3))
            rows.append(exact)
            runs.append((exact, "-"))
        for look in args.looks:
            began = time.perf_counter()
            pixel = keeping_lowest(args.pixel) if args.keep_lowest else policies.load(args.pixel)  # fresh per look
            if args.raise_blood:
                pixel = raised(pixel, args.raise_blood)
            if args.acting:
                pixel = acting_as(pixel, args.acting)
            if args.keep_clear_mm:
                pixel = keeping_clear(pixel, args.keep_clear_mm)
            if args.felt_contact:
                pixel = feeling_contact(pixel, args.felt_contact)
            if args.full_above:
                pixel = reading_full_above(pixel, args.full_above)
            row = evaluate("suction", pixel, partner, args.episodes, False,
                           **({} if look == "scene" else {"image_appearance": look}))
            row["player"] = (str(args.pixel) + (" (keeping the lowest)" if args.keep_lowest else "")
                             + (f" (blood raised {args.raise_blood:+.3f})" if args.raise_blood else "")
                             + (f" (acting: {args.acting})" if args.acting else "")
                             + (f" (keeping {args.keep_clear_mm:g} mm clear)" if args.keep_clear_mm else "")
                             + (f" (full above {args.full_above:g})" if args.full_above else "")
                             + (" (felt contact {:g} mm, {:g} mm, {:g} steps, {:g} mm)".format(*args.felt_contact)
                                if args.felt_contact else ""))
            row.update(look=look, seconds=round(time.perf_counter() - began, 1),
                       gap=round(row["success_rate"] - privileged["success_rate"], 3))
            rows.append(row)
            runs.append((row, look))
        for row, look in runs:
            median = row["median_steps_to_completion"]
            gap = row.get("gap")
            print(f"{partner:10s} {row['player']:14s} {look:16s} {row['success_rate']:8.2f} "
                  f"{'-' if median is None else f'{median:.0f}':>13s} {row['mean_contact_steps']:9.1f} "
                  f"{row['tip_path_mm']:12.0f} {'' if gap is None else f'{gap:+.2f}':>6s} {row['seconds']:8.0f}",
                  flush=True)
        if args.json:  # as it goes: a long run keeps what it measured
            args.json.write_text(json.dumps({"episodes": args.episodes, "rows": rows}, indent=2) + "\n")


if __name__ == "__main__":
    main()
