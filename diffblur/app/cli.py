"""The `diffblur` command (also `python -m diffblur`)."""

from __future__ import annotations

import argparse
import sys

import numpy as np


def _demo(args: argparse.Namespace) -> int:
    from diffblur.app.demo import format_table, run_demo

    path, results, fits = run_demo(args.out, scene_name=args.scene, size=args.size, fit=not args.no_fit)
    print(format_table(results, fits))
    print(f"wrote {path}")
    return 0


def _gallery(args: argparse.Namespace) -> int:
    from diffblur.scenes import save_preset_gallery

    print(f"wrote {save_preset_gallery(args.out, height=args.size, width=args.size)}")
    return 0


def _blur(args: argparse.Namespace) -> int:
    from diffblur.app.blur_image import DEPTH_METHODS, blur_image, check_output_path, default_method, load_inputs, method_options, spread_warning, write_picture

    # Everything the command line decides is checked before the photograph is read and blurred.
    depth_given = args.depth_file is not None or args.depth_image is not None
    method = args.method or default_method(depth_given)
    if depth_given and method not in DEPTH_METHODS:
        flag = "--depth-file" if args.depth_file is not None else "--depth-image"
        raise ValueError(f"{flag}: method {method!r} does not read depth; use --method {' or '.join(DEPTH_METHODS)}, or drop the depth")
    options = method_options(method, samples=args.samples, iterations=args.iterations, max_radius=args.max_radius, shutter=args.shutter)
    check_output_path(args.out)
    inputs = load_inputs(
        args.image,
        velocity=args.velocity,
        velocity_file=args.velocity_file,
        velocity_image=args.velocity_image,
        max_speed=args.max_speed,
        depth_file=args.depth_file,
        depth_image=args.depth_image,
    )
    height, width = inputs.color.shape[2:]
    speed = float(np.hypot(*inputs.velocity[0]).max())
    warning = spread_warning(speed * args.exposure, height, width)
    if warning is not None:
        print(f"diffblur blur: warning: {warning}", file=sys.stderr)
    blurred = blur_image(inputs, method=method, backend=args.backend, exposure=args.exposure, **options)
    write_picture(args.out, blurred)
    print(f"blurred {args.image} ({width}x{height}, up to {speed:.1f} px) with {method} on {args.backend}: wrote {args.out}")
    return 0


def _bench(args: argparse.Namespace) -> int:
    from diffblur.app.bench import run_benchmarks

    scenes = tuple(args.scenes.split(",")) if args.scenes else None
    run_benchmarks(out_dir=args.out, quick=args.quick, height=args.size, width=args.size, scenes=scenes, backends=tuple(args.backends.split(",")), repeats=args.repeats, targets=args.targets, threads=args.threads)
    print(f"wrote {args.out}/BENCHMARKS.md, {args.out}/docs/benchmarks.json, {args.out}/docs/pareto.png")
    return 0


def _synth(args: argparse.Namespace) -> int:
    import time

    from diffblur.app.synth import SynthOptions, synthesize_folder

    options = SynthOptions(
        motions=tuple(args.motions.split(",")),
        length=tuple(args.length),
        shutters=tuple(args.shutters.split(",")),
        response=args.response,
        highlight_gain=tuple(args.highlight_gain),
        shot_noise=tuple(args.shot_noise),
        read_noise=tuple(args.read_noise),
        jpeg_quality=None if args.jpeg is None else tuple(args.jpeg),
        exposure=args.exposure,
    )
    start = time.perf_counter()
    records = synthesize_folder(args.in_dir, args.out_dir, seed=args.seed, options=options, segmentation=args.segmentation, sequence=args.sequence, estimate_flows=args.estimate_flow, workers=args.workers)
    made = [r for r in records if "skipped" not in r]
    for record in records:
        if "skipped" in record:
            print(f"skipped {record['source']}: {record['skipped']}", file=sys.stderr)
    print(f"wrote {len(made)} pairs to {args.out_dir} in {time.perf_counter() - start:.1f} s")
    return 0


def _add_synth_parser(commands) -> None:
    from diffblur.shutters import SHUTTERS
    from diffblur.app.synth import MOTIONS

    synth = commands.add_parser(
        "synth",
        help="blurred/sharp pairs from sharp photographs, for deblurring datasets",
        description="For each image of IN_DIR: a seeded random motion, a camera model around the blur (inverse sRGB response, "
        "highlights past white, blur, saturation, Poisson-Gaussian noise, response, optional JPEG); writes NAME_sharp.png, "
        "NAME_blurred.png (.jpg) and NAME.json with every parameter (diffblur.app.synth.reproduce makes the pair again).",
    )
    synth.add_argument("in_dir", help="folder of sharp photographs (or of a sequence's frames with --sequence)")
    synth.add_argument("out_dir", help="folder for the pairs")
    synth.add_argument("--seed", type=int, default=0, help="seed of every random choice (default: 0)")
    synth.add_argument("--motions", default="pan,shake", help=f"comma-separated, drawn per image: {', '.join(MOTIONS)} (objects needs --segmentation) (default: pan,shake)")
    synth.add_argument("--length", type=float, nargs=2, default=(4.0, 30.0), metavar=("LOW", "HIGH"), help="path length over the exposure, px (default: 4 30)")
    synth.add_argument("--shutters", default="box", help=f"comma-separated, drawn per image: {', '.join(SHUTTERS)} (default: box)")
    synth.add_argument("--response", default="srgb", choices=("srgb", "linear"), help="camera response around the blur (default: srgb)")
    synth.add_argument("--highlight-gain", type=float, nargs=2, default=(1.0, 4.0), metavar=("LOW", "HIGH"), help="brightness of clipped highlights, times white (default: 1 4)")
    synth.add_argument("--shot-noise", type=float, nargs=2, default=(0.0, 0.01), metavar=("LOW", "HIGH"), help="Poisson part of the noise variance, per unit of linear light (default: 0 0.01)")
    synth.add_argument("--read-noise", type=float, nargs=2, default=(0.0, 0.01), metavar=("LOW", "HIGH"), help="Gaussian noise sigma, linear light (default: 0 0.01)")
    synth.add_argument("--jpeg", type=int, nargs=2, default=None, metavar=("LOW", "HIGH"), help="JPEG quality range of the blurred image (default: PNG, no JPEG)")
    synth.add_argument("--segmentation", default=None, help="folder of NAME.png label pictures (0 = background): motion 'objects' gives each label its own motion")
    synth.add_argument("--sequence", action="store_true", help="IN_DIR holds a sequence's frames: blur each frame along its flows (NAME.prev.flo and NAME.next.flo next to it)")
    synth.add_argument("--estimate-flow", action="store_true", help="with --sequence, estimate missing flows from the neighbouring frames (needs the 'flow' extra: OpenCV)")
    synth.add_argument("--exposure", type=float, default=1.0, help="with --sequence, the fraction of the frame interval the shutter is open (default: 1)")
    synth.add_argument("--workers", type=int, default=1, help="processes (default: 1)")
    synth.set_defaults(run=_synth)


def _add_fit(commands) -> None:
    """`diffblur fit` (fitting/cli.py); its module imports no framework until a fit runs."""
    from fitting.cli import add_fit_parser

    add_fit_parser(commands)


def build_parser() -> argparse.ArgumentParser:
    from diffblur.scenes import PRESETS

    parser = argparse.ArgumentParser(prog="diffblur", description="Differentiable motion blur in PyTorch and JAX.")
    commands = parser.add_subparsers(dest="command", required=True)
    demo = commands.add_parser("demo", help="blur a built-in scene with every method, compare with ground truth, write a picture")
    demo.add_argument("--out", required=True, help="folder for demo.png")
    demo.add_argument("--scene", default="translate", choices=PRESETS, help="built-in scene (default: translate)")
    demo.add_argument("--size", type=int, default=160, help="image height and width in pixels (default: 160)")
    demo.add_argument("--no-fit", action="store_true", help="skip recovering the motion by fitting")
    demo.set_defaults(run=_demo)
    gallery = commands.add_parser("gallery", help="write a picture of every built-in scene: sharp, ground truth, velocity, depth")
    gallery.add_argument("--out", required=True, help="folder for preset_gallery.png")
    gallery.add_argument("--size", type=int, default=128, help="image height and width in pixels (default: 128)")
    gallery.set_defaults(run=_gallery)
    _add_fit(commands)
    bench = commands.add_parser("bench", help="time every method and setting in both backends against ground truth: BENCHMARKS.md, docs/benchmarks.json, docs/pareto.png")
    bench.add_argument("--out", default=".", help="folder for BENCHMARKS.md and docs/ (default: .)")
    bench.add_argument("--quick", action="store_true", help="a few settings on two scenes, one repeat, no 1280x720 targets pass")
    bench.add_argument("--size", type=int, default=160, help="scene height and width in pixels (default: 160)")
    bench.add_argument("--scenes", default=None, help="comma-separated scenes: 'uniform' and the presets (default: all)")
    bench.add_argument("--backends", default="torch,jax", help="comma-separated: torch, jax (default: both)")
    bench.add_argument("--threads", type=int, default=None, help="PyTorch and fused-kernel (numba) threads (1 also turns XLA's thread pool off); default: the frameworks' own")
    bench.add_argument("--repeats", type=int, default=None, help="timed runs per measurement (default: 3, quick: 1)")
    bench.add_argument("--targets", action=argparse.BooleanOptionalAction, default=None, help="run the 1280x720 performance targets (default: unless --quick)")
    bench.set_defaults(run=_bench)
    _add_blur_parser(commands)
    _add_synth_parser(commands)
    return parser


def _add_blur_parser(commands) -> None:
    from diffblur.app.blur_image import BACKENDS
    from diffblur.ops.module import METHOD_INPUTS
    from diffblur.shutters import SHUTTERS

    blur = commands.add_parser(
        "blur",
        help="blur a photograph by a global velocity, a .npy velocity field or a painted velocity picture",
        description="Blur a photograph (sRGB PNG/JPEG; decoded to linear light, blurred, encoded again). "
        "Painted velocity picture: red = x, green = y, 8-bit level 128 = still, 255 / 1 = +/- MAX_SPEED px; "
        "painted depth picture: white = near (depth 1), black = far (depth 10); both upsampled to the photograph.",
    )
    blur.add_argument("image", help="the photograph")
    blur.add_argument("-o", "--out", required=True, help="output image (format from the suffix, e.g. .png)")
    source = blur.add_mutually_exclusive_group(required=True)
    source.add_argument("--velocity", type=float, nargs=2, metavar=("VX", "VY"), help="one velocity for the whole image, pixels (half-spread)")
    source.add_argument("--velocity-file", help=".npy velocity field, shape (2, H, W), pixels")
    source.add_argument("--velocity-image", help="painted velocity picture, any size (see above)")
    blur.add_argument("--max-speed", type=float, default=20.0, help="speed of a fully red/green painted pixel (default: 20 px)")
    depth = blur.add_mutually_exclusive_group()
    depth.add_argument("--depth-file", help=".npy positive depth, shape (1, H, W) or (H, W)")
    depth.add_argument("--depth-image", help="painted depth picture, any size (see above)")
    blur.add_argument("--method", choices=tuple(METHOD_INPUTS), help="blur method (default: reconstruct with a depth, gather without: the closest to an exact blur when nothing separates by depth)")
    blur.add_argument("--backend", default="torch", choices=BACKENDS, help="framework (default: torch)")
    blur.add_argument("--samples", type=int, help="taps or points per pixel; accumulate's instants (default: the method's)")
    blur.add_argument("--iterations", type=int, help="warp_blend's iterations (default: the method's)")
    blur.add_argument("--max-radius", type=float, help="reconstruct's largest blur radius, px (default: the method's)")
    blur.add_argument("--shutter", choices=tuple(SHUTTERS), help="shutter window (default: the method's)")
    blur.add_argument("--exposure", type=float, default=1.0, help="scale on the velocity (default: 1)")
    blur.set_defaults(run=_blur)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.run(args)
    except (ValueError, TypeError, FileNotFoundError) as error:
        print(f"diffblur {args.command}: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
