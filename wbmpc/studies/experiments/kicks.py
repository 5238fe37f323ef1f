"""Experiment 2, ``disturbance_rejection``: a 0.8 m/s lateral base kick while trotting in place, at two
gait phases.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from wbmpc.model.robot import Robot
from wbmpc.ocp.gait import make_gait
from wbmpc.sim.closed_loop import ClosedLoopResult, machine_description
from wbmpc.sim.disturbances import Kick
from wbmpc.studies.experiments.common import (
    GAIT_PERIOD,
    ExperimentResult,
    _base_loop,
    _ee_velocity,
    _figure,
    _pick,
    _run,
    _setup,
    _solve_stats,
)


def disturbance_rejection(quick=None, progress=True, robot=None, magnitude: float = 0.8) -> ExperimentResult:
    """A lateral base-velocity kick while trotting in place, at two gait phases.

    Phases are fractions of the trot period after a lift-off of a diagonal pair (the trot is symmetric under
    a half-period shift): phase 0 hits at the lift-off (a whole swing ahead), phase 0.25 mid-swing. Reports
    the peak lateral base velocity, the lateral displacement, the recovery time (|v_y| < 0.1 m/s) and the rear
    calf torques against their limits.
    """
    quick, robot, nodes, mpc_config, solver = _setup(quick, robot, gait=make_gait("trot", GAIT_PERIOD))
    kick_time = _pick(quick, full=2.0, quick=0.4)  # lift-offs at multiples of 0.4 s
    runs, per_phase = {}, {}
    for phase in (0.0, 0.25):
        t_kick = kick_time + phase * GAIT_PERIOD
        loop = _base_loop(
            duration=t_kick + _pick(quick, full=2.5, quick=0.5),
            disturbances=(Kick(t_kick, (0.0, magnitude, 0.0)),),
        )
        result = _run(robot, nodes, mpc_config, loop, progress, solver=solver)
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
