"""Closed-loop simulation: MPC at 80 Hz, joint interpolation + PD at 500 Hz, a rigid-contact plant at 2 kHz.

This is the paper's benchmark setting: the plant is Pinocchio's forward dynamics with the scheduled feet in
rigid contact (:class:`wbmpc.plant.ContactPlant`), no physics engine. The simulated time waits for each
solve (no computation delay); the measured wall-clock solve times are logged.
"""

from __future__ import annotations

import platform
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from wbmpc.arm_task import ArmReference, heading_frame, velocity_command
from wbmpc.low_level import LowLevelController
from wbmpc.mpc import Commands, MPCSolution, WholeBodyMPC
from wbmpc.plant import ContactPlant, fallen
from wbmpc.time_grid import node_times


@dataclass
class ClosedLoopConfig:
    """Settings of a closed-loop run.

    Attributes:
        duration: Simulated time [s].
        mpc_rate: MPC update rate [Hz] (paper: 80).
        low_level_rate: Interpolation + PD rate [Hz] (paper: 500).
        plant_dt: Plant integration step [s]; must divide both control periods.
        plant: ``"rigid"`` (Pinocchio forward dynamics, scheduled feet in rigid contact: the paper's
            benchmark) or ``"pybullet"`` (a physics engine: contacts happen, feet can slip).
        kp, kd: Joint PD gains of the low level [N m/rad], [N m s/rad] (paper, simulation without delay: 0).
        base_velocity: Commanded base linear velocity [m/s], heading frame.
        base_yaw_rate: Commanded yaw rate [rad/s].
        arm_reference: End-effector position reference, or ``None`` for a constant velocity command.
        arm_kp: Position gain [1/s] of the arm reference feedback.
        arm_preview: One end-effector velocity per MPC stage from the reference's future (True), or the
            paper's single velocity held over the horizon (False).
        ee_velocity: Constant end-effector velocity command [m/s] used when there is no arm reference.
        ee_force: Commanded end-effector force [N], world.
        max_tilt: Roll/pitch [rad] beyond which the run counts as a fall.
    """

    duration: float = 10.0
    mpc_rate: float = 80.0
    low_level_rate: float = 500.0
    plant_dt: float = 0.0005
    plant: str = "rigid"
    kp: float = 0.0
    kd: float = 0.0
    base_velocity: tuple[float, float, float] = (0.2, 0.0, 0.0)
    base_yaw_rate: float = 0.0
    arm_reference: ArmReference | None = field(default_factory=ArmReference)
    arm_kp: float = 4.0
    arm_preview: bool = True
    ee_velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    ee_force: tuple[float, float, float] = (0.0, 0.0, 0.0)
    max_tilt: float = 1.0

    def steps(self) -> tuple[int, int, int]:
        """Total plant steps, plant steps per MPC update and per low-level update."""
        per_mpc = round(1.0 / (self.mpc_rate * self.plant_dt))
        per_low = round(1.0 / (self.low_level_rate * self.plant_dt))
        if (
            abs(per_mpc * self.plant_dt * self.mpc_rate - 1) > 1e-9
            or abs(per_low * self.plant_dt * self.low_level_rate - 1) > 1e-9
        ):
            raise ValueError(
                f"plant_dt={self.plant_dt} s must divide the MPC period 1/{self.mpc_rate} s and the "
                f"low-level period 1/{self.low_level_rate} s"
            )
        return round(self.duration / self.plant_dt), per_mpc, per_low


@dataclass
class ClosedLoopLog:
    """Time series of a run (low-level rate) and per-solve records (MPC rate)."""

    t: list = field(default_factory=list)
    q: list = field(default_factory=list)
    v: list = field(default_factory=list)
    tau: list = field(default_factory=list)
    tau_ff: list = field(default_factory=list)
    contact: list = field(default_factory=list)
    ee_position: list = field(default_factory=list)
    ee_reference: list = field(default_factory=list)
    solve_t: list = field(default_factory=list)
    solve_time: list = field(default_factory=list)
    iterations: list = field(default_factory=list)
    success: list = field(default_factory=list)
    fallback: list = field(default_factory=list)
    violation: list = field(default_factory=list)
    status: list = field(default_factory=list)
    ee_command: list = field(default_factory=list)
    timings: list = field(default_factory=list)
    plans: list = field(default_factory=list)

    def arrays(self) -> dict[str, np.ndarray]:
        """Every series as a numpy array (plans and per-solve timing dicts excluded)."""
        return {k: np.asarray(v) for k, v in self.__dict__.items() if k not in ("plans", "timings")}


@dataclass
class ClosedLoopResult:
    log: ClosedLoopLog
    summary: dict
    fell: bool


def run_closed_loop(
    mpc: WholeBodyMPC,
    config: ClosedLoopConfig | None = None,
    q0: np.ndarray | None = None,
    progress: bool = True,
    keep_plans: bool = False,
) -> ClosedLoopResult:
    """Simulate the MPC in closed loop on the rigid-contact plant.

    Args:
        mpc: The MPC (built once; its gait decides the scheduled contacts of the plant too).
        config: Run settings.
        q0: Initial configuration; the robot's nominal pose by default (feet on the ground).
        progress: Show a tqdm progress bar.
        keep_plans: Keep every MPC plan in the log (memory heavy; for replays of predictions).

    Returns:
        The log, a summary dict (see :func:`summarize`) and whether the robot fell.
    """
    config = config or ClosedLoopConfig()
    robot = mpc.robot
    model, data = robot.model, robot.model.createData()
    n_steps, per_mpc, per_low = config.steps()
    plant = make_plant(robot, config)
    q0 = robot.q_nominal if q0 is None else np.asarray(q0, dtype=float)
    state = plant.reset(q0, np.zeros(model.nv))
    low = LowLevelController(config.kp, config.kd, torque_limits=robot.joint_torque_limits)
    ee_id = robot.frame_id(robot.ee_frame) if robot.has_arm else None
    log = ClosedLoopLog()
    base_cmd = np.asarray(config.base_velocity, dtype=float)
    mpc.reset()
    arm_reference = config.arm_reference
    if ee_id is not None and arm_reference is not None and arm_reference.center is None:
        pin.framesForwardKinematics(model, data, q0)
        arm_reference = arm_reference.centered_at(q0, data.oMf[ee_id].translation)
    fell = False
    tau = np.zeros(robot.nj)
    ee_ref = np.full(3, np.nan)

    bar = _progress(n_steps // per_mpc, progress)
    for step in range(n_steps):
        t = step * config.plant_dt
        q, v = state.q, state.v
        contact = mpc.config.gait.contact(t)
        if step % per_mpc == 0:
            pin.framesForwardKinematics(model, data, q)
            commands = Commands(
                base_linear_velocity=base_cmd,
                base_angular_velocity=np.array([0, 0, config.base_yaw_rate]),
                ee_force=np.asarray(config.ee_force, dtype=float),
            )
            if ee_id is not None:
                ee_pos = data.oMf[ee_id].translation.copy()
                if arm_reference is not None:
                    R_heading, _ = heading_frame(q)
                    stage_times = node_times(mpc.time_steps(), t)[:-1] if config.arm_preview else None
                    ee_cmd, ee_ref = velocity_command(
                        arm_reference,
                        q,
                        ee_pos,
                        t,
                        R_heading @ base_cmd,
                        kp=config.arm_kp,
                        node_times=stage_times,
                    )
                else:
                    ee_cmd = np.asarray(config.ee_velocity, dtype=float)
                commands.ee_velocity = ee_cmd
                log.ee_command.append(ee_cmd if ee_cmd.ndim == 1 else ee_cmd[:, 0])
            plan = mpc.solve(q, v, t, commands)
            _log_solve(log, plan, keep_plans)
            low.update(plan)
            if bar is not None:
                bar.update(1)
                bar.set_postfix(iters=plan.iterations, ms=f"{1e3 * plan.solve_time:.0f}")
            if fallen(state, max_tilt=config.max_tilt):
                fell = True
                break
        if step % per_low == 0:
            tau = low.torque(t, q, v)  # clipped to the limits; exceedances counted by the controller
            log.t.append(t)
            log.q.append(q.copy())
            log.v.append(v.copy())
            log.tau.append(tau.copy())
            log.tau_ff.append(low.last_reference.tau_ff)
            log.contact.append(contact)
            if ee_id is not None:  # only the end-effector frame is needed here
                pin.forwardKinematics(model, data, q)
                log.ee_position.append(pin.updateFramePlacement(model, data, ee_id).translation.copy())
            else:
                log.ee_position.append(np.full(3, np.nan))
            log.ee_reference.append(ee_ref.copy())
        try:
            state = plant.step(tau, contact)
        except FloatingPointError:
            fell = True
            break
    if bar is not None:
        bar.close()
    summary = summarize(mpc, log, config, fell, low.violations, plant)
    if hasattr(plant, "close"):
        plant.close()
    return ClosedLoopResult(log=log, summary=summary, fell=fell)


def make_plant(robot, config: ClosedLoopConfig):
    """The plant named by ``config.plant``, stepping at ``config.plant_dt``."""
    if config.plant == "rigid":
        return ContactPlant(robot.model, robot.foot_frames, dt=config.plant_dt, foot_radius=robot.foot_radius)
    if config.plant == "pybullet":
        from wbmpc.pybullet_sim import PyBulletPlant

        return PyBulletPlant(robot, dt=config.plant_dt)
    raise ValueError(f"unknown plant {config.plant!r}; available: 'rigid', 'pybullet'")


def _log_solve(log: ClosedLoopLog, plan: MPCSolution, keep_plans: bool) -> None:
    log.solve_t.append(plan.t)
    log.solve_time.append(plan.solve_time)
    log.iterations.append(plan.iterations)
    log.success.append(plan.success)
    log.fallback.append(plan.fallback)
    log.violation.append(plan.constraint_violation)
    log.status.append(plan.status)
    log.timings.append(plan.timings)
    if keep_plans:
        log.plans.append(plan)


def _progress(total: int, enabled: bool):
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, desc="MPC", unit="solve")


def tilt(q: np.ndarray) -> float:
    """Angle [rad] between the base z axis and the world z axis (roll/pitch combined)."""
    qx, qy = q[3], q[4]
    return float(np.arccos(np.clip(1 - 2 * (qx**2 + qy**2), -1.0, 1.0)))


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


def summarize(
    mpc: WholeBodyMPC,
    log: ClosedLoopLog,
    config: ClosedLoopConfig,
    fell: bool,
    torque_violations: int,
    plant: ContactPlant | None = None,
) -> dict:
    """Key numbers of a run: solve-time statistics (in-process), convergence, tracking, safety."""
    arrays = log.arrays()
    solve_ms = 1e3 * arrays["solve_time"]
    warm = solve_ms[1:] if solve_ms.size > 1 else solve_ms
    iters = arrays["iterations"][1:] if arrays["iterations"].size > 1 else arrays["iterations"]
    ee_err = (
        np.linalg.norm(arrays["ee_position"] - arrays["ee_reference"], axis=1) if len(log.t) else np.array([])
    )
    ee_err = ee_err[np.isfinite(ee_err)]
    q = arrays["q"]
    summary = {
        "robot": mpc.robot.name,
        "gait": mpc.config.gait.name,
        "solver": mpc.config.solver,
        "compiled": mpc.config.compiled,
        "plant": config.plant,
        "nodes": mpc.n_nodes,
        "duration_s": float(log.t[-1]) if log.t else 0.0,
        "requested_duration_s": config.duration,
        "base_velocity_cmd": list(config.base_velocity),
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
        "max_tilt_rad": float(max(tilt(qi) for qi in q)) if len(q) else None,
        "base_height_range_m": [float(q[:, 2].min()), float(q[:, 2].max())] if len(q) else None,
        "distance_travelled_m": float(np.linalg.norm(q[-1, :2] - q[0, :2])) if len(q) else None,
        "torque_violations": int(torque_violations),
        "fell": bool(fell),
        "low_level": {"kp": config.kp, "kd": config.kd, "rate_hz": config.low_level_rate},
        "mpc_rate_hz": config.mpc_rate,
        "plant_dt_s": config.plant_dt,
        "machine": machine_description(),
    }
    if plant is not None:
        summary["contact_violations"] = {k: int(np.sum(v)) for k, v in plant.violation_counts.items()}
    return summary
