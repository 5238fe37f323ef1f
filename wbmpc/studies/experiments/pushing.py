"""Experiment 4, ``box_pushing``: push a box against a wall with a force target while trotting in place."""

from __future__ import annotations

import numpy as np

from wbmpc.ocp.gait import make_gait
from wbmpc.sim.loop_config import PlantConfig
from wbmpc.sim.pybullet_plant import Box, Wall
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


def box_pushing(quick=None, progress=True, robot=None, force: float = 30.0) -> ExperimentResult:
    """Push a box against a wall with an end-effector force target while trotting in place.

    A 5 kg box stands on the ground with its near face at the gripper and its far face against a wall. The
    commanded force on the robot is ``(-force, 0, 0)`` (the box pushes back), ramped in over 0.5 s; the
    simulator measures the actual contact force on the gripper.
    """
    quick, robot, nodes, mpc_config, solver = _setup(quick, robot, gait=make_gait("trot", GAIT_PERIOD))
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

    loop = _base_loop(
        duration=_pick(quick, full=5.0, quick=1.0),
        plant=PlantConfig(kind="pybullet", scene=scene),
        commands=_commands(overrides=schedule),
    )
    result = _run(robot, nodes, mpc_config, loop, progress, solver=solver)
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
