"""The simulation experiments of the paper (and the simulated counterparts of its hardware tasks) in PyBullet.

Each experiment is a function ``name(quick=None, progress=True, log_dir=None) -> ExperimentResult`` that
builds the MPC, runs the closed loop(s) in PyBullet, and returns the key numbers (``result.summary``, JSON
ready), the runs (logs) and a paper-style figure (``result.figure``). The command

    python -m wbmpc.studies.experiments                      # all, full runs -> data/results/sim/<name>.json
    python -m wbmpc.studies.experiments wiping --quick       # one, quick mode -> data/output/sim/<name>.json

writes the summaries, the figures (``data/output/sim/<name>.png``) and the columnar logs
(``data/output/sim/logs/<name>_<run>.npz``, see :mod:`wbmpc.io.logs`).

Full runs use the compiled Fatrop solver and 15 nodes; quick mode (``WBMPC_QUICK=1``) uses the in-process
solver, 10 nodes and about a second of simulated time, enough to check each experiment's key outcome.

==========================  ====================================================================
``arm_tracking``            trot at 0.2 m/s while the end effector reaches low and high
``disturbance_rejection``   0.8 m/s lateral base kick while trotting in place, at two gait phases
``pulling_load``            drag a tethered load with a commanded force: stance, walking, max load
``box_pushing``             push a box against a wall with a force target while trotting in place
``wiping``                  wipe a vertical board with a normal-force target while standing
``compliance``              zero arm targets, low arm gains: a push moves the arm, which yields
``time_steps_drift``        adaptive vs uniform time steps with computation delay: base drift
``robustness_sweep``        success over kick magnitudes and gait phases (a benchmark)
==========================  ====================================================================
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pinocchio as pin

from wbmpc.control.arm_task import ArmReference
from wbmpc.control.mpc import MPCConfig, WholeBodyMPC
from wbmpc.io.logs import json_default
from wbmpc.model.robot import Robot, load_b1_z1
from wbmpc.ocp import OCPSettings
from wbmpc.ocp.gait import make_gait
from wbmpc.ocp.time_grid import geometric_time_steps
from wbmpc.quick import quick_mode
from wbmpc.sim.closed_loop import ClosedLoopConfig, ClosedLoopResult, machine_description, run_closed_loop
from wbmpc.sim.disturbances import Kick, Push
from wbmpc.sim.pybullet_plant import Box, Payload, Wall
from wbmpc.studies import cli_checks
from wbmpc.viz.plots import save_figure

REPO_ROOT = Path(__file__).resolve().parents[2]
GAIT_PERIOD = 0.8  # s, trot (paper)


@dataclass
class ExperimentResult:
    """Outcome of one experiment.

    Attributes:
        name: Experiment name.
        summary: Key numbers (JSON-serialisable).
        runs: The closed-loop runs by label (their logs: ``runs[label].log``, ``.run_log()``, ``.save()``).
        figure: A matplotlib figure in the paper's style (``None`` if not drawn).
    """

    name: str
    summary: dict
    runs: dict[str, ClosedLoopResult] = field(default_factory=dict)
    figure: object | None = None


# --------------------------------------------------------------------------------------------- helpers
def _pick(is_quick: bool, full, quick):
    """:func:`wbmpc.quick.pick` for an explicit quick flag (the experiments take ``quick=`` arguments)."""
    return quick if is_quick else full


def _setup(quick: bool | None, robot: Robot | None, **mpc_kwargs):
    quick = quick_mode() if quick is None else quick
    robot = robot or load_b1_z1()
    nodes = 10 if quick else 15
    config = MPCConfig(compiled=not quick, **mpc_kwargs)
    return quick, robot, nodes, config


_MPC_CACHE: dict[tuple, WholeBodyMPC] = {}


def _mpc(robot: Robot, nodes: int, config: MPCConfig) -> WholeBodyMPC:
    """An MPC for ``robot`` with ``nodes`` nodes and ``config``, re-used between runs when only runtime
    settings differ (gait, time steps, weights: building the problem and its solvers takes seconds)."""
    structural = (
        config.solver,
        config.compiled,
        tuple(config.compile_flags),
        config.tol,
        config.max_iter,
        config.cold_max_iter,
        config.retry_max_iter,
        config.mu_init_warm,
        config.mu_init_cold,
    )
    key = (id(robot), nodes, structural)
    mpc = _MPC_CACHE.get(key)
    if mpc is None or mpc.robot is not robot:
        mpc = _MPC_CACHE[key] = WholeBodyMPC(robot, OCPSettings(n_nodes=nodes), config)
    mpc.config = config
    mpc.reset()
    return mpc


def _run(robot, nodes, mpc_config, loop: ClosedLoopConfig, progress: bool, q0=None) -> ClosedLoopResult:
    mpc = _mpc(robot, nodes, mpc_config)
    mpc.verbose = progress
    return run_closed_loop(mpc, loop, q0=q0, progress=progress)


def _base_loop(**kwargs) -> ClosedLoopConfig:
    """PyBullet at 2 kHz, MPC 80 Hz, low level 500 Hz; no arm reference unless given: the experiments
    command the hand's world velocity (pulling, pushing, wiping), the paper's command."""
    defaults = {
        "plant": "pybullet",
        "arm_reference": None,
        "ee_velocity_frame": "world",
        "base_velocity": (0.0, 0.0, 0.0),
    }
    return ClosedLoopConfig(**(defaults | kwargs))


def _solve_stats(result: ClosedLoopResult) -> dict:
    s = result.summary
    return {
        "solve_ms": s["solve_ms"],
        "iterations_mean": s["iterations_mean"],
        "converged_fraction": s["converged_fraction"],
        "fallbacks": s["fallbacks"],
        "compiled": s["compiled"],
        "delay": s["delay"],
    }


def _common(result: ClosedLoopResult, quick: bool) -> dict:
    s = result.summary
    return {
        "quick": quick,
        "duration_s": s["duration_s"],
        "fell": s["fell"],
        "max_tilt_rad": s["max_tilt_rad"],
        "nodes": s["nodes"],
        "plant": s["plant"],
        "low_level": s["low_level"],
        "delay": s["delay"],
        "solver": _solve_stats(result),
        "machine": s["machine"],
    }


def _ee_start(robot: Robot, q: np.ndarray) -> np.ndarray:
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, q)
    return data.oMf[robot.frame_id(robot.ee_frame)].translation.copy()


def _robot_front(robot: Robot, q: np.ndarray) -> float:
    """World x [m] of the robot's most forward point at ``q`` (the gripper tip with the arm forward), from
    PyBullet's collision geometry: surfaces the gripper should touch are placed there, not at the
    end-effector frame (``gripper_center`` sits 7.7 cm behind the tip on the B1 + Z1)."""
    import pybullet as p

    from wbmpc.sim.pybullet_plant import PyBulletPlant

    with PyBulletPlant(robot) as plant:
        plant.reset(q, np.zeros(robot.nv))
        n = p.getNumJoints(plant.body_id, physicsClientId=plant.client)
        return max(p.getAABB(plant.body_id, j, physicsClientId=plant.client)[1][0] for j in range(-1, n))


def _ee_velocity(log) -> np.ndarray:
    t, p = np.asarray(log.t), np.asarray(log.ee_position)
    return np.gradient(p, t, axis=0) if len(t) > 2 else np.zeros_like(p)


def _figure(nrows: int, ncols: int = 1, height: float = 2.4, width: float = 8.0):
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height * nrows), layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False)
    return fig, axes[:, 0] if ncols == 1 else axes


def _pitch(q: np.ndarray) -> np.ndarray:
    return np.array([pin.rpy.matrixToRpy(pin.Quaternion(qi[3:7]).toRotationMatrix())[1] for qi in q])


# --------------------------------------------------------------------------------------------- 1
def arm_tracking(quick=None, progress=True, robot=None) -> ExperimentResult:
    """Whole-body adaptability: trot at 0.2 m/s while the end effector tracks a low/high reference.

    The reference (:class:`wbmpc.control.arm_task.ArmReference`) moves the gripper 15 cm down and up
    (5 cm fore-aft)
    with a 5 s period, ramped in over 1 s. Pure feed-forward torques (Kp = Kd = 0), no delay (paper).
    Reports the end-effector RMS error and how base height and pitch adapt.
    """
    quick, robot, nodes, mpc_config = _setup(quick, robot, gait=make_gait("trot", GAIT_PERIOD))
    loop = _base_loop(
        duration=_pick(quick, full=10.0, quick=1.0),
        base_velocity=(0.2, 0.0, 0.0),
        arm_reference=ArmReference(ramp=_pick(quick, full=1.0, quick=0.3)),
    )
    result = _run(robot, nodes, mpc_config, loop, progress)
    arrays = result.log.arrays()
    q = arrays["q"]
    pitch = _pitch(q)
    summary = _common(result, quick) | {
        "ee_rms_cm": 100 * result.summary["ee_rms_m"],
        "ee_max_error_cm": 100 * result.summary["ee_max_error_m"],
        "base_height_range_m": result.summary["base_height_range_m"],
        "base_pitch_range_rad": [float(pitch.min()), float(pitch.max())],
        "distance_travelled_m": result.summary["distance_travelled_m"],
        "ee_reference_amplitude_m": list(ArmReference().amplitude),
    }
    fig, ax = _figure(3)
    t = arrays["t"]
    ax[0].plot(t, arrays["ee_position"][:, 2], label="end effector z")
    ax[0].plot(t, arrays["ee_reference"][:, 2], "--", label="reference z")
    ax[0].set(ylabel="height [m]")
    ax[1].plot(t, q[:, 2], color="tab:green")
    ax[1].set(ylabel="base height [m]")
    ax[2].plot(t, np.degrees(pitch), color="tab:red")
    ax[2].set(ylabel="base pitch [deg]", xlabel="time [s]")
    ax[0].legend(fontsize=8)
    ax[0].set_title(f"Arm tracking while trotting: EE RMS {summary['ee_rms_cm']:.2f} cm")
    return ExperimentResult("arm_tracking", summary, {"trot": result}, fig)


# --------------------------------------------------------------------------------------------- 2
def disturbance_rejection(quick=None, progress=True, robot=None, magnitude: float = 0.8) -> ExperimentResult:
    """A lateral base-velocity kick while trotting in place, at two gait phases.

    Phases are fractions of the trot period after a lift-off of a diagonal pair (the trot is symmetric under
    a half-period shift): phase 0 hits at the lift-off (a whole swing ahead), phase 0.25 mid-swing. Reports
    the peak lateral base velocity, the lateral displacement, the recovery time (|v_y| < 0.1 m/s) and the rear
    calf torques against their limits.
    """
    quick, robot, nodes, mpc_config = _setup(quick, robot, gait=make_gait("trot", GAIT_PERIOD))
    kick_time = _pick(quick, full=2.0, quick=0.4)  # lift-offs at multiples of 0.4 s
    runs, per_phase = {}, {}
    for phase in (0.0, 0.25):
        t_kick = kick_time + phase * GAIT_PERIOD
        loop = _base_loop(
            duration=t_kick + _pick(quick, full=2.5, quick=0.5),
            disturbances=(Kick(t_kick, (0.0, magnitude, 0.0)),),
        )
        result = _run(robot, nodes, mpc_config, loop, progress)
        runs[f"phase_{phase:g}"] = result
        per_phase[f"{phase:g}"] = _kick_report(robot, result, t_kick)
    summary = {
        "quick": quick,
        "kick_m_per_s": magnitude,
        "phases": per_phase,
        "fell": any(r.fell for r in runs.values()),
        # The MPC's push recovery (wbmpc.control.push_recovery): swing abort and end-effector release.
        "push_recovery": {
            name: getattr(mpc_config, name)
            for name in ("kick_recovery", "kick_recovery_phase", "kick_ee_release")
        },
        "solver": _solve_stats(next(iter(runs.values()))),
        "machine": machine_description(),
    }
    fig, ax = _figure(3)
    calves = _rear_calves(robot)
    for (label, result), style in zip(runs.items(), ("-", "--"), strict=True):
        a = result.log.arrays()
        R = [pin.Quaternion(qi[3:7]).toRotationMatrix() for qi in a["q"]]
        v_y = np.array([(Ri @ vi[:3])[1] for Ri, vi in zip(R, a["v"], strict=True)])
        ax[0].plot(a["t"], v_y, style, label=f"base, {label}")
        ax[1].plot(a["t"], _ee_velocity(result.log)[:, 1], style, label=f"EE, {label}")
        for j, name in calves.items():
            ax[2].plot(a["t"], a["tau"][:, j], style, label=f"{name}, {label}")
    limit = robot.joint_torque_limits[list(calves)[0]]
    for sign in (-1, 1):
        ax[2].axhline(sign * limit, color="k", lw=0.8)
    ax[0].set(ylabel="lateral base vel. [m/s]")
    ax[1].set(ylabel="lateral EE vel. [m/s]")
    ax[2].set(ylabel="rear calf torque [N m]", xlabel="time [s]")
    for a_ in ax:
        a_.legend(fontsize=7)
    ax[0].set_title(f"{magnitude} m/s lateral kick while trotting in place")
    return ExperimentResult("disturbance_rejection", summary, runs, fig)


def _rear_calves(robot: Robot) -> dict[int, str]:
    names = [n for n in robot.joint_names if "calf" in n and n.startswith(("RL", "RR"))]
    return {robot.joint_names.index(n): n for n in names}


def _kick_report(robot: Robot, result: ClosedLoopResult, t_kick: float) -> dict:
    a = result.log.arrays()
    t = a["t"]
    v_world = np.array(
        [pin.Quaternion(qi[3:7]).toRotationMatrix() @ vi[:3] for qi, vi in zip(a["q"], a["v"], strict=True)]
    )
    after = t >= t_kick
    recovered = after & (np.abs(v_world[:, 1]) < 0.1) & (t > t_kick + 0.05)
    calves = _rear_calves(robot)
    idx = list(calves)
    limits = robot.joint_torque_limits[idx]
    return {
        "kick_time_s": t_kick,
        "fell": result.fell,
        "peak_lateral_velocity_m_per_s": float(np.max(np.abs(v_world[after, 1]))) if after.any() else None,
        "lateral_displacement_m": float(a["q"][-1, 1] - a["q"][after][0, 1]) if after.any() else None,
        "recovery_time_s": float(t[recovered][0] - t_kick) if recovered.any() else None,
        "rear_calf_peak_torque_ratio": float(np.max(np.abs(a["tau"][after][:, idx]) / limits))
        if after.any()
        else None,
        "max_tilt_rad": result.summary["max_tilt_rad"],
    }


# --------------------------------------------------------------------------------------------- 3
def _tether_scene(robot: Robot, q0: np.ndarray, mass: float, length: float = 1.5, friction: float = 0.5):
    """A sled-like load (a sphere that slides, not rolls) on a taut tether in front of the end effector."""
    ee = _ee_start(robot, q0)
    radius = 0.08
    drop = ee[2] - radius
    reach = float(np.sqrt(max(length**2 - drop**2, 0.01)))
    position = (ee[0] + reach, ee[1], radius)
    load = Payload(
        mass=mass,
        position=position,
        radius=radius,
        friction=friction,
        attach="tether",
        tether_length=length,
        rolling_friction=1.0,
    )
    direction = (np.array(position) - ee) / length  # unit vector from the EE to the load
    return {"load": load}, direction


def _pull_run(
    robot, nodes, mpc_config, quick, mass, walking: bool, progress, ground_friction=0.8, duration=None
):
    q0 = robot.q_nominal
    scene, direction = _tether_scene(robot, q0, mass)
    mu = 0.5 * ground_friction  # load friction x ground friction (PyBullet multiplies them)
    # Steady sliding, rope at theta above the horizontal: T cos(theta) = mu (m g - T sin(theta)).
    cos_t, sin_t = direction[0], -direction[2]
    tension = mu * mass * robot.gravity / (cos_t + mu * sin_t)
    ee_force = tuple(tension * direction)  # the rope pulls the end effector towards the load
    speed = 0.1
    if walking:
        kwargs = {"base_velocity": (-speed, 0.0, 0.0), "ee_velocity": (-speed, 0.0, 0.0)}
        gait = make_gait("trot", GAIT_PERIOD)
    else:
        kwargs = {"ee_velocity": (-0.05, 0.0, 0.0)}
        gait = make_gait("stand", GAIT_PERIOD)
    if duration is None:
        duration = _pick(quick, full=4.0, quick=1.0) if walking else _pick(quick, full=3.0, quick=1.2)

    def ramp(t):  # ramp the commanded force in over 0.3 s (the rope tightens as the arm moves)
        s = min(1.0, t / 0.3)
        return {"ee_force": tuple(s * f for f in ee_force)}

    loop = _base_loop(
        duration=duration, scene=scene, ground_friction=ground_friction, command_schedule=ramp, **kwargs
    )
    result = _run(robot, nodes, replace(mpc_config, gait=gait), loop, progress, q0=q0)
    return result, np.array(ee_force)


def pulling_load(quick=None, progress=True, robot=None, masses=None) -> ExperimentResult:
    """Pull a tethered load (sliding sphere, friction 0.5 x ground 0.8) with a commanded end-effector force.

    In stance the arm pulls back at 5 cm/s; walking, the robot trots backwards at 0.1 m/s. The commanded
    force is the load's sliding friction along the rope. Success: no fall and the load follows (moves at
    least half the commanded displacement). The sweep over ``masses`` (walking) finds the largest load that
    succeeds (the paper: 14 kg in simulation).
    """
    quick, robot, nodes, mpc_config = _setup(quick, robot)
    masses = (
        masses if masses is not None else _pick(quick, full=(12.0, 14.0, 16.0, 18.0, 20.0, 25.0), quick=())
    )
    runs, cases = {}, {}
    for label, walking, mass in [("stance_10kg", False, 10.0), ("walking_10kg", True, 10.0)] + [
        (f"walking_{m:g}kg", True, m) for m in masses
    ]:
        result, force = _pull_run(robot, nodes, mpc_config, quick, mass, walking, progress)
        runs[label] = result
        cases[label] = _pull_report(result, walking, mass, force)
        if label.startswith("walking") and mass > 10 and not cases[label]["success"]:
            break  # heavier loads only get harder
    walking_ok = [c["mass_kg"] for c in cases.values() if c["walking"] and c["success"]]
    summary = {
        "quick": quick,
        "cases": cases,
        "max_load_walking_kg": max(walking_ok) if walking_ok else None,
        "masses_tried_kg": sorted({c["mass_kg"] for c in cases.values()}),
        "fell": any(c["fell"] for c in cases.values() if c["mass_kg"] == 10.0),
        "solver": _solve_stats(runs["stance_10kg"]),
        "machine": machine_description(),
    }
    fig, ax = _figure(2)
    for label, result in runs.items():
        a = result.log.arrays()
        load = a["scene_positions"][:, result.summary["scene_bodies"].index("load")]
        ax[0].plot(a["t"], load[:, 0] - load[0, 0], label=label)
        ax[1].plot(a["t"], a["q"][:, 0] - a["q"][0, 0], label=label)
    ax[0].set(ylabel="load x displacement [m]")
    ax[1].set(ylabel="base x displacement [m]", xlabel="time [s]")
    ax[0].legend(fontsize=7)
    ax[0].set_title("Pulling a tethered load")
    return ExperimentResult("pulling_load", summary, runs, fig)


def _pull_report(result: ClosedLoopResult, walking: bool, mass: float, force_cmd: np.ndarray) -> dict:
    a = result.log.arrays()
    ee = a["ee_position"]
    commanded_disp = (0.1 if walking else 0.05) * result.summary["duration_s"]
    ee_disp = float(ee[0, 0] - ee[-1, 0])  # the EE moves towards -x
    load = a["scene_positions"][:, result.summary["scene_bodies"].index("load")]
    load_disp = float(load[0, 0] - load[-1, 0])
    return {
        "mass_kg": mass,
        "walking": walking,
        "fell": result.fell,
        "commanded_force_n": force_cmd.tolist(),
        "ee_displacement_m": ee_disp,
        "commanded_displacement_m": commanded_disp,
        "success": bool(not result.fell and load_disp > 0.5 * commanded_disp),
        "max_tilt_rad": result.summary["max_tilt_rad"],
        "converged_fraction": result.summary["converged_fraction"],
        "load_displacement_m": load_disp,
    }


# --------------------------------------------------------------------------------------------- 4
def box_pushing(quick=None, progress=True, robot=None, force: float = 30.0) -> ExperimentResult:
    """Push a box against a wall with an end-effector force target while trotting in place.

    A 5 kg box stands on the ground with its near face at the gripper and its far face against a wall. The
    commanded force on the robot is ``(-force, 0, 0)`` (the box pushes back), ramped in over 0.5 s; the
    simulator measures the actual contact force on the gripper.
    """
    quick, robot, nodes, mpc_config = _setup(quick, robot, gait=make_gait("trot", GAIT_PERIOD))
    ee = _ee_start(robot, robot.q_nominal)
    front = _robot_front(robot, robot.q_nominal) + 0.002
    depth, height = 0.2, ee[2] + 0.1
    scene = {
        "box": Box((depth, 0.4, height), (front + 0.5 * depth, ee[1], 0.5 * height), mass=5.0, friction=0.8),
        "wall": Wall((front + depth, ee[1], 0.6), (-1.0, 0.0, 0.0), size=(2.0, 1.2)),
    }
    hold = _pick(quick, full=1.0, quick=0.5)

    def schedule(t):
        return {
            "ee_force": (-force * min(1.0, t / 0.5), 0.0, 0.0),
            "ee_velocity": (0.02 if t < 0.5 else 0.0, 0, 0),
        }

    loop = _base_loop(duration=_pick(quick, full=5.0, quick=1.0), scene=scene, command_schedule=schedule)
    result = _run(robot, nodes, mpc_config, loop, progress)
    a = result.log.arrays()
    held = a["t"] >= hold
    fx = a["ee_force_sim"][held, 0]
    summary = _common(result, quick) | {
        "force_target_n": -force,
        "measured_force_x_mean_n": float(np.mean(fx)) if fx.size else None,
        "measured_force_x_std_n": float(np.std(fx)) if fx.size else None,
        "contact_fraction": float(np.mean(np.linalg.norm(a["ee_force_sim"][held], axis=1) > 1.0))
        if fx.size
        else 0,
    }
    fig, ax = _figure(2)
    ax[0].plot(a["t"], a["ee_force_sim"][:, 0], label="measured (sim)")
    ax[0].plot(a["t"], a["ee_force_cmd"][:, 0], "--", label="target")
    ax[0].set(ylabel="force on EE, x [N]")
    ax[0].legend(fontsize=8)
    ax[1].plot(a["t"], a["q"][:, 0] - a["q"][0, 0], label="base x")
    ax[1].plot(a["t"], a["q"][:, 1] - a["q"][0, 1], label="base y")
    ax[1].set(ylabel="base drift [m]", xlabel="time [s]")
    ax[1].legend(fontsize=8)
    ax[0].set_title("Pushing a box against a wall while trotting in place")
    return ExperimentResult("box_pushing", summary, {"push": result}, fig)


# --------------------------------------------------------------------------------------------- 5
def wiping(quick=None, progress=True, robot=None, normal_force: float = 20.0) -> ExperimentResult:
    """Wipe a vertical board while standing: the gripper slides 10 cm left and right along the board with a
    normal-force target; the simulator measures the normal force actually applied."""
    quick, robot, nodes, mpc_config = _setup(quick, robot, gait=make_gait("stand", GAIT_PERIOD))
    ee = _ee_start(robot, robot.q_nominal)
    front = _robot_front(robot, robot.q_nominal)
    board = Wall((front + 0.002, ee[1], ee[2]), (-1.0, 0.0, 0.0), size=(1.2, 0.8), friction=0.3)
    # The reference's centre is 1.5 cm inside the board: the position feedback keeps the tip pressed on it.
    reference = ArmReference(amplitude=(0.0, 0.1, 0.0), period=_pick(quick, full=3.0, quick=1.5), ramp=0.5)
    reference = reference.centered_at(robot.q_nominal, ee + np.array([0.015, 0.0, 0.0]))

    def schedule(t):
        return {"ee_force": (-normal_force * min(1.0, t / 0.5), 0.0, 0.0)}

    loop = _base_loop(
        duration=_pick(quick, full=6.0, quick=1.2),
        scene={"board": board},
        arm_reference=reference,
        command_schedule=schedule,
    )
    result = _run(robot, nodes, mpc_config, loop, progress)
    a = result.log.arrays()
    held = a["t"] >= 0.5
    fx = a["ee_force_sim"][held, 0]
    summary = _common(result, quick) | {
        "normal_force_target_n": normal_force,
        "measured_normal_force_mean_n": float(-np.mean(fx)) if fx.size else None,
        "measured_normal_force_std_n": float(np.std(fx)) if fx.size else None,
        "contact_fraction": float(np.mean(np.abs(fx) > 1.0)) if fx.size else 0.0,
        "wipe_travel_y_m": float(np.ptp(a["ee_position"][held, 1])) if fx.size else 0.0,
        "ee_rms_cm": 100 * result.summary["ee_rms_m"],
    }
    fig, ax = _figure(2)
    ax[0].plot(a["t"], -a["ee_force_sim"][:, 0], label="measured normal force (sim)")
    ax[0].plot(a["t"], -a["ee_force_cmd"][:, 0], "--", label="target")
    ax[0].set(ylabel="normal force [N]")
    ax[0].legend(fontsize=8)
    ax[1].plot(a["t"], a["ee_position"][:, 1], label="EE y")
    ax[1].plot(a["t"], a["ee_reference"][:, 1], "--", label="reference y")
    ax[1].set(ylabel="along the board [m]", xlabel="time [s]")
    ax[1].legend(fontsize=8)
    ax[0].set_title("Wiping a vertical board")
    return ExperimentResult("wiping", summary, {"wipe": result}, fig)


# --------------------------------------------------------------------------------------------- 6
def compliance(quick=None, progress=True, robot=None, push: float = 40.0) -> ExperimentResult:
    """Zero end-effector velocity and force targets, low arm gains: a sideways push on the gripper moves the
    arm, which yields and settles where it was pushed (the MPC re-plans from the measured arm).

    Reports the displacement during the push, the displacement kept afterwards and the settling time (the
    gripper slower than 2 cm/s for good).
    """
    quick, robot, nodes, mpc_config = _setup(quick, robot, gait=make_gait("stand", GAIT_PERIOD))
    start, duration = _pick(quick, full=1.0, quick=0.4), 0.3
    loop = _base_loop(
        duration=_pick(quick, full=4.0, quick=1.1),
        arm_gains=(0.0, 0.5),
        disturbances=(Push(start, duration, (0.0, push, 0.0), target="ee"),),
    )
    result = _run(robot, nodes, mpc_config, loop, progress)
    a = result.log.arrays()
    t, y = a["t"], a["ee_position"][:, 1]
    speed = np.linalg.norm(_ee_velocity(result.log), axis=1)
    after = t >= start + duration
    moving = after & (speed > 0.02)
    settle = float(t[moving][-1] - (start + duration)) if moving.any() else 0.0
    summary = _common(result, quick) | {
        "push_n": push,
        "push_window_s": [start, start + duration],
        "max_displacement_cm": float(100 * np.max(np.abs(y - y[0]))),
        "final_displacement_cm": float(100 * (y[-1] - y[0])),
        "settling_time_s": settle,
        "final_ee_speed_m_per_s": float(speed[-1]),
    }
    fig, ax = _figure(2)
    ax[0].plot(t, 100 * (y - y[0]))
    ax[0].axvspan(start, start + duration, color="tab:orange", alpha=0.2, label="push")
    ax[0].set(ylabel="EE lateral displacement [cm]")
    ax[0].legend(fontsize=8)
    ax[1].plot(t, speed)
    ax[1].set(ylabel="EE speed [m/s]", xlabel="time [s]")
    ax[0].set_title("Compliance: zero arm targets, low arm gains")
    return ExperimentResult("compliance", summary, {"push": result}, fig)


# --------------------------------------------------------------------------------------------- 7
def time_steps_drift(quick=None, progress=True, robot=None, delay: float | str = 0.0125) -> ExperimentResult:
    """Adaptive (geometric 10 -> 100 ms) vs uniform (40 ms) time steps, same 0.56 s horizon and 15 nodes,
    trotting in place with computation delay and Kd = 5 (paper: 0.4 vs 1.2 cm/s base drift).

    The default delay is a fixed 12.5 ms, the paper's compiled solve time (one MPC period); ``"measured"``
    uses each solve's wall time on this machine instead.
    """
    quick, robot, _, mpc_config = _setup(quick, robot, gait=make_gait("trot", GAIT_PERIOD))
    nodes = 15  # the comparison is about the grid: same nodes in both modes
    duration = _pick(quick, full=10.0, quick=0.8)
    grids = {"adaptive": (0.01, 0.1), "uniform": (0.04, 0.04)}
    runs, drift = {}, {}
    for label, (dt_min, dt_max) in grids.items():
        config = replace(mpc_config, dt_min=dt_min, dt_max=dt_max)
        loop = _base_loop(duration=duration, kd=5.0, delay=delay, velocity_cutoff_hz=50.0)
        result = _run(robot, nodes, config, loop, progress)
        runs[label] = result
        q = result.log.arrays()["q"]
        d = result.summary["duration_s"] or 1.0
        drift[label] = {
            "drift_cm_per_s": float(100 * np.linalg.norm(q[-1, :2] - q[0, :2]) / d),
            "horizon_s": float(np.sum(geometric_time_steps(nodes, dt_min, dt_max))),
            "fell": result.fell,
            "converged_fraction": result.summary["converged_fraction"],
            "iterations_mean": result.summary["iterations_mean"],
        }
    summary = {
        "quick": quick,
        "delay": delay,
        "kd": 5.0,
        "velocity_cutoff_hz": 50.0,
        "nodes": nodes,
        "grids": drift,
        "fell": any(r.fell for r in runs.values()),
        "solver": _solve_stats(runs["adaptive"]),
        "machine": machine_description(),
    }
    fig, ax = _figure(1, height=3.0)
    for label, result in runs.items():
        q = result.log.arrays()["q"]
        ax[0].plot(
            q[:, 0] - q[0, 0], q[:, 1] - q[0, 1], label=f"{label}: {drift[label]['drift_cm_per_s']:.2f} cm/s"
        )
    ax[0].set(xlabel="base x [m]", ylabel="base y [m]", title="Base drift trotting in place (with delay)")
    ax[0].axis("equal")
    ax[0].legend(fontsize=8)
    return ExperimentResult("time_steps_drift", summary, runs, fig)


# --------------------------------------------------------------------------------------------- sweep
def robustness_sweep(quick=None, progress=True, robot=None, magnitudes=None, phases=None) -> ExperimentResult:
    """Success (no fall) over a grid of lateral kick magnitudes [m/s] and gait phases (a benchmark).

    Phase 0 is the lift-off of a diagonal pair; 0.25 mid-swing; 0.5 the next lift-off (the other pair).
    """
    quick, robot, nodes, mpc_config = _setup(quick, robot, gait=make_gait("trot", GAIT_PERIOD))
    magnitudes = magnitudes or _pick(quick, full=(0.4, 0.6, 0.8, 1.0), quick=(0.8,))
    phases = phases or _pick(quick, full=(0.0, 0.125, 0.25, 0.375), quick=(0.0,))
    t0 = _pick(quick, full=1.2, quick=0.4)  # a lift-off (a multiple of half the trot period): phase 0
    grid, runs = [], {}
    for m in magnitudes:
        for ph in phases:
            t_kick = t0 + ph * GAIT_PERIOD
            loop = _base_loop(
                duration=t_kick + _pick(quick, full=2.0, quick=0.5),
                disturbances=(Kick(t_kick, (0.0, m, 0.0)),),
            )
            result = _run(robot, nodes, mpc_config, loop, progress=False)
            runs[f"{m:g}_{ph:g}"] = result
            grid.append(
                {
                    "magnitude_m_per_s": m,
                    "phase": ph,
                    "success": not result.fell,
                    "max_tilt_rad": result.summary["max_tilt_rad"],
                }
            )
            if progress:
                print(
                    f"[robustness] kick {m} m/s at phase {ph}: {'ok' if not result.fell else 'FELL'}",
                    flush=True,
                )
    summary = {
        "quick": quick,
        "grid": grid,
        "success_rate": float(np.mean([g["success"] for g in grid])),
        "success_rate_by_magnitude": {
            f"{m:g}": float(np.mean([g["success"] for g in grid if g["magnitude_m_per_s"] == m]))
            for m in magnitudes
        },
        "machine": machine_description(),
    }
    fig, ax = _figure(1, height=3.0, width=5.0)
    table = np.array([[float(g["success"]) for g in grid if g["magnitude_m_per_s"] == m] for m in magnitudes])
    ax[0].imshow(table, cmap="RdYlGn", vmin=0, vmax=1, aspect="auto")
    ax[0].set_xticks(range(len(phases)), [f"{p:g}" for p in phases])
    ax[0].set_yticks(range(len(magnitudes)), [f"{m:g}" for m in magnitudes])
    ax[0].set(
        xlabel="gait phase of the kick", ylabel="lateral kick [m/s]", title="Success (green) over the grid"
    )
    return ExperimentResult("robustness_sweep", summary, runs, fig)


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


def save(
    result: ExperimentResult,
    directory: Path,
    log_directory: Path | None = None,
    figure_directory: Path | None = None,
) -> Path:
    """Write ``<name>.json`` (summary) to ``directory``, ``<name>.png`` (figure) to ``figure_directory``
    (default ``data/output/sim``, git-ignored) and, if ``log_directory`` is given, the runs' logs."""
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / f"{result.name}.json"
    path.write_text(json.dumps(result.summary, indent=2, default=json_default))
    if result.figure is not None:
        save_figure(result.figure, result.name, figure_directory or REPO_ROOT / "data/output/sim")
    if log_directory is not None:
        for label, run in result.runs.items():
            run.save(log_directory / f"{result.name}_{label}.npz")
    return path


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


if __name__ == "__main__":
    main()


def replay_html(
    viewer, result: ExperimentResult, directory: Path | None = None, run: str | None = None
) -> Path:
    """Replay one run of an experiment in a :class:`wbmpc.viz.Viewer` (measured feet forces as arrows)
    and export it as a self-contained HTML file ``<directory>/<name>[_<run>].html``."""
    label = run or next(iter(result.runs))
    log = result.runs[label].log.arrays()
    forces = np.concatenate([log["foot_forces"], log["ee_force_sim"][:, None, :]], axis=1)
    viewer.animation(log["q"], log["t"], forces=forces, contact=log["contact_sim"])
    directory = Path(directory) if directory is not None else REPO_ROOT / "data/output/sim"
    suffix = "" if len(result.runs) == 1 else f"_{label}"
    return viewer.export_html(directory / f"{result.name}{suffix}.html")
