"""Base orientation from the configuration's quaternion, in NumPy (vectorised over leading axes).

Pinocchio's free-flyer configuration stores the base orientation as ``q[3:7] = (x, y, z, w)``. These are
the few formulas the plants, the closed loop and the log analysis need on whole arrays of samples, where
building a ``pin.Quaternion`` per sample would be slow; :func:`wbmpc.model.robot.heading` is the yaw of one
configuration.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

__all__ = [
    "base_z_axis",
    "cross3",
    "quaternion_conjugate",
    "quaternion_from_matrix",
    "quaternion_multiply",
    "rotation_matrix",
    "tilt",
]


def rotation_matrix(quat: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion ``(x, y, z, w)`` (not normalised here).

    Args:
        quat: Quaternion(s), shape (..., 4).

    Returns:
        Shape (..., 3, 3): the base axes in world coordinates as columns.
    """
    x, y, z, w = np.moveaxis(np.asarray(quat, dtype=float), -1, 0)
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    return np.moveaxis(np.array(rows), (0, 1), (-2, -1))


def base_z_axis(q: np.ndarray) -> np.ndarray:
    """World coordinates of the base's z axis: the last column of :func:`rotation_matrix`.

    Args:
        q: Configuration(s) with the quaternion in ``q[..., 3:7]`` (normalised here), shape (..., nq).

    Returns:
        Shape (..., 3).
    """
    quat = np.asarray(q, dtype=float)[..., 3:7]
    x, y, z, w = np.moveaxis(quat / np.linalg.norm(quat, axis=-1, keepdims=True), -1, 0)
    return np.stack([2 * (x * z + y * w), 2 * (y * z - x * w), 1 - 2 * (x * x + y * y)], axis=-1)


def tilt(q: np.ndarray) -> float | np.ndarray:
    """Angle [rad] between the base z axis and the world z axis (roll and pitch combined, not yaw):
    ``arccos(R_zz) = arccos(1 - 2 (x^2 + y^2))`` of the normalised quaternion.

    Args:
        q: Configuration(s), shape (nq,) or (..., nq).

    Returns:
        A float for one configuration, else an array of shape (...,).
    """
    q = np.asarray(q, dtype=float)
    if q.ndim == 1:  # one configuration, on every logged tick of the loop: plain floats, about 1 us
        x, y, z, w = q[3:7]
        cos_tilt = 1.0 - 2.0 * (x * x + y * y) / (x * x + y * y + z * z + w * w)
        return math.acos(min(1.0, max(-1.0, cos_tilt)))
    return np.arccos(np.clip(base_z_axis(q)[..., 2], -1.0, 1.0))


def quaternion_from_matrix(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of a rotation matrix (3, 3)."""
    return pin.Quaternion(R).coeffs()


def quaternion_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` of quaternions (x, y, z, w), shape (4,)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ]
    )


def quaternion_conjugate(quat: np.ndarray) -> np.ndarray:
    """Conjugate (the inverse of a unit quaternion) of (x, y, z, w), shape (4,)."""
    return np.array([-quat[0], -quat[1], -quat[2], quat[3]])


def cross3(a, b) -> np.ndarray:
    """Cross product of two 3-vectors (``np.cross`` costs about 25 us on 3-vectors, this about 2 us: it runs
    several times per plant step)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])
