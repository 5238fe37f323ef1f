"""What each mismatch of the emulated robot does to the MPC: one at a time, and together.

Every variant runs the same stand-then-trot schedule on the emulated robot
(:func:`wbmpc.sim.presets.hardware_config`: PyBullet, the hardware low level, the measured computation
delay, compiled Fatrop, N = 15, the arm held still in the heading frame) with one mismatch of
:class:`~wbmpc.sim.hardware.HardwareProfile` switched on over the ideal robot (or all of them), and records
per solve: the iterations, which constraint row groups the first iterate (the shifted warm start) violates
and by how much, and which inequality rows are active at the solution
(:class:`wbmpc.ocp.inspection.ConstraintInspector`); torque limits are named by joint.

Run::

    python -m wbmpc.studies.emulated_ablation      # every variant, writes data/hardware/ablation.json
    python -m wbmpc.studies.emulated_ablation --variant full --variant com_offset --gait stand:2,trot@0.2:4

The JSON holds one summary per variant (iterations mean / p95 / max, converged share, fell, tilt,
torque-clipped steps, forward speed against the command, the row groups most violated at the first
iterate, the active torque limits by joint) and the CPU.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from wbmpc.quick import pick
from wbmpc.studies import cli_checks

REPO_ROOT = Path(__file__).resolve().parents[2]
DEFAULT_OUTPUT = REPO_ROOT / "data/hardware/ablation.json"
DEFAULT_GAIT = "stand:2,trot@0.2:6"


def variants() -> dict[str, dict]:
    """Variant name -> ``{"profile": HardwareProfile, "state": ..., "calibrated": bool}``.

    ``ideal``: every mismatch off, ground-truth state. Sensor variants run the estimator (their errors
    reach the controller only through it); the others use the ground-truth state so that only their
    mismatch differs from ``ideal``. ``calibrated``: the MPC's model has the true base CoM offset (what a
    calibration gives, :mod:`wbmpc.model.calibration`).
    """
    from wbmpc.estimation import ImuNoise
    from wbmpc.sim.hardware import HardwareProfile

    full, ideal = HardwareProfile(), HardwareProfile.ideal()
    imu = full.imu
    white = ImuNoise(gyro=imu.gyro, accelerometer=imu.accelerometer)
    bias = ImuNoise(gyro_bias=imu.gyro_bias, accelerometer_bias=imu.accelerometer_bias)
    friction = {k: getattr(full, k) for k in ("leg_coulomb", "leg_viscous", "arm_coulomb", "arm_viscous")}
    one = {
        "ideal": ({}, "ground_truth"),
        "estimator": ({}, "estimated"),
        "encoder_noise": ({"encoder_noise": full.encoder_noise}, "estimated"),
        "encoder_velocity_noise": ({"encoder_velocity_noise": full.encoder_velocity_noise}, "estimated"),
        "imu_noise": ({"imu": white}, "estimated"),
        "imu_bias": ({"imu": bias}, "estimated"),
        "friction": (friction, "ground_truth"),
        "armature": ({"leg_armature": full.leg_armature, "arm_armature": full.arm_armature}, "ground_truth"),
        "torque_latency": ({"torque_latency": full.torque_latency}, "ground_truth"),
        "com_offset": ({"base_com_offset": full.base_com_offset}, "ground_truth"),
    }
    out = {
        name: {"profile": replace(ideal, **c), "state": s, "calibrated": False}
        for name, (c, s) in one.items()
    }
    out["com_offset_calibrated"] = out["com_offset"] | {"calibrated": True}
    out["full"] = {"profile": full, "state": "estimated", "calibrated": False}
    out["full_calibrated"] = {"profile": full, "state": "estimated", "calibrated": True}
    return out


class SolveRecorder:
    """Wraps ``mpc.solve`` to record, per solve, the constraint report of the first iterate and of the
    solution (an observer of the closed loop; :meth:`detach` restores the MPC)."""

    def __init__(self, mpc, tol: float = 1e-3):
        from wbmpc.ocp.inspection import ConstraintInspector

        self.mpc, self.tol = mpc, tol
        self.inspector = ConstraintInspector(mpc.ocp)
        self.records: list[dict] = []
        self._solve = mpc.solve
        mpc.solve = self._wrapped
        nj = mpc.robot.nj
        torque_rows = self.inspector.groups.get("torque_limits", np.array([], int))
        self._torque_joint = {int(r): mpc.robot.joint_names[i % nj] for i, r in enumerate(torque_rows)}

    def _wrapped(self, *args, **kwargs):
        plan = self._solve(*args, **kwargs)
        inputs = self.mpc.last_inputs
        first = self.inspector.report(inputs["x0"], inputs["p"], self.tol)
        record = {
            "t": float(args[2] if len(args) > 2 else kwargs.get("t", 0.0)),
            "iterations": int(plan.iterations),
            "success": bool(plan.success and not plan.fallback),
            "call_ms": 1e3 * float(plan.timings.get("total", plan.solve_time)),
            "first_violation": {k: r.max_violation for k, r in first.items() if r.max_violation > 0},
            "first_stage": {k: r.stage for k, r in first.items() if r.max_violation > 0},
        }
        if record["success"]:
            final = self.inspector.report(plan.w, inputs["p"], self.tol)
            record["active"] = {k: r.active for k, r in final.items() if r.active}
            rows = self.inspector.active_rows(plan.w, inputs["p"], "torque_limits", self.tol)
            group = self.inspector.groups["torque_limits"]
            record["torque_limit_joints"] = sorted({self._torque_joint[int(group[i])] for i in rows})
        self.records.append(record)
        return plan

    def detach(self) -> None:
        self.mpc.solve = self._solve


def summarize_records(records: list[dict], t_start: float) -> dict:
    """Per-variant aggregates of :class:`SolveRecorder` records (the cold first solve left out)."""
    warm = records[1:] or records
    iterations = np.array([r["iterations"] for r in warm], float)
    groups: dict[str, list[float]] = {}
    worst: dict[str, int] = {}
    for r in warm:
        for name, value in r["first_violation"].items():
            groups.setdefault(name, []).append(value)
        if r["first_violation"]:
            name = max(r["first_violation"], key=r["first_violation"].get)
            worst[name] = worst.get(name, 0) + 1
    active: dict[str, list[int]] = {}
    torque_joints: dict[str, int] = {}
    for r in warm:
        for name, count in r.get("active", {}).items():
            active.setdefault(name, []).append(count)
        for joint in r.get("torque_limit_joints", []):
            torque_joints[joint] = torque_joints.get(joint, 0) + 1
    n = len(warm)
    trot = [r for r in warm if r["t"] >= t_start]
    return {
        "solves": n,
        "iterations_mean": float(iterations.mean()),
        "iterations_p95": float(np.percentile(iterations, 95)),
        "iterations_max": int(iterations.max()),
        "iterations_mean_trot": float(np.mean([r["iterations"] for r in trot])) if trot else None,
        "converged_fraction": float(np.mean([r["success"] for r in warm])),
        "call_ms_mean": float(np.mean([r["call_ms"] for r in warm])),
        "first_iterate_violation": {
            name: {
                "mean": float(np.mean(v)),
                "p95": float(np.percentile(v, 95)),
                "max": float(np.max(v)),
                "worst_in_share": worst.get(name, 0) / n,
            }
            for name, v in sorted(groups.items(), key=lambda kv: -worst.get(kv[0], 0))
        },
        "active_rows_mean": {name: float(np.sum(v) / n) for name, v in active.items()},
        "torque_limit_active_share": {
            j: c / n for j, c in sorted(torque_joints.items(), key=lambda kv: -kv[1])
        },
    }


def run_variant(name: str, spec: dict, gait: str, robot, calibrated_robot, progress: bool = False) -> dict:
    """One variant on the emulated robot: the run's summary numbers and the solve records' aggregates."""
    from wbmpc.analysis import emulated_mpc, record_emulated_run
    from wbmpc.ocp.gait import parse_gait_schedule

    mpc = emulated_mpc(calibrated_robot if spec["calibrated"] else robot, parse_gait_schedule(gait))
    recorder = SolveRecorder(mpc)
    try:
        result, _ = record_emulated_run(
            gait=gait, profile=spec["profile"], robot=robot, mpc=mpc, state=spec["state"], progress=progress
        )
    finally:
        recorder.detach()
    schedule = parse_gait_schedule(gait)
    trot_start = float(schedule.start_times[1]) if len(schedule.gaits) > 1 else 0.0
    s = result.summary
    tracking = [seg for seg in s["tracking"] if seg["commanded"][0] != 0.0]
    return {
        "variant": name,
        "state": spec["state"],
        "calibrated": spec["calibrated"],
        "profile": spec["profile"].describe(),
        "fell": s["fell"],
        "duration_s": s["duration_s"],
        "max_tilt_rad": s["max_tilt_rad"],
        "torque_clipped_steps": s["torque_violations"],
        "forward_speed": [
            {"commanded": seg["commanded"][0], "achieved": seg["achieved"][0], "ratio": seg["ratio"][0]}
            for seg in tracking
        ],
        "solves": summarize_records(recorder.records, trot_start),
        "records": recorder.records,
    }


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(
        prog="python -m wbmpc.studies.emulated_ablation", description=__doc__.splitlines()[0]
    )
    names = list(variants())
    parser.add_argument("--variant", action="append", choices=names, help="run only these (repeatable)")
    parser.add_argument(
        "--gait", default=None, help=f"gait schedule (default {DEFAULT_GAIT}; quick mode: shorter)"
    )
    parser.add_argument("--output", type=Path, default=DEFAULT_OUTPUT, help="JSON file to write")
    args = parser.parse_args(argv)
    gait = args.gait or pick(full=DEFAULT_GAIT, quick="stand:0.3,trot@0.2:0.4")
    from wbmpc.ocp.gait import parse_gait_schedule

    try:
        parse_gait_schedule(gait)
    except ValueError as exc:
        parser.error(f"--gait {gait!r}: {exc}")
    cli_checks.writable_file(parser, "--output", args.output, "ablation.json")
    from tqdm.auto import tqdm

    from wbmpc.model.base_com import shift_base_com
    from wbmpc.model.robot import load_b1_z1
    from wbmpc.sim.closed_loop import machine_description
    from wbmpc.sim.hardware import HardwareProfile

    robot = load_b1_z1()
    calibrated = shift_base_com(robot, HardwareProfile().base_com_offset)
    chosen = {k: v for k, v in variants().items() if not args.variant or k in args.variant}
    rows = []
    for name, spec in tqdm(chosen.items(), desc="variants", unit="run"):
        start = time.perf_counter()
        row = run_variant(name, spec, gait, robot, calibrated)
        row["wall_s"] = time.perf_counter() - start
        rows.append(row)
        print(_line(row), flush=True)
    per_solve = args.output.with_name(args.output.stem + "_solves.csv")
    write_solve_table(rows, per_solve)
    for row in rows:
        row.pop("records")
    out = {"gait": gait, "machine": machine_description(), "per_solve": per_solve.name, "variants": rows}
    args.output.write_text(json.dumps(out, indent=1))
    print(f"wrote {args.output} and {per_solve}")
    return out


def write_solve_table(rows: list[dict], path: Path) -> None:
    """One CSV row per solve of every variant: time, iterations, converged, call time, the most violated
    row group of the first iterate and its violation, and the torque limits active at the solution."""
    import csv

    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(
            [
                "variant",
                "t_s",
                "iterations",
                "converged",
                "call_ms",
                "worst_first_rows",
                "worst_first_violation",
                "worst_first_stage",
                "active_torque_limits",
            ]
        )
        for row in rows:
            for r in row["records"]:
                first = r["first_violation"]
                worst = max(first, key=first.get) if first else ""
                writer.writerow(
                    [
                        row["variant"],
                        f"{r['t']:.4f}",
                        r["iterations"],
                        int(r["success"]),
                        f"{r['call_ms']:.2f}",
                        worst,
                        f"{first[worst]:.4g}" if worst else "",
                        r["first_stage"].get(worst, "") if worst else "",
                        " ".join(r.get("torque_limit_joints", [])),
                    ]
                )


def _line(row: dict) -> str:
    s = row["solves"]
    speed = " ".join(f"{seg['achieved']:+.3f}/{seg['commanded']:.2f}" for seg in row["forward_speed"])
    worst = next(iter(s["first_iterate_violation"]), "-")
    return (
        f"{row['variant']:24s} iterations {s['iterations_mean']:5.2f} (p95 {s['iterations_p95']:4.1f}, max "
        f"{s['iterations_max']:3d})  converged {100 * s['converged_fraction']:5.1f} %  "
        f"fell {row['fell']!s:5}  "
        f"tilt {row['max_tilt_rad']:.3f}  clipped {row['torque_clipped_steps']:4d}  speed {speed}  "
        f"worst first-iterate rows: {worst}"
    )


if __name__ == "__main__":
    main()
    sys.exit(0)
