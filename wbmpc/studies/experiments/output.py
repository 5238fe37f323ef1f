"""Writing an experiment's results: its summary, figure and logs (:func:`save`), an HTML replay
(:func:`replay_html`).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from wbmpc.io.logs import json_default
from wbmpc.studies.experiments.common import REPO_ROOT, ExperimentResult
from wbmpc.viz.plots import save_figure


def save(
    result: ExperimentResult,
    directory: Path,
    log_directory: Path | None = None,
    figure_directory: Path | None = None,
) -> Path:
    """Write ``<name>.json`` (summary) to ``directory``, ``<name>.png`` (figure) to ``figure_directory``
    (default ``data/output/sim``, git-ignored) and, if ``log_directory`` is given, the runs' logs."""
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / f"{result.name}.json"
    path.write_text(json.dumps(result.summary, indent=2, default=json_default))
    if result.figure is not None:
        save_figure(result.figure, result.name, figure_directory or REPO_ROOT / "data/output/sim")
    if log_directory is not None:
        for label, run in result.runs.items():
            run.save(log_directory / f"{result.name}_{label}.npz")
    return path


def replay_html(
    viewer, result: ExperimentResult, directory: Path | None = None, run: str | None = None
) -> Path:
    """Replay one run of an experiment in a :class:`wbmpc.viz.Viewer` (measured feet forces as arrows)
    and export it as a self-contained HTML file ``<directory>/<name>[_<run>].html``."""
    label = run or next(iter(result.runs))
    log = result.runs[label].log.arrays()
    forces = np.concatenate([log["foot_forces"], log["ee_force_sim"][:, None, :]], axis=1)
    viewer.animation(log["q"], log["t"], forces=forces, contact=log["contact_sim"])
    directory = Path(directory) if directory is not None else REPO_ROOT / "data/output/sim"
    suffix = "" if len(result.runs) == 1 else f"_{label}"
    return viewer.export_html(directory / f"{result.name}{suffix}.html")
