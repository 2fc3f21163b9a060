"""How well the endoscope's image gives the blood left, on the training looks and on held-out ones.

The estimator of a pixel seat's configuration (``--config``, by default ``suction_pixels_estimates``: the pixel seat
that acts as its teacher on what the image tells it) fitted once per option on frames of the teacher's own episodes
(its first DAgger round: 32 worlds, training looks), then scored on frames of other episodes (12 worlds) drawn with the
training looks and with the held-out looks. Where the configuration estimates the other arm's tip too, its mean
absolute error (in the observation's units) is printed beside the blood's. The teacher leaves a cavity too early on
an estimate 0.01 too low and not on one 0.03 too high (``benchmarks/privileged_inputs.py``), so the errors that count
are those where the cavity is nearly empty.

    python benchmarks/pixel_estimates.py [--config suction_pixels_estimates] [--normalise none per_image brightness]
                                         [--colour-jitter 0 0.3] [--jitter-brightness yes no] [--shading 0 0.3]
                                         [--image-noise 0 8] [--class-jitter 0 0.3]
                                         [--looks train held_out held_out_light ...] [--updates 2500] [--json FILE]

Prints per option and look: the mean absolute error, and for a blood fraction under 0.15 the mean error, the mean
absolute error and the error's 1st and 99th percentiles.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

from dvrl_marl.cli import resolve_config
from dvrl_marl.envs.endoscope import APPEARANCES
from dvrl_marl.training import pixel_seat


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--normalise", nargs="+", default=["none", "per_image"],
                        choices=["none", "per_image", "brightness"])
    parser.add_argument("--colour-jitter", nargs="+", type=float, default=[0.0],
                        help="fit once per value too (each fitted image's channels times 1 +/- up to it)")
    parser.add_argument("--jitter-brightness", nargs="+", default=["yes"], choices=["yes", "no"],
                        help="no: the jitter's three gains divided by their mean (the colour changes, not the "
                             "brightness); fit once per value")
    parser.add_argument("--shading", nargs="+", type=float, default=[0.0],
                        help="fit once per value too (each fitted image times a gradient of light, 1 +/- up to it)")
    parser.add_argument("--image-noise", nargs="+", type=float, default=None,
                        help="fit once per value too (each fitted image plus Gaussian noise of a spread up to it); "
                             "default: the configuration's")
    parser.add_argument("--class-jitter", nargs="+", type=float, default=None,
                        help="fit once per value too (each class of each fitted image times its own gain per channel, "
                             "the frames collected with their segmentation); default: the configuration's")
    parser.add_argument("--config", default="suction_pixels_estimates",
                        help="the pixel seat's configuration (a name under baselines/configs or a file)")
    parser.add_argument("--looks", nargs="+", default=["train", "held_out"], choices=sorted(APPEARANCES),
                        help="the looks the estimates are scored on (held_out_light: that quantity alone held out)")
    parser.add_argument("--updates", type=int, default=2500, help="Adam steps of each fit")
    parser.add_argument("--json", type=Path, help="write the rows here")
    args = parser.parse_args()
    _, config = pixel_seat.load_config(resolve_config(args.config))
    blood = pixel_seat._blood_columns(config)
    noises = args.image_noise if args.image_noise is not None else [config.image_noise]
    class_jitters = args.class_jitter if args.class_jitter is not None else [config.class_jitter]
    config = config.model_copy(update={"class_jitter": max(class_jitters)})  # (collects the segmentation if any)
    began = time.perf_counter()
    fitted_on = pixel_seat.collect(config.model_copy(update={"worlds": 32}), None, 12345, 12345)
    # model_copy skips validation: the held-out looks are for scoring only, never for a fit
    scored_on = {look: pixel_seat.collect(config.model_copy(update={"worlds": 12, "image_appearance": look}), None,
                                          777, 777) for look in args.looks}
    scored = len(scored_on[args.looks[0]]['targets'])
    print(f"frames: {len(fitted_on['targets']):,d} to fit, {scored:,d} to score per look "
          f"({time.perf_counter() - began:.0f} s)", flush=True)
    rows = []
    fits = [(normalise, jitter, brightness == "yes", shading, noise, by_class) for normalise in args.normalise
            for jitter in args.colour_jitter for brightness in args.jitter_brightness for shading in args.shading
            for noise in noises for by_class in class_jitters if jitter > 0 or brightness == args.jitter_brightness[0]]
    for normalise, jitter, brightness, shading, noise, by_class in fits:
        options = pixel_seat.PixelSeatConfig(**{**config.model_dump(), "normalise": normalise,
                                                "colour_jitter": jitter, "jitter_brightness": brightness,
                                                "shading": shading, "image_noise": noise, "class_jitter": by_class})
        torch.manual_seed(0)
        model = pixel_seat.PixelActor(options, 4)
        pixel_seat.fit(model, fitted_on, options, args.updates, 0)
        for look, data in scored_on.items():
            row = {"normalise": normalise, "colour_jitter": jitter, "jitter_brightness": brightness,
                   "shading": shading, "image_noise": noise, "class_jitter": by_class, "look": look,
                   **pixel_seat.estimate_errors(model, data, blood=blood)}
            rows.append(row)
            kind = (f"jitter {jitter:.2f}" + ("" if brightness else " (colour)") + f" shading {shading:.2f}"
                    f" noise {noise:.0f} class {by_class:.2f}")
            other = (f"; the other tip's |error| {row['other_mean_absolute']:.4f}" if "other_mean_absolute" in row
                     else "")
            print(f"{normalise:10s} {kind:32s} {look:16s} mean |error| {row['mean_absolute']:.4f}; nearly "
                  f"empty: mean {row['small_mean']:+.4f}, |error| {row['small_mean_absolute']:.4f}, 1st / 99th "
                  f"percentile {row['small_first_percentile']:+.4f} / {row['small_99th_percentile']:+.4f}{other}",
                  flush=True)
        if args.json:
            args.json.write_text(json.dumps({"config": args.config, "updates": args.updates, "rows": rows}, indent=2)
                                 + "\n")


if __name__ == "__main__":
    main()
