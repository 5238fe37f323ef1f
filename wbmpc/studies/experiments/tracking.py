"""Experiment 1, ``arm_tracking``: trot at 0.2 m/s while the end effector reaches low and high."""

from __future__ import annotations

import numpy as np

from wbmpc.control.arm_task import ArmReference
from wbmpc.ocp.gait import make_gait
from wbmpc.studies.experiments.common import (
    GAIT_PERIOD,
    ExperimentResult,
    _base_loop,
    _commands,
    _common,
    _figure,
    _pick,
    _pitch,
    _run,
    _setup,
)


def arm_tracking(quick=None, progress=True, robot=None) -> ExperimentResult:
    """Whole-body adaptability: trot at 0.2 m/s while the end effector tracks a low/high reference.

    The reference (:class:`wbmpc.control.arm_task.ArmReference`) moves the gripper 15 cm down and up
    (5 cm fore-aft)
    with a 5 s period, ramped in over 1 s. Pure feed-forward torques (Kp = Kd = 0), no delay (paper).
    Reports the end-effector RMS error and how base height and pitch adapt.
    """
    quick, robot, nodes, mpc_config, solver = _setup(quick, robot, gait=make_gait("trot", GAIT_PERIOD))
    loop = _base_loop(
        duration=_pick(quick, full=10.0, quick=1.0),
        commands=_commands(
            base_velocity=(0.2, 0.0, 0.0), arm_reference=ArmReference(ramp=_pick(quick, full=1.0, quick=0.3))
        ),
    )
    result = _run(robot, nodes, mpc_config, loop, progress, solver=solver)
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
