"""Command line of the sweeps: ``python -m wbmpc.studies.sweeps --help``."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from wbmpc.studies.sweeps.cases import STUDIES
from wbmpc.studies.sweeps.engine import REPO_ROOT, SweepRun, read_table
from wbmpc.studies.sweeps.reports import (
    nodes_figures,
    payload_figures,
    robustness_figures,
    time_steps_figures,
)

# name -> f(rows, directory) -> figure paths, drawn after the sweep (CLI) into data/output/sweeps/
FIGURES = {
    "robustness": robustness_figures,
    "payload": payload_figures,
    "nodes": nodes_figures,
    "time_steps": time_steps_figures,
}
# Full runs of these studies write their tables to data/results/sweeps/ (committed summaries).
RESULT_STUDIES = ("robustness", "payload", "nodes", "time_steps")


def main(argv: list[str] | None = None) -> SweepRun | dict:
    """Command line: run a study (a grid, a case function) as a sweep, or the engine's benchmark."""
    parser = argparse.ArgumentParser(
        prog="python -m wbmpc.studies.sweeps",
        description="Run a parameter sweep on Dask: one row per case in a CSV table, resumable.",
    )
    parser.add_argument("study", nargs="?", default="demo", choices=sorted(STUDIES), help="what to sweep")
    parser.add_argument("--scheduler", help="address of an existing Dask scheduler (tcp://HOST:PORT)")
    parser.add_argument("--workers", type=int, help="worker processes of the local cluster (default: cores)")
    parser.add_argument("--output", type=Path, help="CSV table (default data/output/sweeps/<study>.csv)")
    parser.add_argument("--quick", action="store_true", help="a small grid and short runs")
    parser.add_argument("--no-resume", action="store_true", help="start a new table")
    parser.add_argument("--retry-failed", action="store_true", help="rerun the error and worker-died cases")
    parser.add_argument("--figures", type=Path, help="figure folder (default data/output/sweeps)")
    parser.add_argument("--no-figures", action="store_true", help="do not draw the study's figures")
    parser.add_argument(
        "--benchmark", type=Path, metavar="JSON", help="measure speed-up and overhead instead"
    )
    args = parser.parse_args(argv)
    from wbmpc.studies.sweeps.benchmark import benchmark
    from wbmpc.studies.sweeps.engine import run_sweep
    from wbmpc.studies.sweeps.reports import robustness_report

    if args.benchmark:
        result = benchmark(args.benchmark, workers=args.workers or 2, progress=True)
        print(json.dumps({k: v for k, v in result.items() if not isinstance(v, list | dict)}, indent=2))
        return result
    make_cases, fn, warmup = STUDIES[args.study]
    folder = (
        "data/results/sweeps" if args.study in RESULT_STUDIES and not args.quick else "data/output/sweeps"
    )
    output = args.output or REPO_ROOT / folder / f"{args.study}{'_quick' if args.quick else ''}.csv"
    run = run_sweep(
        make_cases(args.quick),
        fn,
        output,
        scheduler=args.scheduler,
        workers=args.workers,
        warmup=warmup,
        resume=not args.no_resume,
        retry_failed=args.retry_failed,
    )
    print(f"{output}: {len(run.rows)} cases run {run.counts}, {run.skipped} skipped, {run.wall_s:.1f} s")
    if args.study in FIGURES and not args.no_figures:
        rows = read_table(output)
        for path in FIGURES[args.study](rows, args.figures or REPO_ROOT / "data/output/sweeps"):
            print(f"figure: {path}")
        if args.study == "robustness":
            print(json.dumps(robustness_report(rows), indent=2))
    return run
