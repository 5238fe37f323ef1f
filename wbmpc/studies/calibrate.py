"""Calibration a lab runs once: a robot's calibration file from one stand-then-trot log.

From a ROS 2 bag (:func:`wbmpc.io.rosbag.read_bag`) or an ``.npz`` run log (:func:`wbmpc.io.logs.load_log`)
of a robot that stands still for a while, then trots:

* each joint group's Coulomb and viscous friction and armature from the torque-tracking error of the free
  limbs (:func:`wbmpc.estimation.identification.identify_joint_friction`: the legs in swing, the arm);
* the base's centre-of-mass offset and the front/rear force split from the standing samples
  (:func:`wbmpc.analysis.identify_com_offset`), with the torques the links receive
  (:meth:`~wbmpc.estimation.identification.FrictionIdentification.applied_torque`: the commands less the
  identified friction, which the slowly creeping standing joints still carry);

printed as a table and written as a calibration file (:class:`wbmpc.model.calibration.Calibration`, read
back by ``load_b1_z1(calibration=PATH)``). Command line::

    python -m wbmpc.studies.calibrate BAG_OR_LOG --output calib.yaml [--robot b1_z1]
        [--topic-map MAP.json] [--delay SECONDS] [--friction-velocity RAD_PER_S] [--base auto]

Argument errors exit with status 2 before any work; a log the identification cannot use (no quiet
standing, missing columns) exits with status 1 and the reason.

The log should hold every torque command (record the joint states at the command rate): with half the
commands the armature comes out low (see :mod:`wbmpc.estimation.identification`). Parameters the log does
not identify (a joint that never moves faster than ~0.1 rad/s, such as a still arm's shoulder) are left at
their nominal values and listed in the file's ``identification`` field.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

from wbmpc.studies import cli_checks

__all__ = ["CalibrationResult", "calibrate", "main", "read_run"]

ROBOT_NAMES = ("b1_z1", "b1")
BASE_CHOICES = ("auto", "imu", "odometry", "log")
_SUFFIXES = (".yaml", ".yml", ".json")


@dataclass
class CalibrationResult:
    """What :func:`calibrate` found.

    Attributes:
        calibration: The :class:`~wbmpc.model.calibration.Calibration` (not yet saved).
        com: The :class:`~wbmpc.analysis.ComIdentification` of the standing samples.
        friction: The :class:`~wbmpc.estimation.identification.FrictionIdentification`.
    """

    calibration: object
    com: object
    friction: object

    def table(self) -> str:
        """The identified values as text: the CoM offset and force split, then the joint groups."""
        com = self.com
        lines = [
            f"base CoM offset [m]: ({com.offset[0]:+.4f}, {com.offset[1]:+.4f}, {com.offset[2]:+.4f}) "
            f"(base frame; {com.samples} standing samples, {com.window_s[0]:.2f}-{com.window_s[1]:.2f} s)",
            f"front force ratio: {com.front_force_ratio:.3f} (rear share {com.rear_share:.3f})",
            f"joint friction and armature (base accelerations: {self.friction.base}; "
            f"v_s = {self.friction.friction_velocity:g} rad/s):",
            self.friction.table(),
        ]
        return "\n".join(lines)


def read_run(source: str | Path, topic_map=None):
    """The run log of a bag folder (or ``.mcap``/``.db3`` file) or an ``.npz`` log.

    Raises:
        FileNotFoundError: if ``source`` does not exist.
    """
    from wbmpc.io.logs import load_log
    from wbmpc.io.rosbag import read_bag

    source = Path(source)
    if not source.exists():
        raise FileNotFoundError(f"no bag or log at {source}")
    is_bag = source.suffix in (".mcap", ".db3") or (source.is_dir() and (source / "metadata.yaml").is_file())
    return read_bag(source, topic_map=topic_map) if is_bag else load_log(source)


def calibrate(
    source,
    robot="b1_z1",
    *,
    topic_map=None,
    delay: float | None = None,
    friction_velocity: float = 0.05,
    base: str = "auto",
) -> CalibrationResult:
    """Identify a robot's calibration from a stand-then-trot log.

    Args:
        source: A bag folder, an ``.mcap``/``.db3`` file, an ``.npz`` log, or a
            :class:`~wbmpc.io.logs.RunLog`.
        robot: A built-in robot's name (``"b1_z1"``, ``"b1"``) or a nominal
            :class:`~wbmpc.model.robot.Robot`.
        topic_map: The bag's :class:`~wbmpc.io.rosbag.TopicMap` (or a JSON path); ``None``: the defaults.
        delay: Command delay [s] of the friction identification (``None``: fitted).
        friction_velocity: Coulomb smoothing rate [rad/s] written to the file and used by the fit.
        base: Source of the base accelerations (see :func:`~wbmpc.estimation.identification.
            identify_joint_friction`).

    Returns:
        :class:`CalibrationResult`.

    Raises:
        FileNotFoundError: if ``source`` does not exist.
        ValueError: if the log has too few standing samples, lacks a column, or an option is bad.
    """
    from wbmpc.analysis import identify_com_offset, standing_mask
    from wbmpc.estimation.identification import identify_joint_friction
    from wbmpc.io.logs import RunLog
    from wbmpc.model.calibration import Calibration, JointParameters
    from wbmpc.model.robot import load

    nominal = load(robot) if isinstance(robot, str) else robot
    friction_options = {"delay": delay, "friction_velocity": friction_velocity, "base": base}
    log = source if isinstance(source, RunLog) else read_run(source, topic_map)
    friction = identify_joint_friction(log, nominal, **friction_options)
    # The standing legs creep, and their motors' friction is in the commands: the CoM is found from the
    # torques the links receive (without it the B1's offset comes out ~1 cm short).
    applied = RunLog(signals=dict(log.signals), solves=log.solves, meta=log.meta)
    applied.signals["tau"] = friction.applied_torque(log)
    com = identify_com_offset(applied, nominal, mask=standing_mask(log))
    joints = {}
    for fit in friction.groups.values():
        if not any(fit.identified.values()):
            continue  # nothing identified: the joints keep their nominal values
        values = JointParameters(*(_rounded(getattr(fit, p)) for p in ("coulomb", "viscous", "armature")))
        joints |= dict.fromkeys(fit.joints, values)
    calibration = Calibration(
        base_com_offset=tuple(_rounded(x) for x in com.offset),
        front_force_ratio=_rounded(com.front_force_ratio),
        friction_velocity=float(friction_velocity),
        joints=joints,
        robot=nominal.name,
        source=None if isinstance(source, RunLog) else str(source),
        identification=_rounded({"com": com.summary(), "friction": friction.summary()}),
    )
    return CalibrationResult(calibration=calibration, com=com, friction=friction)


def _rounded(value, digits: int = 6):
    """Floats (also inside dicts and lists) to ``digits`` significant digits: a readable file."""
    if isinstance(value, dict):
        return {k: _rounded(v, digits) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_rounded(v, digits) for v in value]
    if hasattr(value, "item") and not isinstance(value, bool | int | float):  # NumPy scalars
        value = value.item()
    if isinstance(value, float) and math.isfinite(value) and value != 0.0:
        return float(f"{value:.{digits}g}")
    return value


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m wbmpc.studies.calibrate",
        description="Identify a robot's calibration (base CoM offset, force split, joint friction and "
        "armature) from a stand-then-trot bag or log and write it as a calibration file.",
    )
    parser.add_argument("source", type=Path, help="ROS 2 bag folder (or .mcap/.db3 file) or .npz run log")
    parser.add_argument(
        "--output", "-o", type=Path, required=True, help="calibration file to write (.yaml, .yml or .json)"
    )
    parser.add_argument("--robot", default="b1_z1", choices=ROBOT_NAMES, help="nominal robot model")
    parser.add_argument("--topic-map", type=Path, default=None, help="TopicMap JSON of the bag")
    parser.add_argument(
        "--delay", type=float, default=None, help="command delay [s] (default: fitted per joint group)"
    )
    parser.add_argument(
        "--friction-velocity", type=float, default=0.05, help="Coulomb smoothing rate [rad/s] (0.05)"
    )
    parser.add_argument(
        "--base", default="auto", choices=BASE_CHOICES, help="source of the base accelerations (auto)"
    )
    return parser


def _check_arguments(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    if not args.source.exists():
        parser.error(f"no bag or log at {args.source}")
    if args.source.is_file() and args.source.suffix not in (".npz", ".mcap", ".db3"):
        parser.error(f"{args.source} is neither a bag (.mcap, .db3, or a folder) nor an .npz log")
    if args.output.suffix.lower() not in _SUFFIXES:
        parser.error(f"--output {args.output} must end with one of {', '.join(_SUFFIXES)}")
    cli_checks.writable_file(parser, "--output", args.output, "calibration.yaml")
    if args.topic_map is not None and not args.topic_map.is_file():
        parser.error(f"--topic-map {args.topic_map}: no such file")
    if args.delay is not None:
        cli_checks.non_negative(parser, "--delay", args.delay)
    if not (math.isfinite(args.friction_velocity) and args.friction_velocity > 0):
        parser.error(f"--friction-velocity must be a finite number > 0, got {args.friction_velocity}")


def main(argv: list[str] | None = None) -> int:
    """Command line entry point; returns the exit status (2: bad arguments, 1: unusable log)."""
    parser = _parser()
    args = parser.parse_args(argv)
    _check_arguments(parser, args)
    try:
        result = calibrate(
            args.source,
            args.robot,
            topic_map=args.topic_map,
            delay=args.delay,
            friction_velocity=args.friction_velocity,
            base=args.base,
        )
    except (ValueError, FileNotFoundError) as exc:
        print(f"calibrate: {exc}", file=sys.stderr)
        return 1
    print(result.table())
    path = result.calibration.save(args.output)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
