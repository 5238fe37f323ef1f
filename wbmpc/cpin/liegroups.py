"""Configuration-space integration and difference (mirror of ``pinocchio.integrate`` / ``difference``).

The free-flyer block is SE(3): ``q = [p, quat]`` with ``quat = (x, y, z, w)`` and tangent
``dq = [nu, omega]`` (linear then angular, both in the base frame), integrated with the SE(3) exponential
``M_1 = M_0 exp6(dq)``. All other joints are vector spaces: ``q_1 = q_0 + dq``.
"""

from __future__ import annotations

import casadi as ca

from wbmpc.cpin.model import SymbolicModel
from wbmpc.cpin.spatial import (
    exp3_quaternion,
    log3,
    quaternion_product,
    quaternion_to_rotation,
    se3_left_jacobian,
    se3_left_jacobian_inverse,
)


def integrate_base(q_base: ca.SX, dq_base: ca.SX) -> ca.SX:
    """SE(3) integration of the free-flyer block: ``[p, quat] (+) [nu, omega]`` -> ``[p', quat']`` (7,)."""
    p, quat = q_base[0:3], q_base[3:7]
    nu, omega = dq_base[0:3], dq_base[3:6]
    R = quaternion_to_rotation(quat)
    p_next = p + ca.mtimes(R, ca.mtimes(se3_left_jacobian(omega), nu))
    dquat = exp3_quaternion(omega)
    # Keep the result in the hemisphere of the input quaternion, as Pinocchio does (matters for |omega| > pi).
    dquat = ca.if_else(dquat[3] < 0, -dquat, dquat)
    quat_next = quaternion_product(quat, dquat)
    # First-order renormalisation, as Pinocchio does after the product.
    quat_next = quat_next * (3 - ca.dot(quat_next, quat_next)) / 2
    return ca.vertcat(p_next, quat_next)


def integrate(model: SymbolicModel, q: ca.SX, dq: ca.SX) -> ca.SX:
    """``q (+) dq``: configuration (nq,) reached from ``q`` by the tangent displacement ``dq`` (nv,)."""
    return ca.vertcat(integrate_base(q[0:7], dq[0:6]), q[7:] + dq[6:])


def difference(model: SymbolicModel, q0: ca.SX, q1: ca.SX) -> ca.SX:
    """``q1 (-) q0``: tangent displacement (nv,) with ``integrate(q0, difference(q0, q1)) = q1``.

    The base part is ``log6(M0^{-1} M1)``; valid for relative base rotations below pi.
    """
    R0, R1 = quaternion_to_rotation(q0[3:7]), quaternion_to_rotation(q1[3:7])
    R = ca.mtimes(R0.T, R1)
    p = ca.mtimes(R0.T, q1[0:3] - q0[0:3])
    omega = log3(R)
    nu = ca.mtimes(se3_left_jacobian_inverse(omega), p)
    return ca.vertcat(nu, omega, q1[7:] - q0[7:])
