"""Blurred/sharp pairs for deblurring datasets: `diffblur synth IN_DIR OUT_DIR`.

Each sharp photograph gets a seeded random motion and goes through a camera model around the blur,
in the order a camera makes the picture (RSBlur, Rim et al. 2022, measured what each step is worth
to a deblurring model tested on real blur):

1. the sRGB response undone (blur mixes light, which is linear; `response="linear"` skips it);
2. highlights pushed past the sensor's white (`highlight_gain`): a clipped sky or lamp in the
   sharp photograph was brighter than 1, and its streak should be too;
3. the blur along the motion, through the library's ops (PyTorch, float32):
   - ``pan``: one straight motion for the whole image (`gather_blur`);
   - ``shake``: one curved path for the whole image, a quadratic through the sharp frame's position
     (`accumulate_warps` with offsets; an instant per half pixel of path);
   - ``objects``: each label of a segmentation picture its own straight motion over a background
     that pans or stays, nearer labels first (`bezier_scatter` with depth); or, for frames of a
     sequence, each pixel's own path through its optical flow to the previous and next frames;
4. saturation at 1, Poisson-Gaussian noise (variance ``shot * x + read**2`` in linear light),
5. the sRGB response, 8-bit quantisation, and optionally JPEG.

The sharp image of the pair is the same photograph through steps 1, 2, 4 (without noise) and 5: what
the camera would have recorded without motion. Every random choice is drawn from a generator seeded
by (seed, file name) and written to the pair's JSON; `synthesize(sharp, params)` makes the pair again
from it (`reproduce` reads the files).
"""

from __future__ import annotations

import json
import math
import os
import zlib
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from diffblur import checks
from diffblur.metrics import linear_to_srgb, srgb_to_linear
from diffblur.shutters import SHUTTERS

MOTIONS = ("pan", "shake", "objects")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
#: Flow files of a frame NAME.png: NAME.prev.flo (to the previous frame) and NAME.next.flo (to the
#: next), Middlebury .flo, displacements in pixels.
FLOW_SUFFIXES = (".prev.flo", ".next.flo")
_FLO_MAGIC = 202021.25

__all__ = ["FLOW_SUFFIXES", "MOTIONS", "SynthOptions", "draw_params", "estimate_flow", "read_flo", "reproduce", "synthesize", "synthesize_folder", "write_flo"]


@dataclass(frozen=True)
class SynthOptions:
    """What `diffblur synth` draws from: ranges are (low, high), drawn uniformly per image."""

    motions: tuple[str, ...] = ("pan", "shake")
    length: tuple[float, float] = (4.0, 30.0)  # path length over the exposure, px
    shutters: tuple[str, ...] = ("box",)
    response: str = "srgb"
    highlight_gain: tuple[float, float] = (1.0, 4.0)
    shot_noise: tuple[float, float] = (0.0, 0.01)
    read_noise: tuple[float, float] = (0.0, 0.01)
    jpeg_quality: tuple[int, int] | None = None
    exposure: float = 1.0  # with flows: the fraction of the frame interval the shutter is open

    def __post_init__(self) -> None:
        for motion in self.motions:
            checks.require_choice("motion", motion, MOTIONS)
        for shutter in self.shutters:
            checks.require_choice("shutter", shutter, SHUTTERS)
        checks.require_choice("response", self.response, ("srgb", "linear"))
        for name in ("length", "highlight_gain", "shot_noise", "read_noise"):
            low, high = getattr(self, name)
            if not 0 <= low <= high:
                raise ValueError(f"{name} must be a range 0 <= low <= high, got {(low, high)}")
        if self.highlight_gain[0] < 1:
            raise ValueError(f"highlight_gain must be >= 1, got {self.highlight_gain}")
        if self.jpeg_quality is not None and not 1 <= self.jpeg_quality[0] <= self.jpeg_quality[1] <= 100:
            raise ValueError(f"jpeg_quality must be a range within 1..100, got {self.jpeg_quality}")
        if not 0 < self.exposure <= 1:
            raise ValueError(f"exposure must be in (0, 1], got {self.exposure}")


def _generator(seed: int, name: str) -> np.random.Generator:
    """The same draws for a file whatever the order or worker that processes it."""
    return np.random.default_rng([seed, zlib.crc32(name.encode())])


def _direction(rng: np.random.Generator, length: float) -> list[float]:
    angle = rng.uniform(0, 2 * math.pi)
    return [0.5 * length * math.cos(angle), 0.5 * length * math.sin(angle)]  # half-spread, px


def draw_params(seed: int, name: str, options: SynthOptions, *, labels: int = 0, flows: bool = False) -> dict[str, Any]:
    """Every random choice for the file `name`: JSON-ready. `labels`: object labels of its
    segmentation (motion "objects" needs some, or `flows`)."""
    rng = _generator(seed, name)
    choices = [m for m in options.motions if m != "objects" or labels or flows]
    if not choices:
        raise ValueError(f"{name}: motion 'objects' needs a segmentation picture or flow files")
    motion: dict[str, Any] = {"kind": "objects" if flows else str(rng.choice(choices))}
    length = float(rng.uniform(*options.length))
    if motion["kind"] == "pan":
        motion["velocity"] = _direction(rng, length)
    elif motion["kind"] == "shake":
        # A quadratic path through the sharp frame's position: the end points' offsets, the second
        # bent away from the first's mirror image by up to half the length.
        end = np.array(_direction(rng, length))
        bend = np.array(_direction(rng, rng.uniform(0, length)))
        motion["offset_prev"], motion["offset_next"] = (-end + bend).tolist(), (end + bend).tolist()
    elif flows:
        motion["flows"] = True
        motion["exposure"] = options.exposure
    else:
        background_still = bool(rng.random() < 0.5)
        motion["background"] = [0.0, 0.0] if background_still else _direction(rng, float(rng.uniform(0, length / 2)))
        motion["labels"] = {str(k): _direction(rng, float(rng.uniform(*options.length))) for k in range(1, labels + 1)}
        motion["depth_order"] = [int(k) for k in rng.permutation(np.arange(1, labels + 1))]
    camera = {
        "response": options.response,
        "highlight_gain": float(rng.uniform(*options.highlight_gain)),
        "shot_noise": float(rng.uniform(*options.shot_noise)),
        "read_noise": float(rng.uniform(*options.read_noise)),
        "jpeg_quality": None if options.jpeg_quality is None else int(rng.integers(options.jpeg_quality[0], options.jpeg_quality[1] + 1)),
        "noise_seed": int(rng.integers(2**31)),
    }
    return {"source": name, "seed": seed, "motion": motion, "shutter": str(rng.choice(options.shutters)), "camera": camera}


def _push_highlights(linear: np.ndarray, gain: float) -> np.ndarray:
    """Scale values above 0.9 smoothly up to `gain` at 1: what clipped at white was brighter."""
    ramp = np.clip((linear - 0.9) / 0.1, 0.0, 1.0)
    return linear * (1.0 + (gain - 1.0) * ramp * ramp * (3 - 2 * ramp))


def _depth_from_labels(labels: np.ndarray, order: list[int]) -> np.ndarray:
    """Depth 2 for the background, nearer for each label in `order` (the first nearest)."""
    depth = np.full(labels.shape, 2.0)
    for rank, label in enumerate(order):
        depth[labels == label] = 1.0 + 0.5 * rank / max(len(order), 1)
    return depth


def _blur(linear: np.ndarray, params: dict, labels: np.ndarray | None, flows: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
    """(H, W, C) linear -> (H, W, C) blurred, float64."""
    import torch

    import torch_impl

    height, width, _ = linear.shape
    color = torch.from_numpy(np.ascontiguousarray(linear.transpose(2, 0, 1)[None], dtype=np.float32))
    motion, shutter = params["motion"], params["shutter"]

    def field(vector) -> torch.Tensor:
        return torch.tensor(vector, dtype=torch.float32).reshape(1, 2, 1, 1).expand(1, 2, height, width).contiguous()

    with torch.no_grad():
        if motion["kind"] == "pan":
            speed = math.hypot(*motion["velocity"])
            out = torch_impl.gather_blur(color, field(motion["velocity"]), samples=max(3, 2 * math.ceil(speed) + 1), shutter=shutter)
        elif motion["kind"] == "shake":
            prev, nxt = np.array(motion["offset_prev"]), np.array(motion["offset_next"])
            path = np.linalg.norm(prev) + np.linalg.norm(nxt)
            out = torch_impl.accumulate_warps(color, None, offset_prev=field(prev.tolist()), offset_next=field(nxt.tolist()), instants=max(3, 2 * math.ceil(path) + 1), shutter=shutter)
        else:
            if flows is not None:
                scale = motion["exposure"]
                prev, nxt = (torch.from_numpy(np.ascontiguousarray(f.transpose(2, 0, 1)[None] * scale, dtype=np.float32)) for f in flows)
                depth = torch.ones(1, 1, height, width)
                fill = "color"
            else:
                velocity = np.broadcast_to(np.array(motion["background"], dtype=np.float64)[:, None, None], (2, height, width)).copy()
                for label, vector in motion["labels"].items():
                    velocity[:, labels == int(label)] = np.array(vector)[:, None]
                nxt = torch.from_numpy(velocity[None].astype(np.float32))
                prev = -nxt
                depth = torch.from_numpy(_depth_from_labels(labels, motion["depth_order"])[None, None].astype(np.float32))
                fill = "still" if not any(motion["background"]) else "color"
            out = torch_impl.bezier_scatter(color, depth, prev, nxt, shutter=shutter, fill=fill)
    return out[0].numpy().astype(np.float64).transpose(1, 2, 0)


def _encode(linear: np.ndarray, response: str) -> np.ndarray:
    """Linear in [0, 1] -> 8-bit (H, W, C)."""
    encoded = linear_to_srgb(linear) if response == "srgb" else np.clip(linear, 0.0, 1.0)
    return np.round(255 * encoded).astype(np.uint8)


def _jpeg_bytes(pixels: np.ndarray, quality: int) -> bytes:
    import io

    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(pixels[:, :, 0] if pixels.shape[2] == 1 else pixels).save(buffer, format="JPEG", quality=quality)
    return buffer.getvalue()


def _decode(data: bytes) -> np.ndarray:
    import io

    from PIL import Image

    decoded = np.asarray(Image.open(io.BytesIO(data)))
    return decoded[:, :, None] if decoded.ndim == 2 else decoded


def _make(sharp: np.ndarray, params: dict, labels: np.ndarray | None, flows) -> tuple[np.ndarray, np.ndarray]:
    """The pair before JPEG compression."""
    camera = params["camera"]
    linear = srgb_to_linear(sharp) if camera["response"] == "srgb" else np.asarray(sharp, dtype=np.float64)
    bright = _push_highlights(linear, camera["highlight_gain"])
    blurred = np.clip(_blur(bright, params, labels, flows), 0.0, 1.0)
    rng = np.random.default_rng(camera["noise_seed"])
    sigma = np.sqrt(camera["shot_noise"] * blurred + camera["read_noise"] ** 2)
    noisy = np.clip(blurred + sigma * rng.standard_normal(blurred.shape), 0.0, 1.0)
    return _encode(np.clip(bright, 0.0, 1.0), camera["response"]), _encode(noisy, camera["response"])


def synthesize(sharp: np.ndarray, params: dict, *, labels: np.ndarray | None = None, flows: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The (sharp, blurred) 8-bit (H, W, C) pair of a photograph `sharp` in [0, 1] (H, W, C), made
    as `params` (from `draw_params` or a pair's JSON) says. `labels`: (H, W) segmentation (0 the
    background, objects 1..n) for motion "objects"; `flows`: the (H, W, 2) flows to the previous
    and next frames for a frame of a sequence."""
    sharp_pixels, blurred_pixels = _make(sharp, params, labels, flows)
    quality = params["camera"]["jpeg_quality"]
    return sharp_pixels, blurred_pixels if quality is None else _decode(_jpeg_bytes(blurred_pixels, quality))


def _relabel(raw: np.ndarray) -> np.ndarray:
    """A segmentation's labels as 0 (background, 0 in the picture) and 1..n in order of value."""
    return np.where(raw > 0, np.searchsorted(np.unique(raw[raw > 0]), raw) + 1, 0)


def read_flo(path: str | os.PathLike) -> np.ndarray:
    """A Middlebury .flo file as (H, W, 2) float32 displacements, px."""
    with open(path, "rb") as stream:
        magic = np.frombuffer(stream.read(4), np.float32)
        if magic.size != 1 or magic[0] != _FLO_MAGIC:
            raise ValueError(f"{os.fspath(path)!r} is not a Middlebury .flo file (bad magic number)")
        width, height = np.frombuffer(stream.read(8), np.int32)
        data = np.frombuffer(stream.read(), np.float32)
    if data.size != 2 * width * height:
        raise ValueError(f"{os.fspath(path)!r}: {data.size} values for a {width}x{height} flow (need {2 * width * height})")
    return data.reshape(height, width, 2)


def write_flo(path: str | os.PathLike, flow: np.ndarray) -> None:
    height, width, _ = flow.shape
    with open(path, "wb") as stream:
        stream.write(np.float32(_FLO_MAGIC).tobytes() + np.array([width, height], np.int32).tobytes() + np.ascontiguousarray(flow, np.float32).tobytes())


def estimate_flow(frame: np.ndarray, other: np.ndarray) -> np.ndarray:
    """(H, W, 2) displacement from `frame` to `other` (8-bit-scale floats in [0, 1]) by OpenCV's
    Farneback method: needs the `flow` extra (opencv-python-headless)."""
    try:
        import cv2
    except ImportError as error:
        raise ImportError("estimating flow needs OpenCV: pip install 'diffblur[flow]', or give NAME.prev.flo / NAME.next.flo files") from error
    grey = [np.round(255 * np.asarray(f).mean(axis=2)).astype(np.uint8) for f in (frame, other)]
    return cv2.calcOpticalFlowFarneback(grey[0], grey[1], None, 0.5, 4, 15, 3, 5, 1.2, 0).astype(np.float32)


def _read_labels(path: Path) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as image:
        labels = np.asarray(image)
    return labels if labels.ndim == 2 else labels[:, :, 0]


def _write(path: Path, pixels: np.ndarray) -> None:
    from PIL import Image

    Image.fromarray(pixels[:, :, 0] if pixels.shape[2] == 1 else pixels).save(path)


def _sources(images: list[Path], index: int, segmentation: Path | None, sequence: bool, estimate: bool):
    """The labels or flows of images[index] (None when it has none)."""
    from diffblur.app.blur_image import read_picture

    image = images[index]
    if segmentation is not None:
        mask = segmentation / (image.stem + ".png")
        return (_read_labels(mask) if mask.is_file() else None), None
    if not sequence:
        return None, None
    files = [image.with_name(image.stem + suffix) for suffix in FLOW_SUFFIXES]
    if all(f.is_file() for f in files):
        return None, tuple(read_flo(f) for f in files)
    if estimate and 0 < index < len(images) - 1:
        frame = read_picture(image)
        return None, (estimate_flow(frame, read_picture(images[index - 1])), estimate_flow(frame, read_picture(images[index + 1])))
    return None, None


def _one(job: tuple) -> dict:
    images, index, out_dir, seed, options, segmentation, sequence, estimate = job
    from diffblur.app.blur_image import read_picture

    image = images[index]
    labels, flows = _sources(images, index, segmentation, sequence, estimate)
    if sequence and flows is None:
        return {"source": image.name, "skipped": "no flow files (NAME.prev.flo, NAME.next.flo) and no neighbours to estimate flow from"}
    if labels is not None:
        labels = _relabel(labels)
    count = 0 if labels is None else int(labels.max())
    sharp = read_picture(image)
    params = draw_params(seed, image.name, options, labels=count, flows=flows is not None)
    sharp_pixels, blurred_pixels = _make(sharp, params, labels, flows)
    _write(out_dir / (image.stem + "_sharp.png"), sharp_pixels)
    quality = params["camera"]["jpeg_quality"]
    blurred_name = image.stem + ("_blurred.png" if quality is None else "_blurred.jpg")
    if quality is None:
        _write(out_dir / blurred_name, blurred_pixels)
    else:
        (out_dir / blurred_name).write_bytes(_jpeg_bytes(blurred_pixels, quality))
    params["files"] = {"sharp": image.stem + "_sharp.png", "blurred": blurred_name}
    if flows is not None:  # the pair keeps the flows it was made with, given or estimated
        for flow, suffix in zip(flows, FLOW_SUFFIXES):
            write_flo(out_dir / (image.stem + suffix), flow)
        params["files"]["flows"] = [image.stem + suffix for suffix in FLOW_SUFFIXES]
    (out_dir / (image.stem + ".json")).write_text(json.dumps(params, indent=1))
    return params


def synthesize_folder(in_dir: str | os.PathLike, out_dir: str | os.PathLike, *, seed: int = 0, options: SynthOptions = SynthOptions(), segmentation: str | os.PathLike | None = None, sequence: bool = False, estimate_flows: bool = False, workers: int = 1, progress: bool = True) -> list[dict]:
    """Pairs for every image of `in_dir` (sorted by name) in `out_dir`: NAME_sharp.png,
    NAME_blurred.png (.jpg with JPEG) and NAME.json. Returns the JSON records."""
    from tqdm import tqdm

    in_dir, out_dir = Path(in_dir), Path(out_dir)
    if not in_dir.is_dir():
        raise FileNotFoundError(f"no such folder: {os.fspath(in_dir)!r}")
    images = sorted(p for p in in_dir.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())
    if not images:
        raise ValueError(f"{os.fspath(in_dir)!r} holds no images ({', '.join(IMAGE_SUFFIXES)})")
    if segmentation is not None and not Path(segmentation).is_dir():
        raise FileNotFoundError(f"no such segmentation folder: {os.fspath(segmentation)!r}")
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    out_dir.mkdir(parents=True, exist_ok=True)
    jobs = [(images, i, out_dir, seed, options, None if segmentation is None else Path(segmentation), sequence, estimate_flows) for i in range(len(images))]
    bar = tqdm(total=len(jobs), desc="pairs", unit="image", disable=not progress)
    records = []
    if workers == 1:
        for job in jobs:
            records.append(_one(job))
            bar.update()
    else:
        import multiprocessing

        with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
            for record in pool.map(_one, jobs):
                records.append(record)
                bar.update()
    bar.close()
    return records


def reproduce(json_path: str | os.PathLike, in_dir: str | os.PathLike, *, segmentation: str | os.PathLike | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The pair a JSON record describes, made again from its source photograph in `in_dir` (and
    its segmentation picture, or the flows written next to the JSON)."""
    from diffblur.app.blur_image import read_picture

    params = json.loads(Path(json_path).read_text())
    image = Path(in_dir) / params["source"]
    labels, flows = None, None
    if params["motion"]["kind"] == "objects":
        if params["motion"].get("flows"):
            flows = tuple(read_flo(Path(json_path).with_name(name)) for name in params["files"]["flows"])
        else:
            labels = _relabel(_read_labels(Path(segmentation) / (image.stem + ".png")))
    return synthesize(read_picture(image), params, labels=labels, flows=flows)
