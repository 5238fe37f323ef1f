"""Closed-loop simulation: MPC at 80 Hz, joint interpolation + PD at 500 Hz, a plant at 1-2 kHz.

Two plants: Pinocchio's forward dynamics with the scheduled feet in rigid contact
(:class:`wbmpc.sim.plant.ContactPlant`, the paper's benchmark setting) or PyBullet
(:class:`wbmpc.sim.pybullet_plant.PyBulletPlant`: contacts, friction, scene objects, disturbances).

Timing: without computation delay (``delay="off"``) the simulated time waits for each solve, as in the
paper's first simulations. With delay (``"measured"``: the wall time of the whole solve call on this machine,
or a fixed number of seconds)
the simulator keeps running on the previous plan while the solver works: the new plan reaches the low
level ``delay`` later (rounded up to plant steps), and the next solve starts at the first MPC tick after
that (a real-time loop cannot start a solve before the previous one returns).

The controller sees the state through :class:`wbmpc.sim.sensing.StateSensor` (ground truth by default;
optional noise and the paper's 50 Hz joint-velocity filter). Every run keeps a log that converts to the
columnar :class:`wbmpc.io.logs.RunLog` (``result.run_log()``, ``result.save(path)``); with
``run_closed_loop(..., log_path=...)`` it is streamed to disk in chunks as the run goes (bounded memory; a
run stopped by Ctrl-C or an exception leaves a readable log marked partial).
"""

from __future__ import annotations

import math
import signal
import threading
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path

import numpy as np
import pinocchio as pin

from wbmpc.control.arm_task import ArmReference, heading_frame, velocity_command
from wbmpc.control.command_ramp import CommandRamp
from wbmpc.control.delay import DelayEstimate, predict_state
from wbmpc.control.low_level import LowLevelController
from wbmpc.control.mpc import Commands, MPCSolution, WholeBodyMPC
from wbmpc.ocp.time_grid import node_times
from wbmpc.sim.disturbances import Kick, Push
from wbmpc.sim.failure_reporter import FailureReporter
from wbmpc.sim.hardware import EstimatedState, PlannedContacts, estimate_errors
from wbmpc.sim.loop_config import ClosedLoopConfig
from wbmpc.sim.loop_log import ClosedLoopLog, ClosedLoopResult
from wbmpc.sim.motor_drive import MotorDrive
from wbmpc.sim.plant import ContactPlant, fallen
from wbmpc.sim.sensing import StateSensor
from wbmpc.sim.summary import (
    base_velocity_heading,
    blasfeo_record,
    command_tracking,
    machine_description,
    summarize,
)

__all__ = [
    "ClosedLoopConfig",
    "ClosedLoopLog",
    "ClosedLoopResult",
    "base_velocity_heading",
    "blasfeo_record",
    "command_tracking",
    "machine_description",
    "make_plant",
    "run_closed_loop",
    "summarize",
]


def run_closed_loop(
    mpc: WholeBodyMPC,
    config: ClosedLoopConfig | None = None,
    q0: np.ndarray | None = None,
    progress: bool = True,
    keep_plans: bool = False,
    log_path: str | Path | None = None,
    log_chunk: float = 1.0,
) -> ClosedLoopResult:
    """Simulate the MPC in closed loop on the rigid-contact plant.

    Args:
        mpc: The MPC (built once; its gait decides the scheduled contacts of the plant too).
        config: Run settings.
        q0: Initial configuration; the robot's nominal pose by default (feet on the ground).
        progress: Show a tqdm progress bar.
        keep_plans: Keep every MPC plan in the log (memory heavy; for replays of predictions; not with
            ``log_path``).
        log_path: Stream the log to this ``.npz`` file as the run goes (memory stays bounded; see
            :mod:`wbmpc.io.logs`): if the run is interrupted (Ctrl-C, an exception) the log written so far
            is consolidated there, marked ``meta["partial"]``, and the exception goes on. ``None``: the
            log stays in memory (``result.save(path)`` writes it).
        log_chunk: Simulated time [s] per chunk written to disk with ``log_path``.

    Returns:
        The log, a summary dict (see :func:`summarize`) and whether the robot fell.
    """
    config = config or ClosedLoopConfig()
    if log_path is None:
        log = ClosedLoopLog()
    else:
        if keep_plans:
            raise ValueError("keep_plans needs the in-memory log: plans are not streamed (log_path)")
        if not log_chunk > 0:
            raise ValueError(f"log_chunk must be a duration > 0 [s], got {log_chunk!r}")
        chunk_steps = max(1, round(log_chunk / config.plant_dt))
        meta = {"requested_duration_s": config.duration, "chunk_s": chunk_steps * config.plant_dt}
        log = ClosedLoopLog.streaming(log_path, chunk_steps, meta)
    mpc_gait = mpc.config.gait
    if config.gait is not None:
        mpc.config = replace(mpc.config, gait=config.gait)  # one schedule for the MPC and the plant
    try:
        with _DeferredInterrupt() as interrupt:
            return _run(mpc, config, q0, progress, keep_plans, log, interrupt)
    except BaseException as exc:  # Ctrl-C or an error: a streamed log keeps what ran (then re-raise)
        log.abort(exc)
        raise
    finally:
        mpc.config = replace(mpc.config, gait=mpc_gait)


class _DeferredInterrupt:
    """Ctrl-C during a run raises ``KeyboardInterrupt`` at the next plant step, not inside a solve.

    CasADi polls for Ctrl-C while it solves and turns it into a solver error, which the MPC counts as a
    failed solve: the run went on and the interrupt was lost. A second Ctrl-C raises at once. Only in the
    main thread and with Python's default handler installed (otherwise nothing changes).
    """

    def __init__(self):
        self.requested = False
        self._previous = None

    def __enter__(self) -> _DeferredInterrupt:
        main = threading.current_thread() is threading.main_thread()
        if main and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            self._previous = signal.signal(signal.SIGINT, self._handle)
        return self

    def _handle(self, signum, frame) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True

    def check(self) -> None:
        """Raise ``KeyboardInterrupt`` if Ctrl-C came since the last check."""
        if self.requested:
            self.requested = False
            raise KeyboardInterrupt

    def __exit__(self, *exc_info) -> None:
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)


def _run(mpc, config, q0, progress, keep_plans, log: ClosedLoopLog, interrupt=None) -> ClosedLoopResult:
    robot = mpc.robot
    schedule = mpc.config.gait
    model, data = robot.model, robot.model.createData()
    n_steps, per_mpc, per_low = config.steps()
    plant = make_plant(robot, config)
    q0 = robot.q_nominal if q0 is None else np.asarray(q0, dtype=float)
    state = plant.reset(q0, np.zeros(model.nv))
    kp, kd = _joint_gains(robot, config)
    # A calibrated MPC model brings the joints' identified friction: the low level feeds it forward.
    calibration = getattr(robot, "calibration", None)
    friction = (
        calibration.joint_friction(robot) if calibration is not None and config.friction_feedforward else None
    )
    low = LowLevelController(kp, kd, torque_limits=robot.joint_torque_limits, friction=friction)
    drive = None
    if config.joint_pd == "drive":
        latency = 0.0 if config.hardware is None else config.hardware.torque_latency
        drive = MotorDrive(kp, kd, robot.joint_torque_limits, round(latency / config.plant_dt))
    sensor = StateSensor(model, per_low * config.plant_dt, config.sensor_noise, config.velocity_cutoff_hz)
    # The MPC's plan (the gait schedule with any swing aborted after a push) decides the rigid plant's
    # contacts and the estimator's, and is what the logs record.
    contact_plan = getattr(mpc, "contact_plan", None) or (lambda times: schedule.sample(times).contact)
    estimator = None
    if config.state == "estimated":
        estimator = EstimatedState(
            robot,
            PlannedContacts(contact_plan),
            per_low * config.plant_dt,
            config.hardware,
            config.velocity_cutoff_hz,
        )
    ee_id = robot.frame_id(robot.ee_frame) if robot.has_arm else None
    if hasattr(mpc, "prepare"):
        mpc.prepare()  # the solvers are built before the clock starts, not inside the first solves
    mpc.reset()
    arm_reference = config.arm_reference
    hold = None  # the heading-frame hold point of an ``ee_velocity`` command: [position, time of it]
    if ee_id is not None and (arm_reference is not None or config.ee_velocity_frame == "heading"):
        pin.framesForwardKinematics(model, data, q0)
        if arm_reference is None:
            hold = [ArmReference.still().centered_at(q0, data.oMf[ee_id].translation).center, 0.0]
        elif arm_reference.center is None:
            arm_reference = arm_reference.centered_at(q0, data.oMf[ee_id].translation)
    kicks = {round(d.time / config.plant_dt): d for d in config.disturbances if isinstance(d, Kick)}
    pushes = [d for d in config.disturbances if isinstance(d, Push)]
    fell = False
    tau = np.zeros(robot.nj)
    ee_ref = np.full(3, np.nan)
    q_meas, v_meas = sensor.measure(state.q, state.v)
    if estimator is not None:
        q_meas, v_meas = estimator.reset(state.q, state.v)
    pending: tuple[int, MPCSolution] | None = None  # (plant step at which it applies, plan)
    ramp = None if config.command_ramp is None else CommandRamp(*config.command_ramp)
    expected_delay = DelayEstimate(None if config.delay in ("off", "measured") else float(config.delay))
    busy_until = 0  # plant step before which no new solve can start (the solver is working)
    next_solve = 0  # plant step of the next MPC tick
    contacts_from = 0  # plant step at which period_contacts begins
    cmd = _commands(config, 0.0, schedule)
    scene_names = plant.body_names
    reporter = FailureReporter(prefix="[closed loop]")  # one line per new failure reason, then counts

    def run_summary(columns: Mapping, fell: bool) -> dict:  # columns from memory or the streamed file
        clipped = low.violations if drive is None else drive.violations
        summary = summarize(mpc, columns, config, fell, clipped, plant)
        summary["joint_pd"] = config.joint_pd
        if drive is not None:
            names = robot.joint_names
            summary["torque_clipped_steps_by_joint"] = {
                names[i]: int(n) for i, n in enumerate(drive.clipped_steps) if n
            }
        summary["diagnostics"] = reporter.summary()
        summary["scene_bodies"] = list(scene_names)
        summary["state"] = config.state
        summary["hardware"] = None if config.hardware is None else config.hardware.describe()
        if estimator is not None and len(columns["t"]):
            summary["estimate_error"] = estimate_errors(*(columns[k] for k in ("q", "v", "q_meas", "v_meas")))
        return summary

    log.summarize = lambda columns: run_summary(columns, False)  # an interrupted run's partial log

    bar = _progress(n_steps // per_mpc, progress)
    for step in range(n_steps):
        log.tick(step)  # a streamed log writes a chunk to disk and empties its lists
        if interrupt is not None:
            interrupt.check()  # Ctrl-C
        t = step * config.plant_dt
        q, v = state.q, state.v
        if pending is not None and step >= pending[0]:
            low.update(pending[1])
            pending = None
        solve_now = step >= busy_until and step >= next_solve
        if config.mpc_schedule == "ticks":
            solve_now = solve_now and step % per_mpc == 0
        else:  # free-running: the next solve starts at the first low-level tick after the last plan arrived
            solve_now = solve_now and step % per_low == 0
        if solve_now:
            next_solve = step + per_mpc
            if sensor.is_ground_truth and estimator is None:
                q_meas, v_meas = q.copy(), v.copy()
            cmd = _commands(config, t, schedule)
            if ramp is not None:
                cmd["base_velocity"], cmd["base_yaw_rate"] = ramp(
                    t, cmd["base_velocity"], cmd["base_yaw_rate"]
                )
            t_plan = t
            if config.delay_compensation and config.delay != "off" and low.plan is not None:
                t_plan = t + math.ceil(expected_delay.expected() / config.plant_dt - 1e-9) * config.plant_dt
            commands = Commands(
                base_linear_velocity=cmd["base_velocity"],
                base_angular_velocity=np.array([0, 0, cmd["base_yaw_rate"]]),
                ee_force=cmd["ee_force"],
            )
            if ee_id is not None:
                pin.framesForwardKinematics(model, data, q_meas)
                ee_pos = data.oMf[ee_id].translation.copy()
                if arm_reference is not None or hold is not None:
                    local_velocity = None
                    reference = arm_reference
                    if hold is not None:  # the hold point moves at the commanded velocity (heading frame)
                        hold[0] = tuple(np.asarray(hold[0]) + cmd["ee_velocity"] * (t - hold[1]))
                        hold[1] = t
                        reference, local_velocity = ArmReference.still(hold[0]), cmd["ee_velocity"]
                    R_heading, _ = heading_frame(q_meas)
                    stage_times = node_times(mpc.time_steps(), t_plan)[:-1] if config.arm_preview else None
                    ee_cmd, ee_ref = velocity_command(
                        reference,
                        q_meas,
                        ee_pos,
                        t,
                        R_heading @ cmd["base_velocity"],
                        kp=config.arm_kp,
                        node_times=stage_times,
                        yaw_rate=cmd["base_yaw_rate"],
                        local_velocity=local_velocity,
                    )
                else:
                    ee_cmd = cmd["ee_velocity"]
                commands.ee_velocity = ee_cmd
                log.ee_command.append(ee_cmd if ee_cmd.ndim == 1 else ee_cmd[:, 0])
            q_plan, v_plan = q_meas, v_meas
            if t_plan > t:  # plan from where the robot will be when the plan arrives
                q_plan, v_plan = predict_state(model, low.plan, q_meas, v_meas, t, t_plan)
            plan = mpc.solve(q_plan, v_plan, t_plan, commands)
            if step > 0:  # the cold first solve, before the robot moves, says nothing of the next ones
                expected_delay.record(plan.timings.get("total", plan.solve_time))
            if plan.fallback:
                kept = "static hold applied" if plan.hold else "previous plan kept"
                reporter.report(t, plan.status, f"{plan.reason} ({kept})")
            if plan.findings:
                reporter.report_findings(t, plan.findings)
            # The plan is ready when the whole call returns (parameters, prechecks, solve, unpacking).
            delay = _delay_steps(config, plan.timings.get("total", plan.solve_time))
            if delay == 0 or low.plan is None:  # no delay, or nothing to hold yet (the robot starts at rest)
                low.update(plan)
                apply_step = step
            else:
                # A compensated plan starts at t_plan: one that is ready sooner waits for it (the plan in use
                # covers the time until then), one that is late is used part-way.
                apply_step = max(step + delay, round(t_plan / config.plant_dt))
                pending = (apply_step, plan)
            busy_until = apply_step
            _log_solve(log, plan, keep_plans, apply_step * config.plant_dt)
            if bar is not None:
                bar.update(1)
                bar.set_postfix(iters=plan.iterations, ms=f"{1e3 * plan.solve_time:.0f}")
        if solve_now or step - contacts_from >= per_mpc or step == 0:
            # The contact plan of the coming MPC period in one vectorised call, sampled after this tick's
            # solve: the MPC's plan (the gait schedule with any swing aborted after a push), so the rigid
            # plant, the logs and the MPC share one plan.
            period_contacts = contact_plan(config.plant_dt * np.arange(step, step + per_mpc))
            contacts_from = step
        contact = period_contacts[:, step - contacts_from]
        if step % per_low == 0:
            if estimator is None:
                q_meas, v_meas = sensor.measure(q, v)  # ground truth: plain copies
            else:
                q_meas, v_meas = estimator.measure(q, v, t)
            if drive is None:
                tau = low.torque(t, q_meas, v_meas)
            else:  # the drivers close the loop; the controller sends setpoints
                ref = low.last_reference = low.reference(t)
                drive.command(ref.tau_ff, ref.q_des, ref.v_des)
        if drive is not None:
            tau = drive.torque(q[7:], v[6:])
        if step % per_low == 0:
            log.t.append(t)
            log.q.append(q.copy())
            log.v.append(v.copy())
            log.q_meas.append(q_meas.copy())
            log.v_meas.append(v_meas.copy())
            log.tau.append(tau.copy())
            log.tau_ff.append(low.last_reference.tau_ff)
            log.contact.append(contact)
            log.contact_sim.append(plant.foot_contacts(contact))
            log.foot_forces.append(plant.contact_forces())
            log.foot_height.append(plant.foot_positions[:, 2] - robot.foot_radius)
            log.base_velocity_cmd.append(cmd["base_velocity"])
            log.base_yaw_rate_cmd.append(cmd["base_yaw_rate"])
            log.ee_force_cmd.append(cmd["ee_force"])
            if ee_id is not None:  # only the end-effector frame is needed here
                pin.forwardKinematics(model, data, q)
                log.ee_position.append(pin.updateFramePlacement(model, data, ee_id).translation.copy())
                log.ee_force_sim.append(plant.ee_contact_force())
            else:
                log.ee_position.append(np.full(3, np.nan))
                log.ee_force_sim.append(np.zeros(3))
            log.ee_reference.append(ee_ref.copy())
            if scene_names:
                log.scene_positions.append(np.array([plant.body_pose(name)[0] for name in scene_names]))
            # On every logged tick, not only on solves: a slow solve would otherwise leave a fall (a tilt the
            # summary's max_tilt_rad shows) unseen until the base happened to recover.
            if fallen(state, max_tilt=config.max_tilt):
                fell = True
                break
        try:
            if step in kicks:
                state = plant.apply_base_velocity_kick(np.asarray(kicks[step].delta_v, dtype=float))
            wrench, ee_force = _push_forces(pushes, t)
            state = plant.step(tau, contact, external_wrench=wrench, ee_force=ee_force)
        except FloatingPointError:
            fell = True
            break
    if bar is not None:
        bar.close()
    summary = log.finish(lambda columns: run_summary(columns, fell))
    plant.close()
    return ClosedLoopResult(log=log, summary=summary, fell=fell)


def _commands(config: ClosedLoopConfig, t: float, gait=None) -> dict:
    """Commands at time ``t``: the config's constants, the gait schedule's segment velocity (a stand segment
    stands still), then the config's ``command_schedule``."""
    cmd = {
        "base_velocity": config.base_velocity,
        "base_yaw_rate": config.base_yaw_rate,
        "ee_velocity": config.ee_velocity,
        "ee_force": config.ee_force,
    }
    segment = None if gait is None else gait.velocity_at(t)
    if segment is not None:
        cmd |= {"base_velocity": (segment[0], segment[1], 0.0), "base_yaw_rate": segment[2]}
    if config.command_schedule is not None:
        override = config.command_schedule(t) or {}
        unknown = set(override) - set(cmd)
        if unknown:
            raise ValueError(
                f"command_schedule returned unknown keys {sorted(unknown)}; known: {sorted(cmd)}"
            )
        cmd |= override
    out = {k: np.asarray(v, dtype=float) for k, v in cmd.items()}
    out["base_yaw_rate"] = float(out["base_yaw_rate"])
    return out


def _delay_steps(config: ClosedLoopConfig, solve_time: float) -> int:
    """Plant steps between a solve's measurement and its plan reaching the low level (``solve_time``: the
    whole :meth:`~wbmpc.control.mpc.WholeBodyMPC.solve` call [s], for ``delay="measured"``)."""
    if config.delay == "off":
        return 0
    seconds = solve_time if config.delay == "measured" else float(config.delay)
    return int(math.ceil(seconds / config.plant_dt - 1e-9))


def _push_forces(pushes: list[Push], t: float) -> tuple[np.ndarray | None, np.ndarray | None]:
    wrench = ee = None
    for push in pushes:
        if push.active(t):
            if push.target == "base":
                wrench = push.wrench() if wrench is None else wrench + push.wrench()
            else:
                f = np.asarray(push.force, dtype=float)
                ee = f if ee is None else ee + f
    return wrench, ee


def _joint_gains(robot, config: ClosedLoopConfig) -> tuple[np.ndarray, np.ndarray]:
    kp = np.full(robot.nj, float(config.kp))
    kd = np.full(robot.nj, float(config.kd))
    if config.arm_gains is not None and robot.has_arm:
        arm = [robot.joint_names.index(name) for name in robot.arm_joint_names]
        kp[arm], kd[arm] = config.arm_gains
    return kp, kd


def make_plant(robot, config: ClosedLoopConfig):
    """The plant named by ``config.plant``, stepping at ``config.plant_dt`` (with the config's scene)."""
    if config.plant == "rigid":
        return ContactPlant(robot.model, robot.foot_frames, dt=config.plant_dt, foot_radius=robot.foot_radius)
    if config.plant == "pybullet":
        from wbmpc.sim.pybullet_plant import PyBulletPlant

        options = {} if config.hardware is None else config.hardware.plant_options(robot)
        if config.joint_pd == "drive":
            options["torque_latency"] = 0.0  # the drive delays its setpoints instead (MotorDrive)
        return PyBulletPlant(
            robot, dt=config.plant_dt, ground_friction=config.ground_friction, scene=config.scene, **options
        )
    raise ValueError(f"unknown plant {config.plant!r}; available: 'rigid', 'pybullet'")


def _log_solve(log: ClosedLoopLog, plan: MPCSolution, keep_plans: bool, apply_t: float) -> None:
    log.solve_t.append(plan.t)
    log.apply_t.append(apply_t)
    log.plan_q.append(plan.q[:2].copy())
    log.plan_v.append(plan.v[:2].copy())
    log.plan_tau.append(plan.tau[0].copy())
    log.plan_forces.append(plan.forces[0].copy())
    log.plan_contact.append(np.asarray(plan.contact[:, 0], bool))
    log.hold.append(bool(plan.hold))
    log.solve_time.append(plan.solve_time)
    log.iterations.append(plan.iterations)
    log.success.append(plan.success)
    log.fallback.append(plan.fallback)
    log.violation.append(plan.constraint_violation)
    log.status.append(plan.status)
    log.reason.append(plan.reason)
    log.timings.append(plan.timings)
    if keep_plans:
        log.plans.append(plan)


def _progress(total: int, enabled: bool):
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, desc="MPC", unit="solve")
