"""Figures and summaries of sweep tables: heatmaps, robustness, time steps, payload, nodes."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path


# --------------------------------------------------------------------------------------------------- figure
def heatmap(
    rows: list[dict],
    value: str | Callable[[dict], float],
    x: str,
    y: str,
    *,
    agg: Callable | None = None,
    ax=None,
    cmap: str = "viridis",
    title: str | None = None,
    annotate: bool = True,
    vmin: float | None = None,
    vmax: float | None = None,
    fontsize: float = 8,
):
    """Heatmap of a result over two parameters (other parameters, e.g. seeds, are aggregated).

    Rows without the value (failed cases) are left out; a cell with no value is grey. Example: success rate
    over a robustness grid: ``heatmap(rows, lambda r: r["status"] == "ok", x="phase", y="magnitude")``.

    Args:
        rows: Table rows (:func:`read_table`).
        value: A column name, or a function of a row giving a number (``None``: no value).
        x, y: Parameter columns of the horizontal and vertical axes.
        agg: Aggregation of the values of one cell (default: mean).
        ax: Axes to draw into (default: a new figure).
        cmap: Colour map.
        title: Axes title (default: the value's name).
        annotate: Write each cell's value (black on light cells, white on dark ones).
        vmin, vmax: Limits of the colour scale (default: the data's).
        fontsize: Font size [pt] of the cell values, the title and the axis labels.

    Returns:
        The matplotlib figure.
    """
    import matplotlib.pyplot as plt
    import numpy as np

    get = value if callable(value) else (lambda row: row.get(value))
    agg = agg or np.mean

    def key(v):
        return (isinstance(v, str), v if not isinstance(v, str) else str(v))

    xs = sorted({r[x] for r in rows}, key=key)
    ys = sorted({r[y] for r in rows}, key=key)
    cells = {}
    for row in rows:
        v = get(row)
        if v is not None and not (isinstance(v, float) and math.isnan(v)):
            cells.setdefault((row[y], row[x]), []).append(float(v))
    table = np.full((len(ys), len(xs)), np.nan)
    for i, yv in enumerate(ys):
        for j, xv in enumerate(xs):
            if (yv, xv) in cells:
                table[i, j] = agg(cells[(yv, xv)])
    if ax is None:
        fig, ax = plt.subplots(figsize=(1.2 + 0.9 * len(xs), 1.0 + 0.6 * len(ys)), layout="constrained")
    else:
        fig = ax.figure
    colours = plt.get_cmap(cmap).with_extremes(bad="lightgrey")
    image = ax.imshow(
        np.ma.masked_invalid(table), cmap=colours, origin="lower", aspect="auto", vmin=vmin, vmax=vmax
    )
    fig.colorbar(image, ax=ax)
    ax.set_xticks(range(len(xs)), [f"{v:g}" if isinstance(v, float) else str(v) for v in xs])
    ax.set_yticks(range(len(ys)), [f"{v:g}" if isinstance(v, float) else str(v) for v in ys])
    name = value if isinstance(value, str) else getattr(value, "__name__", "value")
    ax.set_xlabel(x, fontsize=fontsize)
    ax.set_ylabel(y, fontsize=fontsize)
    ax.set_title(title or name, fontsize=fontsize)
    ax.tick_params(labelsize=fontsize)
    if annotate:
        for (i, j), v in np.ndenumerate(table):
            if not np.isnan(v):
                colour = text_color(image, v)
                ax.text(j, i, f"{v:.3g}", ha="center", va="center", fontsize=fontsize, color=colour)
    return fig


def text_color(image, value: float) -> str:
    """``"black"`` or ``"white"``, whichever reads better on the colour ``image`` gives ``value``."""
    r, g, b, _ = image.cmap(image.norm(value))
    return "black" if 0.299 * r + 0.587 * g + 0.114 * b > 0.5 else "white"


# ------------------------------------------------------------------------------------------ study figures
def committed_table(name: str) -> list[dict]:
    """The rows of the committed sweep table ``<repo>/data/results/sweeps/<name>.csv``.

    Found from the package's location (like :func:`wbmpc.viz.plots.repo_root`), not the current folder, so a
    notebook started from anywhere reads the same data.

    Raises:
        FileNotFoundError: the table is not there (or holds no row), with the path looked at.
    """
    from wbmpc.viz.plots import repo_root

    path = repo_root() / "data" / "results" / "sweeps" / f"{name}.csv"
    if not path.is_file():
        raise FileNotFoundError(
            f"the committed sweep table {path} is missing: it comes with the repository (git checkout "
            f"data/results/sweeps) or is rewritten by `python -m wbmpc.studies.sweeps robustness`"
        )
    from wbmpc.studies.sweeps.engine import read_table

    rows = read_table(path)
    if not rows:
        raise FileNotFoundError(f"the committed sweep table {path} holds no rows")
    return rows


FIGURE_FONT_SIZE = 9  # [pt]: every text of the robustness figures, so that they read alike side by side


def robustness_figures(rows: list[dict], directory: str | Path, min_cells: int = 2) -> list[Path]:
    """Heatmaps of a robustness table over kick magnitude x gait phase: survival (mean over seeds) and the
    peak calf torque over its limit, one figure per direction (rows: delays; columns: the two). A table that
    compares the swing abort on and off (a ``kick_recovery`` column with numbers and empty cells, empty
    meaning off) gets one figure per setting: ``robustness_<direction>[_recovery_off|_recovery_<value>].png``.
    A direction with fewer than ``min_cells`` cells (magnitude x phase) gets no figure: a map of one cell says
    less than the report's line (:func:`robustness_report`).
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    done = [r for r in rows if r["status"] in ("ok", "fell")]
    settings = sorted({r.get("kick_recovery") for r in done}, key=str)
    compare = len(settings) > 1
    paths = []
    for direction in sorted({r.get("direction", "lateral") for r in done}):
        for setting in settings:
            mine = [
                r
                for r in done
                if r.get("direction", "lateral") == direction and r.get("kick_recovery") == setting
            ]
            if len({(r["magnitude"], r["phase"]) for r in mine}) < max(min_cells, 1):
                continue
            suffix = "" if not compare else "_recovery_off" if setting is None else f"_recovery_{setting:g}"
            tag = "" if not compare else ", swing abort off" if setting is None else ", swing abort on"
            delays = sorted({r.get("delay") or 0.0 for r in mine})
            n_m, n_p = len({r["magnitude"] for r in mine}), len({r["phase"] for r in mine})
            fig = Figure(figsize=(2 * (1.8 + 0.75 * n_p), 0.9 + (1.0 + 0.4 * n_m) * len(delays)))
            fig.set_layout_engine("constrained")
            axes = fig.subplots(len(delays), 2, squeeze=False)
            for i, delay in enumerate(delays):
                cell = [r for r in mine if (r.get("delay") or 0.0) == delay]
                label = "no delay" if not delay else f"delay {1e3 * delay:g} ms"
                heatmap(cell, lambda r: float(r["status"] == "ok"), x="phase", y="magnitude", ax=axes[i, 0],
                        cmap="RdYlGn", title=f"survival (fraction), {label}", vmin=0.0, vmax=1.0,
                        fontsize=FIGURE_FONT_SIZE)  # fmt: skip
                heatmap(cell, "calf_torque_ratio", x="phase", y="magnitude", ax=axes[i, 1], cmap="magma",
                        title=f"peak calf torque / limit, {label}", vmin=0.0, vmax=1.0,
                        fontsize=FIGURE_FONT_SIZE)  # fmt: skip
                for ax in axes[i]:
                    ax.set_xlabel("gait phase of the kick", fontsize=FIGURE_FONT_SIZE)
                    ax.set_ylabel("kick [m/s]", fontsize=FIGURE_FONT_SIZE)
            fig.suptitle(f"{direction} kick while trotting in place{tag}", fontsize=FIGURE_FONT_SIZE + 1)
            path = directory / f"robustness_{direction}{suffix}.png"
            fig.savefig(path, dpi=110)
            paths.append(path)
    return paths


def robustness_report(rows: list[dict], up_to: float = 0.8) -> dict:
    """Survival rates of a robustness table: overall, up to ``up_to`` m/s, per magnitude, at the lift-offs."""
    done = [r for r in rows if r["status"] in ("ok", "fell")]

    def rate(sel):
        return None if not sel else sum(r["status"] == "ok" for r in sel) / len(sel)

    return {
        "cases": len(done),
        "errors": len(rows) - len(done),
        "survival": rate(done),
        f"survival_up_to_{up_to:g}": rate([r for r in done if r["magnitude"] <= up_to + 1e-9]),
        "survival_lift_off": rate([r for r in done if r["phase"] in (0.0, 0.5)]),
        "survival_by_magnitude": {
            f"{m:g}": rate([r for r in done if r["magnitude"] == m])
            for m in sorted({r["magnitude"] for r in done})
        },
        "survival_by_direction": {
            d: rate([r for r in done if r.get("direction") == d])
            for d in sorted({r.get("direction") for r in done})
        },
        "survival_by_direction_and_magnitude": {
            f"{d} {m:g}": rate([r for r in done if r.get("direction") == d and r["magnitude"] == m])
            for d in sorted({r.get("direction") for r in done})
            for m in sorted({r["magnitude"] for r in done if r.get("direction") == d})
        },
        # lift_off: the FR/RL lift-off the phases count from (rows without the column: 1.2 s)
        "survival_by_lift_off": {
            f"{lo:g}": rate([r for r in done if (r.get("lift_off") or 1.2) == lo])
            for lo in sorted({r.get("lift_off") or 1.2 for r in done})
        },
        "falls": sorted(
            [
                (r.get("direction"), r["magnitude"], r["phase"], r.get("delay"), r.get("seed"))
                for r in done
                if r["status"] == "fell"
            ],
            key=str,
        ),  # fmt: skip
    }


def time_steps_summary(rows: list[dict]) -> list[dict]:
    """Per grid and delay: runs, falls, and the base drift [cm/s] of the runs that stood (mean, std, min,
    max over the seeds), sorted by delay then grid."""
    import numpy as np

    out = []
    keys = sorted({(float(r["delay"]), r["grid"]) for r in rows if r.get("grid") is not None})
    for delay, g in keys:
        mine = [r for r in rows if r.get("grid") == g and float(r["delay"]) == delay]
        stood = [
            float(r["drift_cm_per_s"])
            for r in mine
            if not r.get("fell") and r.get("drift_cm_per_s") is not None
        ]
        out.append(
            {
                "grid": g,
                "delay_ms": 1e3 * delay,
                "runs": len(mine),
                "fell": sum(bool(r.get("fell")) for r in mine),
                "drift_mean": float(np.mean(stood)) if stood else None,
                "drift_std": float(np.std(stood, ddof=1)) if len(stood) > 1 else None,
                "drift_min": min(stood) if stood else None,
                "drift_max": max(stood) if stood else None,
            }
        )
    return out


def time_steps_figures(rows: list[dict], directory: str | Path) -> list[Path]:
    """Base drift over delay, adaptive vs uniform grid: mean and min-max over the seeds of the runs that
    stood; a delay where runs fell is marked with how many."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import numpy as np
    from matplotlib.figure import Figure

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    fig = Figure(figsize=(5.5, 3.2), layout="constrained")
    ax = fig.subplots()
    summary = time_steps_summary(rows)
    for i, g in enumerate(("adaptive", "uniform")):
        mine = [s for s in summary if s["grid"] == g]
        stood = [s for s in mine if s["drift_mean"] is not None]
        if stood:
            x = np.array([s["delay_ms"] for s in stood]) + (i - 0.5) * 0.8  # side by side
            mean = np.array([s["drift_mean"] for s in stood])
            err = [mean - [s["drift_min"] for s in stood], np.array([s["drift_max"] for s in stood]) - mean]
            ax.errorbar(x, mean, yerr=err, marker="o", capsize=3, label=g, color=f"C{i}")
        for s in mine:
            if s["fell"]:
                ax.annotate(
                    f"{g}: {s['fell']}/{s['runs']} fell", (s["delay_ms"], 0.05 + 0.1 * i),
                    xycoords=("data", "axes fraction"), ha="center", fontsize=7, color=f"C{i}",
                )  # fmt: skip
    if summary:
        delays = [s["delay_ms"] for s in summary]
        ax.set_xlim(min(delays) - 4, max(delays) + 8)
    ax.set(xlabel="computation delay [ms]", ylabel="base drift [cm/s]", title="Adaptive vs uniform steps")
    ax.legend(fontsize=8)
    path = directory / "time_steps.png"
    fig.savefig(path, dpi=110)
    return [path]


def _xy_figure(rows: list[dict], x: str, ys: tuple[str, ...], name: str, directory: str | Path, by=None):
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    fig = Figure(figsize=(5.5, 2.2 * len(ys)), layout="constrained")
    axes = fig.subplots(len(ys), 1, squeeze=False)[:, 0]
    groups = sorted({r.get(by) for r in rows}, key=str) if by else [None]
    for ax, y in zip(axes, ys, strict=True):
        for g in groups:
            mine = sorted(
                [r for r in rows if (by is None or r.get(by) == g) and r.get(y) is not None],
                key=lambda r: r[x],
            )
            ax.plot(
                [r[x] for r in mine], [float(r[y]) for r in mine], "o-", label=f"{by}={g}" if by else None
            )
        ax.set(xlabel=x, ylabel=y)
        if by:
            ax.legend(fontsize=8)
    path = directory / f"{name}.png"
    fig.savefig(path, dpi=110)
    return [path]


def payload_figures(rows: list[dict], directory: str | Path) -> list[Path]:
    """Load displacement and success over the load mass, standing and walking."""
    return _xy_figure(rows, "mass", ("load_displacement_m", "success"), "payload", directory, by="walking")


def nodes_figures(rows: list[dict], directory: str | Path) -> list[Path]:
    """Solve time and end-effector tracking over the node count."""
    return _xy_figure(rows, "nodes", ("solve_ms_median", "ee_rms_cm", "iterations_mean"), "nodes", directory)
