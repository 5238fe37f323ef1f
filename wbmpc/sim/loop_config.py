"""The closed loop's configuration: plant, rates, controller gains, delay, state, commands, disturbances.

:class:`ClosedLoopConfig` is what :func:`wbmpc.sim.closed_loop.run_closed_loop` runs; presets that fill it
for a purpose are in :mod:`wbmpc.sim.presets`.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from wbmpc import checks
from wbmpc.control.arm_task import ArmReference
from wbmpc.ocp.gait import Gait, GaitSchedule
from wbmpc.sim.disturbances import Disturbance, Kick, Push
from wbmpc.sim.hardware import HardwareProfile
from wbmpc.sim.sensing import SensorNoise


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
        """Rates, durations, gains and commands: finite, in range, right size."""
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
