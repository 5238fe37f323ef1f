"""Experiment 3, ``pulling_load``: drag a tethered load with a commanded force: stance, walking, max load."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from wbmpc.model.robot import Robot
from wbmpc.ocp.gait import make_gait
from wbmpc.sim.closed_loop import ClosedLoopResult, machine_description
from wbmpc.sim.loop_config import PlantConfig
from wbmpc.sim.pybullet_plant import Payload
from wbmpc.studies.experiments.common import (
    GAIT_PERIOD,
    ExperimentResult,
    _base_loop,
    _commands,
    _ee_start,
    _figure,
    _pick,
    _run,
    _setup,
    _solve_stats,
)


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
    robot,
    nodes,
    mpc_config,
    quick,
    mass,
    walking: bool,
    progress,
    ground_friction=0.8,
    duration=None,
    *,
    solver,
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
        duration=duration,
        plant=PlantConfig(kind="pybullet", scene=scene, ground_friction=ground_friction),
        commands=_commands(overrides=ramp, **kwargs),
    )
    result = _run(robot, nodes, replace(mpc_config, gait=gait), loop, progress, q0=q0, solver=solver)
    return result, np.array(ee_force)


def pulling_load(quick=None, progress=True, robot=None, masses=None) -> ExperimentResult:
    """Pull a tethered load (sliding sphere, friction 0.5 x ground 0.8) with a commanded end-effector force.

    In stance the arm pulls back at 5 cm/s; walking, the robot trots backwards at 0.1 m/s. The commanded
    force is the load's sliding friction along the rope. Success: no fall and the load follows (moves at
    least half the commanded displacement). The sweep over ``masses`` (walking) finds the largest load that
    succeeds (the paper: 14 kg in simulation).
    """
    quick, robot, nodes, mpc_config, solver = _setup(quick, robot)
    masses = (
        masses if masses is not None else _pick(quick, full=(12.0, 14.0, 16.0, 18.0, 20.0, 25.0), quick=())
    )
    runs, cases = {}, {}
    for label, walking, mass in [("stance_10kg", False, 10.0), ("walking_10kg", True, 10.0)] + [
        (f"walking_{m:g}kg", True, m) for m in masses
    ]:
        result, force = _pull_run(robot, nodes, mpc_config, quick, mass, walking, progress, solver=solver)
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
