"""Small CasADi helpers for 3-D rotations and rigid motions, written to keep SX graphs small.

Vectors are CasADi column vectors of size 3, rotations 3x3 matrices. Constant matrices are passed through
:func:`clean_constant` so that exact zeros and ones let CasADi drop the corresponding operations.

Conventions follow Pinocchio: quaternions are stored ``(x, y, z, w)``; a motion is ``(linear, angular)``;
a force is ``(linear, angular)`` with the moment about the frame origin.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

# Below this squared rotation angle [rad^2] the exponential/log maps switch to Taylor expansions, whose
# truncation error (theta^6 ~ 1e-24) is far below double precision. The exact branch is evaluated at
# max(theta^2, eps) so that no 0/0 enters the graph, not even in derivatives of the unused branch.
SMALL_ANGLE_SQ = 1e-8


def clean_constant(values: np.ndarray, tol: float = 1e-12) -> ca.SX:
    """Return a constant SX matrix with entries within ``tol`` of 0 or +-1 snapped to exactly 0 or +-1."""
    values = np.array(values, dtype=float)
    for target in (0.0, 1.0, -1.0):
        values[np.abs(values - target) < tol] = target
    return ca.SX(ca.DM(values))


def skew(x: ca.SX) -> ca.SX:
    """Skew-symmetric matrix ``[x]_x`` with ``[x]_x y = x \\times y``."""
    return ca.vertcat(
        ca.horzcat(0, -x[2], x[1]),
        ca.horzcat(x[2], 0, -x[0]),
        ca.horzcat(-x[1], x[0], 0),
    )


def cross(a: ca.SX, b: ca.SX) -> ca.SX:
    """Cross product of two 3-vectors (element-wise formula: constant zeros are simplified away)."""
    return ca.vertcat(a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def axis_rotation(axis: int, angle: ca.SX) -> ca.SX:
    """Rotation matrix about the x (0), y (1) or z (2) axis by ``angle`` [rad]."""
    c, s = ca.cos(angle), ca.sin(angle)
    if axis == 0:
        return ca.vertcat(ca.horzcat(1, 0, 0), ca.horzcat(0, c, -s), ca.horzcat(0, s, c))
    if axis == 1:
        return ca.vertcat(ca.horzcat(c, 0, s), ca.horzcat(0, 1, 0), ca.horzcat(-s, 0, c))
    return ca.vertcat(ca.horzcat(c, -s, 0), ca.horzcat(s, c, 0), ca.horzcat(0, 0, 1))


def angle_axis_rotation(axis: np.ndarray, angle: ca.SX) -> ca.SX:
    """Rodrigues' formula ``R = I + sin(t) [k]_x + (1 - cos(t)) [k]_x^2`` for a constant unit axis ``k``."""
    k = clean_constant(np.asarray(axis, dtype=float).reshape(3, 1))
    K = skew(k)
    return ca.SX.eye(3) + ca.sin(angle) * K + (1 - ca.cos(angle)) * ca.mtimes(K, K)


def quaternion_to_rotation(quat: ca.SX) -> ca.SX:
    """Rotation matrix of a unit quaternion ``(x, y, z, w)`` (Eigen's formula, no normalisation)."""
    x, y, z, w = quat[0], quat[1], quat[2], quat[3]
    tx, ty, tz = 2 * x, 2 * y, 2 * z
    twx, twy, twz = tx * w, ty * w, tz * w
    txx, txy, txz = tx * x, ty * x, tz * x
    tyy, tyz, tzz = ty * y, tz * y, tz * z
    return ca.vertcat(
        ca.horzcat(1 - (tyy + tzz), txy - twz, txz + twy),
        ca.horzcat(txy + twz, 1 - (txx + tzz), tyz - twx),
        ca.horzcat(txz - twy, tyz + twx, 1 - (txx + tyy)),
    )


def quaternion_product(a: ca.SX, b: ca.SX) -> ca.SX:
    """Hamilton product ``a * b`` of quaternions stored ``(x, y, z, w)``."""
    av, aw, bv, bw = a[0:3], a[3], b[0:3], b[3]
    return ca.vertcat(aw * bv + bw * av + cross(av, bv), aw * bw - ca.dot(av, bv))


def _safe_angle(omega: ca.SX) -> tuple[ca.SX, ca.SX, ca.SX]:
    """Return (theta^2, small-angle flag, theta evaluated at max(theta^2, eps))."""
    theta_sq = ca.dot(omega, omega)
    small = theta_sq < SMALL_ANGLE_SQ
    return theta_sq, small, ca.sqrt(ca.fmax(theta_sq, SMALL_ANGLE_SQ))


def exp3_quaternion(omega: ca.SX) -> ca.SX:
    """Unit quaternion ``(x, y, z, w)`` of the rotation vector ``omega`` [rad]: ``(sin(t/2) k, cos(t/2))``."""
    theta_sq, small, theta = _safe_angle(omega)
    half_sinc = ca.if_else(small, 0.5 - theta_sq / 48, ca.sin(theta / 2) / theta)
    cos_half = ca.if_else(small, 1 - theta_sq / 8, ca.cos(theta / 2))
    return ca.vertcat(half_sinc * omega, cos_half)


def exp3(omega: ca.SX) -> ca.SX:
    """SO(3) exponential: rotation matrix of the rotation vector ``omega`` [rad]."""
    theta_sq, small, theta = _safe_angle(omega)
    a = ca.if_else(small, 1 - theta_sq / 6, ca.sin(theta) / theta)
    b = ca.if_else(small, 0.5 - theta_sq / 24, (1 - ca.cos(theta)) / (theta * theta))
    W = skew(omega)
    return ca.SX.eye(3) + a * W + b * ca.mtimes(W, W)


def se3_left_jacobian(omega: ca.SX) -> ca.SX:
    """``V(omega) = I + (1 - cos t)/t^2 [w]_x + (t - sin t)/t^3 [w]_x^2``, the translation part of exp6."""
    theta_sq, small, theta = _safe_angle(omega)
    b = ca.if_else(small, 0.5 - theta_sq / 24, (1 - ca.cos(theta)) / (theta * theta))
    c = ca.if_else(small, 1.0 / 6 - theta_sq / 120, (theta - ca.sin(theta)) / (theta * theta * theta))
    W = skew(omega)
    return ca.SX.eye(3) + b * W + c * ca.mtimes(W, W)


def log3(R: ca.SX) -> ca.SX:
    """SO(3) logarithm: rotation vector [rad] of ``R``, valid for rotation angles below pi.

    Uses ``theta = atan2(|vee(R - R^T)|/2, (tr R - 1)/2)``, accurate at small angles; near pi the axis
    becomes ill-conditioned (as for any formula based on the skew part).
    """
    w = 0.5 * ca.vertcat(R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1])
    sin_sq = ca.dot(w, w)
    small = sin_sq < SMALL_ANGLE_SQ
    sin_t = ca.sqrt(ca.fmax(sin_sq, SMALL_ANGLE_SQ))
    cos_t = 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1)
    theta = ca.atan2(sin_t, cos_t)
    # theta / sin(theta) ~ 1 + sin^2/6 for small angles
    scale = ca.if_else(small, 1 + sin_sq / 6, theta / sin_t)
    return scale * w


def se3_left_jacobian_inverse(omega: ca.SX) -> ca.SX:
    """Inverse of :func:`se3_left_jacobian`: ``I - [w]/2 + (1/t^2)(1 - t sin t / (2 (1 - cos t))) [w]^2``."""
    theta_sq, small, theta = _safe_angle(omega)
    d = ca.if_else(
        small,
        1.0 / 12 + theta_sq / 720,
        (1 - theta * ca.sin(theta) / (2 * (1 - ca.cos(theta)))) / (theta * theta),
    )
    W = skew(omega)
    return ca.SX.eye(3) - 0.5 * W + d * ca.mtimes(W, W)
