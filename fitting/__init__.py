"""Recover motion parameters by gradient descent against a blurred target, in PyTorch or JAX.

`recover(sharp, target, model=...)` fits one of `MODELS` (a global velocity, an exposure, a shutter
shape, a velocity per motion ID, camera pan/zoom/roll, a rotation, a coarse grid of velocities, a
dense field); `select_model` tries them from the simplest up. Neither framework is imported until a
fit asks for it.
"""

from fitting._models import MODELS
from fitting._recover import FitResult, recover
from fitting._select import Selection, select_model

__all__ = ["MODELS", "FitResult", "Selection", "recover", "select_model"]
