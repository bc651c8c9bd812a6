"""The `diffblur` command (also `python -m diffblur`)."""

from __future__ import annotations

import argparse
import sys


def _demo(args: argparse.Namespace) -> int:
    from diffblur.demo import format_table, run_demo

    path, results = run_demo(args.out, scene_name=args.scene, size=args.size)
    print(format_table(results))
    print(f"wrote {path}")
    return 0


def _gallery(args: argparse.Namespace) -> int:
    from diffblur.scenes import save_preset_gallery

    print(f"wrote {save_preset_gallery(args.out, height=args.size, width=args.size)}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    from diffblur.scenes import PRESETS

    parser = argparse.ArgumentParser(prog="diffblur", description="Differentiable motion blur in PyTorch and JAX.")
    commands = parser.add_subparsers(dest="command", required=True)
    demo = commands.add_parser("demo", help="blur a built-in scene with every method, compare with ground truth, write a picture")
    demo.add_argument("--out", required=True, help="folder for demo.png")
    demo.add_argument("--scene", default="crossing", choices=PRESETS, help="built-in scene (default: crossing)")
    demo.add_argument("--size", type=int, default=160, help="image height and width in pixels (default: 160)")
    demo.set_defaults(run=_demo)
    gallery = commands.add_parser("gallery", help="write a picture of every built-in scene: sharp, ground truth, velocity, depth")
    gallery.add_argument("--out", required=True, help="folder for preset_gallery.png")
    gallery.add_argument("--size", type=int, default=128, help="image height and width in pixels (default: 128)")
    gallery.set_defaults(run=_gallery)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.run(args)
    except (ValueError, TypeError, FileNotFoundError) as error:
        print(f"diffblur {args.command}: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
