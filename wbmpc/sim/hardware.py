"""An emulated robot: the PyBullet plant with the errors of hardware, and the state estimator in the loop.

On the robot the MPC differs from the simulation in ways its model does not know about:
the motors have friction and rotor inertia, the base centre of mass sits far from the model's (the B1's
rear legs carry about 60 % of the weight), torque commands arrive a few milliseconds late, nothing measures
the floating base (a state estimator reconstructs it from a noisy, biased IMU and noisy encoders) and the
solve takes real time. :class:`HardwareProfile` collects these mismatches, each one switchable, with its
value; the MPC keeps its nominal model.

Two ways to use it:

* ``ClosedLoopConfig(plant=PlantConfig("pybullet", hardware=profile), sensing=SensingConfig("estimated"))``
  applies the robot side of a profile: the motors' friction, armature and latency
  (:class:`wbmpc.sim.actuators.MotorModel`, :meth:`HardwareProfile.motor_model`), the base's
  centre-of-mass offset, and the IMU and encoder errors the estimator reads; every controller setting
  stays the config's own.
* :func:`wbmpc.sim.presets.hardware_config` is the preset: the same plus the controller a Unitree robot runs
  (estimated state, measured computation delay, compensated, the hardware low-level gains, the 50 Hz
  joint-velocity filter, the joint PD law in the motor drivers, ramped velocity commands),
  e.g. ``run_closed_loop(mpc, hardware_config(duration=10.0))``.

What the mismatches do to the MPC (``data/hardware/fall_ablation.json``; fixed 12.5 ms delay):

* Without the rotor inertia, the 3 ms torque latency (and, less, the sensor noise) destabilises the legs'
  damping loop ``Kd (v_des - v)`` behind the 50 Hz filter in swing: calf speeds beyond their limits, torques
  at 140 N m. The reflected rotor inertia (``leg_armature``) lowers the swing legs' crossover ``Kd / I``
  enough that the same latency does no visible harm. Motor friction is harmless.
* The base CoM offset makes the nominal MPC lean back (pitch -0.18 rad trotting, rear calves at their torque
  limit, the base drifting backwards instead of trotting forward: ``data/hardware/emulated_b1_stand_trot``).
  The offset identified from a log (:func:`wbmpc.analysis.identify_com_offset`) put into the
  MPC's model and force targets (:func:`wbmpc.model.base_com.shift_base_com`) removes the lean: the
  paper's fix.
* ``delay="measured"`` on a machine where solves take ~10 MPC periods (this 2-core one) adds a plan ~0.1 s
  old on top; the fixed delay separates the robot's mismatches from the machine's speed.

:class:`EstimatedState` is the estimator in the loop: at the low-level rate it synthesises an IMU reading
from two consecutive true states (:func:`wbmpc.estimation.synthesize_imu`) and encoder readings, takes the
contacts from the MPC's contact plan (the gait schedule with any swing aborted after a push, through
:class:`PlannedContacts`; :func:`wbmpc.estimation.contact_trust`) and runs
:class:`wbmpc.estimation.StateEstimator`; the controller sees its estimate instead of the plant's state.
"""

from __future__ import annotations

import math
import numbers
import operator
import sys
from dataclasses import asdict, dataclass, field, fields
from types import SimpleNamespace

import numpy as np

from wbmpc.estimation import (
    EstimatorNoise,
    ImuNoise,
    ImuReading,
    JointReading,
    StateEstimator,
    contact_trust,
    synthesize_imu,
)
from wbmpc.estimation.filters import trust_offsets, window_trust
from wbmpc.model.quaternion import base_z_axis
from wbmpc.sim.actuators import MotorModel

__all__ = [
    "EstimatedState",
    "SyntheticSensors",
    "PlannedContacts",
    "HardwareProfile",
    "estimate_errors",
    "rear_leg_share",
]

#: A MEMS-grade IMU after its start-up calibration (white noise per 500 Hz sample, constant biases).
_HARDWARE_IMU = ImuNoise(
    gyro=0.003,
    accelerometer=0.05,
    gyro_bias=(0.005, -0.004, 0.003),
    accelerometer_bias=(0.05, -0.03, 0.04),
)


@dataclass(frozen=True)
class HardwareProfile:
    """The mismatches of the emulated robot, each switchable (0 or ``None`` turns one off).

    Leg values are per joint of a leg (hip, thigh, calf), repeated for the four legs; arm values apply to
    every actuated arm joint. :meth:`ideal` gives a profile with every mismatch off.

    Attributes:
        leg_coulomb: Motor Coulomb friction of the leg joints [N m] (hip, thigh, calf).
        leg_viscous: Motor viscous friction of the leg joints [N m s/rad].
        leg_armature: Reflected rotor inertia of the leg joints [kg m^2] (rotor ~1-3e-4 kg m^2 times a
            gear ratio of ~10-15 squared; the calf's gearing is the highest).
        arm_coulomb: Motor Coulomb friction of the arm joints [N m], on top of the URDF's (1-2 N m, which
            the plant applies anyway).
        arm_viscous: Motor viscous friction of the arm joints [N m s/rad], on top of the URDF's damping.
        arm_armature: Reflected rotor inertia of the arm joints [kg m^2].
        friction_velocity: Joint rate [rad/s] over which the Coulomb friction rises (``tanh`` smoothing).
        base_com_offset: Shift of the base link's centre of mass [m], base frame (x forward). The default
            moves it 19 cm backwards: the rear legs then carry ~60 % of the weight standing (48 % nominal).
        torque_latency: Delay of the torque commands on their way to the motors [s].
        encoder_noise: Joint-angle noise [rad] (standard deviation per sample).
        encoder_velocity_noise: Joint-rate noise [rad/s] per sample, before the 50 Hz filter.
        imu: IMU white noise and constant biases (:class:`wbmpc.estimation.ImuNoise`); ``None``: exact.
        estimator: Tuning of the state estimator (``None``: the defaults of
            :class:`wbmpc.estimation.EstimatorNoise`).
        seed: Seed of the sensor noise.
    """

    leg_coulomb: tuple[float, float, float] = (1.0, 1.0, 1.0)
    leg_viscous: tuple[float, float, float] = (0.2, 0.2, 0.2)
    leg_armature: tuple[float, float, float] = (0.02, 0.02, 0.04)
    arm_coulomb: float = 0.3
    arm_viscous: float = 0.1
    arm_armature: float = 0.005
    friction_velocity: float = 0.05
    base_com_offset: tuple[float, float, float] | None = (-0.19, 0.0, 0.0)
    torque_latency: float = 0.003
    encoder_noise: float = 5e-4
    encoder_velocity_noise: float = 0.05
    imu: ImuNoise | None = field(default_factory=lambda: _HARDWARE_IMU)
    estimator: EstimatorNoise | None = None
    seed: int = 0

    def __post_init__(self):
        for name in ("leg_coulomb", "leg_viscous", "leg_armature"):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.shape != (3,) or not np.all(np.isfinite(value)) or np.any(value < 0):
                raise ValueError(
                    f"HardwareProfile.{name} must be 3 values >= 0 (hip, thigh, calf), got {value}"
                )
        for name in ("arm_coulomb", "arm_viscous", "arm_armature", "torque_latency", "encoder_noise"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"HardwareProfile.{name} must be finite and >= 0, got {value!r}")
        if not (np.isfinite(self.encoder_velocity_noise) and self.encoder_velocity_noise >= 0):
            raise ValueError(
                f"HardwareProfile.encoder_velocity_noise must be >= 0, got {self.encoder_velocity_noise}"
            )
        if not (np.isfinite(self.friction_velocity) and self.friction_velocity > 0):
            raise ValueError(f"HardwareProfile.friction_velocity must be > 0, got {self.friction_velocity!r}")
        if self.base_com_offset is not None:
            offset = np.asarray(self.base_com_offset, dtype=float)
            if offset.shape != (3,) or not np.all(np.isfinite(offset)):
                raise ValueError(f"HardwareProfile.base_com_offset must be 3 finite values, got {offset}")
        if self.imu is not None and not isinstance(self.imu, ImuNoise):
            raise ValueError(f"HardwareProfile.imu must be an ImuNoise or None, got {self.imu!r}")

    @classmethod
    def ideal(cls, **changes) -> HardwareProfile:
        """A profile with every mismatch off (the nominal robot, exact sensors), then ``changes``."""
        off = {
            "leg_coulomb": (0.0, 0.0, 0.0),
            "leg_viscous": (0.0, 0.0, 0.0),
            "leg_armature": (0.0, 0.0, 0.0),
            "arm_coulomb": 0.0,
            "arm_viscous": 0.0,
            "arm_armature": 0.0,
            "base_com_offset": None,
            "torque_latency": 0.0,
            "encoder_noise": 0.0,
            "encoder_velocity_noise": 0.0,
            "imu": None,
        }
        return cls(**(off | changes))

    def motor_model(self, robot) -> MotorModel:
        """The motors of this profile for ``robot``'s joints (legs of 3 joints: hip, thigh, calf).

        Raises:
            ValueError: If the robot's leg joints do not come in threes.
        """
        arm = set(robot.arm_joint_names) if robot.has_arm else set()
        legs = [name for name in robot.joint_names if name not in arm]
        if len(legs) % 3:
            raise ValueError(f"expected legs of 3 joints (hip, thigh, calf), got leg joints {legs}")

        def per_joint(leg_values, arm_value):
            leg_values = iter(np.tile(leg_values, len(legs) // 3))
            return np.array([arm_value if name in arm else next(leg_values) for name in robot.joint_names])

        return MotorModel(
            coulomb=per_joint(self.leg_coulomb, self.arm_coulomb),
            viscous=per_joint(self.leg_viscous, self.arm_viscous),
            friction_velocity=self.friction_velocity,
            armature=per_joint(self.leg_armature, self.arm_armature),
            latency=self.torque_latency,
        )

    def describe(self) -> dict:
        """The profile as plain JSON-ready values (for run summaries)."""
        out = {f.name: getattr(self, f.name) for f in fields(self)}
        out["imu"] = None if self.imu is None else asdict(self.imu)
        out["estimator"] = None if self.estimator is None else asdict(self.estimator)
        return {k: list(v) if isinstance(v, tuple) else v for k, v in out.items()}


class PlannedContacts:
    """A contact plan ``plan(times) -> (n_feet, n)`` flags seen as a gait schedule (``contact(t)``,
    ``sample(times).contact``), e.g. :meth:`wbmpc.control.mpc.WholeBodyMPC.contact_plan`: the schedule with
    the swings aborted after a push, so that the estimator trusts the legs the controller put down. Each
    column of the plan depends on its own time only (the estimator samples it once per update)."""

    def __init__(self, plan):
        if not callable(plan):
            raise ValueError(f"plan must be a function times -> contact flags (n_feet, n), got {plan!r}")
        self.plan = plan

    def sample(self, times) -> SimpleNamespace:
        times = np.atleast_1d(np.asarray(times, dtype=float))
        return SimpleNamespace(contact=np.asarray(self.plan(times), dtype=bool))

    def contact(self, t: float) -> np.ndarray:
        return self.sample([t]).contact[:, 0]


class SyntheticSensors:
    """The robot's IMU and encoders, read off the true state: what a robot's ``rt/lowstate`` carries.

    Args:
        dt: Sample period [s] (the IMU is synthesised from two consecutive true states this far apart).
        profile: Sensor errors (``imu``, ``encoder_noise``, ``encoder_velocity_noise``, ``seed``);
            ``None``: exact sensors.
    """

    def __init__(self, dt: float, profile: HardwareProfile | None = None):
        self.profile = profile or HardwareProfile.ideal()
        self.dt = float(dt)
        self._rng = np.random.default_rng(self.profile.seed)
        self._prev: tuple[np.ndarray, np.ndarray] | None = None

    def reset(self, q: np.ndarray, v: np.ndarray) -> None:
        """Start from the true state ``(q, v)`` (the noise restarts from the profile's seed)."""
        self._rng = np.random.default_rng(self.profile.seed)
        self._prev = (q.copy(), v.copy())

    def readings(self, q: np.ndarray, v: np.ndarray) -> tuple[ImuReading, JointReading]:
        """The IMU and encoder readings of the true state ``(q, v)`` one period after the previous one.

        Raises:
            RuntimeError: before :meth:`reset`.
        """
        if self._prev is None:
            raise RuntimeError("call reset(q0, v0) first")
        n, rng = self.profile, self._rng
        imu = synthesize_imu(q, v, *self._prev, self.dt, noise=n.imu, rng=rng)
        nj = q.size - 7
        joints = JointReading(
            q[7:] + n.encoder_noise * rng.standard_normal(nj),
            v[6:] + n.encoder_velocity_noise * rng.standard_normal(nj),
        )
        self._prev = (q.copy(), v.copy())
        return imu, joints


class EstimatedState:
    """The state estimator in the closed loop, fed with synthesised IMU and encoder readings.

    Args:
        robot: The robot.
        schedule: Gait, gait schedule or :class:`PlannedContacts` deciding the contacts (``contact(t)``,
            ``sample(times)``).
        dt: Sample period [s] (the low-level period: one :meth:`measure` per period).
        profile: Sensor errors and estimator tuning (``imu``, ``encoder_noise``, ``encoder_velocity_noise``,
            ``estimator``, ``seed``); ``None``: exact sensors.
        velocity_cutoff_hz: Joint-velocity low-pass cut-off [Hz] of the estimator (``None``: unfiltered).
    """

    def __init__(
        self, robot, schedule, dt: float, profile: HardwareProfile | None = None, velocity_cutoff_hz=50.0
    ):
        self.profile = profile or HardwareProfile.ideal()
        self.schedule = schedule
        self.dt = float(dt)
        self.estimator = StateEstimator(
            robot, self.dt, self.profile.estimator, velocity_cutoff_hz=velocity_cutoff_hz
        )
        self.sensors = SyntheticSensors(self.dt, self.profile)

    def reset(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Start from the true state (the robot at rest before the run); returns it as the first estimate."""
        self.estimator.reset(q, v)
        self.sensors.reset(q, v)
        return q.copy(), v.copy()

    def readings(self, q: np.ndarray, v: np.ndarray) -> tuple[ImuReading, JointReading]:
        """The IMU and encoder readings of the true state ``(q, v)`` one period after the previous one."""
        return self.sensors.readings(q, v)

    def measure(self, q: np.ndarray, v: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The estimate ``(q_hat, v_hat)`` from the readings of the true state ``(q, v)`` at ``t`` [s]."""
        imu, joints = self.readings(q, v)
        return self.update(imu, joints, t)

    def update(
        self, imu: ImuReading, joints: JointReading, t: float, periods: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        """The estimate ``(q_hat, v_hat)`` from readings taken at ``t`` [s] (the contacts of the schedule
        then).

        Args:
            periods: Sample periods the readings stand for (> 1: they superseded older ones, which were
                lost or skipped). The filter advances one period per update, so it is advanced over each
                missing period too, with these readings held, at that period's time: fed only the newest
                readings it would under-count time (the integrated position lagging the truth).
        """
        for k in range(periods - 1, 0, -1):
            self._update_once(imu, joints, t - k * self.dt)
        return self._update_once(imu, joints, t)

    def _update_once(self, imu: ImuReading, joints: JointReading, t: float) -> tuple[np.ndarray, np.ndarray]:
        schedule, estimator = self.schedule, self.estimator
        both = _contact_and_trust(schedule, t) if _one_sample(schedule) else None
        if both is None or len(both[0]) != estimator.n_feet:
            contact = np.asarray(schedule.contact(t), dtype=bool)
            return estimator.update(imu, joints, contact, contact_trust(schedule, t))
        estimator._require_reset()
        estimator._check_readings(imu, joints)
        return estimator._advance(imu, joints, *both)  # the flags and trusts are valid by construction


def _one_sample(schedule) -> bool:
    """Whether ``schedule.contact(t)`` is ``schedule.sample([t]).contact[:, 0]``, each sample independent of
    the others: a :class:`PlannedContacts`, a gait or a gait schedule (their module is not imported here:
    without it, there are none)."""
    gait = sys.modules.get("wbmpc.ocp.gait")
    return type(schedule) is PlannedContacts or (
        gait is not None and type(schedule) in (gait.Gait, gait.GaitSchedule)
    )


def _contact_and_trust(schedule, t: float, window: float = 0.04, samples: int = 8):
    """``(schedule.contact(t), contact_trust(schedule, t, window, samples))`` from one ``schedule.sample``
    (the trust's window holds ``t``) for a schedule of :func:`_one_sample`.

    Returns:
        Contact flags and trusts (in [0, 1], 0 for swing feet) as lists (n_feet,); ``None`` for ``t < 0`` (the
        window starts at 0) or a ``t`` that is not a finite number (the schedule's own lookups raise).
    """
    if not (isinstance(t, numbers.Real) and math.isfinite(t) and t >= 0.0):
        return None
    offsets = trust_offsets(float(window), operator.index(samples))
    if offsets[samples] != 0.0:  # the middle sample is t itself
        return None
    contact = np.asarray(schedule.sample(np.maximum(t + offsets, 0.0)).contact, dtype=bool)
    return contact[:, samples].tolist(), window_trust(contact, samples)


def estimate_errors(q: np.ndarray, v: np.ndarray, q_hat: np.ndarray, v_hat: np.ndarray) -> dict:
    """Errors of an estimate against the truth over a run (arrays (T, nq), (T, nv)).

    Returns:
        ``height_max_m``, ``height_rms_m`` (base height), ``position_final_m`` (horizontal drift at the end),
        ``velocity_rms_mps``, ``velocity_max_mps`` (base linear velocity, base frame), ``tilt_max_rad``
        (roll/pitch error), ``joint_velocity_rms_radps``.
    """
    dz = q_hat[:, 2] - q[:, 2]
    dv = np.linalg.norm(v_hat[:, :3] - v[:, :3], axis=1)
    z_true = base_z_axis(q)
    z_hat = base_z_axis(q_hat)
    tilt = np.arccos(np.clip(np.sum(z_true * z_hat, axis=1), -1.0, 1.0))
    return {
        "height_max_m": float(np.max(np.abs(dz))),
        "height_rms_m": float(np.sqrt(np.mean(dz**2))),
        "position_final_m": float(np.linalg.norm(q_hat[-1, :2] - q[-1, :2])),
        "velocity_rms_mps": float(np.sqrt(np.mean(dv**2))),
        "velocity_max_mps": float(np.max(dv)),
        "tilt_max_rad": float(np.max(tilt)),
        "joint_velocity_rms_radps": float(np.sqrt(np.mean((v_hat[:, 6:] - v[:, 6:]) ** 2))),
    }


def rear_leg_share(foot_forces: np.ndarray, rear: tuple[int, ...] = (2, 3)) -> float:
    """Share of the total vertical foot force carried by the rear feet (forces (..., n_feet, 3) [N])."""
    fz = np.asarray(foot_forces, dtype=float)[..., 2].reshape(-1, np.shape(foot_forces)[-2]).sum(axis=0)
    return float(fz[list(rear)].sum() / fz.sum())
