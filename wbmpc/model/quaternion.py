"""Base orientation from the configuration's quaternion, in NumPy (vectorised over leading axes).

Pinocchio's free-flyer configuration stores the base orientation as ``q[3:7] = (x, y, z, w)``. These are
the few formulas the plants, the closed loop and the log analysis need on whole arrays of samples, where
building a ``pin.Quaternion`` per sample would be slow; :func:`wbmpc.model.robot.heading` is the yaw of one
configuration.
"""

from __future__ import annotations

import numpy as np

__all__ = ["base_z_axis", "rotation_matrix", "tilt"]


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
    out = np.arccos(np.clip(base_z_axis(q)[..., 2], -1.0, 1.0))
    return float(out) if np.ndim(out) == 0 else out
