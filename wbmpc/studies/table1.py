"""The paper's Table I: the six dynamics formulations in closed loop, before and after compilation.

Each formulation runs the same closed loop (default robot, 15 nodes, geometric steps 10-100 ms over 0.56 s,
trot at 0.2 m/s with the arm's low/high reference, rigid-contact Pinocchio forward-dynamics plant, MPC at
80 Hz, 500 Hz interpolation + PD) twice: with the in-process CasADi functions ("pre-compilation") and with
the generated, compiled library ("post-compilation"). The solve times are statistics over the solves after
a warm-up. Timing assertions never go in tests: this command measures and writes

* ``data/bench/table1.csv`` (one row per formulation; :func:`load_table` reads it back),
* ``data/bench/table1.md`` (the table as markdown),
* ``data/output/bench/table1.png`` (solve times and instruction counts).

    python -m wbmpc.studies.table1            # full run: 6 builds + 12 closed loops (about 40 min on 2 cores)
    python -m wbmpc.studies.table1 --quick    # 5 nodes, few steps, in-process only (about a minute)
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

from wbmpc.ocp.formulations import FORMULATIONS
from wbmpc.quick import quick_mode
from wbmpc.studies import cli_checks

REPO_ROOT = Path(__file__).resolve().parents[2]

#: Low-level gains of the benchmark. With pure feed-forward torques (0, 0) the centroidal-velocity
#: plans (torques from RNEA on finite-differenced velocity inputs) fall within 0.6 s; a small PD keeps
#: every formulation on its feet so that all six are timed on the same task.
DEFAULT_KP, DEFAULT_KD = 30.0, 2.0

COLUMNS = (
    "formulation",
    "label",
    "states",
    "inputs",
    "dynamics_constraint",
    "base_in_input",
    "path_constraint",
    "instructions",
    "decision_variables",
    "constraints",
    "nodes",
    "pre_mean_ms",
    "pre_std_ms",
    "pre_median_ms",
    "pre_p95_ms",
    "post_mean_ms",
    "post_std_ms",
    "post_median_ms",
    "post_p95_ms",
    "iterations_mean",
    "post_iterations_mean",
    "converged_fraction",
    "post_converged_fraction",
    "constraint_violation_max",
    "fell",
    "max_tilt_rad",
    "ee_rms_m",
    "build_s",
    "build_peak_mb",
    "pre_evaluations_ms",
    "pre_linear_algebra_ms",
    "post_evaluations_ms",
    "post_linear_algebra_ms",
    "stage_nx",
    "stage_nu_max",
    "stage_ng_max",
    "steps",
    "kp",
    "kd",
    "machine",
)


def table_row(
    robot,
    formulation: str,
    nodes: int,
    steps: int,
    warmup: int,
    compiled: bool,
    kp: float,
    kd: float,
    progress: bool,
) -> dict:
    """One formulation: layout, instruction count, in-process (and compiled) closed-loop timings."""
    from wbmpc.ocp import OCP, OCPSettings
    from wbmpc.studies.bench import run_case

    # The paper's layout (the arm force and node 0's state pinned decision variables), so that the
    # decision variables compare with Table I.
    settings = OCPSettings(
        n_nodes=nodes, formulation=formulation, ee_force_input=True, initial_state_variables=True
    )
    ocp = OCP(robot, settings)
    row = ocp.formulation.describe()
    sizes = ocp.stage_sizes()
    row |= {
        "decision_variables": ocp.n_variables,
        "constraints": ocp.n_constraints,
        "nodes": nodes,
        "stage_nx": sizes["nx"][0],
        "stage_nu_max": max(sizes["nu"]),
        "stage_ng_max": max(sizes["ng"]),
    }
    del ocp
    pre = run_case(
        robot, "fatrop", False, nodes, steps, warmup, progress, formulation, kp, kd, paper_layout=True
    )
    row |= {
        **_timing_columns("pre", pre),
        "iterations_mean": pre["iterations_mean"],
        "converged_fraction": pre["converged_fraction"],
        "constraint_violation_max": pre["constraint_violation_max"],
        "fell": pre["fell"],
        "max_tilt_rad": pre["max_tilt_rad"],
        "ee_rms_m": pre["ee_rms_m"],
        "steps": pre["steps"],
        "kp": kp,
        "kd": kd,
        "machine": pre["machine"],
    }
    if compiled:
        post = run_case(
            robot, "fatrop", True, nodes, steps, warmup, progress, formulation, kp, kd, paper_layout=True
        )
        row |= {
            **_timing_columns("post", post),
            "post_iterations_mean": post["iterations_mean"],
            "post_converged_fraction": post["converged_fraction"],
            "build_s": post["build_s"],
            "build_peak_mb": post["build_peak_mb"],
            "fell": pre["fell"] or post["fell"],
            "constraint_violation_max": max(
                pre["constraint_violation_max"], post["constraint_violation_max"]
            ),
        }
    return row


def _timing_columns(prefix: str, record: dict) -> dict:
    """Timing columns ``<prefix>_{mean,std,median,p95,evaluations,linear_algebra}_ms`` of a run record."""
    columns = {f"{prefix}_{stat}_ms": record[f"{stat}_ms"] for stat in ("mean", "std", "median", "p95")}
    columns[f"{prefix}_evaluations_ms"] = record["profile_mean_ms"]["evaluations"]
    columns[f"{prefix}_linear_algebra_ms"] = _linear_algebra(record)
    return columns


def _linear_algebra(record: dict) -> float | None:
    """Fatrop's own time per solve [ms]: search direction (Riccati recursion) + initialisation."""
    profile = record["profile_mean_ms"]
    parts = [profile.get("search_direction"), profile.get("initialization")]
    return None if any(p is None for p in parts) else float(sum(parts))


def write_csv(rows: list[dict], path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS)
        writer.writeheader()
        for row in rows:
            writer.writerow({key: _fmt(row.get(key)) for key in COLUMNS})


def load_table(path: Path | str | None = None) -> list[dict]:
    """Rows of a Table I CSV with numbers and booleans parsed (empty cells become ``None``).

    Args:
        path: CSV file; the committed full run ``data/bench/table1.csv`` by default.
    """
    path = Path(path) if path is not None else REPO_ROOT / "data/bench/table1.csv"
    if not path.exists():
        raise FileNotFoundError(f"no Table I results at {path}; run `python -m wbmpc.studies.table1` first")
    with path.open() as f:
        return [{key: _parse(value) for key, value in row.items()} for row in csv.DictReader(f)]


def markdown(rows: list[dict]) -> str:
    """The table in the paper's layout, with our extra columns (iterations, violation, build time)."""
    head = (
        "| Formulation | States | Inputs | Dynamics constraint | Path constr. | Instr. per constr. "
        "| Dec. vars | Pre-comp. [ms] avg (std) | Post-comp. [ms] avg (std) | Iterations | Max. violation "
        "| Build [s] |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|\n"
    )
    lines = []
    for r in rows:
        post = "---" if r.get("post_mean_ms") is None else f"{r['post_mean_ms']:.1f} ({r['post_std_ms']:.1f})"
        build = "---" if r.get("build_s") is None else f"{r['build_s']:.0f}"
        lines.append(
            f"| {r['label']} | {r['states']} | {r['inputs']} | {r['dynamics_constraint']} "
            f"| {'yes' if r['path_constraint'] else 'no'} | {r['instructions']} | {r['decision_variables']} "
            f"| {r['pre_mean_ms']:.1f} ({r['pre_std_ms']:.1f}) | {post} | {r['iterations_mean']:.2f} "
            f"| {r['constraint_violation_max']:.1e} | {build} |"
        )
    return head + "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    """Solve time (mean, std) before/after compilation and instructions per dynamics constraint."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    from wbmpc.viz.plots import save_figure

    fig = Figure(figsize=(12, 4.2))
    ax1, ax2 = fig.subplots(1, 2)
    labels = [r["label"].replace(" (", "\n(") for r in rows]
    x = np.arange(len(rows))
    pre = [r["pre_mean_ms"] for r in rows]
    ax1.bar(x - 0.2, pre, 0.4, yerr=[r["pre_std_ms"] for r in rows], capsize=3, label="in-process")
    if any(r.get("post_mean_ms") is not None for r in rows):
        post = [r.get("post_mean_ms") or 0.0 for r in rows]
        ax1.bar(
            x + 0.2, post, 0.4, yerr=[r.get("post_std_ms") or 0.0 for r in rows], capsize=3, label="compiled"
        )
    ax1.set_xticks(x, labels, fontsize=7, rotation=20, ha="right")
    ax1.set(ylabel="solve time [ms], mean ± std", title=f"Fatrop, {rows[0]['nodes']} nodes, closed loop")
    ax1.legend(fontsize=8)
    ax2.bar(x, [r["instructions"] for r in rows], color="tab:green")
    ax2.set_xticks(x, labels, fontsize=7, rotation=20, ha="right")
    ax2.set(ylabel="instructions", title="instructions per dynamics constraint")
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    save_figure(fig, path.name, path.parent)


def check_arguments(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Reject bad values before any work (argparse prints the one-line reason and exits with status 2)."""
    cli_checks.at_least(parser, "--steps", args.steps, 1, "measured MPC steps")
    cli_checks.at_least(parser, "--warmup", args.warmup, 0, "discarded solves")
    cli_checks.nodes(parser, "--nodes", args.nodes)
    cli_checks.non_negative(parser, "--kp", args.kp)
    cli_checks.non_negative(parser, "--kd", args.kd)
    if args.output is not None:
        cli_checks.writable_file(parser, "--output", args.output, "table1.csv")
    cli_checks.writable_folder(parser, "figure folder", REPO_ROOT / "data/output/bench")


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(
        prog="python -m wbmpc.studies.table1", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--quick", action="store_true", help="5 nodes, few steps, in-process only")
    parser.add_argument("--steps", type=int, default=None, help="measured MPC steps per run (default 200)")
    parser.add_argument("--warmup", type=int, default=None, help="discarded solves at the start (default 20)")
    parser.add_argument("--nodes", type=int, default=None, help="nodes incl. terminal (default 15)")
    parser.add_argument("--formulations", nargs="+", default=list(FORMULATIONS), choices=list(FORMULATIONS))
    parser.add_argument("--no-compile", action="store_true", help="skip the post-compilation runs")
    parser.add_argument("--kp", type=float, default=DEFAULT_KP, help="low-level stiffness [N m/rad]")
    parser.add_argument("--kd", type=float, default=DEFAULT_KD, help="low-level damping [N m s/rad]")
    parser.add_argument("--output", type=Path, default=None, help="CSV path (default data/bench/table1.csv)")
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args(argv)
    check_arguments(parser, args)
    from wbmpc.model.robot import load_b1_z1

    quick = args.quick or quick_mode()
    steps = args.steps or (10 if quick else 200)
    warmup = args.warmup if args.warmup is not None else (3 if quick else 20)
    nodes = args.nodes or (5 if quick else 15)
    compiled = not (args.no_compile or quick)
    output = args.output or REPO_ROOT / (
        "data/output/bench/table1_quick.csv" if quick else "data/bench/table1.csv"
    )
    robot = load_b1_z1()
    rows = []
    for name in args.formulations:
        print(f"[table1] {name}: N={nodes}, {steps} steps{' + compiled' if compiled else ''}", flush=True)
        row = table_row(robot, name, nodes, steps, warmup, compiled, args.kp, args.kd, not args.quiet)
        post = f", compiled {row['post_mean_ms']:.1f} ms" if compiled else ""
        print(
            f"         in-process {row['pre_mean_ms']:.1f} ms{post}, iterations {row['iterations_mean']:.2f}",
            flush=True,
        )
        rows.append(row)
        write_csv(rows, output)  # partial results survive an interruption
    output.with_suffix(".md").write_text(markdown(rows))
    plot(rows, REPO_ROOT / "data/output/bench" / (output.stem + ".png"))
    print(f"[table1] wrote {output}, {output.with_suffix('.md')}")
    return rows


def _fmt(value):
    if value is None:
        return ""
    if isinstance(value, bool | np.bool_):
        return "true" if value else "false"
    if isinstance(value, float | np.floating):
        return f"{float(value):.6g}"
    return value


def _parse(value: str):
    if value == "":
        return None
    if value in ("true", "false"):
        return value == "true"
    for kind in (int, float):
        try:
            return kind(value)
        except ValueError:
            pass
    return value


if __name__ == "__main__":
    main()
