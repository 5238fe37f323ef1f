"""Experiment 5, ``wiping``: wipe a vertical board with a normal-force target while standing."""

from __future__ import annotations

import numpy as np

from wbmpc.control.arm_task import ArmReference
from wbmpc.ocp.gait import make_gait
from wbmpc.sim.loop_config import PlantConfig
from wbmpc.sim.pybullet_plant import Wall
from wbmpc.studies.experiments.common import (
    GAIT_PERIOD,
    ExperimentResult,
    _base_loop,
    _commands,
    _common,
    _ee_start,
    _figure,
    _pick,
    _robot_front,
    _run,
    _setup,
)


def wiping(quick=None, progress=True, robot=None, normal_force: float = 20.0) -> ExperimentResult:
    """Wipe a vertical board while standing: the gripper slides 10 cm left and right along the board with a
    normal-force target; the simulator measures the normal force actually applied."""
    quick, robot, nodes, mpc_config, solver = _setup(quick, robot, gait=make_gait("stand", GAIT_PERIOD))
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
        plant=PlantConfig(kind="pybullet", scene={"board": board}),
        commands=_commands(arm_reference=reference, overrides=schedule),
    )
    result = _run(robot, nodes, mpc_config, loop, progress, solver=solver)
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
