"""Recursive Newton-Euler inverse dynamics in CasADi (mirror of ``pinocchio.rnea`` with ``fext``).

.. math::  \\tau = M(q) a + b(q, v) - \\sum_c J_c(q)^T F_c

``M`` includes the model's armature (``model.armature``, the rotor inertia on the diagonal): like
``pinocchio.rnea``, ``tau_i += armature_i a_i``.

where each :math:`F_c` is a 3-D force [N] in world axes applied at the origin of contact frame ``c``
(``LOCAL_WORLD_ALIGNED`` Jacobian). The first six rows are the base wrench in the base frame: they must
vanish for a physically consistent motion of the unactuated base.
"""

from __future__ import annotations

from collections.abc import Sequence

import casadi as ca

from wbmpc.cpin.kinematics import Motion, SymbolicData, forward_kinematics
from wbmpc.cpin.model import SymbolicModel
from wbmpc.cpin.spatial import cross


def _inertia_times(info, m: Motion) -> tuple[ca.SX, ca.SX]:
    """Spatial inertia about the joint origin times a motion: ``(m (v - c x w), I_c w + c x f)``."""
    f_lin = info.mass * (m.linear - cross(info.lever, m.angular))
    return f_lin, ca.mtimes(info.rotational_inertia, m.angular) + cross(info.lever, f_lin)


def rnea(
    model: SymbolicModel,
    q: ca.SX,
    v: ca.SX,
    a: ca.SX,
    forces: dict[str, ca.SX] | None = None,
    data: SymbolicData | None = None,
) -> ca.SX:
    """Joint torques and base wrench (nv,) realising acceleration ``a`` under external point forces.

    Args:
        model: Symbolic model tables.
        q: Configuration (nq,).
        v: Generalised velocity (nv,).
        a: Generalised acceleration (nv,) [m/s^2, rad/s^2].
        forces: ``{frame name: world-frame force (3,) [N]}`` acting on the robot at the frame origins.
        data: Output of ``forward_kinematics(model, q, v, a)`` to reuse (e.g. shared with frame velocities).

    Returns:
        ``tau`` (nv,): base wrench in the base frame (rows 0-5) then joint torques [N m].
    """
    data = forward_kinematics(model, q, v, a) if data is None else data
    if data.a is None:
        raise ValueError("rnea needs forward kinematics computed with velocity and acceleration")
    n = len(model.joints)
    f_lin: list = [None] * n
    f_ang: list = [None] * n
    for info in model.joints[1:]:
        j = info.index
        vi, ai = data.v[j], data.a[j]
        h_lin, h_ang = _inertia_times(info, vi)
        ia_lin, ia_ang = _inertia_times(info, ai)
        # f = I a + v x* (I v)
        f_lin[j] = ia_lin + cross(vi.angular, h_lin)
        f_ang[j] = ia_ang + cross(vi.angular, h_ang) + cross(vi.linear, h_lin)

    for frame, force in (forces or {}).items():
        joint, _, p_f = model.frame(frame)
        local = data.rotate_to_local(joint, force)
        f_lin[joint] = f_lin[joint] - local
        f_ang[joint] = f_ang[joint] - cross(p_f, local)

    tau = [None] * model.nv
    for info in reversed(model.joints[1:]):
        j = info.index
        if info.kind == "freeflyer":
            for k in range(3):
                tau[k] = f_lin[j][k]
                tau[3 + k] = f_ang[j][k]
            continue
        axis = ca.SX(info.axis_vector.reshape(3, 1))
        tau[info.idx_v] = ca.dot(axis, f_ang[j] if info.kind == "revolute" else f_lin[j])
        # Transmit the joint wrench to the parent: (R f, R n + p x R f).
        R, p = data.rotations[j], data.translations[j]
        parent_lin = ca.mtimes(R, f_lin[j])
        parent_ang = ca.mtimes(R, f_ang[j]) + cross(p, parent_lin)
        f_lin[info.parent] = f_lin[info.parent] + parent_lin
        f_ang[info.parent] = f_ang[info.parent] + parent_ang
    for k, armature in enumerate(model.armature):
        if armature != 0.0:  # no operation for the zero entries: the code of a model without armature
            tau[k] = tau[k] + float(armature) * a[k]
    return ca.vertcat(*tau)


def rnea_function(model: SymbolicModel, contact_frames: Sequence[str], name: str = "rnea") -> ca.Function:
    """A ``casadi.Function`` ``(q, v, a, F) -> tau``, ``F`` stacking 3-D world forces per contact frame."""
    q, v, a = ca.SX.sym("q", model.nq), ca.SX.sym("v", model.nv), ca.SX.sym("a", model.nv)
    F = ca.SX.sym("F", 3 * len(contact_frames))
    forces = {frame: F[3 * i : 3 * i + 3] for i, frame in enumerate(contact_frames)}
    tau = rnea(model, q, v, a, forces)
    return ca.Function(name, [q, v, a, F], [tau], ["q", "v", "a", "F"], ["tau"])
