"""The example end to end: `run(...)` renders (or reads back) the training and test scenes, trains the
model in one framework for a time budget, and reports on the test scenes; `main()` is its command line.

Threads: `threads` caps PyTorch's intra-op threads, numba's (the fused CPU kernels) and XLA's CPU
threads; it must be set before the frameworks start, so `main()` sets it first.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from examples.learn_motion.common import TrainConfig
from examples.learn_motion.data import SHUTTERS, TEST_SEED, TRAIN_SEED, dataset
from examples.learn_motion.report import evaluate, markdown, save_figure, true_motion

__all__ = ["limit_threads", "main", "run"]

HERE = Path(__file__).resolve().parent


def limit_threads(threads: int | None) -> None:
    """Cap numba's threads (the fused CPU kernels) and XLA's CPU threads: environment variables, read
    when they start, so this comes before either is imported. PyTorch's are set in `run`."""
    if not threads:
        return
    os.environ["NUMBA_NUM_THREADS"] = str(threads)
    os.environ["OMP_NUM_THREADS"] = str(threads)
    flag = f"--xla_cpu_multi_thread_eigen={'true' if threads > 1 else 'false'} intra_op_parallelism_threads={threads}"
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + flag).strip()


def run(
    framework: str = "torch",
    config: TrainConfig = TrainConfig(),
    *,
    size: int = 48,
    train_scenes: int = 768,
    test_scenes: int = 32,
    device: str = "auto",
    threads: int | None = None,
    cache: str | Path | None = None,
    out: str | Path | None = None,
    figure_scenes: int = 4,
    log=print,
) -> dict:
    """Train `framework`'s model on `train_scenes` scenes (TRAIN_SEED) and report on `test_scenes`
    (TEST_SEED). Returns the results (also written, with the picture, to `out` when given)."""
    started = time.perf_counter()
    train = dataset(TRAIN_SEED, train_scenes, size, cache=cache, log=log)
    test = dataset(TEST_SEED, test_scenes, size, cache=cache, log=log)
    data_seconds = time.perf_counter() - started
    if framework == "torch":
        import torch

        from examples.learn_motion import torch_model as impl

        device = ("cuda" if torch.cuda.is_available() else "cpu") if device == "auto" else device
        if threads:
            torch.set_num_threads(threads)
        model, history = impl.train(train, config, device=device, log=log)
        initial_blur, initial_motion = impl.predict(impl.make_model(config, device), test, device=device)
        predicted_blur, predicted_motion = impl.predict(model, test, device=device)
        true_blur, _ = impl.predict(model, test, motion=true_motion(test, config.motion), device=device)
        versions = {"torch": torch.__version__}
    elif framework == "jax":
        import jax

        from examples.learn_motion import jax_model as impl

        model, history = impl.train(train, config, log=log)
        initial_blur, initial_motion = impl.predict(impl.make_model(config), test)
        predicted_blur, predicted_motion = impl.predict(model, test)
        true_blur, _ = impl.predict(model, test, motion=true_motion(test, config.motion))
        device = str(jax.devices()[0].platform)
        versions = {"jax": jax.__version__}
    else:
        raise ValueError(f"framework must be 'torch' or 'jax', got {framework!r}")
    results = evaluate(test, predicted_blur, predicted_motion, true_blur, config.motion, initial=(initial_blur, initial_motion))
    results.update(
        framework=framework,
        device=device,
        config=config.as_dict(),
        size=size,
        train_scenes=train_scenes,
        test_scenes=test_scenes,
        seeds={"train": TRAIN_SEED, "test": TEST_SEED, "model": config.seed},
        shutters=[str(s) for s in SHUTTERS],
        steps=history["steps"],
        train_seconds=round(history["train_seconds"], 1),
        data_seconds=round(data_seconds, 1),
        history=history,
        machine={"cpus": os.cpu_count(), "platform": platform.platform(), "threads": threads, **versions},
    )
    label = f"{framework}, {config.method} ({config.motion}), {history['steps']} steps in {history['train_seconds']:.0f} s"
    if log is not None:
        log(markdown(results, label))
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        (out / f"results_{framework}.json").write_text(json.dumps(results, indent=1) + "\n")
        title = f"{framework}: {config.method}, {history['steps']} steps, test scenes (seed {TEST_SEED})"
        results["figure"] = save_figure(out / f"results_{framework}.png", test, predicted_blur, predicted_motion, config.motion, scenes=figure_scenes, title=title)
    return results


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m examples.learn_motion", description=__doc__.split("\n\n")[0])
    parser.add_argument("--framework", choices=("torch", "jax"), default="torch")
    parser.add_argument("--minutes", type=float, default=4.0, help="training time budget (default 4)")
    parser.add_argument("--steps", type=int, default=100_000, help="at most this many steps (default: the time decides)")
    parser.add_argument("--method", choices=("bezier", "gather", "reconstruct"), default="bezier")
    parser.add_argument("--motion", choices=("offsets", "velocity"), default=None, help="default: offsets with bezier, else velocity")
    parser.add_argument("--size", type=int, default=48, help="scene side in pixels, a multiple of 8 (default 48)")
    parser.add_argument("--train-scenes", type=int, default=768)
    parser.add_argument("--test-scenes", type=int, default=32)
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--width", type=int, default=8, help="the U-Net's first width (default 8)")
    parser.add_argument("--lr", type=float, default=1e-3)
    parser.add_argument(
        "--smoothness",
        type=float,
        default=TrainConfig.smoothness,
        help=f"weight of the motion prior, the total variation of the predicted motion, in the loss (default {TrainConfig.smoothness:g}; 0: the blur's error alone)",
    )
    parser.add_argument("--no-residual", action="store_true", help="the U-Net's output is the motion (default: a correction to block matching's)")
    parser.add_argument("--seed", type=int, default=0, help="the model's initialisation and batch order")
    parser.add_argument("--threads", type=int, default=None, help="CPU threads for each framework (default: theirs)")
    parser.add_argument("--device", default="auto", help="torch: auto (cuda when available), cpu or cuda; JAX takes its default device")
    parser.add_argument("--cache", default=str(HERE / ".cache"), help="where the rendered scenes are kept ('' for nowhere)")
    parser.add_argument("--out", default=str(HERE), help="folder for results_<framework>.json and .png (default: beside this file)")
    args = parser.parse_args(argv)
    limit_threads(args.threads)
    motion = args.motion or ("offsets" if args.method == "bezier" else "velocity")
    config = TrainConfig(
        method=args.method, motion=motion, width=args.width, batch=args.batch, lr=args.lr, smoothness=args.smoothness, minutes=args.minutes, steps=args.steps, seed=args.seed, residual=not args.no_residual
    )
    run(
        args.framework,
        config,
        size=args.size,
        train_scenes=args.train_scenes,
        test_scenes=args.test_scenes,
        device=args.device,
        threads=args.threads,
        cache=args.cache or None,
        out=args.out,
    )
    return 0
