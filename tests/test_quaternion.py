"""The NumPy quaternion helpers against Pinocchio's quaternion, one sample and arrays of samples."""

import numpy as np
import pinocchio as pin
import pytest

from wbmpc.model.quaternion import (
    base_z_axis,
    cross3,
    quaternion_conjugate,
    quaternion_from_matrix,
    quaternion_multiply,
    rotation_matrix,
    tilt,
)


def _random_configurations(n, seed=0):
    rng = np.random.default_rng(seed)
    q = np.zeros((n, 7))
    q[:, :3] = rng.normal(size=(n, 3))
    q[:, 3:7] = [pin.Quaternion(rng.normal(size=4)).normalized().coeffs() for _ in range(n)]
    return q


def test_rotation_matrix_z_axis_and_tilt_match_pinocchio():
    q = _random_configurations(50)
    R = np.array([pin.Quaternion(qi[3:7]).toRotationMatrix() for qi in q])
    np.testing.assert_allclose(rotation_matrix(q[:, 3:7]), R, atol=1e-14)
    np.testing.assert_allclose(base_z_axis(q), R[:, :, 2], atol=1e-14)
    np.testing.assert_allclose(tilt(q), np.arccos(np.clip(R[:, 2, 2], -1, 1)), atol=1e-7)
    # Leading axes are kept; one configuration gives plain floats.
    assert rotation_matrix(q[:6, 3:7].reshape(2, 3, 4)).shape == (2, 3, 3, 3)
    assert isinstance(tilt(q[0]), float)


def test_tilt_is_roll_and_pitch_not_yaw_and_ignores_the_quaternion_scale():
    q = np.zeros(7)
    q[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(0.0, 0.0, 2.5)).coeffs()  # yaw only
    assert tilt(q) == pytest.approx(0.0, abs=1e-7)
    q[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(0.3, 0.0, 1.0)).coeffs()
    assert tilt(q) == pytest.approx(0.3, abs=1e-12)
    q[3:7] *= 3.0  # not normalised: the same tilt
    assert tilt(q) == pytest.approx(0.3, abs=1e-12)


def test_product_conjugate_and_matrix_round_trip_match_pinocchio():
    rng = np.random.default_rng(3)
    for _ in range(20):
        a, b = (pin.Quaternion(rng.normal(size=4)).normalized() for _ in range(2))
        np.testing.assert_allclose(quaternion_multiply(a.coeffs(), b.coeffs()), (a * b).coeffs(), atol=1e-14)
        np.testing.assert_allclose(quaternion_conjugate(a.coeffs()), a.conjugate().coeffs(), atol=0)
        R = a.toRotationMatrix()
        back = quaternion_from_matrix(R)
        np.testing.assert_allclose(rotation_matrix(back), R, atol=1e-14)
        x, y = rng.normal(size=3), rng.normal(size=3)
        np.testing.assert_allclose(cross3(x, y), np.cross(x, y), atol=1e-14)
