"""State estimation from the IMU and the joint encoders: a two-stage Kalman filter after MIT Cheetah 3.

On the robot nothing measures the floating base directly. :class:`StateEstimator` reconstructs the MPC's
initial state ``(q_hat, v_hat)`` from an IMU (gyroscope, accelerometer, optionally the IMU's own orientation
output) and the joint encoders, in two stages (Bledt et al., "MIT Cheetah 3: Design and Control of a Robust,
Dynamic Quadruped Robot", IROS 2018):

1. **Attitude** -- an error-state (multiplicative) Kalman filter on SO(3) with state ``(R, b_g)``, the base
   orientation (base -> world) and the gyroscope bias [rad/s]. Prediction integrates the bias-corrected gyro,

   .. math::  R_k = R_{k-1} \\operatorname{Exp}\\big((\\bar\\omega_k - b_g)\\,\\Delta t\\big), \\qquad
              \\bar\\omega_k = \\tfrac12(\\omega_{k-1} + \\omega_k),

   the correction uses the accelerometer as a gravity-direction sensor, velocity-aided: the specific force
   ``f = R^T (a - g)`` is compared with ``h = R^T (a_hat - g)``, where ``a_hat`` is the base acceleration
   [m/s^2] seen by stage 2's leg-corrected velocity over the last period (0 without leg kinematics), so
   the trot's own accelerations are not mistaken for tilt; ``d h / d dtheta = [h]_x`` (yaw is unobservable
   and follows the gyro). Its noise is inflated when the residual ``|f - h|`` is large (impacts, slips).
   If the IMU reports an orientation ``R_m``, the residual ``Log(R^T R_m)`` corrects all three axes.

2. **Translation** -- a linear Kalman filter with the world-frame state
   ``x = [p (3), v (3), p_1 (3), ..., p_n (3)]``: base position [m], base velocity [m/s] and the foot
   positions [m]. The process model is driven by the IMU acceleration rotated to the world,
   ``a = R f + g`` with ``g = (0, 0, -9.81)``,

   .. math::  p_k = p_{k-1} + v_{k-1}\\Delta t + \\tfrac12 a\\,\\Delta t^2, \\quad
              v_k = v_{k-1} + a\\,\\Delta t, \\quad
              p_{i,k} = p_{i,k-1} + \\dot p_i^{roll}\\Delta t,

   where stance feet are static in the world up to the rolling of the spherical foot (``p_i`` is the
   sphere's centre, the foot frame; it moves with ``omega_foot x (r_foot e_z)`` when the foot rolls) and
   swing feet get a large process noise (they are not trusted). The measurement model is leg kinematics:
   for each foot, forward kinematics of the measured joint angles gives the foot relative to the base,
   ``r_i(q_j)`` in base axes, and the leg Jacobian gives its velocity,

   .. math::  p_i - p = R\\,r_i(q_j), \\qquad
              v = \\dot p_i^{roll} - R\\,(\\omega \\times r_i + J_i(q_j)\\,\\dot q_j),

   the second row only for stance feet. Contacts come from the gait schedule (the robot has no contact
   sensors): a trust ``c_i`` in [0, 1] (:func:`contact_trust`, 0 at touchdown and lift-off) scales the
   measurement and foot process covariances by ``1 + (1 - c_i) k``.

The joint velocities are low-passed at 50 Hz (:class:`wbmpc.sim.sensing.LowPassFilter`) before use, as the
encoders' finite differences are noisy. The IMU is assumed at the base frame origin, axes aligned with the
base.

Returned states follow the Pinocchio free-flyer convention used by
:meth:`wbmpc.control.mpc.WholeBodyMPC.solve` and
reported by the plants (:class:`wbmpc.sim.plant.PlantState`): ``q = [p (world), quaternion (x, y, z, w), joint
angles]`` and ``v = [R^T v (base frame), omega (base frame), joint rates]``.

Example:
    >>> est = StateEstimator(robot, dt=0.002)
    >>> est.reset(q0, v0)
    >>> q_hat, v_hat = est.update(imu, joints, contact=gait.contact(t), trust=contact_trust(gait, t))
"""

from __future__ import annotations

import math
import operator
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import pinocchio as pin

from wbmpc import checks
from wbmpc.estimation import filters
from wbmpc.estimation.filters import LowPassFilter
from wbmpc.model.robot import Robot

__all__ = [
    "EstimatorNoise",
    "ImuNoise",
    "ImuReading",
    "JointReading",
    "StateEstimator",
    "contact_trust",
    "synthesize_imu",
]

_E_Z = np.array([0.0, 0.0, 1.0])
_Z = (0.0, 0.0, 1.0)


# ---------------------------------------------------------------------------------------------- readings


@dataclass
class ImuReading:
    """One IMU sample, in the IMU frame (= the base frame).

    Attributes:
        gyro: Angular velocity [rad/s] (3,).
        accelerometer: Specific force ``f = R^T (a - g)`` [m/s^2] (3,); at rest it reads ``(0, 0, +9.81)``
            for a level base.
        orientation: Optional orientation output of the IMU, quaternion (x, y, z, w) base -> world (4,),
            normalised here.
    """

    gyro: np.ndarray
    accelerometer: np.ndarray
    orientation: np.ndarray | None = None

    def __post_init__(self):
        self.gyro = checks.array("imu.gyro", self.gyro, 3)
        self.accelerometer = checks.array("imu.accelerometer", self.accelerometer, 3)
        if self.orientation is not None:
            quat = checks.array("imu.orientation", self.orientation, 4)
            norm = np.linalg.norm(quat)
            if norm < 1e-9:
                raise ValueError("imu.orientation has zero norm")
            self.orientation = quat / norm


@dataclass
class JointReading:
    """One encoder sample of the actuated joints (Pinocchio joint order, ``q[7:]``, ``v[6:]``).

    Attributes:
        positions: Joint angles [rad] (nj,).
        velocities: Joint rates [rad/s] (nj,), unfiltered (the estimator low-passes them).
    """

    positions: np.ndarray
    velocities: np.ndarray

    def __post_init__(self):
        self.positions = checks.array("joints.positions", self.positions)
        self.velocities = checks.array("joints.velocities", self.velocities)
        if self.velocities.shape != self.positions.shape:
            raise ValueError(
                f"joints.velocities must have the shape of joints.positions {self.positions.shape}, "
                f"got {self.velocities.shape}"
            )


# ---------------------------------------------------------------------------------------------- settings
def _check_fields(obj, names: tuple[str, ...]) -> None:
    for name in names:
        value = getattr(obj, name)
        if not (np.isfinite(value) and value >= 0):
            raise ValueError(f"{type(obj).__name__}.{name} must be finite and >= 0, got {value!r}")


@dataclass(frozen=True)
class EstimatorNoise:
    """Tuning of :class:`StateEstimator`: standard deviations of the noises the filter assumes.

    Per-sample standard deviations hold at the filter's rate ``dt``; random walks are per square root of a
    second.

    Attributes:
        gyro: Gyroscope white noise [rad/s] per sample.
        gyro_bias_walk: Gyroscope bias random walk [rad/s/sqrt(s)].
        gyro_bias_initial: Prior standard deviation of the gyroscope bias [rad/s].
        accelerometer: Accelerometer white noise [m/s^2] per sample (drives the base velocity process
            noise, together with unmodelled accelerometer bias).
        gravity_direction: Noise [m/s^2] of the accelerometer read as a gravity sensor: mostly the base's own
            acceleration, not sensor noise; sets how fast the tilt is corrected (larger: slower, smoother).
        gravity_gate: Scale [m/s^2] of the inflation of ``gravity_direction`` by the deviation of ``|f|``
            from ``g``: ``sigma = gravity_direction * (1 + (||f| - g| / gravity_gate)^2)``.
        orientation: Noise [rad] of the IMU's orientation output (used only when a reading carries one).
        foot_position: Leg-kinematics foot position noise [m] (encoder noise through the leg, link lengths).
        foot_velocity: Leg-kinematics foot velocity noise [m/s] (filtered joint rates through the Jacobian).
        foot_slip: Process noise of a stance foot's position [m/sqrt(s)] (slip, ground compliance).
        swing_inflation: Factor ``k`` of the covariance inflation ``1 + (1 - trust) k`` of untrusted feet:
            swing feet (trust 0) and stance feet near touchdown or lift-off.
        base_position_walk: Process noise of the base position [m/sqrt(s)] beyond the integrated velocity.
        initial_position: Prior standard deviation of the base and foot positions at :meth:`reset` [m].
        initial_velocity: Prior standard deviation of the base velocity at :meth:`reset` [m/s].
        initial_attitude: Prior standard deviation of the attitude at :meth:`reset` [rad].
    """

    gyro: float = 0.005
    gyro_bias_walk: float = 1e-4
    gyro_bias_initial: float = 0.01
    accelerometer: float = 0.2
    gravity_direction: float = 2.0
    gravity_gate: float = 1.0
    orientation: float = 0.01
    foot_position: float = 0.005
    foot_velocity: float = 0.05
    foot_slip: float = 0.01
    swing_inflation: float = 1e4
    base_position_walk: float = 1e-3
    initial_position: float = 1e-3
    initial_velocity: float = 1e-2
    initial_attitude: float = 1e-3

    def __post_init__(self):
        _check_fields(self, tuple(self.__dataclass_fields__))
        for name in ("gravity_direction", "gravity_gate", "orientation", "foot_position", "foot_velocity"):
            if getattr(self, name) <= 0:
                raise ValueError(f"EstimatorNoise.{name} must be > 0, got {getattr(self, name)!r}")


@dataclass(frozen=True)
class ImuNoise:
    """Errors of a synthesised IMU (:func:`synthesize_imu`); zeros give the exact reading.

    Attributes:
        gyro: Gyroscope white noise [rad/s] per sample.
        accelerometer: Accelerometer white noise [m/s^2] per sample.
        gyro_bias: Constant gyroscope bias [rad/s] (3,).
        accelerometer_bias: Constant accelerometer bias [m/s^2] (3,).
        orientation: Noise [rad] of the orientation output (a random rotation vector); ``None``: no
            orientation output in the reading.
    """

    gyro: float = 0.0
    accelerometer: float = 0.0
    gyro_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    accelerometer_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    orientation: float | None = None

    def __post_init__(self):
        _check_fields(self, ("gyro", "accelerometer"))
        if self.orientation is not None:
            _check_fields(self, ("orientation",))
        checks.array("ImuNoise.gyro_bias", self.gyro_bias, 3)
        checks.array("ImuNoise.accelerometer_bias", self.accelerometer_bias, 3)


# ---------------------------------------------------------------------------------------------- IMU model
def synthesize_imu(
    q: np.ndarray,
    v: np.ndarray,
    q_prev: np.ndarray,
    v_prev: np.ndarray,
    dt: float,
    gravity: float = 9.81,
    noise: ImuNoise | None = None,
    rng: np.random.Generator | None = None,
) -> ImuReading:
    """The IMU reading of a base-mounted IMU from two consecutive plant states (Pinocchio convention).

    The base acceleration is the backward finite difference of the world-frame base velocity,
    ``a = (R v_lin - R_prev v_lin,prev) / dt``; the accelerometer reads the specific force
    ``f = R^T (a - g) + b_a + n_a`` with ``g = (0, 0, -gravity)``; the gyroscope reads the base angular
    velocity ``omega + b_g + n_g`` (base frame, ``v[3:6]``).

    Args:
        q, v: State at this sample, shapes (nq,), (nv,) (base velocity in the base frame).
        q_prev, v_prev: State one sample earlier.
        dt: Sample period [s].
        gravity: Gravity magnitude [m/s^2].
        noise: Sensor errors; ``None`` gives the exact reading.
        rng: Noise generator (needed for reproducible white noise; a fresh default one otherwise).

    Returns:
        The reading, with an orientation output if ``noise.orientation`` is not ``None``.

    Raises:
        ValueError: On inconsistent shapes, non-finite values or a non-positive ``dt``.
    """
    q, q_prev = checks.array("q", q), checks.array("q_prev", q_prev, np.size(q))
    v, v_prev = checks.array("v", v, q.size - 1), checks.array("v_prev", v_prev, q.size - 1)
    if q.size < 7:
        raise ValueError(f"q must hold a free-flyer base (size >= 7), got {q.size}")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be > 0 [s], got {dt}")
    R = _rotation(q[3:7])
    a = (R @ v[:3] - _rotation(q_prev[3:7]) @ v_prev[:3]) / dt
    f = R.T @ (a + gravity * _E_Z)
    gyro = v[3:6].copy()
    orientation = None
    noise = noise or ImuNoise()
    if noise.orientation is not None:
        orientation = q[3:7] / np.linalg.norm(q[3:7])
    if noise != ImuNoise():
        rng = rng or np.random.default_rng()
        gyro += np.asarray(noise.gyro_bias) + noise.gyro * rng.standard_normal(3)
        f += np.asarray(noise.accelerometer_bias) + noise.accelerometer * rng.standard_normal(3)
        if noise.orientation:
            R_m = R @ pin.exp3(noise.orientation * rng.standard_normal(3))
            orientation = pin.Quaternion(R_m).coeffs().copy()
    return ImuReading(gyro=gyro, accelerometer=f, orientation=orientation)


def contact_trust(schedule, t: float, window: float = 0.04, samples: int = 8) -> np.ndarray:
    """How much to trust each foot's leg kinematics at time ``t``, from the gait schedule.

    ``trust_i = clip(min(t - t_touchdown, t_liftoff - t) / window, 0, 1)`` for stance feet, 0 for swing feet:
    a ramp over ``window`` seconds after touchdown and before lift-off, where the real contact may differ from
    the scheduled one (Cheetah 3's phase-based trust).

    Args:
        schedule: A :class:`~wbmpc.ocp.gait.Gait` or :class:`~wbmpc.ocp.gait.GaitSchedule` (anything with
            ``sample(times).contact`` of shape (n_feet, len(times))).
        t: Time [s].
        window: Ramp duration [s] (0: plain contact flags).
        samples: Schedule samples per ramp (the trust's resolution is ``window / samples``).

    Returns:
        Trust (n_feet,) in [0, 1].
    """
    if not (np.isfinite(t) and np.isfinite(window) and window >= 0):
        raise ValueError(f"t and window must be finite (window >= 0), got t={t!r}, window={window!r}")
    if window == 0:
        return schedule.sample(np.array([t])).contact[:, 0].astype(float)
    samples = operator.index(samples)
    offsets = filters.trust_offsets(float(window), samples)
    contact = schedule.sample(np.maximum(t + offsets, 0.0)).contact  # before t = 0: the first sample
    return np.array(filters.window_trust(contact, samples))


# ---------------------------------------------------------------------------------------------- estimator
class StateEstimator:
    """Two-stage Kalman filter (attitude, then base position, velocity and feet) from IMU and encoders.

    Its constants are built once, the legs' Jacobian once per contact pattern, 3-vector arithmetic runs on
    floats in numpy's order of operations (the same results; matrix products and factorisations are numpy's).

    Args:
        robot: The robot (model, foot frames, foot radius).
        dt: Filter period [s] (the low-level rate, 500 Hz: 0.002).
        noise: Filter tuning; defaults documented in :class:`EstimatorNoise`.
        velocity_cutoff_hz: Joint-velocity low-pass cut-off [Hz] (50 as on hardware; ``None``: unfiltered).
        use_kinematics: Apply the leg-kinematics measurements (``False``: IMU dead reckoning only, for
            comparison).

    Attributes:
        P: Covariance of the translation stage (6 + 3 n_feet square), world frame.
        P_attitude: Covariance of the attitude stage (6 square): attitude error (base frame) [rad], gyro
            bias [rad/s].
        gyro_bias: Estimated gyroscope bias [rad/s] (3,).
    """

    def __init__(
        self,
        robot: Robot,
        dt: float,
        noise: EstimatorNoise | None = None,
        velocity_cutoff_hz: float | None = 50.0,
        use_kinematics: bool = True,
    ):
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be > 0 [s], got {dt}")
        self.robot = robot
        self.model = robot.model
        self.data = robot.model.createData()
        self.dt = float(dt)
        self.noise = noise or EstimatorNoise()
        self.use_kinematics = bool(use_kinematics)
        self.filter = LowPassFilter(velocity_cutoff_hz, self.dt)
        self.n_feet = robot.n_feet
        self._foot_ids = [robot.frame_id(name) for name in robot.foot_frames]
        self._g = robot.gravity
        self.n_x = 6 + 3 * self.n_feet
        self._q: np.ndarray | None = None
        self._q_kin = np.zeros(self.model.nq)  # the base at the origin, unrotated: feet in base axes
        self._q_kin[6] = 1.0
        self._c: SimpleNamespace | None = None

    # ------------------------------------------------------------------ state
    @property
    def initialized(self) -> bool:
        return self._q is not None

    @property
    def rotation(self) -> np.ndarray:
        """Estimated base orientation R (base -> world) (3, 3)."""
        self._require_reset()
        return self._R.copy()

    @property
    def foot_positions(self) -> np.ndarray:
        """Estimated foot (frame) positions [m] (n_feet, 3), world."""
        self._require_reset()
        return self._x[6:].reshape(self.n_feet, 3).copy()

    def reset(self, q0: np.ndarray, v0: np.ndarray) -> None:
        """Start from a known state (e.g. the robot standing at its initial pose).

        Args:
            q0: Configuration (nq,), Pinocchio convention.
            v0: Velocity (nv,), base velocities in the base frame.
        """
        q0 = checks.array("q0", q0, self.model.nq)
        v0 = checks.array("v0", v0, self.model.nv)
        n = self.noise
        self._R = _rotation(q0[3:7])
        self._quat_ref = (q0[3:7] / np.linalg.norm(q0[3:7])).tolist()
        self.gyro_bias = np.zeros(3)
        self.P_attitude = np.diag([n.initial_attitude**2] * 3 + [n.gyro_bias_initial**2] * 3)
        self._gyro_prev: list[float] | None = None
        r = np.array(self._foot_kinematics(q0[7:], [])[0])
        self._x = np.concatenate([q0[:3], self._R @ v0[:3], (q0[:3] + r @ self._R.T).ravel()])
        self.P = np.diag(
            [n.initial_position**2] * 3
            + [n.initial_velocity**2] * 3
            + [n.initial_position**2] * (3 * self.n_feet)
        )
        self.filter.reset()
        self.filter(v0[6:])
        self._q, self._v = q0.copy(), v0.copy()
        self._q[3:7] = self._quat_ref

    # ------------------------------------------------------------------ update
    def update(
        self,
        imu: ImuReading,
        joints: JointReading,
        contact: np.ndarray,
        trust: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Advance the filter by one period ``dt`` with the new readings.

        Args:
            imu: IMU sample at this time.
            joints: Encoder sample at this time.
            contact: Stance flags (n_feet,) from the gait schedule (True: the foot is on the ground).
            trust: Per-foot trust in [0, 1] (:func:`contact_trust`); ``None``: 1 for stance feet.

        Returns:
            ``(q_hat, v_hat)``: configuration (nq,) [position, quaternion (x, y, z, w), joint angles] and
            velocity (nv,) [base linear velocity and angular velocity in the base frame, filtered joint
            rates].

        Raises:
            ValueError: On a wrong type, shape or a non-finite value of an input (named in the message).
            RuntimeError: If :meth:`reset` was not called.
        """
        self._require_reset()
        self._check_readings(imu, joints)
        contact_arr = np.asarray(contact)
        if contact_arr.shape != (self.n_feet,):
            raise ValueError(f"contact must have shape ({self.n_feet},), got {contact_arr.shape}")
        if contact_arr.dtype != bool and not np.all(np.isin(contact_arr, (0, 1))):
            raise ValueError(f"contact must hold booleans, got {contact_arr!r}")
        stance = (contact_arr if contact_arr.dtype == bool else contact_arr.astype(bool)).tolist()
        if trust is None:
            trust_list = [1.0 if s else 0.0 for s in stance]
        else:
            trust_arr = checks.array("trust", trust, self.n_feet)
            trust_list = trust_arr.tolist()
            if not all(0.0 <= x <= 1.0 for x in trust_list):
                raise ValueError(f"trust must be in [0, 1], got {trust_arr!r}")
            trust_list = [x if s else 0.0 for x, s in zip(trust_list, stance, strict=True)]
        return self._advance(imu, joints, stance, trust_list)

    def _check_readings(self, imu, joints) -> None:
        """The type and shape checks of :meth:`update`'s readings (``ValueError`` naming the input)."""
        if not isinstance(imu, ImuReading):
            raise ValueError(f"imu must be an ImuReading, got {type(imu).__name__}")
        if not isinstance(joints, JointReading):
            raise ValueError(f"joints must be a JointReading, got {type(joints).__name__}")
        if joints.positions.shape != (nj := self.robot.nj,):
            raise ValueError(f"joints.positions must have shape ({nj},), got {joints.positions.shape}")

    def _advance(self, imu: ImuReading, joints: JointReading, stance: list[bool], trust: list[float]):
        """:meth:`update` once its inputs are checked: stance flags (bools) and trusts (floats in [0, 1], 0
        for swing feet) as lists (:class:`wbmpc.sim.hardware.EstimatedState` calls it with its own)."""
        c = self._constants()
        qd = self.filter(joints.velocities)
        omega = self._attitude_predict(imu.gyro, c)
        v_prev = self._x[3:6].tolist()
        self._translation_update(imu.accelerometer, joints.positions, qd, omega, stance, trust, c)
        # Velocity-aided tilt: the base acceleration seen by the leg-corrected velocity (IMU only: none).
        a_hat = [0.0] * 3
        if self.use_kinematics:
            a_hat = [(u - w) / self.dt for u, w in zip(self._x[3:6].tolist(), v_prev, strict=True)]
        self._attitude_correct(imu, a_hat, c)

        quat = filters.quaternion(self._R)  # (x, y, z, w)
        ref = self._quat_ref  # the sign of quat . ref (~ +-1) decides
        if quat[0] * ref[0] + quat[1] * ref[1] + quat[2] * ref[2] + quat[3] * ref[3] < 0:
            quat = [-a for a in quat]  # keep one hemisphere: no sign jumps
        self._quat_ref = quat
        q = np.concatenate([self._x[:3], quat, joints.positions])
        v = np.concatenate([self._R.T @ self._x[3:6], omega, qd])
        self._q, self._v = q, v  # never read back: the caller may keep (and change) them
        return q, v

    def _constants(self) -> SimpleNamespace:
        """:func:`wbmpc.estimation.filters.two_stage_constants` of the tuning and ``dt`` (rebuilt if they
        change)."""
        c = self._c
        if c is None or c.noise is not self.noise or c.dt != self.dt:
            self._c = c = filters.two_stage_constants(self.noise, self.dt, self.n_feet)
        return c

    # ------------------------------------------------------------------ stage 1: attitude
    def _attitude_predict(self, gyro: np.ndarray, c: SimpleNamespace) -> np.ndarray:
        """Error-state KF on (R, b_g), prediction; returns the bias-corrected body rate [rad/s]."""
        now, dt = gyro.tolist(), self.dt
        before = now if self._gyro_prev is None else self._gyro_prev
        self._gyro_prev = now
        rates = zip(before, now, self.gyro_bias.tolist(), strict=True)  # trapezoidal rate over the period
        # Predict: R <- R Exp(w dt); error dtheta (base frame) propagates with Exp(-w dt), bias enters -dt.
        dR = pin.exp3(np.array([(0.5 * (u + w) - b) * dt for u, w, b in rates]))
        self._R = self._R @ dR
        F = c.F_att
        F[:3, :3] = dR.T
        self.P_attitude = filters.symmetric(F @ self.P_attitude @ F.T + c.Q_att)
        return gyro - self.gyro_bias

    def _attitude_correct(self, imu: ImuReading, a_hat: list[float], c: SimpleNamespace) -> None:
        """Error-state KF on (R, b_g), correction by the accelerometer (and the IMU orientation if given).

        ``f = R^T (a - g)`` with the base acceleration ``a`` [m/s^2] (world) estimated by the translation
        stage: ``h = R^T (a_hat + g e_z)``, ``d h / d dtheta = [h]_x``.
        """
        n, R = self.noise, self._R
        h = R.T @ np.array([a_hat[0] + self._g * 0.0, a_hat[1] + self._g * 0.0, a_hat[2] + self._g * 1.0])
        res = imu.accelerometer - h
        # Inflate when the residual is large (unmodelled acceleration: impacts, slips).
        sigma = n.gravity_direction * (1.0 + (np.float64(math.sqrt(res.dot(res))) / n.gravity_gate) ** 2)
        var = c.ones3 * sigma**2
        if imu.orientation is None:
            H = c.H_acc
            H[:, :3] = pin.skew(h)
        else:  # IMU's own orientation: residual Log(R^T R_m), H = [I 0]
            H = c.H_imu
            H[:3, :3] = pin.skew(h)
            res = np.concatenate([res, pin.log3(R.T @ _rotation(imu.orientation))])
            var = np.concatenate([var, np.full(3, n.orientation**2)])
        dx, self.P_attitude = filters.kalman_correct(self.P_attitude, H, res, var)
        self._R = filters.orthonormalize(R @ pin.exp3(dx[:3]))
        self.gyro_bias = self.gyro_bias + dx[3:]

    # ------------------------------------------------------------------ stage 2: position and velocity
    def _translation_update(self, accelerometer, qj, qd, omega, stance, trust, c) -> None:
        """Linear KF on [p, v, p_feet] (world) with IMU acceleration input and leg-kinematics measurements
        (per-foot products batched: ``np.matmul`` on a stack makes the same BLAS call for each foot)."""
        n, dt, R, nf = self.noise, self.dt, self._R, self.n_feet
        on = [i for i, s in enumerate(stance) if s]
        r, J = self._foot_kinematics(qj, on)  # base frame: positions (nf of 3), stance Jacobians
        Jqd = J.reshape(-1, 3, J.shape[2]) @ qd  # per stance foot: linear, angular (relative to the base)
        om, lin, turn = omega.tolist(), Jqd[::2].tolist(), []  # turn: omega x r_i + J_i qd (stance feet)
        for i, u in zip(on, lin, strict=True):
            w = filters.cross(om, r[i])
            turn += [w[0] + u[0], w[1] + u[1], w[2] + u[2]]
        stack = np.array(accelerometer.tolist() + sum(r, []) + turn).reshape(-1, 3, 1)
        rotated = np.matmul(R, stack).reshape(-1, 3).tolist()  # R f, R r_i, R turn_i
        a = rotated[0]
        a[2] -= self._g  # R f - g e_z: the world acceleration of the base
        # Rolling spherical feet: the frame (sphere centre) moves with omega_foot x (radius e_z), omega_foot
        # = omega + the foot's rate relative to the base (one product of all feet's rows, swing ones unused).
        roll = [[0.0] * 3 for _ in stance]
        if on:
            w_feet = omega + Jqd[1::2]
            if len(on) < nf:
                w_feet = w_feet[[on.index(i) if s else 0 for i, s in enumerate(stance)]]
            w_feet = (w_feet @ R.T).tolist()  # world
            for i in on:
                roll[i] = [self.robot.foot_radius * y for y in filters.cross(w_feet[i], _Z)]

        # Predict.
        x = c.F @ self._x  # += [dt^2 / 2 a, dt a, dt roll]
        x += np.array([c.half_dt2 * y for y in a] + [dt * y for y in a + sum(roll, [])])
        inflate = [1.0 + (1.0 - t) * n.swing_inflation for t in trust]  # 1 for trusted stance feet
        P, slip = c.F @ self.P @ c.F.T + c.Q, n.foot_slip**2 * dt
        P.reshape(-1)[c.feet] += np.array([slip * k for k in inflate for _ in range(3)])
        if not self.use_kinematics:
            self._x, self.P = x, filters.symmetric(P)
            return

        # Measurements: every foot's position relative to the base; stance feet's velocity (roll - R turn).
        H = c.H.get(key := tuple(stance))
        if H is None:
            H = c.H[key] = filters.kinematics_jacobian(self.n_x, key)
        x_list = x.tolist()
        bx, by, bz, vx, vy, vz = x_list[:6]
        var_p, var_v = n.foot_position**2, n.foot_velocity**2
        res, var = [], []
        for i, s in enumerate(stance):
            (rx, ry, rz), (fx, fy, fz) = rotated[1 + i], x_list[6 + 3 * i : 9 + 3 * i]
            res += [rx - (fx - bx), ry - (fy - by), rz - (fz - bz)]
            var += [var_p * inflate[i]] * 3
            if s:
                (ux, uy, uz), (wx, wy, wz) = rotated[1 + nf + on.index(i)], roll[i]
                res += [(wx - ux) - vx, (wy - uy) - vy, (wz - uz) - vz]
                var += [var_v * inflate[i]] * 3
        dx, self.P = filters.kalman_correct(P, H, np.array(res), np.array(var))
        self._x = x + dx

    def _foot_kinematics(self, qj: np.ndarray, on: list[int]) -> tuple[list[list[float]], np.ndarray]:
        """Feet relative to the base, base axes, at the joint angles ``qj``: positions (n_feet of 3 floats),
        joint Jacobians (len(on), 6, nj) of the feet ``on`` (LOCAL_WORLD_ALIGNED: linear rows, angular)."""
        model, data, q = self.model, self.data, self._q_kin
        q[7:] = qj
        pin.computeJointJacobians(model, data, q)
        r = [pin.updateFramePlacement(model, data, fid).translation.tolist() for fid in self._foot_ids]
        J = [pin.getFrameJacobian(model, data, self._foot_ids[i], pin.LOCAL_WORLD_ALIGNED) for i in on]
        return r, (np.array(J) if J else np.zeros((0, 6, model.nv)))[:, :, 6:]

    def _require_reset(self) -> None:
        if self._q is None:
            raise RuntimeError("call StateEstimator.reset(q0, v0) before update()")


# ---------------------------------------------------------------------------------------------- helpers
def _rotation(quat: np.ndarray) -> np.ndarray:
    """Rotation matrix of a quaternion (x, y, z, w) (normalised here)."""
    quat = np.asarray(quat, dtype=float)
    return pin.Quaternion(quat / np.linalg.norm(quat)).toRotationMatrix()
