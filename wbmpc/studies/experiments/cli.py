"""The simulation experiments of the paper (and the simulated counterparts of its hardware tasks) in PyBullet.

The command line ``python -m wbmpc.studies.experiments [names] [--quick] [--no-logs] [--quiet]`` (see the
package :mod:`wbmpc.studies.experiments`) and the table of the experiments by name, :data:`EXPERIMENTS`.
"""

from __future__ import annotations

import argparse
import time

from wbmpc.model.robot import load_b1_z1
from wbmpc.quick import quick_mode
from wbmpc.studies import cli_checks
from wbmpc.studies.experiments.common import REPO_ROOT
from wbmpc.studies.experiments.compliant_arm import compliance
from wbmpc.studies.experiments.drift import time_steps_drift
from wbmpc.studies.experiments.kicks import disturbance_rejection
from wbmpc.studies.experiments.output import save
from wbmpc.studies.experiments.pulling import pulling_load
from wbmpc.studies.experiments.pushing import box_pushing
from wbmpc.studies.experiments.sweep import robustness_sweep
from wbmpc.studies.experiments.tracking import arm_tracking
from wbmpc.studies.experiments.wipe import wiping

EXPERIMENTS = {
    "arm_tracking": arm_tracking,
    "disturbance_rejection": disturbance_rejection,
    "pulling_load": pulling_load,
    "box_pushing": box_pushing,
    "wiping": wiping,
    "compliance": compliance,
    "time_steps_drift": time_steps_drift,
    "robustness_sweep": robustness_sweep,
}


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(
        prog="python -m wbmpc.studies.experiments", description=__doc__.splitlines()[0]
    )
    parser.add_argument("names", nargs="*", default=list(EXPERIMENTS), help=f"any of {list(EXPERIMENTS)}")
    parser.add_argument("--quick", action="store_true", help="quick mode (also with WBMPC_QUICK=1)")
    parser.add_argument("--no-logs", action="store_true", help="do not write the columnar logs")
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args(argv)
    unknown = set(args.names) - set(EXPERIMENTS)
    if unknown:
        parser.error(f"unknown experiments {sorted(unknown)}; available: {list(EXPERIMENTS)}")
    quick = args.quick or quick_mode()
    directory = REPO_ROOT / ("data/output/sim" if quick else "data/results/sim")
    logs = None if args.no_logs else REPO_ROOT / "data/output/sim/logs"
    for label, folder in (("results folder", directory), ("figure folder", REPO_ROOT / "data/output/sim")):
        cli_checks.writable_folder(parser, label, folder)
    if logs is not None:
        cli_checks.writable_folder(parser, "log folder (or --no-logs)", logs)
    robot = load_b1_z1()
    out = {}
    for name in args.names:
        start = time.perf_counter()
        print(f"[experiments] {name} ({'quick' if quick else 'full'})", flush=True)
        result = EXPERIMENTS[name](quick=quick, progress=not args.quiet, robot=robot)
        result.summary["wall_time_s"] = time.perf_counter() - start
        path = save(result, directory, logs)
        print(f"[experiments] {name}: wrote {path} ({result.summary['wall_time_s']:.0f} s)", flush=True)
        out[name] = result.summary
    return out
