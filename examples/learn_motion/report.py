"""The report on the test scenes: PSNR and SSIM against the blurred ground truth of four images, the
endpoint error of the learned motion, a markdown table and a picture."""

from __future__ import annotations

import numpy as np

from diffblur.metrics import psnr, ssim, to_display, velocity_to_color

__all__ = ["ROWS", "evaluate", "markdown", "save_figure", "true_motion"]

#: The report's rows, in order: what is compared with the blurred target.
ROWS = {
    "sharp": "(a) sharp middle frame",
    "average": "(b) average of the two input frames",
    "network": "(c) blur from the network's motion",
    "true": "(d) blur from the true motion, same op",
    "initial": "(e) the same model before training (block matching alone)",
}
#: Pixels whose true half-spread is above this (px) count as moving for the "moving" endpoint error.
MOVING = 0.5


def true_motion(data: dict, motion: str) -> np.ndarray:
    """The renderer's motion in the form the network predicts: offsets (prev, next) or the velocity."""
    if motion == "offsets":
        return np.concatenate([data["offset_prev"], data["offset_next"]], axis=1)
    return 0.5 * (data["offset_next"] - data["offset_prev"])


def _endpoint_error(predicted: np.ndarray, true: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean over pixels (and over the two endpoints of an offsets pair) of the distance in pixels."""
    pairs = predicted.shape[1] // 2
    distances = [np.hypot(*(predicted[:, 2 * k : 2 * k + 2] - true[:, 2 * k : 2 * k + 2]).transpose(1, 0, 2, 3)) for k in range(pairs)]
    distance = np.mean(distances, axis=0)
    return float(distance.mean() if mask is None else distance[mask].mean())


def evaluate(data: dict, network_blur: np.ndarray, network_motion: np.ndarray, true_blur: np.ndarray, motion: str, *, initial: tuple | None = None) -> dict:
    """PSNR (dB) and SSIM, means over the scenes, of each of ROWS against the target; endpoint errors
    (px) of the network's motion and of no motion at all, over every pixel and over the moving ones.
    initial: (blur, motion) of the model before training, for row (e)."""
    target = data["target"].astype(np.float64)
    frames = data["frames"].astype(np.float64)
    images = {
        "sharp": data["color"],
        "average": 0.5 * (frames[:, :3] + frames[:, 3:]),
        "network": network_blur,
        "true": true_blur,
    }
    if initial is not None:
        images["initial"] = initial[0]
    rows = {}
    for name, image in images.items():
        image = np.clip(np.asarray(image, dtype=np.float64), 0.0, None)
        rows[name] = {"psnr": float(psnr(image, target)), "ssim": float(ssim(image, target, data_range=1.0))}
    true = true_motion(data, motion)
    velocity = 0.5 * (data["offset_next"] - data["offset_prev"])
    moving = np.hypot(velocity[:, 0], velocity[:, 1]) > MOVING
    zero = np.zeros_like(true)
    errors = {
        "network": _endpoint_error(network_motion, true),
        "network_moving": _endpoint_error(network_motion, true, moving),
        "zero_motion": _endpoint_error(zero, true),
        "zero_motion_moving": _endpoint_error(zero, true, moving),
    }
    if initial is not None:
        errors.update(initial=_endpoint_error(initial[1], true), initial_moving=_endpoint_error(initial[1], true, moving))
    return {
        "rows": rows,
        "endpoint_error": errors,
        "scenes": int(len(target)),
        "moving_fraction": float(moving.mean()),
    }


def markdown(results: dict, label: str = "") -> str:
    """The report's table: PSNR / SSIM per row, then the endpoint errors."""
    head = f"| {label or 'on the test scenes'} | PSNR (dB) | SSIM |\n|---|---:|---:|\n"
    body = "".join(f"| {ROWS[name]} | {row['psnr']:.2f} | {row['ssim']:.4f} |\n" for name, row in results["rows"].items())
    epe = results["endpoint_error"]
    tail = (
        f"\nEndpoint error of the learned motion: {epe['network']:.2f} px over all pixels, {epe['network_moving']:.2f} px "
        f"over the moving ones ({100 * results['moving_fraction']:.0f} % of the pixels, true half-spread > {MOVING} px); "
        f"predicting no motion: {epe['zero_motion']:.2f} px and {epe['zero_motion_moving']:.2f} px"
        + (f"; the model before training: {epe['initial']:.2f} px and {epe['initial_moving']:.2f} px" if "initial" in epe else "")
        + ".\n"
    )
    return head + body + tail


def save_figure(path, data: dict, network_blur: np.ndarray, network_motion: np.ndarray, motion: str, *, scenes: int = 4, title: str = "") -> str:
    """A PNG: per test scene (rows) the two input frames, the predicted and the true motion (as the
    velocity, on a colour wheel, the same scale in a row), the blurred target, the blur from the
    predicted motion and its error (|difference| x 4)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    true = true_motion(data, motion)
    as_velocity = (lambda m: 0.5 * (m[:, 2:4] - m[:, 0:2])) if motion == "offsets" else (lambda m: m)
    columns = ["frame t = -1", "frame t = +1", "predicted motion", "true motion", "target (blurred)", "blur, predicted motion", "|error| x 4"]
    count = min(scenes, len(data["target"]))
    figure = Figure(figsize=(2.0 * len(columns), 2.1 * count + (0.4 if title else 0)))
    FigureCanvasAgg(figure)
    axes = figure.subplots(count, len(columns), squeeze=False)
    for row in range(count):
        k = slice(row, row + 1)
        predicted, truth = as_velocity(network_motion[k]), as_velocity(true[k])
        largest = max(float(np.hypot(*truth[0]).max()), float(np.hypot(*predicted[0]).max()), 1e-3)
        error = np.clip(4 * np.abs(network_blur[k] - data["target"][k]), 0, 1)
        pictures = [
            to_display(data["frames"][k, :3])[0],
            to_display(data["frames"][k, 3:])[0],
            velocity_to_color(predicted, max_magnitude=largest)[0].transpose(1, 2, 0),
            velocity_to_color(truth, max_magnitude=largest)[0].transpose(1, 2, 0),
            to_display(data["target"][k])[0],
            to_display(network_blur[k])[0],
            error[0].transpose(1, 2, 0),
        ]
        for col, picture in enumerate(pictures):
            axis = axes[row, col]
            axis.imshow(np.clip(picture, 0, 1), interpolation="nearest")
            axis.set_xticks([]), axis.set_yticks([])
            if row == 0:
                axis.set_title(columns[col], fontsize=9)
        axes[row, 2].set_ylabel(f"up to {largest:.1f} px", fontsize=8)
    if title:
        figure.suptitle(title, fontsize=10)
    figure.tight_layout()
    figure.savefig(path, dpi=80)
    return str(path)
