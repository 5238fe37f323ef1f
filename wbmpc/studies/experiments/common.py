"""What the experiments share: the result type, the MPC set-up and cache, the loop's defaults, the
summary fields every experiment reports and small kinematic and figure helpers.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from wbmpc.control.mpc import MPCConfig, SolverSettings, WholeBodyMPC
from wbmpc.model.robot import Robot, load_b1_z1
from wbmpc.ocp import OCPSettings
from wbmpc.quick import quick_mode
from wbmpc.sim.closed_loop import ClosedLoopConfig, ClosedLoopResult, run_closed_loop
from wbmpc.sim.loop_config import CommandSchedule, PlantConfig

REPO_ROOT = Path(__file__).resolve().parents[3]
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
    config = MPCConfig(**mpc_kwargs)
    return quick, robot, nodes, config, SolverSettings(compiled=not quick)


_MPC_CACHE: dict[tuple, WholeBodyMPC] = {}


def _mpc(robot: Robot, nodes: int, config: MPCConfig, solver: SolverSettings) -> WholeBodyMPC:
    """An MPC for ``robot`` with ``nodes`` nodes, ``solver`` and ``config``, re-used between runs when only
    the runtime configuration differs (gait, time steps, weights: building the problem and its solvers takes
    seconds)."""
    key = (id(robot), nodes, solver)
    mpc = _MPC_CACHE.get(key)
    if mpc is None or mpc.robot is not robot:
        mpc = _MPC_CACHE[key] = WholeBodyMPC(robot, OCPSettings(n_nodes=nodes), config, solver)
    mpc.config = config
    mpc.reset()
    return mpc


@contextlib.contextmanager
def mpc_in_use(mpc: WholeBodyMPC, nodes: int, solver: SolverSettings):
    """Make the experiments run ``mpc`` (any :class:`WholeBodyMPC`, a subclass included) wherever they would
    build their own MPC for ``mpc.robot`` with ``nodes`` nodes and ``solver``, for the ``with`` block; the
    experiments' own MPC of that key (if any) is back afterwards. Used by studies that compare solvers in
    the unchanged experiments (:mod:`wbmpc.studies.newton_steps`)."""
    key = (id(mpc.robot), nodes, solver)
    saved = _MPC_CACHE.get(key)
    _MPC_CACHE[key] = mpc
    try:
        yield mpc
    finally:
        if saved is None:
            _MPC_CACHE.pop(key, None)
        else:
            _MPC_CACHE[key] = saved


def _run(
    robot, nodes, mpc_config, loop: ClosedLoopConfig, progress: bool, q0=None, *, solver: SolverSettings
) -> ClosedLoopResult:
    mpc = _mpc(robot, nodes, mpc_config, solver)
    mpc.verbose = progress
    return run_closed_loop(mpc, loop, q0=q0, progress=progress)


def _commands(**fields) -> CommandSchedule:
    """The experiments' commands: no arm reference unless given, the hand's world velocity (pulling,
    pushing, wiping: the paper's command), standing still unless a base velocity is given."""
    defaults = {"arm_reference": None, "ee_velocity_frame": "world", "base_velocity": (0.0, 0.0, 0.0)}
    return CommandSchedule(**(defaults | fields))


def _base_loop(
    commands: CommandSchedule | None = None, plant: PlantConfig | None = None, **loop
) -> ClosedLoopConfig:
    """PyBullet at 2 kHz, MPC 80 Hz, low level 500 Hz, with :func:`_commands` unless given; ``loop``: other
    :class:`~wbmpc.sim.loop_config.ClosedLoopConfig` fields."""
    return ClosedLoopConfig(
        commands=commands or _commands(), plant=plant or PlantConfig(kind="pybullet"), **loop
    )


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
