"""Blur a photograph: `diffblur blur IMAGE -o OUT`.

The buffers a renderer would give (velocity, depth) come from the command line instead: one global
velocity, a full-resolution ``.npy`` field, or a coarse hand-painted picture that is upsampled to
the photograph's size (seed 000 Figure 12 blurs a photograph with painted buffers this way).

Painted pictures are read like this (any size; upsampled bilinearly to the photograph's):
- velocity picture: red = x, green = y, 8-bit levels; 128 means still, 255 means +max_speed and
  1 means -max_speed pixels (the half-spread of `diffblur.conventions`), linear in between;
- depth picture: grey level; white = near (depth 1), black = far (depth 10).

Photographs are sRGB-encoded: they are decoded to linear intensities before blurring (blur mixes
light, which is linear) and encoded again to write the result.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from diffblur.metrics import linear_to_srgb, srgb_to_linear

#: Depth of white and black in a painted depth picture.
PAINTED_DEPTH_NEAR, PAINTED_DEPTH_FAR = 1.0, 10.0
#: The 8-bit level of a still pixel in a painted velocity picture.
PAINTED_STILL_LEVEL = 128
BACKENDS = ("torch", "jax")

#: The command's options that set an op's option, by method: (command option, the op's option name).
#: A method missing from an option's row does not take it (the command says so before reading files).
METHOD_OPTIONS: dict[str, dict[str, str]] = {
    "samples": {"reconstruct": "samples", "gather": "samples", "bezier": "samples", "accumulate": "instants"},
    "iterations": {"warp_blend": "iterations"},
    "max_radius": {"reconstruct": "max_radius"},
    "shutter": {"reconstruct": "shutter", "gather": "shutter", "bezier": "shutter", "accumulate": "shutter"},
}

#: The methods that read a depth buffer; the others would ignore one.
DEPTH_METHODS = ("reconstruct", "bezier")

__all__ = [
    "BACKENDS",
    "BlurInputs",
    "DEPTH_METHODS",
    "METHOD_OPTIONS",
    "blur_image",
    "check_output_path",
    "default_method",
    "load_inputs",
    "method_options",
    "read_picture",
    "spread_warning",
    "write_picture",
]


def default_method(depth_given: bool) -> str:
    """The command's method when none is named: "reconstruct" with a depth buffer (it keeps a moving
    object's smear off what is in front of it), "gather" without one. Without depth every pixel sits
    at one depth and reconstruct's depth test separates nothing, while its jitter and its taps over
    S / (S + 1) of the path still cost accuracy: against the exact box blur of a photograph by one
    velocity the gather is the closest of the methods (scripts/measure_blur_methods_on_photo.py)."""
    return "reconstruct" if depth_given else "gather"


def method_options(method: str, **given) -> dict:
    """The op options of `method` for the command's options `given` (None = not given), e.g. the
    command's `samples` is accumulate's `instants`. A ValueError names an option the method does not
    take and the methods that do."""
    options = {}
    for name, value in given.items():
        if value is None:
            continue
        takers = METHOD_OPTIONS[name]
        if method not in takers:
            flag = "--" + name.replace("_", "-")
            raise ValueError(f"{flag} does not apply to method {method!r}; it sets an option of {', '.join(takers)}")
        options[takers[method]] = value
    return options


def check_output_path(path: str | os.PathLike) -> None:
    """Fail before any work if the output picture cannot be written: a suffix PIL does not write,
    or a folder that does not exist."""
    from PIL import Image

    Image.init()
    suffix = os.path.splitext(os.fspath(path))[1].lower()
    writable = sorted(ext for ext, fmt in Image.registered_extensions().items() if fmt in Image.SAVE)
    if suffix not in writable:
        common = ", ".join(e for e in (".png", ".jpg", ".tif", ".bmp", ".webp") if e in writable)
        raise ValueError(f"cannot write {os.fspath(path)!r}: {suffix or 'no suffix'!r} is not an image format PIL writes; use e.g. {common}")
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise FileNotFoundError(f"no such folder for the output picture: {folder!r}")


@dataclass(frozen=True)
class BlurInputs:
    """The buffers of one photograph, (1, C, H, W) linear color, (1, 2, H, W) velocity in pixels,
    (1, 1, H, W) depth, all float32."""

    color: np.ndarray
    velocity: np.ndarray
    depth: np.ndarray


def read_picture(path: str | os.PathLike) -> np.ndarray:
    """An image file as float64 (H, W, C) in [0, 1] (alpha dropped, grey kept as one channel)."""
    from PIL import Image, UnidentifiedImageError

    if not os.path.isfile(path):
        raise FileNotFoundError(f"no such image file: {os.fspath(path)!r}")
    try:
        with Image.open(path) as image:
            mode = "L" if image.mode in ("1", "L", "LA", "I", "I;16", "F") else "RGB"
            array = np.asarray(image.convert(mode), dtype=np.float64) / 255.0
    except UnidentifiedImageError as error:
        raise ValueError(f"{os.fspath(path)!r} is not an image file PIL can read") from error
    return array[:, :, None] if array.ndim == 2 else array


def write_picture(path: str | os.PathLike, linear: np.ndarray) -> None:
    """Write (1, C, H, W) linear intensities as an sRGB-encoded 8-bit image (format from the suffix)."""
    from PIL import Image

    encoded = linear_to_srgb(linear[0]).transpose(1, 2, 0)
    pixels = np.round(255 * encoded).astype(np.uint8)
    Image.fromarray(pixels[:, :, 0] if pixels.shape[2] == 1 else pixels).save(path)


def _upsample(channels: np.ndarray, height: int, width: int) -> np.ndarray:
    """(K, h, w) -> (K, height, width), bilinear with pixel centres aligned (a painted buffer)."""
    from skimage.transform import resize

    if channels.shape[1:] == (height, width):
        return channels
    return np.stack([resize(c, (height, width), order=1, mode="edge", anti_aliasing=False) for c in channels])


def _load_field(path: str, name: str, channels: int, height: int, width: int) -> np.ndarray:
    """A .npy buffer of shape (channels, H, W) or (1, channels, H, W) matching the photograph."""
    if not os.path.isfile(path):
        raise FileNotFoundError(f"no such {name} file: {path!r}")
    field = np.load(path)
    if field.ndim == 4 and field.shape[0] == 1:
        field = field[0]
    if field.ndim == 2 and channels == 1:
        field = field[None]
    expected = (channels, height, width)
    if field.shape != expected:
        raise ValueError(f"{name} file {path!r} has shape {field.shape}; the photograph needs {expected} (or (1, {channels}, {height}, {width}))")
    if not np.issubdtype(field.dtype, np.floating) and not np.issubdtype(field.dtype, np.integer):
        raise TypeError(f"{name} file {path!r} holds {field.dtype}, not numbers")
    if not np.all(np.isfinite(field)):
        raise ValueError(f"{name} file {path!r} holds NaN or infinite values")
    return field.astype(np.float64)


def load_inputs(
    image: str,
    *,
    velocity: tuple[float, float] | None = None,
    velocity_file: str | None = None,
    velocity_image: str | None = None,
    max_speed: float = 20.0,
    depth_file: str | None = None,
    depth_image: str | None = None,
) -> BlurInputs:
    """The photograph and its buffers. Exactly one velocity source; depth optional (default: every
    pixel at depth 1, so the depth test never separates anything)."""
    sources = [s for s in (velocity, velocity_file, velocity_image) if s is not None]
    if len(sources) != 1:
        raise ValueError(f"give exactly one velocity source (a global velocity, a .npy field or a painted picture), got {len(sources)}")
    if depth_file is not None and depth_image is not None:
        raise ValueError("give at most one depth source (a .npy field or a painted picture), got both")
    if not (max_speed > 0 and np.isfinite(max_speed)):
        raise ValueError(f"max_speed must be a finite number > 0, got {max_speed}")
    photo = read_picture(image)
    height, width = photo.shape[:2]
    color = srgb_to_linear(photo).transpose(2, 0, 1)
    if velocity is not None:
        if not np.all(np.isfinite(velocity)):
            raise ValueError(f"velocity must be finite, got {velocity}")
        field = np.broadcast_to(np.asarray(velocity, dtype=np.float64)[:, None, None], (2, height, width))
    elif velocity_file is not None:
        field = _load_field(velocity_file, "velocity", 2, height, width)
    else:
        painted = read_picture(velocity_image)
        if painted.shape[2] < 2:
            raise ValueError(f"velocity picture {velocity_image!r} is grey; paint x in red and y in green")
        signed = np.clip((255 * painted[:, :, :2] - PAINTED_STILL_LEVEL) / (255 - PAINTED_STILL_LEVEL), -1, 1)
        field = _upsample(signed.transpose(2, 0, 1) * max_speed, height, width)
    if depth_file is not None:
        depth = _load_field(depth_file, "depth", 1, height, width)
        if not np.all(depth > 0):
            raise ValueError(f"depth file {depth_file!r} must be > 0 everywhere (positive linear depth)")
    elif depth_image is not None:
        grey = read_picture(depth_image).mean(axis=2)
        depth = _upsample((PAINTED_DEPTH_FAR + (PAINTED_DEPTH_NEAR - PAINTED_DEPTH_FAR) * grey)[None], height, width)
    else:
        depth = np.ones((1, height, width))
    as_batch = lambda a: np.ascontiguousarray(a[None], dtype=np.float32)  # noqa: E731
    return BlurInputs(as_batch(color), as_batch(field), as_batch(depth))


def spread_warning(reach: float, height: int, width: int) -> str | None:
    """A sentence when the blur's reach (the largest speed times the exposure, in pixels, each way)
    is longer than the photograph: the outer taps of every pixel then read past the border, which
    clamps, so much of the picture becomes a smear of its border colours. Legal (the ops take any
    finite velocity) but seldom meant: a velocity in the wrong unit, say. None when it fits."""
    if not reach > max(height, width):  # also None for a NaN, which the op refuses with its own error
        return None
    return (
        f"the blur reaches {reach:.3g} px each way (velocity x exposure), more than the {width}x{height} photograph: "
        "reads past the border take the border's colour, so much of the result is a smear of the border. "
        "Velocities are in pixels of this photograph (--velocity-image scales by --max-speed)"
    )


def blur_image(inputs: BlurInputs, *, method: str = "reconstruct", backend: str = "torch", exposure: float = 1.0, **options) -> np.ndarray:
    """Blur the photograph's buffers with `MotionBlur(method, **options)` of one backend; returns
    (1, C, H, W) linear float32."""
    from diffblur import checks
    from diffblur.ops.module import METHOD_INPUTS

    checks.require_choice("backend", backend, BACKENDS)
    checks.require_choice("method", method, tuple(METHOD_INPUTS))
    given = {"velocity": inputs.velocity, "depth": inputs.depth}
    if backend == "torch":
        import torch

        import torch_impl

        layer = torch_impl.MotionBlur(method, exposure=exposure, learn_exposure=False, **options)
        arrays = {name: torch.from_numpy(given[name]) for name in METHOD_INPUTS[method]}
        with torch.no_grad():
            return layer(torch.from_numpy(inputs.color), **arrays).numpy()
    import jax.numpy as jnp

    import jax_impl

    layer = jax_impl.MotionBlur(method, exposure=exposure, learn_exposure=False, **options)
    arrays = {name: jnp.asarray(given[name]) for name in METHOD_INPUTS[method]}
    return np.asarray(layer(jnp.asarray(inputs.color), **arrays))
