"""The notebooks run, top to bottom, and print what their text says (each also asserts inside)."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

NOTEBOOKS = Path(__file__).resolve().parent.parent / "notebooks"

#: Per notebook, patterns its printed output must contain.
EXPECTED_OUTPUT = {
    "quickstart.ipynb": [r"max \|torch - jax\| = \d\.\de-0[5-9]", r"d loss / d exposure at 0\.5: torch -"],
    "extremes.ipynb": [r"box:  loss\(\+4\) = 0\.00e\+00", r"local minima, prefiltered:\s+\[20\.\]"],
    "fitting.ipynb": [
        r"torch: velocity = \(-?(2\.9|3\.0)\d, -?1\.[45]\d\)",
        r"jax  : velocity = \(-?(2\.9|3\.0)\d, -?1\.[45]\d\)",
        r"global velocity error \(up to sign\): 0\.0\d\d px",
        r"exposure: true 1\.000, recovered (0\.99|1\.00)\d\d",
        r"angle: true 0\.500 rad, recovered 0\.(49|50)\d rad",
    ],
    "speed_accuracy.ipynb": [
        r"\d+ rows from `diffblur bench",
        r"propeller  \| (warp_blend|gather) [^|]* \[(jax|torch)\] \d+\.\d ms",
        r"reconstruct / gather_blur forward at S=15 on the moving scenes, torch: median \d\.\dx \(\d\.\dx to \d+\.\dx\)",
        r"propeller front \(\d+ rows, fastest first\)",
        r"propeller: bezier \d+\.\d\d dB vs gather \d+\.\d\d dB",
        r"wrote BENCHMARKS\.md, docs/benchmarks\.json, docs/pareto\.png",
        r"live crossing 32 px: bezier \d+\.\d\d dB > gather \d+\.\d\d dB",
    ],
}


def test_every_notebook_is_executed_here():
    assert sorted(p.name for p in NOTEBOOKS.glob("*.ipynb")) == sorted(EXPECTED_OUTPUT)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(EXPECTED_OUTPUT))
def test_notebook_runs_and_prints_what_it_claims(name):
    import nbclient
    import nbformat

    notebook = nbformat.read(NOTEBOOKS / name, as_version=4)
    # The kernel shows figures inline, as for a user (the suite's conftest sets Agg for itself).
    env = {key: value for key, value in os.environ.items() if key != "MPLBACKEND"}
    client = nbclient.NotebookClient(notebook, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(NOTEBOOKS)}})
    client.execute(env=env)
    printed = "".join(
        output.get("text", "") for cell in notebook.cells if cell.cell_type == "code" for output in cell.outputs if output.get("name") == "stdout"
    )
    figures = sum(1 for cell in notebook.cells if cell.cell_type == "code" for output in cell.outputs if "image/png" in output.get("data", {}))
    assert figures >= 1, "every notebook shows at least one picture"
    for pattern in EXPECTED_OUTPUT[name]:
        assert re.search(pattern, printed), f"{name} did not print {pattern!r}; it printed:\n{printed}"
