"""Forward dynamics in CasADi (mirror of ``pinocchio.aba`` with ``fext``).

.. math::  a = M(q)^{-1} \\left( \\tau - b(q, v) + \\sum_c J_c(q)^T F_c \\right)

with the force convention of :func:`wbmpc.cpin.rnea.rnea`: each :math:`F_c` is a 3-D force [N] in world
axes at the origin of contact frame ``c``. Two algorithms give the same result:

* ``"articulated"`` (default, fewer instructions): Featherstone's articulated-body algorithm. The 6x6
  articulated inertias are kept as 3x3 blocks ``[[A, B], [B^T, C]]``, and the rows and columns that the
  projection ``I^a - U U^T / D`` annihilates (the joint axis of an axis-aligned joint) are exact zeros.
* ``"crba"``: :math:`M` by the composite rigid body algorithm, the bias :math:`b - J_c^T F` by RNEA at
  :math:`a = 0` on the same kinematics, then a sparse :math:`M = L^T D L` factorisation that follows the
  kinematic tree (Featherstone, *Rigid Body Dynamics Algorithms*, sec. 6.5): no fill-in, so its cost
  grows with the depth of the tree, not with nv^3.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import casadi as ca

from wbmpc.cpin.crba import (
    add_armature,
    body_inertia,
    composite_inertias,
    force_to_parent,
    rotate_symmetric,
    symmetric,
)
from wbmpc.cpin.kinematics import Motion, _subspace, forward_kinematics, motion_act_inv, motion_cross
from wbmpc.cpin.model import SymbolicModel
from wbmpc.cpin.rnea import rnea
from wbmpc.cpin.spatial import clean_constant, cross, skew

_UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def dof_parents(model: SymbolicModel) -> list[int]:
    """Parent degree of freedom of each velocity index (-1 for the first), as in Featherstone's lambda.

    The six free-flyer DoFs form a chain, so the base block of ``M`` is treated as dense.
    """
    parents = [-1] * model.nv
    for info in model.joints[1:]:
        width = 6 if info.kind == "freeflyer" else 1
        if info.parent != 0:
            parent = model.joints[info.parent]
            parents[info.idx_v] = parent.idx_v + (5 if parent.kind == "freeflyer" else 0)
        for k in range(1, width):
            parents[info.idx_v + k] = info.idx_v + k - 1
    return parents


def ltdl(M: list[list], parents: Sequence[int]) -> tuple[list[list], list]:
    """Sparse ``M = L^T D L`` factorisation of a tree-structured matrix (Featherstone's LTDL).

    ``L`` is unit lower triangular with the sparsity of ``M`` (``L[k][i]`` nonzero only for ``i`` an
    ancestor of ``k``), so the factorisation has no fill-in when parents come before children.

    Args:
        M: Symmetric positive-definite matrix as nested lists of SX scalars (only ancestor entries read).
        parents: Parent index of each row (-1 for a root), ``parents[k] < k``.

    Returns:
        ``(L, D)``: ``L[k][i]`` for ancestors ``i`` of ``k`` (other entries untouched), ``D`` the diagonal.
    """
    H = [list(row) for row in M]
    for k in reversed(range(len(H))):
        inv = 1 / H[k][k]
        i = parents[k]
        while i != -1:
            ratio = H[k][i] * inv
            j = i
            while j != -1:
                H[i][j] = H[i][j] - ratio * H[k][j]
                j = parents[j]
            H[k][i] = ratio
            i = parents[i]
    return H, [H[k][k] for k in range(len(H))]


def ltdl_solve(L: list[list], D: list, parents: Sequence[int], b: Sequence) -> list:
    """Solve ``L^T D L x = b`` with the factors of :func:`ltdl` (back then forward substitution)."""
    n = len(b)
    y = list(b)
    for k in reversed(range(n)):  # L^T y' = b: every descendant of k is final before k is used
        i = parents[k]
        while i != -1:
            y[i] = y[i] - L[k][i] * y[k]
            i = parents[i]
    x = [y[k] / D[k] for k in range(n)]
    for k in range(n):  # L x = D^-1 y': ancestors first
        i = parents[k]
        while i != -1:
            x[k] = x[k] - L[k][i] * x[i]
            i = parents[i]
    return x


def _aba_crba(model: SymbolicModel, q, v, tau, forces) -> ca.SX:
    """``M^{-1} (tau - rnea(q, v, 0, F))`` with ``M`` from CRBA on the same kinematics and a tree LTDL."""
    zero = ca.SX.zeros(model.nv, 1)
    data = forward_kinematics(model, q, v, zero)
    bias = rnea(model, q, v, zero, forces, data)  # b(q, v) - J_c^T F
    _, M = composite_inertias(model, data)
    add_armature(model, M)
    parents = dof_parents(model)
    L, D = ltdl(M, parents)
    return ca.vertcat(*ltdl_solve(L, D, parents, [tau[k] - bias[k] for k in range(model.nv)]))


@dataclass
class _Articulated:
    """Symmetric 6x6 articulated inertia ``[[A, B], [B^T, C]]`` acting on motions ``(linear, angular)``."""

    A: ca.SX
    B: ca.SX
    C: ca.SX

    def times(self, m: Motion) -> tuple[ca.SX, ca.SX]:
        return (
            ca.mtimes(self.A, m.linear) + ca.mtimes(self.B, m.angular),
            ca.mtimes(self.B.T, m.linear) + ca.mtimes(self.C, m.angular),
        )

    def __add__(self, other: _Articulated) -> _Articulated:
        return _Articulated(self.A + other.A, self.B + other.B, self.C + other.C)


def _rank_one_downdate(Y: _Articulated, u_lin, u_ang, inv_d, info, armature: float = 0.0) -> _Articulated:
    """``Y - U U^T / D`` with ``U = Y S = (u_lin, u_ang)`` and ``D = S^T U + armature``.

    Without armature the result annihilates the joint's motion subspace (``(Y - U U^T / D) S = U - U =
    0``): for an axis-aligned joint the corresponding rows and columns are set to exact zeros instead of
    computed as rounding noise, which removes their operations here and in every transform to the root.
    With armature they do not vanish (``U armature / D``) and are computed.
    """
    w_lin, w_ang = u_lin * inv_d, u_ang * inv_d
    A = [[Y.A[i, j] - w_lin[i] * u_lin[j] for j in range(3)] for i in range(3)]
    B = [[Y.B[i, j] - w_lin[i] * u_ang[j] for j in range(3)] for i in range(3)]
    C = [[Y.C[i, j] - w_ang[i] * u_ang[j] for j in range(3)] for i in range(3)]
    if info.axis is not None and armature == 0.0:
        k = info.axis
        for i in range(3):
            if info.kind == "revolute":  # S = (0, e_k): column k of B and of C vanish
                B[i][k] = C[i][k] = C[k][i] = 0
            else:  # S = (e_k, 0): column k of A and row k of B vanish
                A[i][k] = A[k][i] = B[k][i] = 0
    return _Articulated(
        symmetric([A[i][j] for i, j in _UPPER]),
        ca.vertcat(*[ca.horzcat(*row) for row in B]),
        symmetric([C[i][j] for i, j in _UPPER]),
    )


def _articulated_to_parent(Y: _Articulated, R: ca.SX, p: ca.SX) -> _Articulated:
    """``X^* Y X^{-1}`` for ``liMi = (R, p)``.

    After rotating the blocks (``A' = R A R^T``, ...), moving the origin by ``P = [p]x`` gives
    ``B'' = B' - A' P`` and ``C'' = C' + P B' + (P B')^T - P A' P``.
    """
    A = rotate_symmetric(R, Y.A)
    B = ca.mtimes(ca.mtimes(R, Y.B), R.T)
    C = rotate_symmetric(R, Y.C)
    P = skew(p)
    AP = ca.mtimes(A, P)
    PB = ca.mtimes(P, B)
    PAP = ca.mtimes(P, AP)
    C_shift = symmetric([PB[i, j] + PB[j, i] - PAP[i, j] for i, j in _UPPER])
    return _Articulated(A, B - AP, C + C_shift)


def _aba_articulated(model: SymbolicModel, q, v, tau, forces) -> ca.SX:
    """Featherstone's articulated-body algorithm (three passes), gravity as the root acceleration ``-g``."""
    data = forward_kinematics(model, q, v)
    n = len(model.joints)
    Ia: list = [None] * n
    pA: list = [None] * n
    c: list = [None] * n
    for info in model.joints[1:]:
        j = info.index
        Y = body_inertia(info)
        Ia[j] = _Articulated(Y.mass * ca.SX.eye(3), -skew(Y.h), Y.rotational)
        vi = data.v[j]
        # pA = v x* (I v): the velocity-product force of the body alone.
        h_lin = Y.mass * vi.linear - cross(Y.h, vi.angular)
        h_ang = cross(Y.h, vi.linear) + ca.mtimes(Y.rotational, vi.angular)
        pA[j] = [cross(vi.angular, h_lin), cross(vi.angular, h_ang) + cross(vi.linear, h_lin)]
        if info.kind != "freeflyer":
            c[j] = motion_cross(vi, _subspace(info, v[info.idx_v]))
    for frame, force in (forces or {}).items():
        joint, _, p_f = model.frame(frame)
        local = data.rotate_to_local(joint, force)
        pA[joint] = [pA[joint][0] - local, pA[joint][1] - cross(p_f, local)]

    U: list = [None] * n
    inv_d: list = [None] * n
    u: list = [None] * n
    for info in reversed(model.joints[1:]):
        j = info.index
        if info.kind == "freeflyer" or info.parent == 0:
            continue
        e = clean_constant(info.axis_vector.reshape(3, 1))
        Y = Ia[j]
        if info.kind == "revolute":
            U[j] = (ca.mtimes(Y.B, e), ca.mtimes(Y.C, e))
            D, s_pA = ca.dot(e, U[j][1]), ca.dot(e, pA[j][1])
        else:
            U[j] = (ca.mtimes(Y.A, e), ca.mtimes(Y.B.T, e))
            D, s_pA = ca.dot(e, U[j][0]), ca.dot(e, pA[j][0])
        armature = float(model.armature[info.idx_v])
        if armature != 0.0:
            D = D + armature
        inv_d[j] = 1 / D
        u[j] = tau[info.idx_v] - s_pA
        Ya = _rank_one_downdate(Y, U[j][0], U[j][1], inv_d[j], info, armature)
        # pa = pA + Ia_a c + U u / D (Ia_a has the exact zeros of the downdate)
        Ic_lin, Ic_ang = Ya.times(c[j])
        gain = u[j] * inv_d[j]
        pa_lin = pA[j][0] + Ic_lin + U[j][0] * gain
        pa_ang = pA[j][1] + Ic_ang + U[j][1] * gain
        R, p = data.rotations[j], data.translations[j]
        Ia[info.parent] = Ia[info.parent] + _articulated_to_parent(Ya, R, p)
        f_par, n_par = force_to_parent(R, p, pa_lin, pa_ang)
        pA[info.parent] = [pA[info.parent][0] + f_par, pA[info.parent][1] + n_par]

    root = model.joints[1]
    Y = Ia[1]
    block = ca.vertcat(ca.horzcat(Y.A, Y.B), ca.horzcat(Y.B.T, Y.C))
    chain = [-1, 0, 1, 2, 3, 4]
    rows = [[block[r, k] for k in range(6)] for r in range(6)]
    rhs = [tau[root.idx_v + k] - (pA[1][0][k] if k < 3 else pA[1][1][k - 3]) for k in range(6)]
    # The base acceleration excludes gravity: a_root = ddq_base + (R_b^T (-g), 0).
    g_base = ca.mtimes(data.rotations[1].T, model.gravity)
    for k in range(6):
        armature = float(model.armature[root.idx_v + k])
        if armature != 0.0:  # armature * ddq_base = armature * (a_root + g_base)
            rows[k][k] = rows[k][k] + armature
            if k < 3:
                rhs[k] = rhs[k] - armature * g_base[k]
    L, D = ltdl(rows, chain)
    a_root = ltdl_solve(L, D, chain, rhs)  # spatial acceleration of the base with gravity folded in
    acc: list = [None] * n
    acc[1] = Motion(ca.vertcat(*a_root[:3]), ca.vertcat(*a_root[3:]))
    ddq = [None] * model.nv
    for k in range(6):
        ddq[root.idx_v + k] = a_root[k] + (g_base[k] if k < 3 else 0)
    for info in model.joints[2:]:
        j = info.index
        a_in = motion_act_inv(data.rotations[j], data.translations[j], acc[info.parent])
        a_j = Motion(a_in.linear + c[j].linear, a_in.angular + c[j].angular)
        qdd = (u[j] - ca.dot(U[j][0], a_j.linear) - ca.dot(U[j][1], a_j.angular)) * inv_d[j]
        ddq[info.idx_v] = qdd
        s = _subspace(info, qdd)
        acc[j] = Motion(a_j.linear + s.linear, a_j.angular + s.angular)
    return ca.vertcat(*ddq)


def aba(
    model: SymbolicModel,
    q: ca.SX,
    v: ca.SX,
    tau: ca.SX,
    forces: dict[str, ca.SX] | None = None,
    method: str = "articulated",
) -> ca.SX:
    """Generalised acceleration (nv,) under joint torques and external point forces.

    Args:
        model: Symbolic model tables.
        q: Configuration (nq,).
        v: Generalised velocity (nv,), base twist in the base frame.
        tau: Generalised force (nv,): base wrench in the base frame (zero for a floating base) then joint
            torques [N m].
        forces: ``{frame name: world-frame force (3,) [N]}`` acting on the robot at the frame origins.
        method: ``"articulated"`` (articulated-body algorithm) or ``"crba"`` (CRBA + RNEA + tree LTDL
            solve); same result, the first has ~9 % fewer instructions on the B1 models.

    Returns:
        ``a`` (nv,) [m/s^2, rad/s^2], the base part the derivative of the base-frame twist, such that
        ``rnea(q, v, a, forces) == tau`` (the model's armature included, as in ``pinocchio.aba``).

    Raises:
        ValueError: for an unknown ``method`` or frame.
    """
    if method == "crba":
        return _aba_crba(model, q, v, tau, forces)
    if method == "articulated":
        return _aba_articulated(model, q, v, tau, forces)
    raise ValueError(f"unknown forward-dynamics method {method!r}; use 'crba' or 'articulated'")


def aba_function(
    model: SymbolicModel, contact_frames: Sequence[str], method: str = "articulated", name: str = "aba"
) -> ca.Function:
    """A ``casadi.Function`` ``(q, v, tau, F) -> a``, ``F`` stacking 3-D world forces per contact frame."""
    q, v, tau = ca.SX.sym("q", model.nq), ca.SX.sym("v", model.nv), ca.SX.sym("tau", model.nv)
    F = ca.SX.sym("F", 3 * len(contact_frames))
    forces = {frame: F[3 * i : 3 * i + 3] for i, frame in enumerate(contact_frames)}
    a = aba(model, q, v, tau, forces, method)
    return ca.Function(name, [q, v, tau, F], [a], ["q", "v", "tau", "F"], ["a"])
