"""Runs on the emulated robot and their bags with a robot's topics only.

:func:`record_emulated_run` (stand, then trot; how ``data/hardware/emulated_b1_stand_trot`` was made, with
:func:`write_robot_bag`), :func:`emulated_mpc` (the MPC these runs use), :func:`downsample`.
"""

from __future__ import annotations

import numpy as np

#: Share of the torque limits the MPC plans with on the emulated robot: the drives add their damping on top
#: and clip at the limit (at 1.0 the rear calves were clipped for a few steps at 0.5 m/s).
EMULATED_TORQUE_FRACTION = 0.9


def emulated_mpc(robot, gait, nodes: int = 15, compiled: bool = True, front_force_ratio=None):
    """The MPC the emulated-robot runs use: ``robot``'s model, the gait (schedule), ``nodes`` nodes, torque
    limits at :data:`EMULATED_TORQUE_FRACTION` (:class:`~wbmpc.ocp.OCPSettings`), compiled Fatrop or
    in-process."""
    from wbmpc.control.mpc import MPCConfig, SolverSettings, WholeBodyMPC
    from wbmpc.ocp import OCPSettings

    config = MPCConfig(gait=gait, front_force_ratio=front_force_ratio)
    settings = OCPSettings(n_nodes=nodes, torque_limit_fraction=EMULATED_TORQUE_FRACTION)
    mpc = WholeBodyMPC(robot, settings, config, SolverSettings(compiled=compiled))
    mpc.verbose = False
    return mpc


def record_emulated_run(
    stand: float = 2.0,
    trot: float = 10.0,
    speed: float = 0.2,
    nodes: int = 15,
    compiled: bool = True,
    profile=None,
    robot=None,
    mpc_robot=None,
    front_force_ratio: float | None = None,
    progress: bool = False,
    gait: str | None = None,
    mpc=None,
    state: str = "estimated",
    delay: str | float = "measured",
    arm_reference=None,
    **loop,
):
    """A run of the MPC on the emulated robot (:func:`wbmpc.sim.presets.hardware_config`): stand, then trot.

    The arm holds still in the heading frame unless ``arm_reference`` is given.

    Args:
        stand, trot: Durations [s] of the standing and trotting segments (gait schedule
            ``stand:S,trot@speed:T``); ignored with ``gait``.
        speed: Forward speed command of the trot [m/s] (the stand segment stands still).
        nodes: MPC nodes; compiled: compiled Fatrop (cached) or in-process.
        profile: The emulated robot (:class:`~wbmpc.sim.hardware.HardwareProfile`; default: its defaults).
        robot: The robot (default :func:`~wbmpc.model.robot.load_b1_z1`); mpc_robot: the model the MPC uses
            (default: ``robot``; e.g. :func:`~wbmpc.model.base_com.shift_base_com` of it, or a calibrated
            one).
        front_force_ratio: Front share of the MPC's force targets (``None``: the MPC robot's).
        progress: Progress bar.
        gait: A gait schedule instead (:func:`wbmpc.ocp.gait.parse_gait_schedule`, e.g.
            ``"stand:2,trot@0.2:10,trot@0.5:5"``); the run lasts its duration.
        mpc: An MPC to run (e.g. with an observer attached; it walks the schedule, its own configuration
            untouched); ``None`` builds one for ``mpc_robot`` with ``nodes``, ``compiled`` and
            ``front_force_ratio``.
        state: ``"estimated"`` (the state estimator) or ``"ground_truth"``.
        delay: Computation delay: ``"measured"`` (each whole solve call's wall time on this machine),
            ``"off"`` or seconds.
        arm_reference: An :class:`~wbmpc.control.arm_task.ArmReference` for the hand; ``None``: held still.
        **loop: Other :func:`~wbmpc.sim.presets.hardware_config` arguments (``low_level``,
            ``disturbances``, ...).

    Returns:
        ``(result, mpc)``: the :class:`~wbmpc.sim.closed_loop.ClosedLoopResult` and the MPC.
    """
    from wbmpc.control.command_schedule import CommandSchedule
    from wbmpc.model.robot import load_b1_z1
    from wbmpc.ocp.gait import parse_gait_schedule
    from wbmpc.sim.closed_loop import run_closed_loop
    from wbmpc.sim.presets import hardware_config

    robot = robot or load_b1_z1()
    spec = gait or (f"stand:{stand:g},trot@{speed:g}:{trot:g}" if trot > 0 else "stand")
    schedule = parse_gait_schedule(spec)
    duration = schedule.duration if gait else stand + trot
    if mpc is None:
        mpc = emulated_mpc(mpc_robot or robot, schedule, nodes, compiled, front_force_ratio)
    commands = CommandSchedule(arm_reference=arm_reference, ee_velocity_frame="heading", gait=schedule)
    run = hardware_config(profile, commands=commands, state=state, delay=delay, duration=duration, **loop)
    return run_closed_loop(mpc, run, progress=progress), mpc


#: Topics a robot records (no simulator truth: no ground-truth odometry, no foot force sensors) and no arm
#: topics (the arm holds still in these runs): about 0.65 MB per second at 250 Hz in MCAP.
ROBOT_TOPICS = {
    "joint_states_measured": None,
    "joint_feedforward": None,
    "ground_truth": None,
    "foot_forces": None,
    "ee_position": None,
    "ee_reference": None,
    "ee_force": None,
    "ee_force_cmd": None,
    "extra_prefix": None,
}


def downsample(log, factor: int):
    """The log with every ``factor``-th signal row (solves unchanged): a lower recording rate."""
    from wbmpc.io.logs import RunLog

    if int(factor) < 1:
        raise ValueError(f"factor must be an integer >= 1, got {factor!r}")
    signals = {k: np.asarray(v)[:: int(factor)] for k, v in log.signals.items()}
    return RunLog(signals=signals, solves=dict(log.solves), meta=dict(log.meta))


def write_robot_bag(log, path, robot, factor: int = 2, storage: str = "mcap"):
    """Record a run as a robot's bag: :data:`ROBOT_TOPICS`, signals at 500 / ``factor`` Hz.

    Returns:
        ``(path, topic_map)``: the bag folder and the :class:`~wbmpc.io.rosbag.TopicMap` to read it with.
    """
    from wbmpc.io.rosbag import TopicMap, write_bag

    topic_map = TopicMap(**ROBOT_TOPICS)
    return write_bag(
        downsample(log, factor), path, robot=robot, storage=storage, topic_map=topic_map
    ), topic_map
