"""The README's promises: CI runs its test command, its code blocks run, its commands work."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from diffblur.app.cli import main

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text()


def code_blocks(language: str, text: str = README) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", text, flags=re.S)


#: The guide's pages: their Python blocks run too.
GUIDE = {path.relative_to(ROOT).as_posix(): path.read_text() for path in sorted((ROOT / "docs").glob("*.md"))}


def test_ci_runs_exactly_the_readme_test_command():
    bash = code_blocks("bash")
    test_commands = [b.strip() for b in bash if "pytest" in b]
    assert len(test_commands) == 1
    ci_lines = [line.strip() for line in (ROOT / ".ci" / "run").read_text().splitlines()]
    assert test_commands[0] in ci_lines


def test_readme_main_job_command_runs_the_demo():
    (main_job,) = [b.strip() for b in code_blocks("bash") if "demo" in b]
    assert main_job.endswith("diffblur demo --out demo_out")


@pytest.mark.parametrize("index", range(len(code_blocks("python"))))
def test_readme_python_blocks_run(index):
    exec(compile(code_blocks("python")[index], f"README.md python block {index}", "exec"), {})


@pytest.mark.parametrize("page, index", [(page, i) for page, text in GUIDE.items() for i in range(len(code_blocks("python", text)))])
def test_guide_python_blocks_run(page, index):
    exec(compile(code_blocks("python", GUIDE[page])[index], f"{page} python block {index}", "exec"), {})


def test_readme_is_short():
    assert len(README.splitlines()) <= 150


@pytest.mark.parametrize("page", ["README.md", "CHANGELOG.md", *GUIDE])
def test_pictures_and_links_point_at_files_that_exist(page):
    text = (ROOT / page).read_text()
    for target in re.findall(r"\]\(([^)#]+)\)", text):
        if not re.match(r"[a-z]+://", target):
            assert (ROOT / page).parent.joinpath(target).exists(), f"{page}: {target}"


def test_the_layout_table_names_files_that_exist():
    """The README's "Where things are": every path it names exists, so a newcomer finds each op's
    definition, backend code, reference and kernel in one step."""
    section = README.split("## Where things are", 1)[1].split("\n## ", 1)[0]
    paths = set(re.findall(r"`((?:diffblur|torch_impl|jax_impl|fitting|tests)/[\w./*]*)`", section))
    assert len(paths) > 20
    for path in paths:
        assert list(ROOT.glob(path)), path


def test_the_layout_table_points_at_each_ops_definition_and_backends():
    """Each row of the layout table names the files that define the op: its definition in
    diffblur/ops and both backends' public functions hold `def <op>(` (or `class <op>`)."""
    section = README.split("## Where things are", 1)[1].split("\n## ", 1)[0]
    rows = [line for line in section.splitlines() if line.startswith("| `")]
    assert len(rows) >= 6
    for row in rows:
        cells = [cell.strip() for cell in row.strip("|").split("|")]
        ops = [name for name in re.findall(r"`(\w+)`", cells[0]) if name not in ("tile_max", "cone")] or ["tile_max"]
        files = {column: re.findall(r"`([\w/.]+\.py)`", cells[column]) for column in (1, 2)}
        for op in ops:
            pattern = re.compile(rf"^(def|class) {op}\b", re.MULTILINE)
            for path in [*files[1], *files[2]]:
                text = (ROOT / path).read_text()
                if path.startswith("diffblur/ops/") and op == "MotionBlur":
                    assert "def blur(" in text, path
                else:
                    assert pattern.search(text), (op, path)


def test_demo_writes_a_picture_and_a_table(tmp_path, capsys):
    from diffblur.app.demo import DEMO_METHODS

    # The fit stage (fitting.recover on both backends) is tested in tests/fitting; skipped here for time.
    assert main(["demo", "--out", str(tmp_path), "--size", "48", "--no-fit"]) == 0
    printed = capsys.readouterr().out
    assert (tmp_path / "demo.png").stat().st_size > 10_000
    labels = [label for label, *_ in DEMO_METHODS]
    rows = [line for line in printed.splitlines() if line.startswith(tuple(labels))]
    assert len(rows) == 2 * len(labels)
    assert {row.split()[-4] for row in rows} == {"torch", "jax"}
    for row in rows:
        psnr = float(row.split()[-3])
        assert 15 < psnr < 60


def test_cli_reports_bad_arguments_readably(tmp_path, capsys):
    assert main(["gallery", "--out", str(tmp_path), "--size", "4"]) == 2
    assert "height and width must be >= 8 pixels" in capsys.readouterr().err


def test_python_dash_m_works():
    result = subprocess.run([sys.executable, "-m", "diffblur", "--help"], capture_output=True, text=True, cwd=ROOT)
    assert result.returncode == 0 and "demo" in result.stdout
