"""The main job: B1 + Z1 trotting at 0.2 m/s for 10 s while the arm tracks a reference reaching low and high.

Run with ``bash scripts/demo.sh`` (sets up the environment) or ``python -m wbmpc.studies.demo --help``.
Writes under ``data/output/demo/``: ``summary.json``, ``log.npz`` (streamed during the run: Ctrl-C leaves
a readable partial log and exits with status 130), PNG plots and a self-contained meshcat
replay ``replay.html``. With ``--save-results`` the summary is also copied to
``data/results/demo_summary.json`` (the committed copy of the full default run).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

from wbmpc import checks
from wbmpc.quick import pick
from wbmpc.studies import cli_checks
from wbmpc.studies.cli_checks import MAX_NODES

REPO_ROOT = Path(__file__).resolve().parents[2]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m wbmpc.studies.demo", description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default=None, help="built-in robot: b1_z1 (default) or b1")
    parser.add_argument(
        "--urdf",
        type=Path,
        default=None,
        help="a robot of your own: its URDF (free-flyer base; instead of --robot). Link masses or inertias "
        "that only PyBullet would change are a note (the rigid plant runs) and refused with --plant pybullet",
    )
    parser.add_argument(
        "--srdf",
        type=Path,
        default=None,
        help="with --urdf: its SRDF (a group_state: the stand pose)",
    )
    parser.add_argument(
        "--feet",
        default=None,
        help="with --urdf: the four foot frames FL,FR,RL,RR (default: found from the SRDF's end_effector "
        "entries or names such as FL_foot, LF_FOOT, front_left_foot)",
    )
    parser.add_argument(
        "--ee",
        default=None,
        help="with --urdf: the arm's end-effector frame, or none (default: found from the SRDF or names such "
        "as gripper, ee_link, tool0)",
    )
    parser.add_argument("--lock", default=None, help="with --urdf: joints to lock at the stand pose, j1,j2")
    parser.add_argument(
        "--pose", default=None, help="with --urdf: the SRDF pose to stand in (default: the first)"
    )
    parser.add_argument(
        "--calibration",
        type=Path,
        default=None,
        help="calibration file of the robot (python -m wbmpc.studies.calibrate): the MPC's model and the "
        "low level's friction feed-forward use it",
    )
    parser.add_argument(
        "--gait",
        default="trot",
        help="trot, walk, stand, pace, bound (default trot), or a schedule of gaits and durations [s] "
        "such as stand:2,trot:6,stand:2 (the last gait goes on to the end of the run); a segment may name "
        "its base velocity, trot@0.5:4 (forward m/s), trot@0.3/0.1/0.2:4 (forward, left m/s, yaw rad/s); "
        "stand segments stand still, the others take --speed",
    )
    parser.add_argument("--period", type=float, default=0.8, help="gait period [s] (default 0.8)")
    parser.add_argument("--speed", type=float, default=0.2, help="forward base velocity [m/s] (default 0.2)")
    parser.add_argument(
        "--duration",
        type=float,
        default=None,
        help="simulated time [s] (default 10, or the schedule's total with --gait a:2,b:3)",
    )
    parser.add_argument("--solver", default="fatrop", choices=["fatrop", "ipopt"], help="NLP solver")
    parser.add_argument("--nodes", type=int, default=15, help="nodes including the terminal one (default 15)")
    parser.add_argument(
        "--plant",
        default="rigid",
        choices=["rigid", "pybullet"],
        help="rigid-contact Pinocchio plant (the paper's benchmark, default) or PyBullet",
    )
    parser.add_argument("--compiled", action="store_true", help="generate and compile the NLP (cached)")
    parser.add_argument(
        "--release",
        action="store_true",
        help="with --compiled: build with -O3 -march=native (about 2 min once; 8 %% faster solves than -O1)",
    )
    parser.add_argument("--kp", type=float, default=0.0, help="joint stiffness of the low level [N m/rad]")
    parser.add_argument("--kd", type=float, default=0.0, help="joint damping of the low level [N m s/rad]")
    parser.add_argument(
        "--no-arm-task", action="store_true", help="hold the end effector (no low/high reference)"
    )
    parser.add_argument("--output", type=Path, default=REPO_ROOT / "data/output/demo", help="output folder")
    parser.add_argument("--no-replay", action="store_true", help="skip the meshcat HTML replay")
    parser.add_argument("--save-results", action="store_true", help="copy the summary to data/results/")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


def print_summary(summary: dict) -> None:
    """A compact table of the key numbers."""
    s = summary["solve_ms"]
    rows = [
        (
            "robot / gait / solver",
            f"{summary['robot']} / {summary['gait']} / {summary['solver']} (in-process)",
        ),
        ("simulated time", f"{summary['duration_s']:.2f} s, {summary['mpc_solves']} MPC solves"),
        ("solve time [ms]", f"median {s['median']:.1f}, p95 {s['p95']:.1f}, max {s['max']:.1f}"),
        (
            "iterations",
            f"mean {summary['iterations_mean']:.2f}, max {summary['iterations_max']}, "
            f"cold start {summary['cold_start_iterations']}",
        ),
        ("converged", f"{100 * summary['converged_fraction']:.1f} % ({summary['fallbacks']} fallbacks)"),
        (
            "constraint violation",
            f"median {summary['constraint_violation']['median']:.1e}, "
            f"max {summary['constraint_violation']['max']:.1e}",
        ),
        (
            "end-effector RMS error",
            f"{100 * summary['ee_rms_m']:.2f} cm" if summary["ee_rms_m"] is not None else "-",
        ),
        ("max roll/pitch tilt", f"{summary['max_tilt_rad']:.3f} rad"),
        ("distance travelled", f"{summary['distance_travelled_m']:.2f} m"),
        *_tracking_rows(summary.get("tracking", [])),
        (
            "contact violations",
            ", ".join(f"{k} {v}" for k, v in summary.get("contact_violations", {}).items()) or "-",
        ),
        ("torque-limit violations", str(summary["torque_violations"])),
        ("fell", str(summary["fell"])),
    ]
    width = max(len(r[0]) for r in rows)
    for name, value in rows:
        print(f"  {name:<{width}}  {value}")


def _tracking_rows(tracking: list[dict]) -> list[tuple[str, str]]:
    """One row per stretch of constant base command: commanded -> achieved (forward, left, yaw rate)."""
    rows = []
    for seg in tracking:
        cmd, got = seg["commanded"], seg["achieved"]
        rows.append(
            (
                f"tracking {seg['t_start']:.1f}-{seg['t_end']:.1f} s",
                f"forward {cmd[0]:+.2f} -> {got[0]:+.2f} m/s, left {cmd[1]:+.2f} -> {got[1]:+.2f} m/s, "
                f"yaw {cmd[2]:+.2f} -> {got[2]:+.2f} rad/s",
            )
        )
    return rows


def check_arguments(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Reject bad values before any work (argparse prints the one-line reason and exits with status 2)."""
    positive = {"--period": args.period, "--nodes": args.nodes}
    if args.duration is not None:
        positive["--duration"] = args.duration
    for flag, value in positive.items():
        if not value > 0 or value != value or value == float("inf"):
            parser.error(f"{flag} must be a finite number > 0, got {value}")
    if args.nodes < 3:
        parser.error(f"--nodes must be >= 3 (nodes including the terminal one), got {args.nodes}")
    if args.release and not args.compiled:
        parser.error("--release sets the compiler flags of the compiled NLP: add --compiled")
    if args.nodes > MAX_NODES:
        parser.error(f"--nodes must be <= {MAX_NODES} (the paper uses 15), got {args.nodes}")
    for flag, value in {"--kp": args.kp, "--kd": args.kd}.items():
        if not 0 <= value < float("inf"):
            parser.error(f"{flag} must be a finite number >= 0, got {value}")
    if args.calibration is not None and not args.calibration.is_file():
        parser.error(f"--calibration {args.calibration}: no such file")
    cli_checks.user_robot(parser, args)
    if not abs(args.speed) < float("inf"):
        parser.error(f"--speed must be finite, got {args.speed}")
    try:  # a speed no robot walks at is refused here, before any model is built
        checks.command_velocity("--speed", linear=(args.speed, 0.0, 0.0))
    except ValueError as exc:
        parser.error(str(exc))
    try:  # a bad output folder fails now, not after the simulation
        args.output.mkdir(parents=True, exist_ok=True)
        probe = args.output / ".write-test"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        parser.error(f"--output {args.output} is not a writable folder: {exc}")


def main(argv: list[str] | None = None) -> dict:
    parser = build_parser()
    args = parser.parse_args(argv)
    check_arguments(parser, args)
    from wbmpc.control.mpc import MPCConfig, SolverSettings, WholeBodyMPC
    from wbmpc.model.robot import load
    from wbmpc.ocp import OCPSettings
    from wbmpc.ocp.gait import make_gait, parse_gait_schedule
    from wbmpc.sim.closed_loop import ClosedLoopConfig, run_closed_loop
    from wbmpc.sim.loop_config import CommandSchedule, LowLevelConfig, PlantConfig

    try:
        if ":" in args.gait or "," in args.gait:
            gait = parse_gait_schedule(args.gait, args.period)
            default_duration = gait.duration
        else:
            gait, default_duration = make_gait(args.gait, args.period), 10.0
        checks.gait_velocities("--gait", gait)
    except ValueError as exc:
        parser.error(f"--gait {args.gait!r}: {exc}")
    if args.urdf is not None:
        robot = _user_robot(parser, args)
    else:
        args.robot = args.robot or "b1_z1"
        try:
            robot = load(args.robot, **({"calibration": args.calibration} if args.calibration else {}))
        except ValueError as exc:
            parser.error(
                f"--robot {args.robot!r}{f' --calibration {args.calibration}' if args.calibration else ''}: "
                f"{exc}"
            )
    if args.plant == "pybullet" and robot.inertial_problems:
        from wbmpc.model.inertials import report

        parser.error(
            f"--plant pybullet: {report(robot.urdf_path, robot.inertial_problems)}\nFix them (any suggestion "
            "above loads) or run on --plant rigid"
        )
    print(robot.summary())
    for note in getattr(gait, "notes", ()):
        print(f"gait schedule: {note}")
    if args.duration is None:
        args.duration = pick(full=default_duration, quick=0.5)
    config = MPCConfig(gait=gait)
    flags = {}
    if args.release:
        from wbmpc.solver.codegen import RELEASE_FLAGS

        flags = {"compile_flags": RELEASE_FLAGS}
    solver = SolverSettings(solver=args.solver, compiled=args.compiled, **flags)
    start = time.perf_counter()
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=args.nodes), config, solver)
    print(
        f"OCP built in {time.perf_counter() - start:.1f} s: {mpc.ocp.n_variables} variables, "
        f"{mpc.ocp.n_constraints} constraints, {mpc.n_nodes} nodes"
    )
    loop = ClosedLoopConfig(
        duration=args.duration,
        low_level=LowLevelConfig(kp=args.kp, kd=args.kd),
        commands=CommandSchedule(base_velocity=(args.speed, 0.0, 0.0)),
        plant=PlantConfig(kind=args.plant),
    )
    if args.no_arm_task or not robot.has_arm:
        loop.commands.arm_reference = None
    out = args.output
    out.mkdir(parents=True, exist_ok=True)
    log_path = out / "log.npz"  # columnar run log (wbmpc.io.logs) streamed as the run goes: load_log reads it
    try:
        result = run_closed_loop(mpc, loop, progress=not args.quiet, log_path=log_path)
    except KeyboardInterrupt:
        raise SystemExit(_interrupted(log_path)) from None
    summary = result.summary
    print_summary(summary)
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    _figures(result, robot, out, args.speed)
    if not args.no_replay:
        _replay(result, robot, out)
    if args.save_results:
        target = REPO_ROOT / "data/results/demo_summary.json"
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(out / "summary.json", target)
        print(f"summary copied to {target}")
    print(f"outputs in {out}")
    return summary


def _user_robot(parser: argparse.ArgumentParser, args: argparse.Namespace):
    """The robot of ``--urdf``/``--srdf``: feet and end effector given or found; a load error or a frame
    that cannot be found is a one-line reason (exit 2), a PyBullet-only mass or inertia problem a note."""
    import warnings

    from wbmpc.model.errors import RobotModelError, RobotModelWarning
    from wbmpc.model.robot import find_contact_frames, load_robot

    try:
        found_feet, found_ee = find_contact_frames(args.urdf, args.srdf)
    except RobotModelError as exc:
        parser.error(str(exc))
    feet = tuple(args.feet.split(",")) if args.feet else found_feet
    if feet is None:
        parser.error(
            f"--urdf {args.urdf}: the four feet were not found from "
            f"{'the SRDF or ' if args.srdf else ''}the link names: give --feet FL,FR,RL,RR (four frame names)"
        )
    ee = None if args.ee == "none" else args.ee or found_ee
    locked = tuple(args.lock.split(",")) if args.lock else ()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RobotModelWarning)
        try:
            robot = load_robot(
                args.urdf,
                args.srdf,
                foot_frames=feet,
                ee_frame=ee,
                locked_joints=locked,
                reference_pose=args.pose,
                calibration=args.calibration,
            )
        except (RobotModelError, ValueError) as exc:
            parser.error(f"--urdf {args.urdf}: {exc}")
    for warning in caught:
        if issubclass(warning.category, RobotModelWarning):
            if args.plant != "pybullet":
                print(f"note: {warning.message}", file=sys.stderr)
        else:
            warnings.warn_explicit(warning.message, warning.category, warning.filename, warning.lineno)
    if ee is None and args.ee != "none":
        arm = [name for name in robot.joint_names if _off_legs(robot, name)]
        if arm:
            parser.error(
                f"--urdf {args.urdf}: no end-effector frame found for the joints off the legs {arm}: give "
                "--ee FRAME (the arm's tool frame), or --ee none to treat them as joints without a task"
            )
    return robot


def _off_legs(robot, joint: str) -> bool:
    """Whether ``joint`` moves none of the feet."""
    model = robot.model
    target = model.getJointId(joint)
    for frame in robot.foot_frames:
        j = model.frames[model.getFrameId(frame)].parentJoint
        while j > 1:
            if j == target:
                return False
            j = model.parents[j]
    return True


def _interrupted(log_path: Path) -> int:
    """Ctrl-C during the run: one line on stderr naming the partial log; the exit status (130, as SIGINT)."""
    from wbmpc.io.logs import load_log

    try:
        reached = f"at t = {load_log(log_path).meta['t_reached']:.2f} s"
    except Exception as exc:  # noqa: BLE001 - the message must come out whatever the log's state
        reached = f"(no readable log: {exc})"
    print(f"demo interrupted {reached}: partial log in {log_path}", file=sys.stderr)
    return 130


def exit_status(summary: dict) -> int:
    """0 for a run that stood and converged; 1 with a one-line reason on stderr otherwise."""
    if summary["fell"]:
        print(f"demo failed: the robot fell at t = {summary['duration_s']:.2f} s", file=sys.stderr)
        return 1
    if summary["converged_fraction"] < 0.9:
        print(
            f"demo failed: only {100 * summary['converged_fraction']:.0f} % of the solves converged",
            file=sys.stderr,
        )
        return 1
    return 0


def _figures(result, robot, out: Path, speed: float) -> None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        from wbmpc.viz import plots
    except ImportError as exc:  # plots are a convenience: never fail the run for them
        print(f"plots skipped: {exc}", file=sys.stderr)
        return
    arrays = result.log.arrays()
    for name, fig in (
        ("closed_loop", plots.plot_closed_loop(arrays, robot, base_velocity_command=speed)),
        ("torques", plots.plot_torques(arrays, robot)),
    ):
        fig.savefig(out / f"{name}.png", dpi=120)


def _replay(result, robot, out: Path) -> None:
    try:
        from wbmpc.viz import Viewer
    except ImportError as exc:
        print(f"replay skipped: {exc}", file=sys.stderr)
        return
    try:
        arrays = result.log.arrays()
        stride = 10  # 50 frames per second from the 500 Hz log
        viewer = Viewer(robot)
        viewer.animation(arrays["q"][::stride], arrays["t"][::stride])
        viewer.export_html(out / "replay.html")
    except Exception as exc:  # noqa: BLE001 - a viewer problem must not lose the run's results
        print(f"replay skipped: {exc}", file=sys.stderr)


if __name__ == "__main__":
    sys.exit(exit_status(main()))
