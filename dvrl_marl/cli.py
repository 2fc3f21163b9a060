"""The ``dvrl-marl`` command line."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

__all__ = ["main"]


def _render(args) -> int:
    import imageio.v3 as iio

    from dvrl_marl.preview import render_scene, scene_summary

    image = render_scene(args.scene, width=args.width, height=args.height)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(out, image)
    print(scene_summary(args.scene))
    print(f"wrote {out} ({image.shape[1]}x{image.shape[0]}, camera 'endoscope')")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="dvrl-marl", description="dVRK reinforcement-learning environments on MuJoCo")
    sub = parser.add_subparsers(dest="command", required=True)
    render = sub.add_parser("render", help="render a scene from its endoscope camera and print a summary")
    render.add_argument("--scene", default="collaborative", help="scene name in scenes/ (default: collaborative)")
    render.add_argument("--out", default="collaborative.png", help="PNG file to write")
    render.add_argument("--width", type=int, default=640)
    render.add_argument("--height", type=int, default=480)
    render.set_defaults(func=_render)
    return parser


def main(argv: list[str] | None = None) -> int:
    import dvrl_marl  # noqa: F401  (sets MUJOCO_GL=egl on headless machines before MuJoCo loads)

    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (FileNotFoundError, ValueError) as error:
        print(f"dvrl-marl: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
