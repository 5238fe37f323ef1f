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


# --- numbers quoted in markdown, checked against what the cells compute ---------------------------------
def _markdown(path: Path) -> str:
    return "\n".join(c.source for c in _read(path).cells if c.cell_type == "markdown")


def test_robustness_notebook_quotes_its_tables():
    """Notebook 06's text quotes counts of the committed sweep tables its cells read: they must match."""
    from wbmpc.studies import sweeps

    text = " ".join(_markdown(REPO_ROOT / "notebooks" / "06_robustness_sweeps.ipynb").split())

    def ok(rows):
        return sum(r["status"] == "ok" for r in rows)

    final = sweeps.committed_table("robustness_landing")
    up_to = [r for r in final if r["status"] in ("ok", "fell") and r["magnitude"] <= 0.8 + 1e-9]
    lift_off = [r for r in up_to if r["phase"] in (0.0, 0.5)]
    assert f"`robustness_landing.csv`, {len(final)} cases" in text
    assert (
        f"{ok(up_to)} of the {len(up_to)} cases up to 0.8 m/s stand ({100 * ok(up_to) / len(up_to):.0f} %)"
        in text
    )
    assert f"{ok(lift_off)} of the {len(lift_off)} lift-off cases" in text

    grid = sweeps.committed_table("robustness_grid")
    up_to = [r for r in grid if r["magnitude"] <= 0.8 + 1e-9]
    assert f"{ok(up_to)} of the {len(up_to)} cases stand ({100 * ok(up_to) / len(up_to):.1f} %)" in text
    undisturbed = {
        delay: [
            r["calf_torque_ratio"] for r in grid if (r["delay"] or 0.0) == delay and r["magnitude"] == 0.0
        ]
        for delay in (0.0, 0.0125)
    }
    low, high = (round(100 * f(undisturbed[0.0])) for f in (min, max))
    assert f"uses {low}-{high} % of it ({round(100 * max(undisturbed[0.0125]))} % with the delay)" in text

    forward = [r for r in sweeps.committed_table("robustness") if r.get("direction") == "forward"]
    assert "not in this grid" not in text, "the forward case is in the table (and in its report)"
    assert forward and all(r["status"] == "fell" for r in forward), "the text says the forward case falls"


def test_hardware_notebook_quotes_its_com_identification():
    """Notebook 05's text on the identified base CoM quotes what its cell computes from the committed bag."""
    import json

    import numpy as np

    from wbmpc import analysis
    from wbmpc.io.rosbag import read_bag
    from wbmpc.model.robot import load_b1_z1

    text = " ".join(_markdown(REPO_ROOT / "notebooks" / "05_hardware_log_analysis.ipynb").split())
    robot = load_b1_z1()
    bag = REPO_ROOT / "data" / "hardware" / "emulated_b1_stand_trot"
    how = json.loads((REPO_ROOT / "data" / "hardware" / "emulated_b1_stand_trot.json").read_text())
    log = read_bag(bag)
    ident = analysis.identify_com_offset(log, robot, mask=analysis.standing_mask(log, t_min=0.5, t_max=2.0))
    emulated = np.array(how["emulated_robot"]["base_com_offset"])
    error_mm = 1e3 * np.linalg.norm(ident.offset[:2] - emulated[:2])
    assert f"{-100 * ident.offset[0]:.2f} cm behind the model's" in text
    assert f"{error_mm:.1f} mm from the emulated {-100 * emulated[0]:g} cm" in text
    assert f"CoM: {-100 * ident.com_shift[0]:.1f} cm back" in text
    assert f"the rear feet carry {100 * ident.summary()['rear_share']:.0f} % of the weight" in text
    assert f"$m_b$ = {ident.link_mass:g} kg of $M$ = {robot.mass:.1f} kg" in text


def test_quickstart_text_leaves_the_problem_sizes_to_its_cells():
    """Notebook 00 prints the problem's sizes; its text must not quote its own (they went stale before)."""
    text = " ".join(_markdown(REPO_ROOT / "notebooks" / "00_quickstart.ipynb").split())
    stale = [
        m.group(0)
        for pattern in (r"\d[\d,]* decision variables", r"n_[xug] = \d{2,}", r"\*\*\d+ nodes\*\*")
        for m in re.finditer(pattern, text)
    ]
    assert not stale, f"sizes quoted in 00's markdown (print them from a cell instead): {stale}"
