"""Motion models, losses and solvers that recover motion parameters from a sharp frame and a
blurred target (issue 6: not built yet; this package holds only its place in the layout)."""
