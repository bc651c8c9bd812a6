"""How the training options were chosen: train on the 768 training scenes as `run` does and score the
model on the validation split, `data.VALIDATION` (64 further scenes of the training seed, which no
training run reads), never on the test scenes. Prints the report and appends one JSON line to `--log`.

    python -m examples.learn_motion.validate --smoothness 0.01 --threads 1
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

from examples.learn_motion.common import TrainConfig
from examples.learn_motion.data import TRAIN_SEED, VALIDATION, dataset
from examples.learn_motion.report import evaluate, markdown, true_motion
from examples.learn_motion.run import HERE, limit_threads

__all__ = ["main", "validate"]


def validate(framework: str, config: TrainConfig, *, size: int = 48, train_scenes: int = 768, cache=HERE / ".cache", log=print) -> dict:
    """Train `framework`'s model and evaluate it (and the model before training) on the validation split."""
    assert train_scenes <= VALIDATION[0], "the validation scenes follow the training scenes"
    train = dataset(TRAIN_SEED, train_scenes, size, cache=cache, log=log)
    held_out = dataset(TRAIN_SEED, VALIDATION[1], size, start=VALIDATION[0], cache=cache, log=log)
    if framework == "torch":
        from examples.learn_motion import torch_model as impl
    else:
        from examples.learn_motion import jax_model as impl
    model, history = impl.train(train, config, log=log)
    initial = impl.predict(impl.make_model(config), held_out)
    blurred, motion = impl.predict(model, held_out)
    true_blur, _ = impl.predict(model, held_out, motion=true_motion(held_out, config.motion))
    results = evaluate(held_out, blurred, motion, true_blur, config.motion, initial=initial)
    results.update(framework=framework, config=config.as_dict(), steps=history["steps"], train_seconds=round(history["train_seconds"], 1), split=list(VALIDATION))
    if log is not None:
        log(markdown(results, f"validation, {framework}, smoothness {config.smoothness:g}, edge {config.edge:g}, seed {config.seed}, {history['steps']} steps"))
    return results


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m examples.learn_motion.validate", description=__doc__.split("\n\n")[0])
    parser.add_argument("--framework", choices=("torch", "jax"), default="torch")
    parser.add_argument("--minutes", type=float, default=4.0)
    parser.add_argument("--smoothness", type=float, default=TrainConfig.smoothness)
    parser.add_argument("--edge", type=float, default=TrainConfig.edge)
    parser.add_argument("--seed", type=int, default=TrainConfig.seed, help="the model's initialisation and batch order")
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--log", default=str(HERE / ".cache" / "validation.jsonl"), help="the JSON lines file the result is appended to")
    args = parser.parse_args(argv)
    limit_threads(args.threads)
    if args.framework == "torch" and args.threads:
        import torch

        torch.set_num_threads(args.threads)
    config = replace(TrainConfig(), minutes=args.minutes, smoothness=args.smoothness, edge=args.edge, seed=args.seed)
    results = validate(args.framework, config)
    results["date"] = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    path = Path(args.log)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a") as f:
        f.write(json.dumps(results) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
