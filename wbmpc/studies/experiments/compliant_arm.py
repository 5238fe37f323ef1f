"""Experiment 6, ``compliance``: zero arm targets, low arm gains: a push moves the arm, which yields."""

from __future__ import annotations

import numpy as np

from wbmpc.ocp.gait import make_gait
from wbmpc.sim.disturbances import Push
from wbmpc.sim.loop_config import LowLevelConfig
from wbmpc.studies.experiments.common import (
    GAIT_PERIOD,
    ExperimentResult,
    _base_loop,
    _common,
    _ee_velocity,
    _figure,
    _pick,
    _run,
    _setup,
)


def compliance(quick=None, progress=True, robot=None, push: float = 40.0) -> ExperimentResult:
    """Zero end-effector velocity and force targets, low arm gains: a sideways push on the gripper moves the
    arm, which yields and settles where it was pushed (the MPC re-plans from the measured arm).

    Reports the displacement during the push, the displacement kept afterwards and the settling time (the
    gripper slower than 2 cm/s for good).
    """
    quick, robot, nodes, mpc_config, solver = _setup(quick, robot, gait=make_gait("stand", GAIT_PERIOD))
    start, duration = _pick(quick, full=1.0, quick=0.4), 0.3
    loop = _base_loop(
        duration=_pick(quick, full=4.0, quick=1.1),
        disturbances=(Push(start, duration, (0.0, push, 0.0), target="ee"),),
        low_level=LowLevelConfig(arm_gains=(0.0, 0.5)),
    )
    result = _run(robot, nodes, mpc_config, loop, progress, solver=solver)
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
