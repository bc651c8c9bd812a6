"""The project's conventions, as constants. Both backends and the NumPy reference read them here.

| thing | shape | meaning |
|---|---|---|
| color | (B, C, H, W) | linear (not gamma-encoded) intensities; any C |
| velocity | (B, 2, H, W) | channel 0 = x (columns, rightwards), 1 = y (rows, downwards), in pixels; the
  half-spread of seed 000: during the exposure the point covers X - V ... X + V |
| depth | (B, 1, H, W) | positive linear depth along the view axis; larger = farther |
| offset_prev, offset_next | (B, 2, H, W) | where the point seen at X at mid-exposure is at t = -1 and t = +1,
  relative to X; linear motion is offset_prev = -V, offset_next = +V |
| exposure time t | [-1, 1] | normalised; t = 0 is the instant the sharp frame shows |

Pixel centres are at integer coordinates: pixel (row i, column j) is the point (x=j, y=i).
Seed 000 uses camera-space z that is negative in front of the camera; this project uses positive
depth, so its comparisons are mirrored (see `soft_depth_compare` in `diffblur.reference`).
"""

from __future__ import annotations

#: Index of the x (column, rightwards) component in a velocity or offset tensor.
X_CHANNEL = 0
#: Index of the y (row, downwards) component in a velocity or offset tensor.
Y_CHANNEL = 1
#: Channels of a velocity or offset tensor.
VECTOR_CHANNELS = 2
#: Channels of a depth tensor.
DEPTH_CHANNELS = 1

#: The epsilon of seed 000 (sec. 2.2 and Listing 1), in pixels. It guards divisions by a speed:
#: lengths below it are treated as EPSILON. Small enough to be invisible (a thousandth of a
#: pixel), large enough that the gradient of `velocity_from_motion` at zero displacement stays
#: bounded by min_radius / EPSILON (500 for the default min_radius of 0.5 px).
EPSILON = 1e-3

#: "Still" means "moves at most this far", in pixels, over the exposure (from the point's t = 0
#: position), never "exactly zero": a renderer's offsets carry float leftovers (1e-6 px) on static
#: surfaces. Every op that asks whether a pixel or a tile moves reads it here: bezier_scatter's
#: moving mask and its fill="still", the adaptive tiles' still class, the early-out. A thousandth of
#: a pixel (the size of EPSILON): a blur that short changes no pixel by more than 1e-3 of its
#: contrast with its neighbour.
STILL_SPEED = EPSILON
#: Seed 000's early-out (Listing 1): a pixel whose neighbourhood moves at most this far (half a
#: pixel beyond still) returns its own colour.
EARLY_OUT_SPEED = STILL_SPEED + 0.5

#: Defaults of seed 000: maximum blur radius k, minimum radius 0.5 px, S filter taps.
DEFAULT_MAX_RADIUS = 20.0
DEFAULT_MIN_RADIUS = 0.5
DEFAULT_SAMPLES = 15

#: Default soft depth band of `soft_depth_compare` in `reconstruct` and `bezier_scatter`, relative to
#: depth: a point z_b counts as in front of z_a up to z_b = z_a (1 + DEFAULT_RELATIVE_Z_EXTENT),
#: fading linearly in log depth. A band in depth units (seed 000 uses 1 mm to 10 cm in metres)
#: depends on the scene's units; a relative one does not: rescaling depth changes no output.
#: Measured (docs/defaults.md; box shutter, 128 x 128, PyTorch, PSNR): on the four Mitsuba scenes and
#: five 2.5D presets reconstruct is within 0.23 dB of its best band (absolute 0.01 to 100, relative
#: 0.01 to 3) at r = 0.3, and bezier_scatter within 0.53 dB on the seven scenes where objects move
#: before still pixels; it gains 0.04 to 1.96 dB over the old absolute 0.1 on the Mitsuba scenes
#: (moving box 33.90 -> 35.16, dolly 25.77 -> 27.73). With a moving camera (dolly, zoom) the
#: scatter's composite="sum" does best with no depth test at all; its default composite="layers"
#: keeps the splats from behind for what a pixel uncovers, and r = 0.3 serves both (docs/defaults.md).
DEFAULT_RELATIVE_Z_EXTENT = 0.3

#: The shutter every op takes unless told otherwise: the box, a shutter open over the whole exposure,
#: as a camera's is and as the scene renderer (`diffblur.scenes`) integrates by default. Ops called
#: with defaults then blur as one camera would. The right window is the camera's: on the translate,
#: propeller, crossing, gears and zoom presets (128 x 128) the scatter loses 1.2 to 3.1 dB (PSNR)
#: with a Gaussian against a box-shutter render, and 1.8 to 3.2 dB with a box against a Gaussian one.
DEFAULT_SHUTTER = "box"

#: The jitter options of `reconstruct` besides an array: interleaved gradient noise, or none.
JITTER_MODES = ("noise", "none")

#: Which directions `reconstruct` takes its taps along: the neighbourhood's dominant velocity
#: (seed 000), or alternately that and the pixel's own velocity (seed 000 sec. 4.3, future work).
TAP_DIRECTIONS = ("neighbor", "neighbor_and_own")

#: How the gather and the reconstruction filter read the image at a tap: "bilinear" (differentiable
#: in the positions, the default), "nearest" (rounded to the nearest pixel, as the documents do; no
#: gradient through positions) or "pyramid" (bilinear, from a pre-filtered level where the taps are
#: farther apart than a pixel: seed 001's texture-space blur, `diffblur.ops.pyramid`).
SAMPLING_MODES = ("bilinear", "nearest", "pyramid")
#: How the warps (`warp_blend`, `accumulate_warps`) read a warped image: bilinear or nearest.
WARP_SAMPLING_MODES = ("bilinear", "nearest")

#: Which implementation an op with a fused CPU kernel runs: "auto" (the kernel where it applies,
#: the tensor ops elsewhere), "fused" (the kernel, or a ValueError naming what it does not cover),
#: "tensor" (always the tensor ops).
IMPLS = ("auto", "fused", "tensor")

#: The cylinder classifier's smoothstep runs from CYLINDER_INNER to CYLINDER_OUTER times the speed
#: (seed 000, Figure 4).
CYLINDER_INNER = 0.95
CYLINDER_OUTER = 1.05

#: Interleaved gradient noise (Jimenez 2014): noise(x, y) = fract(C * fract(A x + B y)), computed in
#: float64 by every backend so that all three give the same jitter bit for bit before the cast.
IGN_A = 0.06711056
IGN_B = 0.00583715
IGN_C = 52.9829189

__all__ = [
    "CYLINDER_INNER",
    "CYLINDER_OUTER",
    "DEFAULT_MAX_RADIUS",
    "DEFAULT_MIN_RADIUS",
    "DEFAULT_SAMPLES",
    "DEFAULT_SHUTTER",
    "DEFAULT_RELATIVE_Z_EXTENT",
    "EARLY_OUT_SPEED",
    "JITTER_MODES",
    "TAP_DIRECTIONS",
    "DEPTH_CHANNELS",
    "EPSILON",
    "IGN_A",
    "IGN_B",
    "IGN_C",
    "IMPLS",
    "SAMPLING_MODES",
    "WARP_SAMPLING_MODES",
    "STILL_SPEED",
    "VECTOR_CHANNELS",
    "X_CHANNEL",
    "Y_CHANNEL",
]
