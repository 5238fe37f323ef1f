"""What a closed-loop run did, in numbers: the run summary (convergence, tracking, tilt, torques, contacts,
timing) and the machine it ran on.
"""

from __future__ import annotations

import platform
from collections.abc import Mapping

import numpy as np
import pinocchio as pin

from wbmpc.control.mpc import WholeBodyMPC
from wbmpc.model.quaternion import tilt
from wbmpc.sim.loop_config import ClosedLoopConfig
from wbmpc.sim.loop_log import ClosedLoopLog
from wbmpc.sim.plant import Plant


def machine_description() -> str:
    """CPU model and core count, for benchmark records."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    import os

    system = f"{platform.system()} {platform.release()}"
    return f"{cpu}, {os.cpu_count()} cores, {system}, Python {platform.python_version()}"


def blasfeo_record() -> dict:
    """Which BLASFEO Fatrop ran on (see :mod:`wbmpc.solver.blasfeo`), for run summaries."""
    from wbmpc.solver import blasfeo

    info = blasfeo.info()
    return {k: info.get(k) for k in ("choice", "reason", "library", "target", "library_features")}


def summarize(
    mpc: WholeBodyMPC,
    log: ClosedLoopLog | Mapping[str, np.ndarray],
    config: ClosedLoopConfig,
    fell: bool,
    torque_violations: int,
    plant: Plant | None = None,
    gait=None,
) -> dict:
    """Key numbers of a run: solve-time statistics (in-process), convergence, tracking, safety.

    ``log`` is the run's log or its columns by name (:meth:`ClosedLoopLog.arrays`); ``gait`` the gait walked
    (default: the MPC's configured one).
    """
    gait = mpc.config.gait if gait is None else gait
    arrays = log if isinstance(log, Mapping) else log.arrays()
    solve_ms = 1e3 * arrays["solve_time"]
    warm = solve_ms[1:] if solve_ms.size > 1 else solve_ms
    iters = arrays["iterations"][1:] if arrays["iterations"].size > 1 else arrays["iterations"]
    ee_err = (
        np.linalg.norm(arrays["ee_position"] - arrays["ee_reference"], axis=1)
        if len(arrays["t"])
        else np.array([])
    )
    ee_err = ee_err[np.isfinite(ee_err)]
    q = arrays["q"]
    low, sensing = config.low_level, config.sensing
    summary = {
        "robot": mpc.robot.name,
        "gait": gait.name,
        "solver": mpc.solver_settings.solver,
        "compiled": mpc.solver_settings.compiled,
        "plant": config.plant.kind,
        "nodes": mpc.n_nodes,
        "duration_s": float(arrays["t"][-1]) if len(arrays["t"]) else 0.0,
        "requested_duration_s": config.duration,
        "base_velocity_cmd": list(config.commands.base_velocity),
        "mpc_solves": int(len(solve_ms)),
        "solve_ms": {
            "median": float(np.median(warm)) if warm.size else None,
            "p95": float(np.percentile(warm, 95)) if warm.size else None,
            "max": float(np.max(warm)) if warm.size else None,
            "mean": float(np.mean(warm)) if warm.size else None,
            "std": float(np.std(warm)) if warm.size else None,
            "cold_start": float(solve_ms[0]) if solve_ms.size else None,
        },
        "cold_start_iterations": int(arrays["iterations"][0]) if arrays["iterations"].size else None,
        "iterations_mean": float(np.mean(iters)) if iters.size else None,
        "iterations_max": int(np.max(iters)) if iters.size else None,
        "converged_fraction": float(np.mean(arrays["success"])) if arrays["success"].size else 0.0,
        "fallbacks": int(np.sum(arrays["fallback"])),
        "constraint_violation": {
            "median": float(np.median(arrays["violation"])) if arrays["violation"].size else None,
            "max": float(np.max(arrays["violation"])) if arrays["violation"].size else None,
        },
        "ee_rms_m": float(np.sqrt(np.mean(ee_err**2))) if ee_err.size else None,
        "ee_max_error_m": float(np.max(ee_err)) if ee_err.size else None,
        "max_tilt_rad": float(np.max(tilt(np.asarray(q)))) if len(q) else None,
        "base_height_range_m": [float(q[:, 2].min()), float(q[:, 2].max())] if len(q) else None,
        "distance_travelled_m": float(np.linalg.norm(q[-1, :2] - q[0, :2])) if len(q) else None,
        "torque_violations": int(torque_violations),
        "fell": bool(fell),
        "low_level": {
            "kp": low.kp,
            "kd": low.kd,
            "arm_gains": list(low.arm_gains) if low.arm_gains is not None else None,
            "rate_hz": low.rate,
        },
        "delay": config.delay,
        "sensor_noise": None if sensing.noise is None else vars(sensing.noise),
        "velocity_cutoff_hz": sensing.velocity_cutoff_hz,
        "mpc_rate_hz": config.mpc_rate,
        "plant_dt_s": config.plant.dt,
        "machine": machine_description(),
        "blasfeo": blasfeo_record(),
    }
    if plant is not None:
        summary["contact_violations"] = {k: int(np.sum(v)) for k, v in plant.violation_counts.items()}
        summary["contact_violations_counted_as"] = (
            "plant steps x feet: stance foot pulling / outside the friction cone; swing foot more than "
            "0.1 mm below the ground"
        )
    summary |= _contact_summary(gait, arrays)
    summary["tracking"] = command_tracking(arrays)
    return summary


def base_velocity_heading(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Base velocity (T, 3) in the heading frame: forward [m/s], left [m/s], yaw rate [rad/s], from
    configurations (T, nq) and velocities (T, nv) (base-frame twist, Pinocchio's free-flyer convention)."""
    q, v = np.atleast_2d(q), np.atleast_2d(v)
    out = np.empty((len(q), 3))
    for k, (qk, vk) in enumerate(zip(q, v, strict=True)):
        R = pin.Quaternion(qk[3:7]).normalized().toRotationMatrix()
        linear, angular = R @ vk[0:3], R @ vk[3:6]
        yaw = np.arctan2(R[1, 0], R[0, 0])
        c, s = np.cos(yaw), np.sin(yaw)
        out[k] = (c * linear[0] + s * linear[1], -s * linear[0] + c * linear[1], angular[2])
    return out


def command_tracking(arrays: Mapping[str, np.ndarray], settle: float = 1.0) -> list[dict]:
    """Commanded against achieved base velocity over each stretch of constant command.

    Args:
        arrays: The run's columns (``t``, ``q``, ``v``, ``base_velocity_cmd``, ``base_yaw_rate_cmd``).
        settle: Time [s] after each change of command left out of the averages.

    Returns:
        One dict per stretch: ``t_start``, ``t_end`` [s] (the averaged window), ``commanded`` and
        ``achieved`` ``[forward m/s, left m/s, yaw rate rad/s]`` (heading frame, signed, true state), and
        ``ratio`` (achieved / commanded per component, ``None`` where the command is 0).
    """
    t = np.asarray(arrays["t"], float)
    if t.size < 2 or not len(arrays.get("base_velocity_cmd", ())):
        return []
    linear = np.asarray(arrays["base_velocity_cmd"], float)[:, :2]
    cmd = np.column_stack([linear, np.asarray(arrays["base_yaw_rate_cmd"], float)])
    achieved = base_velocity_heading(arrays["q"], arrays["v"])
    change = np.flatnonzero(np.any(np.abs(np.diff(cmd, axis=0)) > 1e-12, axis=1)) + 1
    out = []
    for start, end in zip(np.r_[0, change], np.r_[change, t.size], strict=True):
        window = t[start:end] >= t[start] + settle
        if window.sum() < 2:
            continue
        c, a = cmd[start], achieved[start:end][window].mean(axis=0)
        out.append(
            {
                "t_start": float(t[start:end][window][0]),
                "t_end": float(t[start:end][window][-1]),
                "commanded": c.tolist(),
                "achieved": a.tolist(),
                "ratio": [float(ai / ci) if abs(ci) > 1e-9 else None for ai, ci in zip(a, c, strict=True)],
            }
        )
    return out


def _contact_summary(gait, arrays: dict) -> dict:
    """Swing-foot clearance and agreement of the MPC's first-stage contacts with the plant's schedule."""
    out = {"holds": int(np.sum(arrays["hold"])) if arrays["hold"].size else 0}
    if arrays["foot_height"].size:
        swing = ~np.asarray(arrays["contact"], bool)
        heights = arrays["foot_height"][swing]
        out["swing_foot_min_height_m"] = float(heights.min()) if heights.size else None
    if arrays["plan_contact"].size:
        fresh = np.asarray(arrays["success"], bool) & ~np.asarray(arrays["fallback"], bool)
        plant = gait.sample(arrays["solve_t"]).contact.T
        out["node0_contact_mismatches"] = int(np.sum(np.any(arrays["plan_contact"] != plant, axis=1) & fresh))
    return out
