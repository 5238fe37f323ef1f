"""Signal filters of the estimators and the simulated sensors, and the linear algebra of the Kalman filters.

:class:`LowPassFilter` is the first-order low-pass the robots apply to their joint velocities (50 Hz on
Unitree robots, where the encoders' finite differences are noisy),

.. math::  \\hat v_k = \\hat v_{k-1} + \\alpha (v_k - \\hat v_{k-1}), \\qquad
           \\alpha = \\frac{\\Delta t}{\\Delta t + 1 / (2 \\pi f_c)}.

:func:`kalman_correct` is the Kalman measurement update of :class:`wbmpc.estimation.StateEstimator`'s two
stages, :func:`orthonormalize` its re-projection onto SO(3). Both run at 500 Hz on matrices of 3 to 24
rows, where ``np.linalg.solve`` and ``np.linalg.svd`` spend more time checking their arguments and setting
up their error state than factorising: they call the same LAPACK routines through numpy's own gufuncs (the
same bits) and check the result instead (a LAPACK failure leaves NaN: the numpy function then raises its
``LinAlgError``).
"""

from __future__ import annotations

import functools
import math
import numbers
from types import SimpleNamespace

import numpy as np

try:  # the LAPACK gufuncs np.linalg.solve / svd call once their arguments are checked
    from numpy.linalg import _umath_linalg as _lapack
except ImportError:  # pragma: no cover - a numpy without them: the public functions
    _lapack = None

__all__ = [
    "LowPassFilter",
    "cross",
    "kalman_correct",
    "kinematics_jacobian",
    "orthonormalize",
    "quaternion",
    "symmetric",
    "trust_offsets",
    "two_stage_constants",
    "window_trust",
]


class LowPassFilter:
    """First-order low-pass filter of a vector signal sampled every ``dt``.

    Args:
        cutoff_hz: Cut-off frequency [Hz] (``None`` or ``inf``: no filtering).
        dt: Sampling period [s].
    """

    def __init__(self, cutoff_hz: float | None, dt: float):
        if not isinstance(dt, numbers.Real) or dt <= 0 or not np.isfinite(dt):
            raise ValueError(f"dt must be > 0 [s], got {dt}")
        if cutoff_hz is not None and (not isinstance(cutoff_hz, numbers.Real) or not cutoff_hz > 0):
            raise ValueError(f"cutoff_hz must be > 0 [Hz] or None, got {cutoff_hz}")
        self.alpha = (
            1.0 if cutoff_hz is None or np.isinf(cutoff_hz) else dt / (dt + 1.0 / (2 * np.pi * cutoff_hz))
        )
        self.value: np.ndarray | None = None

    def __call__(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        self.value = x.copy() if self.value is None else self.value + self.alpha * (x - self.value)
        return self.value.copy()

    def reset(self) -> None:
        self.value = None


def kalman_correct(
    P: np.ndarray, H: np.ndarray, residual: np.ndarray, variances: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Kalman correction ``dx = K r`` and the Joseph-form covariance, with the noise ``diag(variances)``.

    Args:
        P: Prior covariance (n, n), symmetric.
        H: Measurement Jacobian (m, n).
        residual: Measurement minus prediction (m,).
        variances: Measurement noise variances (m,), > 0.

    Returns:
        ``(dx, P)``: the state correction (n,) and the posterior covariance (n, n), symmetrised.

    Raises:
        numpy.linalg.LinAlgError: If the innovation covariance is singular.
    """
    HP = H @ P
    S = HP @ H.T
    S.reshape(-1)[:: S.shape[0] + 1] += variances  # + diag(variances)
    K = _solve(S, HP).T  # P H^T S^-1 (S, P symmetric)
    dx = K @ residual
    if not math.isfinite(dx.dot(dx)):  # LAPACK failed (NaN): np.linalg.solve's error; or dx overflows
        np.linalg.solve(S, HP)
    A = _eye(P.shape[0]) - K @ H
    P = A @ P @ A.T
    P += (K * variances) @ K.T
    return dx, 0.5 * (P + P.T)


def symmetric(P: np.ndarray) -> np.ndarray:
    """The symmetric part ``(P + P^T) / 2`` of a square matrix."""
    return 0.5 * (P + P.T)


def orthonormalize(R: np.ndarray) -> np.ndarray:
    """The rotation ``U V^T`` nearest to a 3x3 matrix ``R = U S V^T`` (its SVD).

    Raises:
        numpy.linalg.LinAlgError: If the SVD does not converge.
    """
    if _lapack is None:  # pragma: no cover
        u, _, vt = np.linalg.svd(R)
        return u @ vt
    u, _, vt = _lapack.svd_f(R, signature="d->ddd")  # a failure leaves NaN (np.linalg.svd raises then)
    out = u @ vt
    if not math.isfinite(out.reshape(-1).dot(out.reshape(-1))):
        np.linalg.svd(R)  # raises its LinAlgError
    return out


def two_stage_constants(noise, dt: float, n_feet: int) -> SimpleNamespace:
    """The constant matrices of :class:`wbmpc.estimation.StateEstimator`'s update for its tuning ``noise``
    (:class:`wbmpc.estimation.EstimatorNoise`), period ``dt`` [s] and ``n_feet``.

    Returns:
        ``F_att``, ``Q_att``: the attitude's process model (its ``dR^T`` block set at each update) and noise;
        ``F``, ``Q``: the translation's (``Q`` without the feet's terms, added on the diagonal entries
        ``feet`` of the flattened covariance); ``half_dt2`` = dt^2 / 2; ``H_acc``, ``H_imu``: buffers of the
        attitude measurement's Jacobian (accelerometer; and IMU orientation); ``H``: the legs' Jacobians
        by contact pattern (:func:`kinematics_jacobian`, filled as they come); ``ones3``; ``noise``, ``dt``.
    """
    n, nx = noise, 6 + 3 * n_feet
    F, F_att = np.eye(nx), np.eye(6)
    F[:3, 3:6], F_att[:3, 3:] = dt * np.eye(3), -dt * np.eye(3)  # p <- v; attitude error <- gyro bias
    Q = np.diag(np.concatenate([np.full(3, n.base_position_walk**2 * dt), np.zeros(nx - 3)]))
    G = np.vstack([0.5 * dt**2 * np.eye(3), dt * np.eye(3)])  # acceleration noise -> (p, v)
    Q[:6, :6] += n.accelerometer**2 * (G @ G.T)
    H_imu = np.zeros((6, 6))
    H_imu[3:, :3] = np.eye(3)  # the IMU's orientation: residual Log(R^T R_m), H = [I 0]
    return SimpleNamespace(
        noise=noise,
        dt=dt,
        F_att=F_att,
        Q_att=np.diag([(n.gyro * dt) ** 2] * 3 + [n.gyro_bias_walk**2 * dt] * 3),
        F=F,
        Q=Q,
        feet=slice(6 * (nx + 1), None, nx + 1),  # the feet's diagonal entries, flat
        half_dt2=0.5 * dt**2,
        H_acc=np.zeros((3, 6)),
        H_imu=H_imu,
        H={},
        ones3=np.ones(3),
    )


def kinematics_jacobian(n_x: int, stance: tuple[bool, ...]) -> np.ndarray:
    """Jacobian (m, n_x) of the leg-kinematics measurements of the state ``[p, v, p_1, ..., p_n]``: per foot
    its position relative to the base (``p_i - p``), then for a stance foot the base velocity ``v``.

    Args:
        n_x: State size ``6 + 3 n``.
        stance: Stance flags (n,).

    Returns:
        H (m, n_x), read-only.
    """
    rows = []
    for i, s in enumerate(stance):
        Hp = np.zeros((3, n_x))
        Hp[:, :3], Hp[:, 6 + 3 * i : 9 + 3 * i] = -np.eye(3), np.eye(3)
        rows.append(Hp)
        if s:
            Hv = np.zeros((3, n_x))
            Hv[:, 3:6] = np.eye(3)
            rows.append(Hv)
    H = np.vstack(rows)
    H.flags.writeable = False
    return H


@functools.lru_cache(maxsize=8)
def trust_offsets(window: float, samples: int) -> np.ndarray:
    """Offsets [s] (2 samples + 1,) from ``t`` of the schedule samples of a contact-trust window
    (:func:`wbmpc.estimation.contact_trust`), ``t`` in the middle; shared, read-only."""
    offsets = np.linspace(-window, window, 2 * samples + 1)
    offsets.flags.writeable = False
    return offsets


def window_trust(contact: np.ndarray, samples: int) -> list[float]:
    """Contact trust (n_feet floats) from the flags (n_feet, 2 samples + 1) over a window (``t`` in the
    middle, :func:`trust_offsets`): for a stance foot the fewer of its stance samples before and after ``t``
    over ``samples``, 0 for a swing foot."""
    trust = []
    for flags in contact.tolist():
        if not flags[samples]:
            trust.append(0.0)
            continue
        back = (flags[samples::-1] + [False]).index(False) - 1  # stance samples before t
        ahead = (flags[samples:] + [False]).index(False) - 1
        trust.append(min(back, ahead) / samples)
    return trust


def quaternion(R: np.ndarray) -> list[float]:
    """The quaternion ``[x, y, z, w]`` of a rotation matrix (3, 3), computed as Eigen does
    (``pinocchio.Quaternion(R).coeffs()``, the same operations) on plain floats."""
    m = R.tolist()
    t = m[0][0] + (m[1][1] + m[2][2])  # Eigen's trace
    if t > 0.0:
        t = math.sqrt(t + 1.0)
        w, t = 0.5 * t, 0.5 / t
        return [(m[2][1] - m[1][2]) * t, (m[0][2] - m[2][0]) * t, (m[1][0] - m[0][1]) * t, w]
    i = 1 if m[1][1] > m[0][0] else 0
    i = 2 if m[2][2] > m[i][i] else i
    j, k = (i + 1) % 3, (i + 2) % 3
    t = math.sqrt(m[i][i] - m[j][j] - m[k][k] + 1.0)
    q = [0.0] * 4
    q[i], t = 0.5 * t, 0.5 / t
    q[3], q[j], q[k] = (m[k][j] - m[j][k]) * t, (m[j][i] + m[i][j]) * t, (m[k][i] + m[i][k]) * t
    return q


def cross(a, b) -> list[float]:
    """``np.cross`` of two 3-vectors of floats (sequences): the same products and differences, as a list,
    without numpy's overhead on 3-vectors."""
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.linalg.solve(a, b)`` of float64 matrices a (n, n), b (n, k): the same LAPACK ``gesv``, whose
    failure (a singular ``a``) leaves NaN in the result, which :func:`kalman_correct` checks."""
    if _lapack is None:  # pragma: no cover
        return np.linalg.solve(a, b)
    return _lapack.solve(a, b, signature="dd->d")


_EYES: dict[int, np.ndarray] = {}


def _eye(n: int) -> np.ndarray:
    """The identity (n, n), shared (read-only)."""
    eye = _EYES.get(n)
    if eye is None:
        eye = _EYES[n] = np.eye(n)
        eye.flags.writeable = False
    return eye
