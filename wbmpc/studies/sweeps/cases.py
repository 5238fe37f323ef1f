"""Case functions of the sweeps (each runs on a worker) and the studies: grids with their case function."""

from __future__ import annotations

import os
import time

from wbmpc.studies.sweeps.engine import ID, THREAD_ENV, grid


# ------------------------------------------------------------------------------------------ case functions
def noop_case(case: dict) -> dict:
    """Does nothing: times the scheduling overhead of a sweep."""
    return {}


def demo_case(case: dict) -> dict:
    """A trivial case for tests and demonstrations.

    Parameters read: ``x`` (number, result ``y = 2 x``), ``action`` (``"raise"``: a ValueError, ``"exit"``:
    the process exits (``os._exit(1)``), ``"segfault"``: a null-pointer read, ``"fall"``: ``fell=True``),
    ``sleep`` [s].
    """
    time.sleep(case.get("sleep", 0.0))
    action = case.get("action")
    if action == "raise":
        raise ValueError(f"case {case[ID]} raised on purpose")
    if action == "exit":
        os._exit(1)
    if action == "segfault":
        import ctypes

        ctypes.string_at(0)
    return {
        "y": 2 * case.get("x", 0),
        "fell": action == "fall",
        "pid": os.getpid(),
        **{k.lower(): os.environ.get(k) for k in THREAD_ENV},
    }


def build_case(case: dict) -> dict:
    """Build (or load) the compiled NLP of a small B1 problem in ``case["cache_dir"]`` (cache sharing tests).

    Results: ``rebuilt`` (this call compiled the library), ``key``, ``build_s``.
    """
    from wbmpc.model.robot import load_b1
    from wbmpc.ocp import OCP, OCPSettings
    from wbmpc.solver import codegen

    ocp = OCP(load_b1(), OCPSettings(n_nodes=case.get("nodes", 3), n_tau_nodes=1))
    built = codegen.build(ocp, ("-O0",), directory=case["cache_dir"], progress=False)
    return {"rebuilt": built.rebuilt, "key": built.key, "build_s": built.build_s}


def warm_build_cache(cases: list[dict]) -> None:
    """Warm-up of :func:`build_case`: build each distinct library of the cases once."""
    for params in {(c["cache_dir"], c.get("nodes", 3)) for c in cases}:
        build_case({ID: "warmup", "cache_dir": params[0], "nodes": params[1]})


_MPCS: dict = {}  # per worker process: building the problem and loading the solver take seconds


def _closed_loop_mpc(nodes: int, compiled: bool):
    from wbmpc.control.mpc import MPCConfig, SolverSettings, WholeBodyMPC
    from wbmpc.model.robot import load_b1_z1
    from wbmpc.ocp import OCPSettings

    key = (nodes, compiled)
    if key not in _MPCS:
        solver = SolverSettings(compiled=compiled, threads=1)  # one Dask worker per core
        _MPCS[key] = WholeBodyMPC(load_b1_z1(), OCPSettings(n_nodes=nodes), MPCConfig(), solver)
        _MPCS[key].verbose = False
    return _MPCS[key]


def closed_loop_case(case: dict) -> dict:
    """A short closed-loop run on the rigid plant (the benchmark case of the sweep engine).

    Parameters read (defaults): ``gait`` ("trot"), ``speed`` (0.0 m/s forward), ``yaw_rate`` (0.0 rad/s),
    ``duration`` (0.5 s), ``nodes`` (15), ``compiled`` (True: the cached Fatrop library).
    """
    from dataclasses import replace

    from wbmpc.ocp.gait import make_gait
    from wbmpc.sim.closed_loop import ClosedLoopConfig, run_closed_loop
    from wbmpc.sim.loop_config import CommandSchedule, PlantConfig

    mpc = _closed_loop_mpc(case.get("nodes", 15), case.get("compiled", True))
    mpc.config = replace(mpc.config, gait=make_gait(case.get("gait", "trot"), 0.8))
    mpc.reset()
    config = ClosedLoopConfig(
        duration=case.get("duration", 0.5),
        plant=PlantConfig(kind="rigid"),
        commands=CommandSchedule(
            arm_reference=None,
            base_velocity=(case.get("speed", 0.0), 0.0, 0.0),
            base_yaw_rate=case.get("yaw_rate", 0.0),
        ),
    )
    result = run_closed_loop(mpc, config, progress=False)
    s = result.summary
    return {
        "fell": bool(result.fell),
        "max_tilt_rad": s["max_tilt_rad"],
        "solve_ms_mean": s["solve_ms"]["mean"],
        "iterations_mean": s["iterations_mean"],
        "converged_fraction": s["converged_fraction"],
        "sim_duration_s": s["duration_s"],
    }


def warm_closed_loop_cache(cases: list[dict]) -> None:
    """Warm-up of :func:`closed_loop_case`: build the compiled library of each horizon once."""
    from wbmpc.solver import codegen

    for nodes in sorted({c.get("nodes", 15) for c in cases if c.get("compiled", True)}):
        mpc = _closed_loop_mpc(nodes, True)
        mpc.compiled_nlp = codegen.build(mpc.ocp, mpc.solver_settings.compile_flags, progress=False)


# ----------------------------------------------- PyBullet studies: robustness, payload, nodes, time steps
# The experiments' settings (wbmpc.studies.experiments): PyBullet at 2 kHz, MPC at 80 Hz, compiled Fatrop with
# 15 nodes (quick: in-process, 10 nodes), 500 Hz interpolation, pure feed-forward torques, ground truth.
_ROBOT: dict = {}  # per worker process: the B1 + Z1 model (the experiments' MPC cache is keyed by it)
ROBUSTNESS_MAGNITUDES = tuple(round(0.1 * i, 1) for i in range(11))  # 0 to 1.0 m/s
ROBUSTNESS_PHASES = tuple(i / 8 for i in range(8))  # fractions of the trot period after a lift-off
DIRECTIONS = {"lateral": (0.0, 1.0, 0.0), "forward": (1.0, 0.0, 0.0)}
# Sensor noise of the seeded cases: encoders, a state estimator's base errors (std per channel).
NOISE = {
    "joint_position": 1e-3,
    "joint_velocity": 0.05,
    "base_position": 2e-3,
    "base_orientation": 2e-3,
    "base_velocity": 0.02,
}


def use_robot(robot) -> None:
    """Make this process's PyBullet cases use ``robot`` (a :class:`~wbmpc.model.robot.Robot`) instead of
    loading their own B1 + Z1 (so an MPC put in the experiments' cache for it is the one they run)."""
    _ROBOT["robot"] = robot


def _experiment_setup(case: dict, **mpc_kwargs):
    """(the experiments' helpers :mod:`wbmpc.studies.experiments.common`, robot, nodes, MPC config, solver
    settings) for a
    PyBullet case (``quick``, ``nodes``, ``compiled`` override the experiments' defaults: compiled with 15
    nodes, quick in-process with 10)."""
    from dataclasses import replace

    from wbmpc.model.robot import load_b1_z1
    from wbmpc.studies.experiments import common as ex

    if "robot" not in _ROBOT:
        _ROBOT["robot"] = load_b1_z1()
    quick, robot, nodes, config, solver = ex._setup(
        bool(case.get("quick", False)), _ROBOT["robot"], **mpc_kwargs
    )
    nodes = int(case.get("nodes", nodes))
    if "compiled" in case:
        solver = replace(solver, compiled=bool(case["compiled"]))
    solver = replace(solver, threads=1)  # one Dask worker per core
    # MPC options a case may switch (comparisons)
    for name in ("kick_recovery", "kick_recovery_phase", "kick_recovery_hold", "kick_ee_release"):
        if name in case and hasattr(config, name):
            config = replace(config, **{name: case[name]})
    return ex, robot, nodes, config, solver


def _sensor(case: dict):
    """Sensor noise of a case: none for ``seed`` None or negative, else :data:`NOISE` with that seed."""
    from wbmpc.sim.sensing import SensorNoise

    seed = case.get("seed")
    if seed is None or seed < 0:
        return None
    return SensorNoise(**NOISE, seed=int(seed))


def _delay(case: dict):
    delay = case.get("delay", 0.0)
    return "off" if delay in (None, 0, 0.0, "off") else delay


def _solver_results(result) -> dict:
    s = result.summary
    diagnostics = s.get("diagnostics") or {}
    return {
        "converged_fraction": s["converged_fraction"],
        "fallbacks": s["fallbacks"],
        "iterations_mean": s["iterations_mean"],
        "iterations_max": s["iterations_max"],
        "solve_ms_median": s["solve_ms"]["median"],
        "solve_ms_p95": s["solve_ms"]["p95"],
        "failure_reasons": diagnostics.get("failure_reasons") or {},
        "sim_duration_s": s["duration_s"],
    }


def robustness_case(case: dict) -> dict:
    """A base kick while trotting in place in PyBullet (as ``experiments.robustness_sweep``).

    Parameters read (defaults): ``magnitude`` [m/s] of the velocity kick (a
    :class:`~wbmpc.sim.disturbances.Kick`), ``direction`` ("lateral": world +y, "forward": +x), ``phase``
    (fraction of the 0.8 s trot period after the FR/RL pair's lift-off at ``lift_off`` [s]; 0.5: the FL/RR
    pair's), ``lift_off`` (1.2: the first FR/RL lift-off after 1.5 periods from the standing start; the same
    pair lifts off every 0.8 s, e.g. 2.0 as in experiment 2),
    ``delay`` (0: off, else seconds of fixed computation delay), ``seed`` (None: ground truth, else
    :data:`NOISE` with that seed, and the 50 Hz joint-velocity filter), ``quick`` (False: compiled solver;
    True: in-process), ``nodes`` (15), ``after`` [s] simulated after the kick (full 2.0, quick 0.5),
    ``kick_recovery``, ``kick_recovery_phase``, ``kick_recovery_hold``, ``kick_ee_release`` (the MPC's
    defaults; None switches the abort or the end-effector release off).

    Results: ``fell``, ``max_tilt_rad``, peak base speed along the kick, ``recovery_time_s`` (speed along the
    kick below 0.1 m/s for good, ``None`` if never), lateral/forward displacement, peak calf torque over its
    limit after the kick (all four calves, applied torques, and the plan's first-node torques), solver
    numbers, and the MPC's swing aborts.
    """
    import numpy as np
    import pinocchio as pin

    from wbmpc.sim.disturbances import Kick
    from wbmpc.sim.loop_config import SensingConfig

    # 15 nodes in quick mode too (in-process): a 10-node horizon (0.37 s) falls short of the swing it aborts.
    ex, robot, nodes, config, solver = _experiment_setup({"nodes": 15, **case}, gait=_trot())
    quick = bool(case.get("quick", False))
    magnitude = float(case.get("magnitude", 0.8))
    direction = np.asarray(DIRECTIONS[case.get("direction", "lateral")])
    t0 = float(case.get("lift_off", 1.2))  # an FR/RL lift-off (every 0.8 s from 1.2 s)
    if abs((t0 - 1.2) / ex.GAIT_PERIOD - round((t0 - 1.2) / ex.GAIT_PERIOD)) > 1e-9 or t0 < 1.2 - 1e-9:
        raise ValueError(f"lift_off = {t0} s is not an FR/RL lift-off (1.2 s + k 0.8 s)")
    t_kick = t0 + float(case.get("phase", 0.0)) * ex.GAIT_PERIOD
    after = float(case.get("after", 0.5 if quick else 2.0))
    noise = _sensor(case)
    loop = ex._base_loop(
        duration=t_kick + after,
        disturbances=(Kick(t_kick, tuple(magnitude * direction)),) if magnitude > 0 else (),
        delay=_delay(case),
        sensing=SensingConfig(noise=noise, velocity_cutoff_hz=50.0 if noise is not None else None),
    )
    mpc = ex._mpc(robot, nodes, config, solver)
    mpc.verbose = False
    aborts_before = mpc.stats.get("swing_aborts", 0)
    result = ex.run_closed_loop(mpc, loop, progress=False)
    a = result.log.arrays()
    t = a["t"]
    v_world = np.array(
        [pin.Quaternion(q[3:7]).toRotationMatrix() @ v[:3] for q, v in zip(a["q"], a["v"], strict=True)]
    )
    along = v_world @ direction
    after_kick = t >= t_kick
    calves = [i for i, n in enumerate(robot.joint_names) if "calf" in n]
    limits = robot.joint_torque_limits[calves]
    slow = np.abs(along) < 0.1
    recovery = None
    if after_kick.any() and not result.fell:
        # the first time after the kick from which the speed along the kick stays below 0.1 m/s
        fast = np.nonzero(after_kick & ~slow)[0]
        last_fast = fast[-1] if fast.size else np.nonzero(after_kick)[0][0] - 1
        if last_fast + 1 < len(t):
            recovery = float(t[last_fast + 1] - t_kick)
    solve_t = np.asarray(a["solve_t"])
    plan_tau = np.asarray(a["plan_tau"])
    planned = plan_tau[solve_t >= t_kick][:, calves] if plan_tau.size else np.zeros((0, len(calves)))
    k0 = np.nonzero(after_kick)[0][0] if after_kick.any() else len(t)
    return {
        "fell": bool(result.fell),
        "max_tilt_rad": result.summary["max_tilt_rad"],
        "peak_speed_along_kick": float(np.max(np.abs(along[after_kick]))) if after_kick.any() else None,
        "recovery_time_s": recovery,
        "displacement_along_kick_m": float((a["q"][-1, :3] - a["q"][k0 - 1 if k0 else 0, :3]) @ direction),
        "calf_torque_ratio": float(np.max(np.abs(a["tau"][after_kick][:, calves]) / limits))
        if after_kick.any()
        else None,
        "calf_torque_ratio_plan": float(np.max(np.abs(planned) / limits)) if planned.size else None,
        "swing_aborts": int(mpc.stats.get("swing_aborts", 0) - aborts_before),
        "t_kick": t_kick,
        **_solver_results(result),
    }


def _trot():
    from wbmpc.ocp.gait import make_gait
    from wbmpc.studies.experiments.common import GAIT_PERIOD

    return make_gait("trot", GAIT_PERIOD)


def warm_experiment_cache(cases: list[dict]) -> None:
    """Warm-up of the PyBullet studies: build (or load) the compiled library of each horizon once."""
    from wbmpc.solver import codegen

    for nodes in sorted({int(_experiment_setup(c)[2]) for c in cases if _experiment_setup(c)[4].compiled}):
        _, robot, _, _, solver = _experiment_setup({"nodes": nodes})
        from wbmpc.ocp import OCP, OCPSettings

        codegen.build(OCP(robot, OCPSettings(n_nodes=nodes)), solver.compile_flags, progress=False)


def _robustness_study(quick: bool) -> list[dict]:
    if quick:  # the lift-off kick and a mid-swing one, both directions at 0.8 m/s, no delay, no noise
        return grid(
            magnitude=[0.8], direction=["lateral", "forward"], phase=[0.0, 0.25], delay=[0.0], seed=[None],
            quick=[True],
        )  # fmt: skip
    return grid(
        magnitude=list(ROBUSTNESS_MAGNITUDES),
        direction=list(DIRECTIONS),
        phase=list(ROBUSTNESS_PHASES),
        delay=[0.0, 0.0125],
        seed=[0, 1, 2],
    )


def payload_case(case: dict) -> dict:
    """Pull a tethered sliding load (``experiments.pulling_load``): ``mass`` [kg], ``walking`` (trot
    backwards at 0.1 m/s; False: stand, the arm pulls back at 5 cm/s), ``quick``. Success: no fall and the
    load moves at least half the commanded displacement."""
    from wbmpc.studies.experiments.pulling import _pull_report, _pull_run

    _, robot, nodes, config, solver = _experiment_setup(case)
    quick = bool(case.get("quick", False))
    mass = float(case.get("mass", 10.0))
    walking = bool(case.get("walking", True))
    result, force = _pull_run(robot, nodes, config, quick, mass, walking, progress=False, solver=solver)
    report = _pull_report(result, walking, mass, force)
    report.pop("mass_kg", None)
    report.pop("walking", None)
    return {
        **report,
        "commanded_force_n": [float(f) for f in report["commanded_force_n"]],
        **_solver_results(result),
    }


def _payload_study(quick: bool) -> list[dict]:
    if quick:
        return grid(mass=[10.0], walking=[False, True], quick=[True])
    return grid(mass=[float(m) for m in range(10, 32, 2)], walking=[False, True])


def nodes_case(case: dict) -> dict:
    """Arm tracking while trotting at 0.2 m/s (``experiments.arm_tracking``) with ``nodes`` nodes, the same
    10-100 ms geometric steps: solve time and tracking. ``duration`` [s] (full 4.0, quick 0.6), ``quick``."""
    from wbmpc.control.arm_task import ArmReference

    ex, robot, nodes, config, solver = _experiment_setup(case, gait=_trot())
    quick = bool(case.get("quick", False))
    loop = ex._base_loop(
        duration=float(case.get("duration", 0.6 if quick else 4.0)),
        commands=ex._commands(
            base_velocity=(0.2, 0.0, 0.0), arm_reference=ArmReference(ramp=0.3 if quick else 1.0)
        ),
    )
    mpc = ex._mpc(robot, nodes, config, solver)
    mpc.verbose = False
    result = ex.run_closed_loop(mpc, loop, progress=False)
    s = result.summary
    return {
        "fell": bool(result.fell),
        "max_tilt_rad": s["max_tilt_rad"],
        "ee_rms_cm": None if s["ee_rms_m"] is None else 100 * s["ee_rms_m"],
        "ee_max_error_cm": None if s["ee_max_error_m"] is None else 100 * s["ee_max_error_m"],
        "speed_m_per_s": s["distance_travelled_m"] / max(s["duration_s"], 1e-9),
        "solve_ms_mean": s["solve_ms"]["mean"],
        "horizon_s": float(sum(mpc.time_steps())),
        **_solver_results(result),
    }


def _nodes_study(quick: bool) -> list[dict]:
    if quick:
        return grid(nodes=[5, 8], quick=[True])
    return grid(nodes=[5, 10, 15, 20, 25, 30])


def time_steps_case(case: dict) -> dict:
    """Base drift trotting in place with computation delay (``experiments.time_steps_drift``): ``grid``
    ("adaptive": geometric 10-100 ms, "uniform": the same horizon in equal steps, 40 ms with the default 15
    nodes; quick: 10 nodes), ``delay`` [s]
    (0: off), ``seed`` (sensor noise, None: ground truth), Kd = 5, 50 Hz velocity filter; ``duration``
    (full 10 s, quick 0.6 s)."""
    from dataclasses import replace

    import numpy as np

    from wbmpc.ocp.time_grid import geometric_time_steps
    from wbmpc.sim.loop_config import LowLevelConfig, SensingConfig

    ex, robot, _, config, solver = _experiment_setup(case, gait=_trot())
    quick = bool(case.get("quick", False))
    nodes = int(case.get("nodes", 10 if quick else 15))
    uniform = float(sum(geometric_time_steps(nodes, 0.01, 0.1))) / (nodes - 1)  # same horizon (N = 15: 40 ms)
    dt_min, dt_max = {"adaptive": (0.01, 0.1), "uniform": (uniform, uniform)}[case.get("grid", "adaptive")]
    config = replace(config, dt_min=dt_min, dt_max=dt_max)
    loop = ex._base_loop(
        duration=float(case.get("duration", 0.6 if quick else 10.0)),
        delay=_delay(case),
        low_level=LowLevelConfig(kd=5.0),
        sensing=SensingConfig(velocity_cutoff_hz=50.0, noise=_sensor(case)),
    )
    mpc = ex._mpc(robot, nodes, config, solver)
    mpc.verbose = False
    result = ex.run_closed_loop(mpc, loop, progress=False)
    q = result.log.arrays()["q"]
    d = result.summary["duration_s"] or 1.0
    return {
        "fell": bool(result.fell),
        "drift_cm_per_s": float(100 * np.linalg.norm(q[-1, :2] - q[0, :2]) / d),
        "drift_x_cm": float(100 * (q[-1, 0] - q[0, 0])),
        "drift_y_cm": float(100 * (q[-1, 1] - q[0, 1])),
        "max_tilt_rad": result.summary["max_tilt_rad"],
        "horizon_s": float(sum(mpc.time_steps())),
        **_solver_results(result),
    }


def _time_steps_study(quick: bool) -> list[dict]:
    if quick:
        return grid(grid=["adaptive", "uniform"], delay=[0.0125], seed=[0], quick=[True])
    return grid(grid=["adaptive", "uniform"], delay=[0.0, 0.0125, 0.025, 0.05], seed=[0, 1, 2])


# --------------------------------------------------------------------------------------------------- CLI
def _closed_loop_study(quick: bool) -> list[dict]:
    if quick:
        return grid(speed=[0.0, 0.2], duration=[0.5])
    return grid(speed=[0.0, 0.1, 0.2, 0.3], yaw_rate=[0.0, 0.2], duration=[2.0])


def _demo_study(quick: bool) -> list[dict]:
    return grid(x=list(range(4 if quick else 20)), sleep=[0.1])


# name -> (cases(quick), case function, warm-up)
STUDIES = {
    "demo": (_demo_study, demo_case, None),
    "closed_loop": (_closed_loop_study, closed_loop_case, warm_closed_loop_cache),
    "robustness": (_robustness_study, robustness_case, warm_experiment_cache),
    "payload": (_payload_study, payload_case, warm_experiment_cache),
    "nodes": (_nodes_study, nodes_case, warm_experiment_cache),
    "time_steps": (_time_steps_study, time_steps_case, warm_experiment_cache),
}
