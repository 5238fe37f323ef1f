"""Notebook hygiene: committed notebooks are clean, well named, titled and quick-mode aware.

Each notebook under ``notebooks/`` is its own test id. The ``check_*`` helpers take a path so they
can be pointed at any notebook.
"""

from __future__ import annotations

import re
from pathlib import Path

import nbformat
import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
NAME_RE = re.compile(r"^\d{2}_[a-z0-9]+(?:_[a-z0-9]+)*\.ipynb$")
QUICK_MARKERS = ("pick(", "quick_mode(")


def find_notebooks(root: Path = REPO_ROOT) -> list[Path]:
    """Return the sorted ``notebooks/*.ipynb`` files under ``root``."""
    return sorted((root / "notebooks").glob("*.ipynb"))


def _read(path: Path) -> nbformat.NotebookNode:
    return nbformat.read(path, as_version=4)


def check_no_outputs(path: Path) -> list[str]:
    """Problems with code cells that carry outputs or an execution count."""
    problems = []
    for i, cell in enumerate(_read(path).cells):
        if cell.cell_type != "code":
            continue
        if cell.get("outputs"):
            problems.append(f"cell {i}: has {len(cell.outputs)} output(s)")
        if cell.get("execution_count") is not None:
            problems.append(f"cell {i}: execution_count={cell.execution_count}")
    return problems


def check_name(path: Path) -> list[str]:
    """Problems with the file name (must be ``NN_lower_snake.ipynb``)."""
    if NAME_RE.match(path.name):
        return []
    return [f"name {path.name!r} is not NN_lower_snake_topic.ipynb"]


def check_title(path: Path) -> list[str]:
    """Problems with the first cell (must be markdown starting with a ``# `` title)."""
    cells = _read(path).cells
    if not cells:
        return ["notebook has no cells"]
    first = cells[0]
    if first.cell_type != "markdown":
        return [f"first cell is {first.cell_type}, not markdown"]
    lines = [line for line in first.source.splitlines() if line.strip()]
    if not lines or not lines[0].startswith("# "):
        return ["first cell does not start with a '# ' title"]
    return []


def check_quick_flag(path: Path) -> list[str]:
    """Problems if no code cell references the quick-mode flag (``pick(`` or ``quick_mode(``)."""
    code = "\n".join(c.source for c in _read(path).cells if c.cell_type == "code")
    if any(marker in code for marker in QUICK_MARKERS):
        return []
    return ["no code cell calls pick(...) or quick_mode(...) (see wbmpc.quick)"]


NOTEBOOKS = find_notebooks()
_IDS = [p.name for p in NOTEBOOKS]


def test_notebooks_exist():
    assert NOTEBOOKS, f"no notebooks found under {REPO_ROOT / 'notebooks'}"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=_IDS)
def test_no_outputs(path):
    problems = check_no_outputs(path)
    assert not problems, f"{path.name}: strip outputs before committing:\n" + "\n".join(problems)


@pytest.mark.parametrize("path", NOTEBOOKS, ids=_IDS)
def test_name(path):
    assert not check_name(path), check_name(path)[0]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=_IDS)
def test_title(path):
    problems = check_title(path)
    assert not problems, f"{path.name}: " + "; ".join(problems)


@pytest.mark.parametrize("path", NOTEBOOKS, ids=_IDS)
def test_quick_flag(path):
    problems = check_quick_flag(path)
    assert not problems, f"{path.name}: " + "; ".join(problems)


# The numbers the notebooks' text quotes are checked in tests/test_notebook_numbers.py.
