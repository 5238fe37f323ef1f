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

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from wbmpc import checks
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
    offsets = np.linspace(-window, window, 2 * samples + 1)
    contact = schedule.sample(np.maximum(t + offsets, 0.0)).contact  # before t = 0: the first sample
    trust = np.zeros(contact.shape[0])
    for i, flags in enumerate(contact):
        if not flags[samples]:
            continue
        back = flags[: samples + 1][::-1]  # t, t - h, ...
        ahead = flags[samples:]
        n_back = samples if back.all() else int(np.argmin(back)) - 1
        n_ahead = samples if ahead.all() else int(np.argmin(ahead)) - 1
        trust[i] = min(n_back, n_ahead) / samples
    return np.clip(trust, 0.0, 1.0)


# ---------------------------------------------------------------------------------------------- estimator
class StateEstimator:
    """Two-stage Kalman filter (attitude, then base position, velocity and feet) from IMU and encoders.

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
        self._quat_ref = q0[3:7] / np.linalg.norm(q0[3:7])
        self.gyro_bias = np.zeros(3)
        self.P_attitude = np.diag([n.initial_attitude**2] * 3 + [n.gyro_bias_initial**2] * 3)
        self._gyro_prev: np.ndarray | None = None
        r, _, _ = self._leg_kinematics(q0[7:], np.zeros(self.robot.nj))
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
        if not isinstance(imu, ImuReading):
            raise ValueError(f"imu must be an ImuReading, got {type(imu).__name__}")
        if not isinstance(joints, JointReading):
            raise ValueError(f"joints must be a JointReading, got {type(joints).__name__}")
        nj = self.robot.nj
        if joints.positions.shape != (nj,):
            raise ValueError(f"joints.positions must have shape ({nj},), got {joints.positions.shape}")
        contact_arr = np.asarray(contact)
        if contact_arr.shape != (self.n_feet,):
            raise ValueError(f"contact must have shape ({self.n_feet},), got {contact_arr.shape}")
        if contact_arr.dtype != bool and not np.all(np.isin(contact_arr, (0, 1))):
            raise ValueError(f"contact must hold booleans, got {contact_arr!r}")
        contact_arr = contact_arr.astype(bool)
        if trust is None:
            trust_arr = contact_arr.astype(float)
        else:
            trust_arr = checks.array("trust", trust, self.n_feet)
            if np.any((trust_arr < 0) | (trust_arr > 1)):
                raise ValueError(f"trust must be in [0, 1], got {trust_arr!r}")
            trust_arr = np.where(contact_arr, trust_arr, 0.0)

        qd = self.filter(joints.velocities)
        omega = self._attitude_predict(imu)
        v_prev = self._x[3:6].copy()
        self._translation_update(imu, joints.positions, qd, omega, contact_arr, trust_arr)
        # Velocity-aided tilt: the base acceleration seen by the leg-corrected velocity (IMU only: none).
        a_hat = (self._x[3:6] - v_prev) / self.dt if self.use_kinematics else np.zeros(3)
        self._attitude_correct(imu, a_hat)

        quat = pin.Quaternion(self._R).coeffs().copy()  # (x, y, z, w)
        if quat @ self._quat_ref < 0:
            quat = -quat  # keep one hemisphere: no sign jumps
        self._quat_ref = quat
        q = np.concatenate([self._x[:3], quat, joints.positions])
        v = np.concatenate([self._R.T @ self._x[3:6], omega, qd])
        self._q, self._v = q, v
        return q.copy(), v.copy()

    # ------------------------------------------------------------------ stage 1: attitude
    def _attitude_predict(self, imu: ImuReading) -> np.ndarray:
        """Error-state KF on (R, b_g), prediction; returns the bias-corrected body rate [rad/s]."""
        n, dt = self.noise, self.dt
        gyro_prev = imu.gyro if self._gyro_prev is None else self._gyro_prev
        self._gyro_prev = imu.gyro.copy()
        w = 0.5 * (gyro_prev + imu.gyro) - self.gyro_bias  # trapezoidal rate over the period
        # Predict: R <- R Exp(w dt); error dtheta (base frame) propagates with Exp(-w dt), bias enters -dt.
        dR = pin.exp3(w * dt)
        self._R = self._R @ dR
        F = np.eye(6)
        F[:3, :3] = dR.T
        F[:3, 3:] = -dt * np.eye(3)
        Q = np.diag([(n.gyro * dt) ** 2] * 3 + [n.gyro_bias_walk**2 * dt] * 3)
        self.P_attitude = _symmetric(F @ self.P_attitude @ F.T + Q)
        return imu.gyro - self.gyro_bias

    def _attitude_correct(self, imu: ImuReading, a_hat: np.ndarray) -> None:
        """Error-state KF on (R, b_g), correction by the accelerometer (and the IMU orientation if given).

        ``f = R^T (a - g)`` with the base acceleration ``a`` [m/s^2] (world) estimated by the translation
        stage: ``h = R^T (a_hat + g e_z)``, ``d h / d dtheta = [h]_x``.
        """
        n, P = self.noise, self.P_attitude
        f = imu.accelerometer
        h = self._R.T @ (a_hat + self._g * _E_Z)
        # Inflate when the residual is large (unmodelled acceleration: impacts, slips).
        sigma = n.gravity_direction * (1.0 + (np.linalg.norm(f - h) / n.gravity_gate) ** 2)
        H = np.zeros((3, 6))
        H[:, :3] = pin.skew(h)
        rows, res, var = [H], [f - h], [np.full(3, sigma**2)]
        if imu.orientation is not None:  # IMU's own orientation: residual Log(R^T R_m), H = [I 0]
            Ho = np.zeros((3, 6))
            Ho[:, :3] = np.eye(3)
            rows.append(Ho)
            res.append(pin.log3(self._R.T @ _rotation(imu.orientation)))
            var.append(np.full(3, n.orientation**2))
        dx, self.P_attitude = _kalman_correct(P, np.vstack(rows), np.concatenate(res), np.concatenate(var))
        self._R = _orthonormalize(self._R @ pin.exp3(dx[:3]))
        self.gyro_bias = self.gyro_bias + dx[3:]

    # ------------------------------------------------------------------ stage 2: position and velocity
    def _translation_update(self, imu, qj, qd, omega, contact, trust) -> None:
        """Linear KF on [p, v, p_feet] (world) with IMU acceleration input and leg-kinematics measurements."""
        n, dt, nf = self.noise, self.dt, self.n_feet
        R = self._R
        a = R @ imu.accelerometer - self._g * _E_Z  # world acceleration of the base
        r, J, w_rel = self._leg_kinematics(qj, qd)  # base frame: foot positions, linear, angular rates
        # Rolling spherical feet: the frame (sphere centre) moves with omega_foot x (radius e_z).
        w_feet = (omega + w_rel) @ R.T  # (nf, 3), world
        roll = self.robot.foot_radius * np.cross(w_feet, _E_Z)
        roll[~contact] = 0.0

        # Predict.
        F = np.eye(self.n_x)
        F[:3, 3:6] = dt * np.eye(3)
        x = F @ self._x
        x[:3] += 0.5 * dt**2 * a
        x[3:6] += dt * a
        x[6:] += dt * roll.ravel()
        inflate = 1.0 + (1.0 - trust) * n.swing_inflation  # 1 for trusted stance feet
        q_feet = np.repeat(n.foot_slip**2 * dt * inflate, 3)
        Q = np.diag(np.concatenate([np.full(3, n.base_position_walk**2 * dt), np.zeros(3), q_feet]))
        G = np.vstack([0.5 * dt**2 * np.eye(3), dt * np.eye(3)])  # acceleration noise -> (p, v)
        Q[:6, :6] += n.accelerometer**2 * (G @ G.T)
        P = F @ self.P @ F.T + Q
        if not self.use_kinematics:
            self._x, self.P = x, _symmetric(P)
            return

        # Measurements: every foot's position relative to the base; stance feet's velocity too.
        rows, res, var = [], [], []
        for i in range(nf):
            sl = slice(6 + 3 * i, 9 + 3 * i)
            Hp = np.zeros((3, self.n_x))
            Hp[:, :3], Hp[:, sl] = -np.eye(3), np.eye(3)
            rows.append(Hp)
            res.append(R @ r[i] - (x[sl] - x[:3]))
            var.append(np.full(3, n.foot_position**2 * inflate[i]))
            if contact[i]:
                Hv = np.zeros((3, self.n_x))
                Hv[:, 3:6] = np.eye(3)
                v_meas = roll[i] - R @ (np.cross(omega, r[i]) + J[i] @ qd)
                rows.append(Hv)
                res.append(v_meas - x[3:6])
                var.append(np.full(3, n.foot_velocity**2 * inflate[i]))
        dx, self.P = _kalman_correct(P, np.vstack(rows), np.concatenate(res), np.concatenate(var))
        self._x = x + dx

    def _leg_kinematics(self, qj: np.ndarray, qd: np.ndarray):
        """Feet relative to the base, base axes: positions (nf, 3), linear Jacobians (nf, 3, nj) and angular
        rates of the feet relative to the base (nf, 3) [rad/s]."""
        model, data = self.model, self.data
        q = np.concatenate([np.zeros(3), [0.0, 0.0, 0.0, 1.0], qj])
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        r = np.empty((self.n_feet, 3))
        J = np.empty((self.n_feet, 3, self.robot.nj))
        w_rel = np.empty((self.n_feet, 3))
        for i, fid in enumerate(self._foot_ids):
            r[i] = data.oMf[fid].translation
            Jf = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)[:, 6:]
            J[i] = Jf[:3]
            w_rel[i] = Jf[3:] @ qd
        return r, J, w_rel

    def _require_reset(self) -> None:
        if self._q is None:
            raise RuntimeError("call StateEstimator.reset(q0, v0) before update()")


# ---------------------------------------------------------------------------------------------- helpers
def _kalman_correct(P: np.ndarray, H: np.ndarray, residual: np.ndarray, variances: np.ndarray):
    """Kalman correction ``dx = K r`` and the Joseph-form covariance, ``R = diag(variances)``."""
    S = H @ P @ H.T + np.diag(variances)
    K = np.linalg.solve(S, H @ P).T  # P H^T S^-1 (S, P symmetric)
    dx = K @ residual
    A = np.eye(P.shape[0]) - K @ H
    P = A @ P @ A.T + (K * variances) @ K.T
    return dx, _symmetric(P)


def _symmetric(P: np.ndarray) -> np.ndarray:
    return 0.5 * (P + P.T)


def _rotation(quat: np.ndarray) -> np.ndarray:
    """Rotation matrix of a quaternion (x, y, z, w) (normalised here)."""
    quat = np.asarray(quat, dtype=float)
    return pin.Quaternion(quat / np.linalg.norm(quat)).toRotationMatrix()


def _orthonormalize(R: np.ndarray) -> np.ndarray:
    u, _, vt = np.linalg.svd(R)
    return u @ vt
