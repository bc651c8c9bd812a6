"""The applications: the `diffblur` command (`cli`: demo, blur, fit, bench, gallery), the benchmark
(`bench`, and `mitsuba_bench` against the Mitsuba ground truth), the demo, blurring a photograph
(`blur_image`) and the timing helpers (`timing`).

The only layer of `diffblur` that imports a backend (`torch_impl`, `jax_impl`), a framework or
`fitting` (tests/core/test_layers.py); it does so inside functions, so `--help` needs neither.
"""
