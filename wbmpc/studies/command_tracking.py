"""Base velocity and yaw-rate commands against what the robot does, on every plant.

For each plant (the rigid-contact plant, PyBullet, the emulated robot with its calibrated model) and each
command (forward 0.2 and 0.5 m/s, left 0.2 m/s, a yaw rate of 0.3 rad/s) the B1 + Z1 stands 2 s, then
trots with the command (the arm held still in the heading frame; compiled Fatrop, N = 15); the achieved
velocity is the true base velocity in the heading frame averaged over the trot after 1 s of settling
(:func:`wbmpc.sim.closed_loop.command_tracking`). Run::

    python -m wbmpc.studies.command_tracking            # writes data/results/command_tracking.csv

Columns: plant, command, axis (forward / left / yaw), commanded, achieved (m/s or rad/s), ratio, the other
two components (drift), fell, Fatrop iterations (mean, max), converged share, max tilt [rad].
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
from pathlib import Path

from wbmpc.quick import pick
from wbmpc.studies import cli_checks

REPO_ROOT = Path(__file__).resolve().parents[2]
DEFAULT_OUTPUT = REPO_ROOT / "data/results/command_tracking.csv"
STAND = 2.0  # [s] standing before the trot (the emulated robot settles on its drives and estimator)
PLANTS = ("rigid", "pybullet", "emulated")
# name -> (forward [m/s], left [m/s], yaw rate [rad/s])
COMMANDS = {
    "forward 0.2 m/s": (0.2, 0.0, 0.0),
    "forward 0.5 m/s": (0.5, 0.0, 0.0),
    "left 0.2 m/s": (0.0, 0.2, 0.0),
    "yaw 0.3 rad/s": (0.0, 0.0, 0.3),
}
AXES = ("forward", "left", "yaw")
COLUMNS = (
    "plant",
    "command",
    "axis",
    "commanded",
    "achieved",
    "ratio",
    "drift_other_axes",
    "fell",
    "iterations_mean",
    "iterations_max",
    "converged_fraction",
    "max_tilt_rad",
    "wall_s",
)


def run_case(plant: str, command: tuple[float, float, float], trot: float, robot, mpc_robot=None) -> dict:
    """One plant and command: stand 2 s, trot ``trot`` s; the tracking row (see the module doc).

    Args:
        plant: ``"rigid"``, ``"pybullet"`` or ``"emulated"`` (:func:`wbmpc.sim.presets.hardware_config`,
            measured delay, estimated state).
        command: ``(forward [m/s], left [m/s], yaw rate [rad/s])``, heading frame.
        trot: Trot duration [s] (the average starts 1 s into it).
        robot: The robot (the plant's); mpc_robot: the MPC's model (default ``robot``).

    Raises:
        ValueError: an unknown plant.
    """
    from wbmpc.analysis import emulated_mpc, record_emulated_run
    from wbmpc.control.mpc import MPCConfig, SolverSettings, WholeBodyMPC
    from wbmpc.ocp import OCPSettings
    from wbmpc.ocp.gait import parse_gait_schedule
    from wbmpc.sim.closed_loop import ClosedLoopConfig, run_closed_loop
    from wbmpc.sim.loop_config import CommandSchedule, PlantConfig

    if plant not in PLANTS:
        raise ValueError(f"unknown plant {plant!r}; available: {list(PLANTS)}")
    vx, vy, wz = command
    gait = f"stand:{STAND:g},trot@{vx:g}/{vy:g}/{wz:g}:{trot:g}"
    schedule = parse_gait_schedule(gait)
    if plant == "emulated":
        mpc = emulated_mpc(mpc_robot or robot, schedule)
    else:
        mpc = WholeBodyMPC(
            robot, OCPSettings(n_nodes=15), MPCConfig(gait=schedule), SolverSettings(compiled=True)
        )
        mpc.verbose = False
    start = time.perf_counter()
    if plant == "emulated":
        result, _ = record_emulated_run(gait=gait, robot=robot, mpc=mpc)
    else:
        config = ClosedLoopConfig(
            duration=schedule.duration,
            plant=PlantConfig(kind=plant),
            commands=CommandSchedule(arm_reference=None),
        )
        result = run_closed_loop(mpc, config, progress=False)
    s = result.summary
    moving = [seg for seg in s["tracking"] if any(abs(c) > 0 for c in seg["commanded"])]
    achieved = moving[0]["achieved"] if moving else [float("nan")] * 3
    axis = max(range(3), key=lambda i: abs(command[i]))
    return {
        "plant": plant,
        "axis": AXES[axis],
        "commanded": command[axis],
        "achieved": achieved[axis],
        "ratio": achieved[axis] / command[axis],
        "drift_other_axes": [achieved[i] for i in range(3) if i != axis],
        "fell": s["fell"],
        "iterations_mean": s["iterations_mean"],
        "iterations_max": s["iterations_max"],
        "converged_fraction": s["converged_fraction"],
        "max_tilt_rad": s["max_tilt_rad"],
        "wall_s": time.perf_counter() - start,
    }


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(
        prog="python -m wbmpc.studies.command_tracking", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--plant", action="append", choices=PLANTS, help="only these plants (repeatable)")
    parser.add_argument("--command", action="append", choices=list(COMMANDS), help="only these commands")
    parser.add_argument("--trot", type=float, default=None, help="trot duration [s] (default 6; quick 1.5)")
    parser.add_argument("--calibration", type=Path, default=None, help="the emulated MPC's calibration file")
    parser.add_argument("--output", type=Path, default=DEFAULT_OUTPUT, help="CSV file to write")
    args = parser.parse_args(argv)
    trot = args.trot if args.trot is not None else pick(full=6.0, quick=1.5)
    if not trot > 1.0:
        parser.error(f"--trot must be > 1 s (the first second is left out as settling), got {trot}")
    if args.calibration is not None and not args.calibration.is_file():
        parser.error(f"--calibration {args.calibration}: no such file")
    cli_checks.writable_file(parser, "--output", args.output, "command_tracking.csv")
    from tqdm.auto import tqdm

    from wbmpc.model.robot import load_b1_z1

    robot = load_b1_z1()
    calibrated = _calibrated(robot, args.calibration)
    cases = [
        (plant, name)
        for plant in (args.plant or PLANTS)
        for name in COMMANDS
        if not args.command or name in args.command
    ]
    rows = []
    for plant, name in tqdm(cases, desc="cases", unit="run"):
        row = run_case(plant, COMMANDS[name], trot, robot, calibrated if plant == "emulated" else None)
        row = {"command": name} | row
        rows.append(row)
        print(
            f"{plant:9s} {name:16s} achieved {row['achieved']:+.3f} ({100 * row['ratio']:5.1f} %)  drift "
            f"{row['drift_other_axes'][0]:+.3f} {row['drift_other_axes'][1]:+.3f}  fell {row['fell']!s:5}  "
            f"iterations {row['iterations_mean']:.2f} / {row['iterations_max']}",
            flush=True,
        )
    with args.output.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: _cell(row[k]) for k in COLUMNS})
    print(f"wrote {args.output}")
    return rows


def _calibrated(robot, path: Path | None):
    """The emulated robot's MPC model: from a calibration file, or with the identified offset of the
    committed calibration (``data/hardware/calibration.yaml``) when there is one, else nominal."""
    path = path or (REPO_ROOT / "data/hardware/calibration.yaml")
    if not path.is_file():
        return robot
    from wbmpc.model.calibration import Calibration

    return Calibration.load(path).apply(robot)


def _cell(value):
    if isinstance(value, float):
        return f"{value:.4f}"
    if isinstance(value, list):
        return " ".join(f"{v:+.4f}" for v in value)
    return value


if __name__ == "__main__":
    main()
    sys.exit(0)
