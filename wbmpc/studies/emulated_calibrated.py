"""The emulated robot calibrated as a lab would, and the MPC on it with and without the calibration.

Two steps, each a command line:

``record``: the lab's two trials on the emulated robot (:func:`wbmpc.sim.presets.hardware_config`: full
hardware profile, estimator, measured computation delay, compiled Fatrop, N = 15, the arm held still in
the heading frame), each recorded as a robot's ROS 2 bag at the 500 Hz command rate:

1. standing on the nominal model (``stand:4``): the base CoM offset and the force split from the leg
   torques of its bag (:func:`wbmpc.studies.calibrate.calibrate`, friction left nominal: nothing swings),
   written to
   ``data/hardware/calibration_com.yaml``;
2. stand 2 s then trot 10 s at 0.2 m/s on that CoM calibration: the committed bag
   ``data/hardware/emulated_b1_stand_trot`` (notebook 05 reads it), from which the calibration step (on the
   bag, as ``python -m wbmpc.studies.calibrate`` would)
   identifies every joint group's friction and armature and the CoM again:
   ``data/hardware/calibration.yaml``.

``targets``: the target run (stand 2 s, trot 10 s at 0.2 m/s, then 5 s at 0.5 m/s) on the emulated robot
with the calibrated model and with the nominal one, and on the ideal plant (rigid contacts, exact state,
no delay) in the same process for the solve times; writes ``data/hardware/emulated_calibrated.json``::

    python -m wbmpc.studies.emulated_calibrated record
    python -m wbmpc.studies.emulated_calibrated targets [--calibration data/hardware/calibration.yaml]
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from wbmpc.studies import cli_checks

REPO_ROOT = Path(__file__).resolve().parents[2]
HARDWARE = REPO_ROOT / "data/hardware"
STAND_ONLY = "stand:4"
CALIBRATION_RUN = "stand:2,trot@0.2:10"
TARGET_RUN = "stand:2,trot@0.2:10,trot@0.5:5"
BAG_NAME = "emulated_b1_stand_trot"


def run_summary(result, gait: str, wall_s: float) -> dict:
    """The numbers of a run the targets are stated in (see the module doc)."""
    s = result.summary
    a = result.log.arrays()
    fresh = np.asarray(a["success"], bool) & ~np.asarray(a["fallback"], bool)
    iterations = np.asarray(a["iterations"])[1:]
    calls = [1e3 * t.get("total", np.nan) for t in result.log.timings] if result.log.timings else []
    return {
        "gait": gait,
        "fell": s["fell"],
        "duration_s": s["duration_s"],
        "iterations_mean": float(iterations.mean()) if iterations.size else None,
        "iterations_p95": float(np.percentile(iterations, 95)) if iterations.size else None,
        "iterations_max": int(iterations.max()) if iterations.size else None,
        "iterations_max_at_s": float(np.asarray(a["solve_t"])[1:][np.argmax(iterations)])
        if iterations.size
        else None,
        "iterations_over_8_at_s": [
            float(t) for t, n in zip(np.asarray(a["solve_t"])[1:], iterations, strict=True) if n > 8
        ],
        "converged_fraction": float(np.mean(fresh)) if fresh.size else 0.0,
        "solve_ms": s["solve_ms"],
        "call_ms_mean": float(np.nanmean(calls[1:])) if len(calls) > 1 else None,
        "max_tilt_rad": s["max_tilt_rad"],
        "torque_clipped_steps": s["torque_violations"],
        "torque_clipped_steps_by_joint": s.get("torque_clipped_steps_by_joint", {}),
        "tracking": s["tracking"],
        "contact_violations": s.get("contact_violations"),
        "delay": s["delay"],
        "joint_pd": s.get("joint_pd"),
        "wall_s": wall_s,
    }


def record(output: Path = HARDWARE, progress: bool = True) -> dict:
    """The two recorded trials and the calibration files (see the module doc); returns what was written."""
    from wbmpc.analysis import record_emulated_run, write_robot_bag
    from wbmpc.model.robot import load_b1_z1
    from wbmpc.studies.calibrate import calibrate

    robot = load_b1_z1()
    written = {}
    stand, _ = record_emulated_run(gait=STAND_ONLY, robot=robot, progress=progress)
    with tempfile.TemporaryDirectory() as folder:  # the lab calibrates from what the robot recorded: a bag
        stand_bag, _ = write_robot_bag(stand.run_log(), Path(folder) / "stand", robot, factor=1)
        first = calibrate(stand_bag, robot)
    com_path = first.calibration.save(output / "calibration_com.yaml")
    written["calibration_com"] = str(com_path.relative_to(REPO_ROOT))
    print(first.table())
    start = time.perf_counter()
    with_com = load_b1_z1(calibration=com_path)
    trot, _ = record_emulated_run(gait=CALIBRATION_RUN, robot=robot, mpc_robot=with_com, progress=progress)
    summary = run_summary(trot, CALIBRATION_RUN, time.perf_counter() - start)
    log = trot.run_log()
    print(
        "calibration trial:",
        json.dumps({k: summary[k] for k in ("fell", "iterations_mean", "iterations_max")}),
    )
    if (output / BAG_NAME).exists():  # the recording replaces the previous one
        shutil.rmtree(output / BAG_NAME)
    bag, _ = write_robot_bag(log, output / BAG_NAME, robot, factor=1, storage="mcap")
    second = calibrate(bag, robot)
    path = second.calibration.save(output / "calibration.yaml")
    print(second.table())
    written |= {"bag": str(Path(bag).relative_to(REPO_ROOT)), "calibration": str(path.relative_to(REPO_ROOT))}
    meta = {
        "bag": BAG_NAME,
        "storage": "mcap",
        "signal_rate_hz": 500,
        "solve_rate_hz": 80,
        "recorded_with": (
            "python -m wbmpc.studies.emulated_calibrated record: record_emulated_run(gait="
            f"{CALIBRATION_RUN!r}, mpc_robot=load_b1_z1(calibration='data/hardware/calibration_com.yaml')) "
            "(the hardware_config preset: measured delay, motor-drive PD, delay compensation), then "
            "write_robot_bag(log, path, robot, factor=1)"
        ),
        "commands": {
            "gait": CALIBRATION_RUN + " (trot period 0.8 s)",
            "arm": "held still in the heading frame (arm_reference=None, ee_velocity_frame='heading')",
        },
        "mpc_model": "CoM calibration from the standing trial (data/hardware/calibration_com.yaml)",
        "emulated_robot": trot.summary["hardware"],
        "run": summary,
        "identified": {"com_only": first.calibration.to_dict(), "full": second.calibration.to_dict()},
    }
    (output / f"{BAG_NAME}.json").write_text(json.dumps(meta, indent=1, default=float))
    written["meta"] = str((output / f"{BAG_NAME}.json").relative_to(REPO_ROOT))
    return written


def targets(calibration: Path, output: Path, gait: str = TARGET_RUN, progress: bool = True) -> dict:
    """The target run with the calibrated and the nominal model, and the ideal plant (see the module doc)."""
    from wbmpc.analysis import record_emulated_run
    from wbmpc.control.mpc import MPCConfig, SolverSettings, WholeBodyMPC
    from wbmpc.model.robot import load_b1_z1
    from wbmpc.ocp import OCPSettings
    from wbmpc.ocp.gait import parse_gait_schedule
    from wbmpc.sim.closed_loop import ClosedLoopConfig, machine_description, run_closed_loop
    from wbmpc.sim.loop_config import CommandSchedule

    robot = load_b1_z1()
    calibrated = load_b1_z1(calibration=calibration)
    rows = {}
    start = time.perf_counter()
    schedule = parse_gait_schedule(gait)
    ideal_mpc = WholeBodyMPC(
        robot, OCPSettings(n_nodes=15), MPCConfig(gait=schedule), SolverSettings(compiled=True)
    )
    ideal_mpc.verbose = False
    ideal = run_closed_loop(
        ideal_mpc,
        ClosedLoopConfig(duration=schedule.duration, commands=CommandSchedule(arm_reference=None)),
        progress=progress,
    )
    rows["ideal_plant"] = run_summary(ideal, gait, time.perf_counter() - start)
    for name, model in (("calibrated", calibrated), ("uncalibrated", robot)):
        start = time.perf_counter()
        result, _ = record_emulated_run(gait=gait, robot=robot, mpc_robot=model, progress=progress)
        rows[name] = run_summary(result, gait, time.perf_counter() - start)
        print(name, json.dumps({k: rows[name][k] for k in ("fell", "iterations_mean", "iterations_max")}))
    ratio = rows["calibrated"]["solve_ms"]["mean"] / rows["ideal_plant"]["solve_ms"]["mean"]
    out = {
        "command": "python -m wbmpc.studies.emulated_calibrated targets",
        "calibration": str(Path(calibration).resolve().relative_to(REPO_ROOT))
        if Path(calibration).resolve().is_relative_to(REPO_ROOT)
        else str(calibration),
        "machine": machine_description(),
        "solve_mean_ratio_calibrated_to_ideal": ratio,
        "runs": rows,
    }
    output.write_text(json.dumps(out, indent=1, default=float))
    print(f"wrote {output}")
    return out


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(
        prog="python -m wbmpc.studies.emulated_calibrated", description=__doc__.splitlines()[0]
    )
    sub = parser.add_subparsers(dest="step", required=True)
    rec = sub.add_parser("record", help="the two trials, the bag and the calibration files")
    rec.add_argument("--output", type=Path, default=HARDWARE, help="folder (default data/hardware)")
    tgt = sub.add_parser("targets", help="the target run, calibrated against nominal, and the ideal plant")
    tgt.add_argument("--calibration", type=Path, default=HARDWARE / "calibration.yaml")
    tgt.add_argument("--gait", default=TARGET_RUN, help=f"gait schedule (default {TARGET_RUN})")
    tgt.add_argument("--output", type=Path, default=HARDWARE / "emulated_calibrated.json")
    for p in (rec, tgt):
        p.add_argument("--quiet", action="store_true", help="no progress bars")
    args = parser.parse_args(argv)
    if args.step == "targets":
        cli_checks.writable_file(parser, "--output", args.output, "emulated_calibrated.json")
        if not args.calibration.is_file():
            parser.error(f"--calibration {args.calibration}: no such file (run the 'record' step first)")
        from wbmpc.ocp.gait import parse_gait_schedule

        try:
            parse_gait_schedule(args.gait)
        except ValueError as exc:
            parser.error(f"--gait {args.gait!r}: {exc}")
        return targets(args.calibration, args.output, args.gait, progress=not args.quiet)
    cli_checks.writable_folder(parser, "--output", args.output)
    return record(args.output, progress=not args.quiet)


if __name__ == "__main__":
    main()
    sys.exit(0)
