"""Recover motion parameters by gradient descent against a blurred target, in PyTorch or JAX.

`recover(sharp, target, model=...)` fits a motion model: an object that carries its own options
(`Global()`, `Exposure(velocity=...)`, `Shutter(velocity=...)`, `MotionIds(ids=...)`, `Layers()`,
`CameraMotion()`, `Rotation()`, `Tiles(grid=...)`, `Dense(tv_weight=...)`), or one of `MODELS` as a
shortcut for its defaults; `select_model` tries them from the simplest up. Neither framework is imported until a
fit asks for it.
"""

from fitting._models import MODELS, CameraMotion, Dense, Exposure, Global, Layers, Model, MotionIds, Rotation, Shutter, Tiles, depth_layers
from fitting._recover import METHOD_SHIFT_WARNING, FitResult, recover
from fitting._select import Selection, select_model

__all__ = ["METHOD_SHIFT_WARNING", "MODELS", "CameraMotion", "Dense", "Exposure", "FitResult", "Global", "Layers", "Model", "MotionIds", "Rotation", "Selection", "Shutter", "Tiles", "depth_layers", "recover", "select_model"]
