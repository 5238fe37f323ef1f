"""Closed-loop simulation: MPC at 80 Hz, joint interpolation + PD at 500 Hz, a plant at 1-2 kHz.

:class:`ClosedLoop` is the scheduler. Each plant step it hands a due plan to the low level, starts a solve on
an MPC tick (the commands of :class:`~wbmpc.control.command_schedule.CommandSchedule` at that time, the arm's
end-effector command, the state the controller sees), computes the joint torques on a low-level tick, and
steps the plant (any :class:`~wbmpc.sim.plant.Plant`: the rigid-contact plant of the paper's benchmark or
PyBullet, behind the emulated robot's motors when a hardware profile is set,
:class:`~wbmpc.sim.actuators.ActuatedPlant`). Logging, the failure reports, the progress bar and the summary's
extra entries are observers (:mod:`wbmpc.sim.observers`). The loop never changes the MPC's configuration:
the run's gait reaches the MPC with each solve's commands.

Timing: without computation delay (``delay="off"``) the simulated time waits for each solve, as in the
paper's first simulations. With delay (``"measured"``: the wall time of the whole solve call on this machine,
or a fixed number of seconds) the simulator keeps running on the previous plan while the solver works: the
new plan reaches the low level ``delay`` later (rounded up to plant steps), and the next solve starts at the
first MPC tick after that (a real-time loop cannot start a solve before the previous one returns).

The controller sees the state through :class:`wbmpc.sim.sensing.StateSensor` (ground truth by default;
optional noise and the paper's 50 Hz joint-velocity filter) or the state estimator. Every run keeps a log
that converts to the columnar :class:`wbmpc.io.logs.RunLog` (``result.run_log()``, ``result.save(path)``);
with ``run_closed_loop(..., log_path=...)`` it is streamed to disk in chunks as the run goes (bounded memory;
a run stopped by Ctrl-C or an exception leaves a readable log marked partial).
"""

from __future__ import annotations

import math
import signal
import threading
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from wbmpc.control.low_level import LowLevelController
from wbmpc.control.mpc import MPCSolution, WholeBodyMPC
from wbmpc.sim.actuators import ActuatedPlant, Actuators
from wbmpc.sim.disturbances import Kick, Push
from wbmpc.sim.hardware import EstimatedState, PlannedContacts, estimate_errors
from wbmpc.sim.loop_config import (
    ClosedLoopConfig,
    CommandSchedule,
    LowLevelConfig,
    PlantConfig,
    SensingConfig,
)
from wbmpc.sim.loop_log import ClosedLoopLog, ClosedLoopResult
from wbmpc.sim.motor_drive import MotorDrive
from wbmpc.sim.observers import FailureObserver, LogRecorder, LoopObserver, ProgressBar
from wbmpc.sim.planner import Planner
from wbmpc.sim.plant import ContactPlant, Plant, fallen
from wbmpc.sim.sensing import StateSensor
from wbmpc.sim.summary import (
    base_velocity_heading,
    blasfeo_record,
    command_tracking,
    machine_description,
    summarize,
)

__all__ = [
    "ClosedLoop",
    "ClosedLoopConfig",
    "ClosedLoopLog",
    "ClosedLoopResult",
    "CommandSchedule",
    "LowLevelConfig",
    "PlantConfig",
    "SensingConfig",
    "base_velocity_heading",
    "blasfeo_record",
    "command_tracking",
    "machine_description",
    "joint_level",
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
    observers: Sequence[LoopObserver] = (),
) -> ClosedLoopResult:
    """Simulate the MPC in closed loop.

    Args:
        mpc: The MPC (built once; it is prepared and reset here, its configuration is not changed).
        config: Run settings (default :class:`ClosedLoopConfig`: the rigid plant, a trot at 0.2 m/s).
        q0: Initial configuration; the robot's nominal pose by default (feet on the ground).
        progress: Show a tqdm progress bar.
        keep_plans: Keep every MPC plan in the log (memory heavy; for replays of predictions; not with
            ``log_path``).
        log_path: Stream the log to this ``.npz`` file as the run goes (memory stays bounded; see
            :mod:`wbmpc.io.logs`): if the run is interrupted (Ctrl-C, an exception) the log written so far
            is consolidated there, marked ``meta["partial"]``, and the exception goes on. ``None``: the
            log stays in memory (``result.save(path)`` writes it).
        log_chunk: Simulated time [s] per chunk written to disk with ``log_path``.
        observers: Extra :class:`~wbmpc.sim.observers.LoopObserver` s, called after the built-in ones.

    Returns:
        The log, a summary dict (see :func:`summarize`) and whether the robot fell.

    Raises:
        ValueError: On a bad config (before anything is built) or ``keep_plans`` with ``log_path``.
    """
    config = config or ClosedLoopConfig()
    n_steps, per_mpc, _ = config.steps()  # checks the config (fields may have changed since construction)
    if log_path is None:
        log = ClosedLoopLog()
    else:
        if keep_plans:
            raise ValueError("keep_plans needs the in-memory log: plans are not streamed (log_path)")
        if not log_chunk > 0:
            raise ValueError(f"log_chunk must be a duration > 0 [s], got {log_chunk!r}")
        chunk_steps = max(1, round(log_chunk / config.plant.dt))
        meta = {"requested_duration_s": config.duration, "chunk_s": chunk_steps * config.plant.dt}
        log = ClosedLoopLog.streaming(log_path, chunk_steps, meta)
    observers = [
        LogRecorder(log, keep_plans),
        FailureObserver(),
        *([ProgressBar(n_steps // per_mpc)] if progress else []),
        *observers,
    ]
    loop = None
    try:
        with _DeferredInterrupt() as interrupt:
            loop = ClosedLoop(mpc, config, q0, observers)
            log.summarize = lambda columns: loop.summary(columns, False)  # an interrupted run's partial log
            fell = loop.run(interrupt)
            summary = log.finish(lambda columns: loop.summary(columns, fell))
            return ClosedLoopResult(log=log, summary=summary, fell=fell)
    except BaseException as exc:  # Ctrl-C or an error: a streamed log keeps what ran (then re-raise)
        log.abort(exc)
        raise
    finally:
        for observer in observers:
            observer.close()
        if loop is not None:
            loop.plant.close()


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


class ClosedLoop:
    """The components of one run and the scheduler that steps them (:meth:`run`).

    Built by :func:`run_closed_loop`; its attributes are what observers read.

    Attributes:
        mpc, robot, config: The controller, its robot, the run's settings.
        plant: The plant (:func:`make_plant`), behind the motors with a hardware profile.
        low: The low level (:class:`~wbmpc.control.low_level.LowLevelController`); drive: the motor drives
            (:class:`~wbmpc.sim.motor_drive.MotorDrive`) with ``joint_pd="drive"``, else ``None``.
        sensor, estimator: What the controller sees (ground truth through the sensor model, or the state
            estimator with ``sensing.state="estimated"``).
        gait: The gait walked (the command schedule's, else the MPC's).
        step, t: Current plant step and its time [s]; state: the plant's state.
        q_meas, v_meas: The state the controller saw last; tau: the joint torques of this step [N m].
        commands: The commands of the last solve (:meth:`CommandSchedule.at`); ee_command: its end-effector
            velocity command (``None`` without an arm); ee_reference: the arm reference position [m].
        contact: The scheduled contacts of this step (n_feet,).
        observers: The :class:`~wbmpc.sim.observers.LoopObserver` s.
    """

    def __init__(
        self,
        mpc: WholeBodyMPC,
        config: ClosedLoopConfig,
        q0: np.ndarray | None = None,
        observers: Sequence[LoopObserver] = (),
    ):
        self.mpc, self.config, self.robot = mpc, config, mpc.robot
        robot = self.robot
        self.n_steps, self.per_mpc, self.per_low = config.steps()
        dt_low = self.per_low * config.plant.dt
        self.schedule: CommandSchedule = config.commands
        self.gait = self.schedule.gait if self.schedule.gait is not None else mpc.config.gait
        self.plant = make_plant(robot, config)
        self.q0 = robot.q_nominal if q0 is None else np.asarray(q0, dtype=float)
        self.state = self.plant.reset(self.q0, np.zeros(robot.nv))
        self.low, self.drive = joint_level(robot, config)
        sensing = config.sensing
        self.sensor = StateSensor(robot.model, dt_low, sensing.noise, sensing.velocity_cutoff_hz)
        self.estimator = None
        if sensing.state == "estimated":
            self.estimator = EstimatedState(
                robot,
                PlannedContacts(self.contact_plan),
                dt_low,
                config.plant.hardware,
                sensing.velocity_cutoff_hz,
            )
        self.planner = Planner(mpc, config, self.q0)
        self.ee_id = self.planner.arm.ee_id
        self.scene_names = self.plant.body_names
        self.observers: list[LoopObserver] = list(observers)
        self.step, self.t = 0, 0.0
        self.tau = np.zeros(robot.nj)
        self.contact = np.ones(robot.n_feet, dtype=bool)

    @property
    def commands(self) -> dict:
        """The commands of the last solve (:meth:`CommandSchedule.at`, ramped)."""
        return self.planner.commands

    @property
    def ee_command(self) -> np.ndarray | None:
        """The last solve's end-effector velocity command [m/s] (``None`` without an arm)."""
        return self.planner.ee_command

    @property
    def ee_reference(self) -> np.ndarray | None:
        """The arm's reference position [m] at the last solve."""
        return self.planner.ee_reference

    def contact_plan(self, times) -> np.ndarray:
        """Contacts (n_feet, n) at ``times`` [s]: the MPC's plan (the gait with any swing aborted after a
        push), shared by the rigid plant, the estimator and the logs."""
        return self.mpc.contact_plan(times, self.gait)

    def summary(self, columns: Mapping, fell: bool) -> dict:
        """The run summary from the log's columns (in memory or the streamed file) and the components."""
        config, drive = self.config, self.drive
        clipped = self.low.violations if drive is None else drive.violations
        summary = summarize(self.mpc, columns, config, fell, clipped, self.plant, gait=self.gait)
        summary["joint_pd"] = config.low_level.joint_pd
        if drive is not None:
            names = self.robot.joint_names
            summary["torque_clipped_steps_by_joint"] = {
                names[i]: int(n) for i, n in enumerate(drive.clipped_steps) if n
            }
        for observer in self.observers:
            summary |= observer.summary()
        summary["scene_bodies"] = list(self.scene_names)
        summary["state"] = config.sensing.state
        hardware = config.plant.hardware
        summary["hardware"] = None if hardware is None else hardware.describe()
        if self.estimator is not None and len(columns["t"]):
            summary["estimate_error"] = estimate_errors(*(columns[k] for k in ("q", "v", "q_meas", "v_meas")))
        return summary

    def run(self, interrupt: _DeferredInterrupt | None = None) -> bool:
        """Run to the config's duration or a fall; returns whether the robot fell."""
        config, mpc, plant = self.config, self.mpc, self.plant
        dt, per_mpc, per_low = config.plant.dt, self.per_mpc, self.per_low
        mpc.prepare()  # the solvers are built before the clock starts, not inside the first solves
        mpc.reset()
        kicks = {round(d.time / dt): d for d in config.disturbances if isinstance(d, Kick)}
        pushes = [d for d in config.disturbances if isinstance(d, Push)]
        self._start_sensing()
        self._pending: tuple[int, MPCSolution] | None = None  # (plant step at which it applies, plan)
        self.planner.reset()
        self._busy_until = 0  # plant step before which no new solve can start (the solver is working)
        self._next_solve = 0  # plant step of the next MPC tick
        contacts_from = 0  # plant step at which period_contacts begins
        for step in range(self.n_steps):
            self.step, self.t = step, step * dt
            for observer in self.observers:
                observer.on_step(self, step)
            if interrupt is not None:
                interrupt.check()  # Ctrl-C
            if self._pending is not None and step >= self._pending[0]:
                self._deliver(self._pending[1])
                self._pending = None
            solve_now = step >= self._busy_until and step >= self._next_solve
            if config.mpc_schedule == "ticks":
                solve_now = solve_now and step % per_mpc == 0
            else:  # free-running: the next solve starts at the first low-level tick after the plan arrived
                solve_now = solve_now and step % per_low == 0
            if solve_now:
                self._solve(step)
            if solve_now or step - contacts_from >= per_mpc or step == 0:
                # The contact plan of the coming MPC period in one vectorised call, sampled after this tick's
                # solve, so the rigid plant, the logs and the MPC share one plan.
                period_contacts = self.contact_plan(dt * np.arange(step, step + per_mpc))
                contacts_from = step
            self.contact = period_contacts[:, step - contacts_from]
            low_tick = step % per_low == 0
            if low_tick:
                self._joint_commands()
            if self.drive is not None:
                self.tau = self._drive_torque()
            if low_tick:
                for observer in self.observers:
                    observer.on_tick(self)
                # On every logged tick, not only on solves: a slow solve would otherwise leave a fall (a tilt
                # the summary's max_tilt_rad shows) unseen until the base happened to recover.
                if fallen(self.state, max_tilt=config.max_tilt):
                    return True
            try:
                if step in kicks:
                    self.state = plant.apply_base_velocity_kick(np.asarray(kicks[step].delta_v, dtype=float))
                wrench, ee_force = _push_forces(pushes, self.t)
                self.state = plant.step(self.tau, self.contact, external_wrench=wrench, ee_force=ee_force)
            except FloatingPointError:
                return True
        return False

    def _solve(self, step: int) -> None:
        """An MPC tick: the plan (:class:`~wbmpc.sim.planner.Planner`) and when it applies."""
        config, low = self.config, self.low
        dt = config.plant.dt
        self._next_solve = step + self.per_mpc
        if self.sensor.is_ground_truth and self.estimator is None:
            self.q_meas, self.v_meas = self.state.q.copy(), self.state.v.copy()
        plan = self.planner.plan(self.q_meas, self.v_meas, self.t, low.plan, record_delay=step > 0)
        t_plan = self.planner.last_plan_time
        # The plan is ready when the whole call returns (parameters, prechecks, solve, unpacking).
        delay = _delay_steps(config, plan.timings.get("total", plan.solve_time))
        if delay == 0 or low.plan is None:  # no delay, or nothing to hold yet (the robot starts at rest)
            self._deliver(plan)
            apply_step = step
        else:
            # A compensated plan starts at t_plan: one that is ready sooner waits for it (the plan in use
            # covers the time until then), one that is late is used part-way.
            apply_step = max(step + delay, round(t_plan / dt))
            self._pending = (apply_step, plan)
        self._busy_until = apply_step
        for observer in self.observers:
            observer.on_solve(self, plan, apply_step * dt)

    def _start_sensing(self) -> None:
        """The first measurement, before the first step (the estimator starts at the true state)."""
        self.q_meas, self.v_meas = self.sensor.measure(self.state.q, self.state.v)
        if self.estimator is not None:
            self.q_meas, self.v_meas = self.estimator.reset(self.state.q, self.state.v)

    def _deliver(self, plan: MPCSolution) -> None:
        """A plan reaches the low level."""
        self.low.update(plan)

    def _drive_torque(self) -> np.ndarray:
        """The motor drives' torque at this plant step (``joint_pd="drive"``)."""
        return self.drive.torque(self.state.q[7:], self.state.v[6:])

    def _joint_commands(self) -> None:
        """A low-level tick: what the controller sees, and the torques (or the drives' setpoints)."""
        q, v, t = self.state.q, self.state.v, self.t
        if self.estimator is None:
            self.q_meas, self.v_meas = self.sensor.measure(q, v)  # ground truth: plain copies
        else:
            self.q_meas, self.v_meas = self.estimator.measure(q, v, t)
        if self.drive is None:
            self.tau = self.low.torque(t, self.q_meas, self.v_meas)
        else:  # the drivers close the loop; the controller sends setpoints
            ref = self.low.last_reference = self.low.reference(t)
            self.drive.command(ref.tau_ff, ref.q_des, ref.v_des)


def make_plant(robot, config: ClosedLoopConfig) -> Plant:
    """The plant of ``config.plant`` at its step, with its scene; behind the hardware profile's motors
    (:class:`~wbmpc.sim.actuators.ActuatedPlant`) when the config has one."""
    plant_config = config.plant
    hardware = plant_config.hardware
    if plant_config.kind == "rigid":
        return ContactPlant(robot.model, robot.foot_frames, dt=plant_config.dt, foot_radius=robot.foot_radius)
    from wbmpc.sim.pybullet_plant import PyBulletPlant

    offset = (
        None if hardware is None or hardware.base_com_offset is None else np.asarray(hardware.base_com_offset)
    )
    plant = PyBulletPlant(
        robot,
        dt=plant_config.dt,
        ground_friction=plant_config.ground_friction,
        scene=plant_config.scene,
        base_com_offset=offset,
        clip_torques=hardware is None,
    )
    if hardware is None:
        return plant
    motors = hardware.motor_model(robot)
    if config.low_level.joint_pd == "drive":
        motors = replace(motors, latency=0.0)  # the drive delays its setpoints instead (MotorDrive)
    return ActuatedPlant(plant, Actuators(motors, robot.joint_torque_limits, plant_config.dt))


def joint_level(robot, config: ClosedLoopConfig) -> tuple[LowLevelController, MotorDrive | None]:
    """The low level and, with ``joint_pd="drive"``, the motor drives that run its PD law."""
    low_config = config.low_level
    kp = np.full(robot.nj, float(low_config.kp))
    kd = np.full(robot.nj, float(low_config.kd))
    if low_config.arm_gains is not None and robot.has_arm:
        arm = [robot.joint_names.index(name) for name in robot.arm_joint_names]
        kp[arm], kd[arm] = low_config.arm_gains
    # A calibrated MPC model brings the joints' identified friction: the low level feeds it forward.
    calibration = getattr(robot, "calibration", None)
    friction = (
        calibration.joint_friction(robot)
        if calibration is not None and low_config.friction_feedforward
        else None
    )
    low = LowLevelController(kp, kd, torque_limits=robot.joint_torque_limits, friction=friction)
    drive = None
    if low_config.joint_pd == "drive":
        hardware = config.plant.hardware
        latency = 0.0 if hardware is None else hardware.torque_latency
        drive = MotorDrive(kp, kd, robot.joint_torque_limits, round(latency / config.plant.dt))
    return low, drive


def _delay_steps(config: ClosedLoopConfig, solve_time: float) -> int:
    """Plant steps between a solve's measurement and its plan reaching the low level (``solve_time``: the
    whole :meth:`~wbmpc.control.mpc.WholeBodyMPC.solve` call [s], for ``delay="measured"``)."""
    if config.delay == "off":
        return 0
    seconds = solve_time if config.delay == "measured" else float(config.delay)
    return int(math.ceil(seconds / config.plant.dt - 1e-9))


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
