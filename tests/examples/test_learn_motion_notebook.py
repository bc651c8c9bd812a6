"""examples/learn_motion/learn_motion.ipynb runs top to bottom at a tiny size (LEARN_MOTION_TINY=1:
16 x 16 scenes, 12 training steps), prints its report and the PyTorch/JAX agreement on the same
weights, and shows its pictures (it also asserts inside)."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

NOTEBOOK = Path(__file__).resolve().parents[2] / "examples" / "learn_motion" / "learn_motion.ipynb"

EXPECTED_OUTPUT = [
    r"\| \(a\) sharp middle frame \| \d+\.\d\d \| [01]\.\d{4} \|",
    r"\| \(c\) blur from the network's motion \| \d+\.\d\d \| [01]\.\d{4} \|",
    r"\| \(d\) blur from the true motion, same op \| \d+\.\d\d \| [01]\.\d{4} \|",
    r"Endpoint error of the learned motion: \d+\.\d\d px",
    r"max \|torch - jax\| = \d\.\de-\d\d \(blur\)",
]


@pytest.mark.slow
def test_the_notebook_runs_at_a_tiny_size():
    pytest.importorskip("torch", reason="the notebook trains the PyTorch model")
    pytest.importorskip("equinox", reason="the notebook runs the JAX model")
    import nbclient
    import nbformat

    notebook = nbformat.read(NOTEBOOK, as_version=4)
    env = {key: value for key, value in os.environ.items() if key != "MPLBACKEND"}
    env["LEARN_MOTION_TINY"] = "1"
    env["PYTHONPATH"] = os.pathsep.join([str(NOTEBOOK.parents[2]), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    client = nbclient.NotebookClient(notebook, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(NOTEBOOK.parent)}})
    client.execute(env=env)
    printed = "".join(
        output.get("text", "") for cell in notebook.cells if cell.cell_type == "code" for output in cell.outputs if output.get("name") == "stdout"
    )
    figures = sum(1 for cell in notebook.cells if cell.cell_type == "code" for output in cell.outputs if "image/png" in output.get("data", {}))
    assert figures >= 2, "the scene and the report's picture"
    for pattern in EXPECTED_OUTPUT:
        assert re.search(pattern, printed), f"the notebook did not print {pattern!r}; it printed:\n{printed}"
