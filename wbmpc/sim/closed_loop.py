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
import platform
import shutil
import signal
import threading
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import numpy as np
import pinocchio as pin

from wbmpc import checks
from wbmpc.control.arm_task import ArmReference, heading_frame, velocity_command
from wbmpc.control.command_ramp import CommandRamp
from wbmpc.control.delay import DelayEstimate, predict_state
from wbmpc.control.diagnostics import FailureReporter
from wbmpc.control.low_level import LowLevelController
from wbmpc.control.mpc import Commands, MPCSolution, WholeBodyMPC
from wbmpc.io.logs import LogWriter, RunLog, load_log, save_log
from wbmpc.model.quaternion import tilt
from wbmpc.ocp.gait import Gait, GaitSchedule
from wbmpc.ocp.time_grid import node_times
from wbmpc.sim.disturbances import Disturbance, Kick, Push
from wbmpc.sim.hardware import EstimatedState, HardwareProfile, PlannedContacts, estimate_errors
from wbmpc.sim.motor_drive import MotorDrive
from wbmpc.sim.plant import ContactPlant, fallen
from wbmpc.sim.sensing import SensorNoise, StateSensor


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
        joint_pd: Where the joint PD law runs: ``"controller"`` (the 500 Hz low level computes the torque
            from the controller's state and the plant applies it, the paper's simulation) or ``"drive"``
            (:class:`wbmpc.sim.motor_drive.MotorDrive`: the low level sends setpoints, feed-forward and
            gains at 500 Hz and the motor drivers evaluate the law at every plant step on the joint
            encoders, as Unitree's robots do; a hardware profile's torque latency then delays the
            setpoints, not the damping loop).
        friction_feedforward: When the MPC's robot carries a calibration (``load_b1_z1(calibration=...)``),
            the low level adds its identified joint friction at the desired joint rates
            (:class:`wbmpc.control.low_level.LowLevelController` ``friction``); False: never.
        base_velocity: Commanded base linear velocity [m/s], heading frame, of the walking segments; a gait
            schedule's segments may name their own (``trot@0.5:4``, :meth:`GaitSchedule.velocity_at`) and a
            stand segment stands still unless it does.
        base_yaw_rate: Commanded yaw rate [rad/s] (of the walking segments, as ``base_velocity``).
        arm_reference: End-effector position reference (heading frame), or ``None`` for the ``ee_velocity``
            command in ``ee_velocity_frame``.
        arm_kp: Position gain [1/s] of the arm reference feedback (and of the heading-frame hold).
        arm_preview: One end-effector velocity per MPC stage from the reference's future (True), or the
            paper's single velocity held over the horizon (False).
        ee_velocity: End-effector velocity command [m/s] used when there is no arm reference, in
            ``ee_velocity_frame``: zero holds the hand still.
        ee_velocity_frame: ``"heading"`` (default): ``ee_velocity`` is relative to the heading frame, which
            carries the hand as the base walks and turns (a hold point moving at ``ee_velocity`` with
            ``arm_kp`` feedback, so zero keeps the hand where it started relative to the body);
            ``"world"``: ``ee_velocity`` is the hand's world velocity, held over the horizon (the paper's
            command; zero pins the hand in the world, which a walking base cannot sustain for long: the
            MPC's precheck ``ee_world_hold_with_walking_base`` says after how far).
        ee_force: Commanded end-effector force [N], world.
        max_tilt: Roll/pitch [rad] beyond which the run counts as a fall.
        delay: Computation delay: ``"off"``, ``"measured"`` (the wall time of each whole
            :meth:`~wbmpc.control.mpc.WholeBodyMPC.solve` call) or seconds.
        mpc_schedule: When solves start: ``"ticks"`` (on the MPC rate's ticks, the first one after the
            previous plan arrived: a solve slightly longer than a period halves the rate) or ``"free"`` (at
            the first low-level tick after the previous plan arrived, but no sooner than one MPC period
            after the previous solve started: an asynchronous MPC worker that restarts when it is done).
        command_ramp: ``(linear [m/s^2], yaw [rad/s^2])`` acceleration limits of the base velocity command
            (:class:`wbmpc.control.command_ramp.CommandRamp`), e.g. between a gait schedule's segments;
            ``None``: commands change in steps.
        delay_compensation: With a delay, plan from the state predicted for the time the plan will arrive
            (:mod:`wbmpc.control.delay`: the measurement moved along the plan being executed by the
            expected delay, the fixed one or a high quantile of the recent solve calls) instead of from the
            measurement's own time.
        sensor_noise: Measurement noise (``None``: ground truth).
        velocity_cutoff_hz: Joint-velocity low-pass cut-off [Hz] (paper: 50; ``None``: unfiltered).
        scene: PyBullet scene objects (:class:`~wbmpc.sim.pybullet_plant.Box`, ``Wall``, ``Payload``).
        disturbances: :class:`~wbmpc.sim.disturbances.Kick` and ``Push`` events (PyBullet plant).
        command_schedule: ``f(t) -> dict`` overriding commands over time: keys ``base_velocity``,
            ``base_yaw_rate``, ``ee_velocity``, ``ee_force`` (values as the fields of the same names).
        ground_friction: Ground friction coefficient of the PyBullet plant.
        arm_gains: ``(kp, kd)`` of the arm joints if different from the legs' (e.g. a compliant arm).
        gait: Gait or :class:`~wbmpc.ocp.gait.GaitSchedule` for this run (e.g.
            ``parse_gait_schedule("stand:2,trot:6,stand:2")``), replacing the MPC's for its duration;
            ``None`` keeps the MPC's. The one schedule decides the plant's contacts and the MPC's stage
            contacts, evaluated in integer plant ticks.
        state: What the MPC and the low level see: ``"ground_truth"`` (the plant's state through
            ``sensor_noise`` and the velocity filter) or ``"estimated"`` (the state estimator
            :class:`wbmpc.estimation.StateEstimator` at the low-level rate on synthesised IMU and encoder
            readings, with the errors of ``hardware`` (exact without one), contacts from the MPC's contact
            plan (the gait schedule with any swing aborted after a push), joint rates filtered at
            ``velocity_cutoff_hz``). The log keeps both: ``q``, ``v`` true,
            ``q_meas``, ``v_meas`` what the controller saw.
        hardware: The emulated robot's mismatches (:class:`wbmpc.sim.hardware.HardwareProfile`; PyBullet
            plant only): motor friction, armature, base centre-of-mass offset, torque latency, sensor errors
            of the estimator. ``None``: the nominal robot. :func:`wbmpc.sim.presets.hardware_config` also
            sets the profile's controller settings.
    """

    duration: float = 10.0
    mpc_rate: float = 80.0
    low_level_rate: float = 500.0
    plant_dt: float = 0.0005
    plant: str = "rigid"
    kp: float = 0.0
    kd: float = 0.0
    joint_pd: str = "controller"
    friction_feedforward: bool = True
    base_velocity: tuple[float, float, float] = (0.2, 0.0, 0.0)
    base_yaw_rate: float = 0.0
    arm_reference: ArmReference | None = field(default_factory=ArmReference)
    arm_kp: float = 4.0
    arm_preview: bool = True
    ee_velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    ee_velocity_frame: str = "heading"
    ee_force: tuple[float, float, float] = (0.0, 0.0, 0.0)
    max_tilt: float = 1.0
    delay: str | float = "off"
    delay_compensation: bool = False
    command_ramp: tuple[float, float] | None = None
    mpc_schedule: str = "ticks"
    sensor_noise: SensorNoise | None = None
    velocity_cutoff_hz: float | None = None
    scene: Sequence = ()
    disturbances: Sequence[Disturbance] = ()
    command_schedule: Callable[[float], dict] | None = None
    ground_friction: float = 0.8
    arm_gains: tuple[float, float] | None = None
    gait: Gait | GaitSchedule | None = None
    state: str = "ground_truth"
    hardware: HardwareProfile | None = None

    def __post_init__(self):
        if self.gait is not None and not isinstance(self.gait, Gait | GaitSchedule):
            raise ValueError(f"gait must be a Gait or GaitSchedule (wbmpc.ocp.gait), got {self.gait!r}")
        if not (
            self.delay in ("off", "measured") or (isinstance(self.delay, int | float) and self.delay >= 0)
        ):
            raise ValueError(f"delay must be 'off', 'measured' or seconds >= 0, got {self.delay!r}")
        if self.plant not in ("rigid", "pybullet"):
            raise ValueError(f"unknown plant {self.plant!r}; available: 'rigid', 'pybullet'")
        if self.mpc_schedule not in ("ticks", "free"):
            raise ValueError(
                f"ClosedLoopConfig.mpc_schedule must be 'ticks' or 'free', got {self.mpc_schedule!r}"
            )
        if self.joint_pd not in ("controller", "drive"):
            raise ValueError(
                f"ClosedLoopConfig.joint_pd must be 'controller' or 'drive', got {self.joint_pd!r}"
            )
        if self.ee_velocity_frame not in ("heading", "world"):
            raise ValueError(
                "ClosedLoopConfig.ee_velocity_frame must be 'heading' or 'world', "
                f"got {self.ee_velocity_frame!r}"
            )
        if self.plant == "rigid" and (self.scene or self.disturbances):
            raise ValueError(
                "scene objects and disturbances need plant='pybullet' (the rigid plant has none)"
            )
        for d in self.disturbances:
            if not isinstance(d, Kick | Push):
                raise ValueError(f"unknown disturbance {d!r}; use wbmpc.sim.disturbances.Kick or Push")
        self._check_numbers()
        self._check_state()

    def _check_state(self) -> None:
        if self.state not in ("ground_truth", "estimated"):
            raise ValueError(f"state must be 'ground_truth' or 'estimated', got {self.state!r}")
        if self.state == "estimated" and self.sensor_noise is not None:
            raise ValueError("sensor_noise is for state='ground_truth'; estimator errors are in hardware")
        if self.hardware is not None and not isinstance(self.hardware, HardwareProfile):
            raise ValueError(f"hardware must be a HardwareProfile or None, got {self.hardware!r}")
        if self.hardware is not None and self.plant != "pybullet":
            raise ValueError("hardware (the emulated robot) needs plant='pybullet'")

    def _check_numbers(self) -> None:
        """Rates, durations, gains and commands: finite, in range, right size (issue 12)."""
        name = "ClosedLoopConfig."
        for key, unit in (("duration", "s"), ("mpc_rate", "Hz"), ("low_level_rate", "Hz"), ("plant_dt", "s")):
            checks.number(name + key, getattr(self, key), low=0.0, low_open=True, unit=unit)
        if self.duration < self.plant_dt:
            raise ValueError(
                f"ClosedLoopConfig.duration = {self.duration} s is shorter than one plant step "
                f"(plant_dt = {self.plant_dt} s): nothing would be simulated"
            )
        if self.low_level_rate < self.mpc_rate:
            raise ValueError(
                f"ClosedLoopConfig.low_level_rate ({self.low_level_rate} Hz) must be >= mpc_rate "
                f"({self.mpc_rate} Hz): the low level interpolates each MPC plan"
            )
        for key in ("kp", "kd", "arm_kp", "ground_friction"):
            checks.number(name + key, getattr(self, key), low=0.0)
        if self.arm_gains is not None:
            gains = checks.vector(name + "arm_gains", self.arm_gains, 2)
            if np.any(gains < 0):
                raise ValueError(f"ClosedLoopConfig.arm_gains (kp, kd) must be >= 0, got {self.arm_gains!r}")
        checks.number(name + "max_tilt", self.max_tilt, low=0.0, low_open=True, unit="rad")
        checks.number(name + "base_yaw_rate", self.base_yaw_rate, unit="rad/s")
        for key in ("base_velocity", "ee_velocity", "ee_force"):
            checks.vector(name + key, getattr(self, key), 3)
        if isinstance(self.delay, int | float) and not isinstance(self.delay, bool):
            checks.number(name + "delay", self.delay, low=0.0, unit="s")
        if self.command_ramp is not None:
            limits = checks.vector(name + "command_ramp", self.command_ramp, 2)
            if np.any(limits <= 0):
                raise ValueError(
                    f"{name}command_ramp (linear, yaw) limits must be > 0, got {self.command_ramp!r}"
                )
        if self.velocity_cutoff_hz is not None:
            cutoff = self.velocity_cutoff_hz
            checks.number(name + "velocity_cutoff_hz", cutoff, low=0.0, low_open=True, unit="Hz")
        if self.arm_reference is not None and not isinstance(self.arm_reference, ArmReference):
            raise ValueError(
                f"ClosedLoopConfig.arm_reference must be an ArmReference or None, got {self.arm_reference!r}"
            )
        if self.sensor_noise is not None and not isinstance(self.sensor_noise, SensorNoise):
            raise ValueError(
                f"ClosedLoopConfig.sensor_noise must be a SensorNoise or None, got {self.sensor_noise!r}"
            )
        if self.command_schedule is not None and not callable(self.command_schedule):
            raise ValueError(
                "ClosedLoopConfig.command_schedule must be a function f(t) -> dict, "
                f"got {self.command_schedule!r}"
            )
        for d in self.disturbances:
            start = d.time if isinstance(d, Kick) else d.start
            if start >= self.duration:
                warnings.warn(
                    f"{d!r} starts at {start} s, after the end of the run (duration {self.duration} s): "
                    "it is never applied; lengthen the run or move it earlier",
                    stacklevel=4,
                )

    def steps(self) -> tuple[int, int, int]:
        """Total plant steps, plant steps per MPC update and per low-level update."""
        self.__post_init__()  # fields may have changed since construction
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
    """Time series of a run (low-level rate) and per-solve records (MPC rate).

    Held in memory by default. A streamed log (:meth:`streaming`) writes its rows to disk every
    ``chunk_steps`` plant steps (:class:`wbmpc.io.logs.LogWriter`) and empties its lists, per-solve
    ``timings`` included (``plans`` are not kept); after the run :attr:`path` is the consolidated ``.npz``
    log, and :meth:`arrays` and :meth:`run_log` read it from there.
    """

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
    reason: list = field(default_factory=list)
    ee_command: list = field(default_factory=list)
    timings: list = field(default_factory=list)
    plans: list = field(default_factory=list)
    q_meas: list = field(default_factory=list)
    v_meas: list = field(default_factory=list)
    contact_sim: list = field(default_factory=list)
    foot_forces: list = field(default_factory=list)
    ee_force_sim: list = field(default_factory=list)
    base_velocity_cmd: list = field(default_factory=list)
    base_yaw_rate_cmd: list = field(default_factory=list)
    ee_force_cmd: list = field(default_factory=list)
    apply_t: list = field(default_factory=list)
    plan_q: list = field(default_factory=list)
    plan_v: list = field(default_factory=list)
    plan_tau: list = field(default_factory=list)
    plan_forces: list = field(default_factory=list)
    scene_positions: list = field(default_factory=list)
    foot_height: list = field(default_factory=list)
    plan_contact: list = field(default_factory=list)
    hold: list = field(default_factory=list)
    path: Path | None = field(default=None, repr=False)  # the .npz log on disk, once a streamed run ends
    writer: LogWriter | None = field(default=None, repr=False)  # streaming: where the chunks go
    chunk_steps: int = 0  # streaming: plant steps per chunk
    summarize: Callable[[Mapping], dict] | None = field(default=None, repr=False)  # set by the run

    SOLVE_COLUMNS = (
        "solve_t",
        "apply_t",
        "solve_time",
        "iterations",
        "success",
        "fallback",
        "violation",
        "status",
        "reason",
        "ee_command",
        "plan_q",
        "plan_v",
        "plan_tau",
        "plan_forces",
        "plan_contact",
        "hold",
    )

    @classmethod
    def streaming(cls, path, chunk_steps: int, meta: dict | None = None) -> ClosedLoopLog:
        """A log written to ``path`` (``.npz``) in chunks of ``chunk_steps`` plant steps as the run goes."""
        if chunk_steps < 1:
            raise ValueError(f"a log chunk must hold at least one plant step, got {chunk_steps}")
        return cls(writer=LogWriter(path, meta), chunk_steps=chunk_steps)

    @classmethod
    def columns(cls) -> tuple[str, ...]:
        """Names of the logged series (list fields; ``plans`` and per-solve ``timings`` dicts excluded)."""
        skip = ("plans", "timings")
        return tuple(f.name for f in fields(cls) if f.default_factory is list and f.name not in skip)

    def arrays(self) -> dict[str, np.ndarray]:
        """Every series as a numpy array (read from disk for a streamed log; empty if never logged)."""
        if self.path is not None:
            run = load_log(self.path)
            return {k: np.asarray([]) for k in self.columns()} | run.solves | run.signals
        return {k: np.asarray(getattr(self, k)) for k in self.columns()}

    def run_log(self, meta: dict | None = None) -> RunLog:
        """The columnar log (:class:`wbmpc.io.logs.RunLog`): low-level-rate signals, one row per solve."""
        if self.path is not None:
            run = load_log(self.path)
            run.meta |= dict(meta or {})
            return run
        arrays = self.arrays()
        n_solves = len(self.solve_t)
        solves = {k: arrays[k] for k in self.SOLVE_COLUMNS if len(arrays[k]) == n_solves}
        solves["status"] = np.asarray([str(x) for x in self.status], dtype=str)
        solves["reason"] = np.asarray([str(x) for x in self.reason], dtype=str)
        skip = set(self.SOLVE_COLUMNS)
        signals = {k: v for k, v in arrays.items() if k not in skip and len(v) == len(self.t)}
        return RunLog(signals=signals, solves=solves, meta=dict(meta or {}))

    def tick(self, step: int) -> None:
        """Called at each plant step before anything of it is logged: a streamed log writes a chunk."""
        if self.writer is not None and step and step % self.chunk_steps == 0:
            self.flush()

    def flush(self) -> None:
        """Write the rows held in memory as the next chunk and empty every list (streamed log)."""
        self.writer.write_chunk(self.run_log())
        for name in (*self.columns(), "plans", "timings"):
            getattr(self, name).clear()

    def finish(self, summarize: Callable[[Mapping], dict], interrupted: str | None = None) -> dict | None:
        """End of the run: its summary, from memory or (streamed) from the consolidated log on disk.

        Args:
            summarize: ``f(columns) -> summary`` (columns by name, as :meth:`arrays`).
            interrupted: What stopped a streamed run early (stored in its ``meta``), or ``None``.
        """
        if self.writer is None:
            return summarize(self.arrays())
        if interrupted is not None:
            self._trim_unfinished_rows()
        self.flush()
        names = self.columns()
        meta = self.writer.close(lambda columns: summarize(_Columns(columns, names)), interrupted)
        self.path, self.writer = self.writer.path, None
        return meta.get("summary")

    def abort(self, exc: BaseException) -> None:
        """An exception stopped the run: a streamed log writes what it has, marked partial (then re-raise)."""
        if self.writer is None or self.writer.closed:
            return
        what = f"{type(exc).__name__}: {exc}"
        if isinstance(exc, KeyboardInterrupt):
            what = "KeyboardInterrupt (Ctrl-C)"
        try:
            self.finish(self.summarize or (lambda columns: None), interrupted=what)
        except Exception as error:  # noqa: BLE001 - the original exception is the one to raise
            exc.add_note(f"the partial log {self.writer.path} could not be written: {error!r}")

    def _trim_unfinished_rows(self) -> None:
        """Drop the rows an interruption left half-appended (a table's columns end at its shortest)."""
        solve_columns = [k for k in self.SOLVE_COLUMNS if getattr(self, k)]
        signal_columns = [k for k in self.columns() if k not in self.SOLVE_COLUMNS and getattr(self, k)]
        for names in (solve_columns, signal_columns):
            n = min((len(getattr(self, k)) for k in names), default=0)
            for k in names:
                del getattr(self, k)[n:]
        del self.timings[len(self.solve_t) :]
        del self.plans[len(self.solve_t) :]


class _Columns(Mapping):
    """Columns read from disk, with the log's never-filled series as empty arrays (as in memory)."""

    def __init__(self, columns: Mapping, names: Sequence[str]):
        self._columns, self._names = columns, tuple(names)

    def __getitem__(self, name: str) -> np.ndarray:
        if name in self._columns:
            return self._columns[name]
        if name in self._names:
            return np.asarray([])
        raise KeyError(name)

    def __iter__(self):
        return iter(dict.fromkeys((*self._names, *self._columns)))

    def __len__(self) -> int:
        return len(dict.fromkeys((*self._names, *self._columns)))


@dataclass
class ClosedLoopResult:
    log: ClosedLoopLog
    summary: dict
    fell: bool

    def run_log(self) -> RunLog:
        """The columnar log with the summary as metadata."""
        return self.log.run_log({"summary": self.summary})

    def save(self, path) -> str:
        """Write the columnar log (``.npz``, see :mod:`wbmpc.io.logs`); returns the path.

        A streamed run's log is already on disk (``result.log.path``): it is copied.
        """
        if self.log.path is None:
            return str(save_log(self.run_log(), path))
        target = Path(path) if Path(path).suffix == ".npz" else Path(f"{path}.npz")
        if target.resolve() != self.log.path.resolve():
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(self.log.path, target)
        return str(target)


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


def blasfeo_record() -> dict:
    """Which BLASFEO Fatrop ran on (see :mod:`wbmpc.solver.blasfeo`), for run summaries."""
    from wbmpc.solver import blasfeo

    info = blasfeo.info()
    return {k: info.get(k) for k in ("choice", "reason", "library", "target", "library_features")}


def summarize(
    mpc: WholeBodyMPC,
    log: ClosedLoopLog | Mapping[str, np.ndarray],
    config: ClosedLoopConfig,
    fell: bool,
    torque_violations: int,
    plant: ContactPlant | None = None,
) -> dict:
    """Key numbers of a run: solve-time statistics (in-process), convergence, tracking, safety.

    ``log`` is the run's log or its columns by name (:meth:`ClosedLoopLog.arrays`).
    """
    arrays = log if isinstance(log, Mapping) else log.arrays()
    solve_ms = 1e3 * arrays["solve_time"]
    warm = solve_ms[1:] if solve_ms.size > 1 else solve_ms
    iters = arrays["iterations"][1:] if arrays["iterations"].size > 1 else arrays["iterations"]
    ee_err = (
        np.linalg.norm(arrays["ee_position"] - arrays["ee_reference"], axis=1)
        if len(arrays["t"])
        else np.array([])
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
        "duration_s": float(arrays["t"][-1]) if len(arrays["t"]) else 0.0,
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
        "max_tilt_rad": float(np.max(tilt(np.asarray(q)))) if len(q) else None,
        "base_height_range_m": [float(q[:, 2].min()), float(q[:, 2].max())] if len(q) else None,
        "distance_travelled_m": float(np.linalg.norm(q[-1, :2] - q[0, :2])) if len(q) else None,
        "torque_violations": int(torque_violations),
        "fell": bool(fell),
        "low_level": {
            "kp": config.kp,
            "kd": config.kd,
            "arm_gains": list(config.arm_gains) if config.arm_gains is not None else None,
            "rate_hz": config.low_level_rate,
        },
        "delay": config.delay,
        "sensor_noise": None if config.sensor_noise is None else vars(config.sensor_noise),
        "velocity_cutoff_hz": config.velocity_cutoff_hz,
        "mpc_rate_hz": config.mpc_rate,
        "plant_dt_s": config.plant_dt,
        "machine": machine_description(),
        "blasfeo": blasfeo_record(),
    }
    if plant is not None:
        summary["contact_violations"] = {k: int(np.sum(v)) for k, v in plant.violation_counts.items()}
        summary["contact_violations_counted_as"] = (
            "plant steps x feet: stance foot pulling / outside the friction cone; swing foot more than "
            "0.1 mm below the ground"
        )
    summary |= _contact_summary(mpc, arrays)
    summary["tracking"] = command_tracking(arrays)
    return summary


def base_velocity_heading(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Base velocity (T, 3) in the heading frame: forward [m/s], left [m/s], yaw rate [rad/s], from
    configurations (T, nq) and velocities (T, nv) (base-frame twist, Pinocchio's free-flyer convention)."""
    q, v = np.atleast_2d(q), np.atleast_2d(v)
    out = np.empty((len(q), 3))
    for k, (qk, vk) in enumerate(zip(q, v, strict=True)):
        R = pin.Quaternion(qk[3:7]).normalized().toRotationMatrix()
        linear, angular = R @ vk[0:3], R @ vk[3:6]
        yaw = np.arctan2(R[1, 0], R[0, 0])
        c, s = np.cos(yaw), np.sin(yaw)
        out[k] = (c * linear[0] + s * linear[1], -s * linear[0] + c * linear[1], angular[2])
    return out


def command_tracking(arrays: Mapping[str, np.ndarray], settle: float = 1.0) -> list[dict]:
    """Commanded against achieved base velocity over each stretch of constant command.

    Args:
        arrays: The run's columns (``t``, ``q``, ``v``, ``base_velocity_cmd``, ``base_yaw_rate_cmd``).
        settle: Time [s] after each change of command left out of the averages.

    Returns:
        One dict per stretch: ``t_start``, ``t_end`` [s] (the averaged window), ``commanded`` and
        ``achieved`` ``[forward m/s, left m/s, yaw rate rad/s]`` (heading frame, signed, true state), and
        ``ratio`` (achieved / commanded per component, ``None`` where the command is 0).
    """
    t = np.asarray(arrays["t"], float)
    if t.size < 2 or not len(arrays.get("base_velocity_cmd", ())):
        return []
    linear = np.asarray(arrays["base_velocity_cmd"], float)[:, :2]
    cmd = np.column_stack([linear, np.asarray(arrays["base_yaw_rate_cmd"], float)])
    achieved = base_velocity_heading(arrays["q"], arrays["v"])
    change = np.flatnonzero(np.any(np.abs(np.diff(cmd, axis=0)) > 1e-12, axis=1)) + 1
    out = []
    for start, end in zip(np.r_[0, change], np.r_[change, t.size], strict=True):
        window = t[start:end] >= t[start] + settle
        if window.sum() < 2:
            continue
        c, a = cmd[start], achieved[start:end][window].mean(axis=0)
        out.append(
            {
                "t_start": float(t[start:end][window][0]),
                "t_end": float(t[start:end][window][-1]),
                "commanded": c.tolist(),
                "achieved": a.tolist(),
                "ratio": [float(ai / ci) if abs(ci) > 1e-9 else None for ai, ci in zip(a, c, strict=True)],
            }
        )
    return out


def _contact_summary(mpc: WholeBodyMPC, arrays: dict) -> dict:
    """Swing-foot clearance and agreement of the MPC's first-stage contacts with the plant's schedule."""
    out = {"holds": int(np.sum(arrays["hold"])) if arrays["hold"].size else 0}
    if arrays["foot_height"].size:
        swing = ~np.asarray(arrays["contact"], bool)
        heights = arrays["foot_height"][swing]
        out["swing_foot_min_height_m"] = float(heights.min()) if heights.size else None
    if arrays["plan_contact"].size:
        fresh = np.asarray(arrays["success"], bool) & ~np.asarray(arrays["fallback"], bool)
        plant = mpc.config.gait.sample(arrays["solve_t"]).contact.T
        out["node0_contact_mismatches"] = int(np.sum(np.any(arrays["plan_contact"] != plant, axis=1) & fresh))
    return out
