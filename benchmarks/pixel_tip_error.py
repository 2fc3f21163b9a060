"""How precisely a pixel seat reads the other arm's tip, look by look: on the training looks, with held-out
quantities alone or together, and on the whole held-out range.

The pixel seat (``--pixel``, one that estimates the other arm's tip) plays ``--episodes`` test seeds beside the
scripted surgeon on each look; at every step the largest of its tip estimate's coordinate errors is recorded (in the
observation's units). A look is ``train``, ``held_out``, or held-out quantities joined by ``+`` (``colour``,
``light``, ``camera``, ``noise``: :func:`dvrl_marl.envs.endoscope.held_out_only`, the rest as in training).

    python benchmarks/pixel_tip_error.py --pixel FOLDER [--episodes 16]
                                         [--looks train colour light camera noise colour+light held_out]

Prints per look: success, the median over worlds of each world's median error, the worst world's median, and the
median over worlds of each world's 90th percentile.
"""

from __future__ import annotations

import argparse

import numpy as np
from partner_zoo import partner_seat
from pixel_seat_trace import Traced

from dvrl_marl import policies
from dvrl_marl.envs.endoscope import APPEARANCES, held_out_only
from dvrl_marl.training import teams


def appearance(look: str):
    """``train``, ``held_out``, or held-out quantities joined by ``+`` (held_out_only names a wrong one)."""
    return APPEARANCES[look] if look in ("train", "held_out") else held_out_only(*look.split("+"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--pixel", required=True, help="the pixel seat's policy folder")
    parser.add_argument("--episodes", type=int, default=16, help="test seeds")
    parser.add_argument("--looks", nargs="+", type=str,
                        default=["train", "colour", "light", "camera", "noise", "colour+light", "held_out"])
    args = parser.parse_args()
    try:
        looks = {look: appearance(look) for look in args.looks}
    except ValueError as error:
        parser.error(f"--looks: a look is train, held_out or held-out quantities joined by '+': {error}")
    policy = policies.load(args.pixel)
    if policy.encoder is None or policy.encoder.keep_lowest is None or policy.encoder.keep_lowest.all():
        parser.error(f"--pixel {args.pixel}: the seat estimates no other arm's tip")
    for look, drawn in looks.items():
        seat = Traced(policies.load(args.pixel))
        result = teams.evaluate_team_batched({"suction": seat, "grasper": partner_seat("scripted", "grasper")},
                                             args.episodes, seed=teams.EVAL_SEED, max_cycles=3000,
                                             image_appearance=drawn)
        error = np.stack(seat.other_error)
        ends = result["steps"]
        medians = [np.median(error[:ends[world], world]) for world in range(args.episodes)]
        high = [np.percentile(error[:ends[world], world], 90) for world in range(args.episodes)]
        print(f"{look:14s} success {result['success_rate']:.2f}  the other tip's error: median of the worlds' "
              f"medians {np.median(medians):.3f}, worst world {max(medians):.3f}, median of the worlds' 90th "
              f"percentiles {np.median(high):.3f}", flush=True)


if __name__ == "__main__":
    main()
