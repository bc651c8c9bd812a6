"""Learn per-pixel motion from two sharp frames through the differentiable blur (issue 24).

See README.md beside this file. `python -m examples.learn_motion --framework torch|jax --minutes 4`.
"""
