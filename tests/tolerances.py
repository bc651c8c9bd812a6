"""The test suite's one tolerance table: per dtype, per kind of comparison. Tests take their
tolerances from here, so that tightening or loosening one is one edit, seen for every test.

Kinds of comparison:
- "output": one op's outputs from two implementations of the same formulas (NumPy reference,
  PyTorch, JAX, a module against its functional op): (atol, rtol).
- "gradient": gradients from two implementations (the frameworks against each other, jit against
  eager): (atol, rtol).
- "fused": a fused CPU kernel against the tensor ops, which sum in another order, per op: atol
  on the output, and on each gradient times max(1, its largest magnitude). The scatter's splats
  add more terms per pixel, in another order, than the filters' taps.
- "half": float16 / bfloat16 outputs against float32, the largest error relative to the output's
  scale: twice the worst measured on 20 x 21 images when positions were held in the half type
  (float16: 6.2e-3, warp_blend; bfloat16: 5.5e-2, the layer's warp_blend). With positions,
  offsets and weights in float32 the worst measured (PyTorch) is 7.6e-4 / 5.8e-3
  (velocity_from_motion, elementwise), and on 300 px wide images 2.4e-4 / 2.0e-3.
"""

from __future__ import annotations

TOLERANCES: dict[str, dict[str, object]] = {
    "float64": {
        "output": (1e-12, 1e-10),
        "gradient": (1e-10, 1e-9),
        "fused": {"gather_blur": 1e-12, "reconstruct": 1e-11, "bezier_scatter": 1e-10},
    },
    "float32": {
        "output": (1e-5, 1e-5),
        "gradient": (1e-4, 1e-4),
        "fused": {"gather_blur": 2e-5, "reconstruct": 2e-5, "bezier_scatter": 1e-4},
    },
    "float16": {"half": 1.5e-2},
    "bfloat16": {"half": 1.2e-1},
}


def tolerance(dtype: str, kind: str, op: str | None = None):
    """TOLERANCES[dtype][kind] (and [op] for "fused"); a KeyError names what the table lacks."""
    try:
        entry = TOLERANCES[dtype][kind]
        return entry[op] if op is not None else entry
    except KeyError:
        raise KeyError(f"no {kind!r} tolerance for {dtype}{'' if op is None else ' ' + op} in tests/tolerances.py") from None
