"""The closed loop's configuration, one dataclass per component, nested in :class:`ClosedLoopConfig`.

* :class:`~wbmpc.control.command_schedule.CommandSchedule`: what the robot is asked (base and arm commands
  over time, the gait);
* :class:`PlantConfig`: the simulated robot (rigid or PyBullet plant, its step, ground, scene objects, the
  emulated hardware's mismatches);
* :class:`LowLevelConfig`: the 500 Hz joint level (rate, PD gains, where the PD law runs);
* :class:`SensingConfig`: what the controller sees (ground truth, noise, filter, or the state estimator);
* :class:`ClosedLoopConfig`: those plus the MPC's timing (rate, computation delay), the arm task's gains,
  disturbances and the run's length.

:func:`wbmpc.sim.closed_loop.run_closed_loop` runs a :class:`ClosedLoopConfig`; presets that fill it for a
purpose are in :mod:`wbmpc.sim.presets`.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from wbmpc import checks
from wbmpc.control.command_schedule import CommandSchedule
from wbmpc.sim.disturbances import Disturbance, Kick, Push
from wbmpc.sim.hardware import HardwareProfile
from wbmpc.sim.sensing import SensorNoise

__all__ = ["ClosedLoopConfig", "CommandSchedule", "LowLevelConfig", "PlantConfig", "SensingConfig"]


@dataclass
class PlantConfig:
    """The simulated robot.

    Attributes:
        kind: ``"rigid"`` (Pinocchio forward dynamics, scheduled feet in rigid contact: the paper's
            benchmark) or ``"pybullet"`` (a physics engine: contacts happen, feet can slip).
        dt: Integration step [s]; must divide the MPC and low-level periods.
        ground_friction: Ground friction coefficient (PyBullet).
        scene: PyBullet scene objects (:class:`~wbmpc.sim.scene.Box`, ``Wall``, ``Payload``).
        hardware: The emulated robot's mismatches (:class:`wbmpc.sim.hardware.HardwareProfile`; PyBullet
            only): the motors' friction, armature and torque latency (:mod:`wbmpc.sim.actuators`), the base
            centre-of-mass offset, the IMU and encoder errors the state estimator reads. ``None``: nominal.
    """

    kind: str = "rigid"
    dt: float = 0.0005
    ground_friction: float = 0.8
    scene: Sequence = ()
    hardware: HardwareProfile | None = None

    def __post_init__(self):
        self.check()

    def check(self) -> None:
        """Validate the fields; raises ``ValueError`` naming the field."""
        if self.kind not in ("rigid", "pybullet"):
            raise ValueError(f"unknown plant {self.kind!r}; available: 'rigid', 'pybullet'")
        checks.number("PlantConfig.dt", self.dt, low=0.0, low_open=True, unit="s")
        checks.number("PlantConfig.ground_friction", self.ground_friction, low=0.0)
        if self.hardware is not None and not isinstance(self.hardware, HardwareProfile):
            raise ValueError(f"PlantConfig.hardware must be a HardwareProfile or None, got {self.hardware!r}")
        if self.hardware is not None and self.kind != "pybullet":
            raise ValueError("hardware (the emulated robot) needs PlantConfig(kind='pybullet')")
        if self.kind == "rigid" and self.scene:
            raise ValueError("scene objects need PlantConfig(kind='pybullet') (the rigid plant has none)")


@dataclass
class LowLevelConfig:
    """The joint level between the MPC's plans and the motors.

    Attributes:
        rate: Interpolation + PD rate [Hz] (paper: 500).
        kp, kd: Joint PD gains [N m/rad], [N m s/rad] (paper, simulation without delay: 0).
        arm_gains: ``(kp, kd)`` of the arm joints if different from the legs' (e.g. a compliant arm).
        joint_pd: Where the PD law runs: ``"controller"`` (the low level computes the torque from the
            controller's state and the plant applies it, the paper's simulation) or ``"drive"``
            (:class:`wbmpc.sim.motor_drive.MotorDrive`: the low level sends setpoints, feed-forward and gains
            and the motor drivers evaluate the law at every plant step on the joint encoders, as Unitree's
            robots do; a hardware profile's torque latency then delays the setpoints, not the damping loop).
        friction_feedforward: When the MPC's robot carries a calibration (``load_b1_z1(calibration=...)``),
            add its identified joint friction at the desired joint rates; False: never.
    """

    rate: float = 500.0
    kp: float = 0.0
    kd: float = 0.0
    arm_gains: tuple[float, float] | None = None
    joint_pd: str = "controller"
    friction_feedforward: bool = True

    def __post_init__(self):
        self.check()

    def check(self) -> None:
        """Validate the fields; raises ``ValueError`` naming the field."""
        name = "LowLevelConfig."
        checks.number(name + "rate", self.rate, low=0.0, low_open=True, unit="Hz")
        for key in ("kp", "kd"):
            checks.number(name + key, getattr(self, key), low=0.0)
        if self.arm_gains is not None:
            gains = checks.vector(name + "arm_gains", self.arm_gains, 2)
            if np.any(gains < 0):
                raise ValueError(f"{name}arm_gains (kp, kd) must be >= 0, got {self.arm_gains!r}")
        if self.joint_pd not in ("controller", "drive"):
            raise ValueError(f"{name}joint_pd must be 'controller' or 'drive', got {self.joint_pd!r}")


@dataclass
class SensingConfig:
    """What the MPC and the low level see of the plant's state.

    Attributes:
        state: ``"ground_truth"`` (the plant's state through ``noise`` and the velocity filter) or
            ``"estimated"`` (the state estimator :class:`wbmpc.estimation.StateEstimator` at the low-level
            rate on synthesised IMU and encoder readings, with the errors of the plant's ``hardware`` (exact
            without one), contacts from the MPC's contact plan, joint rates filtered at
            ``velocity_cutoff_hz``). The log keeps both: ``q``, ``v`` true, ``q_meas``, ``v_meas`` seen.
        noise: Measurement noise of the ground truth (``None``: exact).
        velocity_cutoff_hz: Joint-velocity low-pass cut-off [Hz] (paper: 50; ``None``: unfiltered).
    """

    state: str = "ground_truth"
    noise: SensorNoise | None = None
    velocity_cutoff_hz: float | None = None

    def __post_init__(self):
        self.check()

    def check(self) -> None:
        """Validate the fields; raises ``ValueError`` naming the field."""
        if self.state not in ("ground_truth", "estimated"):
            raise ValueError(f"SensingConfig.state must be 'ground_truth' or 'estimated', got {self.state!r}")
        if self.noise is not None and not isinstance(self.noise, SensorNoise):
            raise ValueError(f"SensingConfig.noise must be a SensorNoise or None, got {self.noise!r}")
        if self.state == "estimated" and self.noise is not None:
            raise ValueError(
                "SensingConfig.noise is for state='ground_truth'; estimator errors are in hardware"
            )
        if self.velocity_cutoff_hz is not None:
            checks.number(
                "SensingConfig.velocity_cutoff_hz", self.velocity_cutoff_hz, low=0.0, low_open=True, unit="Hz"
            )


@dataclass
class ClosedLoopConfig:
    """Settings of a closed-loop run: the components' configs, the MPC's timing and the run's events.

    Attributes:
        duration: Simulated time [s].
        commands: What the robot is asked over the run, gait included
            (:class:`~wbmpc.control.command_schedule.CommandSchedule`).
        plant: The simulated robot (:class:`PlantConfig`).
        low_level: The joint level (:class:`LowLevelConfig`).
        sensing: What the controller sees (:class:`SensingConfig`).
        mpc_rate: MPC update rate [Hz] (paper: 80).
        delay: Computation delay: ``"off"`` (simulated time waits for each solve, as in the paper's first
            simulations), ``"measured"`` (the wall time of each whole
            :meth:`~wbmpc.control.mpc.WholeBodyMPC.solve` call) or seconds.
        delay_compensation: With a delay, plan from the state predicted for the time the plan will arrive
            (:mod:`wbmpc.control.delay`) instead of from the measurement's own time.
        mpc_schedule: When solves start: ``"ticks"`` (on the MPC rate's ticks, the first one after the
            previous plan arrived: a solve slightly longer than a period halves the rate) or ``"free"`` (at
            the first low-level tick after the previous plan arrived, but no sooner than one MPC period
            after the previous solve started: an asynchronous MPC worker that restarts when it is done).
        arm_kp: Position gain [1/s] of the arm reference feedback (and of the heading-frame hold).
        arm_preview: One end-effector velocity per MPC stage from the reference's future (True), or the
            paper's single velocity held over the horizon (False).
        max_tilt: Roll/pitch [rad] beyond which the run counts as a fall.
        disturbances: :class:`~wbmpc.sim.disturbances.Kick` and ``Push`` events (PyBullet plant).

    Raises:
        ValueError: On any field out of range (named), checked at construction and again when a run starts.
    """

    duration: float = 10.0
    commands: CommandSchedule = field(default_factory=CommandSchedule)
    plant: PlantConfig = field(default_factory=PlantConfig)
    low_level: LowLevelConfig = field(default_factory=LowLevelConfig)
    sensing: SensingConfig = field(default_factory=SensingConfig)
    mpc_rate: float = 80.0
    delay: str | float = "off"
    delay_compensation: bool = False
    mpc_schedule: str = "ticks"
    arm_kp: float = 4.0
    arm_preview: bool = True
    max_tilt: float = 1.0
    disturbances: Sequence[Disturbance] = ()

    def __post_init__(self):
        self.check()

    def check(self) -> None:
        """Validate this config and its components (also after fields were changed in place)."""
        parts = (
            ("commands", CommandSchedule),
            ("plant", PlantConfig),
            ("low_level", LowLevelConfig),
            ("sensing", SensingConfig),
        )
        for key, kind in parts:
            if not isinstance(getattr(self, key), kind):
                raise ValueError(
                    f"ClosedLoopConfig.{key} must be a {kind.__name__}, got {getattr(self, key)!r}"
                )
            getattr(self, key).check()
        if not (
            self.delay in ("off", "measured") or (isinstance(self.delay, int | float) and self.delay >= 0)
        ):
            raise ValueError(f"delay must be 'off', 'measured' or seconds >= 0, got {self.delay!r}")
        if self.mpc_schedule not in ("ticks", "free"):
            raise ValueError(
                f"ClosedLoopConfig.mpc_schedule must be 'ticks' or 'free', got {self.mpc_schedule!r}"
            )
        if self.plant.kind == "rigid" and self.disturbances:
            raise ValueError("disturbances need PlantConfig(kind='pybullet') (the rigid plant has none)")
        for d in self.disturbances:
            if not isinstance(d, Kick | Push):
                raise ValueError(f"unknown disturbance {d!r}; use wbmpc.sim.disturbances.Kick or Push")
        self._check_numbers()

    def _check_numbers(self) -> None:
        """Rates, durations and gains: finite and in range."""
        name = "ClosedLoopConfig."
        for key, unit in (("duration", "s"), ("mpc_rate", "Hz")):
            checks.number(name + key, getattr(self, key), low=0.0, low_open=True, unit=unit)
        if self.duration < self.plant.dt:
            raise ValueError(
                f"ClosedLoopConfig.duration = {self.duration} s is shorter than one plant step "
                f"(PlantConfig.dt = {self.plant.dt} s): nothing would be simulated"
            )
        if self.low_level.rate < self.mpc_rate:
            raise ValueError(
                f"LowLevelConfig.rate ({self.low_level.rate} Hz) must be >= ClosedLoopConfig.mpc_rate "
                f"({self.mpc_rate} Hz): the low level interpolates each MPC plan"
            )
        checks.number(name + "arm_kp", self.arm_kp, low=0.0)
        checks.number(name + "max_tilt", self.max_tilt, low=0.0, low_open=True, unit="rad")
        if isinstance(self.delay, int | float) and not isinstance(self.delay, bool):
            checks.number(name + "delay", self.delay, low=0.0, unit="s")
        for d in self.disturbances:
            start = d.time if isinstance(d, Kick) else d.start
            if start >= self.duration:
                warnings.warn(
                    f"{d!r} starts at {start} s, after the end of the run (duration {self.duration} s): "
                    "it is never applied; lengthen the run or move it earlier",
                    stacklevel=4,
                )

    def steps(self) -> tuple[int, int, int]:
        """Total plant steps, plant steps per MPC update and per low-level update (checks the config)."""
        self.check()  # fields may have changed since construction
        dt = self.plant.dt
        per_mpc = round(1.0 / (self.mpc_rate * dt))
        per_low = round(1.0 / (self.low_level.rate * dt))
        if abs(per_mpc * dt * self.mpc_rate - 1) > 1e-9 or abs(per_low * dt * self.low_level.rate - 1) > 1e-9:
            raise ValueError(
                f"PlantConfig.dt={dt} s must divide the MPC period 1/{self.mpc_rate} s and the "
                f"low-level period 1/{self.low_level.rate} s"
            )
        return round(self.duration / dt), per_mpc, per_low
