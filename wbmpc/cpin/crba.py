"""Composite rigid body algorithm in CasADi (mirror of ``pinocchio.crba``): the joint-space inertia matrix.

.. math::  M_{ij} = S_i^T \\, {}^iX_j^* \\, I^c_j S_j \\quad (i \\text{ ancestor of } j), \\qquad
           I^c_j = I_j + \\sum_{k \\in \\text{children}(j)} {}^jX_k^* I^c_k \\, {}^kX_j

with :math:`I^c_j` the composite spatial inertia of the subtree rooted at joint j, in the joint frame. Each
inertia is kept as (mass [kg], first moment :math:`h = m c` [kg m], rotational inertia about the frame
origin [kg m^2]) rather than a dense 6x6 matrix, and each 1-DoF column :math:`I^c_j S_j` is a single spatial
force carried up the tree with the ``liMi`` transforms of :func:`~wbmpc.cpin.kinematics.forward_kinematics`.
The free-flyer rows and columns are in the base frame (Pinocchio's ``LOCAL`` base velocity).
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from wbmpc.cpin.kinematics import SymbolicData, forward_kinematics
from wbmpc.cpin.model import JointInfo, SymbolicModel
from wbmpc.cpin.spatial import clean_constant, cross, skew


@dataclass
class Inertia:
    """A spatial inertia about a frame origin, in that frame's axes.

    Attributes:
        mass: Mass [kg] (a constant).
        h: First moment ``m c`` (3, 1) [kg m], ``c`` the centre of mass in the frame.
        rotational: Rotational inertia about the frame origin (3, 3) [kg m^2], symmetric.
    """

    mass: float
    h: ca.SX
    rotational: ca.SX

    def matrix(self) -> ca.SX:
        """The 6x6 matrix ``[[m I, -[h]x], [[h]x, I_o]]`` acting on motions ``(linear, angular)``."""
        H = skew(self.h)
        return ca.vertcat(ca.horzcat(self.mass * ca.SX.eye(3), -H), ca.horzcat(H, self.rotational))

    def __add__(self, other: Inertia) -> Inertia:
        return Inertia(self.mass + other.mass, self.h + other.h, self.rotational + other.rotational)


def symmetric(entries) -> ca.SX:
    """3x3 symmetric matrix from ``(xx, xy, xz, yy, yz, zz)``; mirrored entries share one SX node."""
    xx, xy, xz, yy, yz, zz = entries
    return ca.vertcat(ca.horzcat(xx, xy, xz), ca.horzcat(xy, yy, yz), ca.horzcat(xz, yz, zz))


_UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def rotate_symmetric(R: ca.SX, S: ca.SX) -> ca.SX:
    """``R S R^T`` for a symmetric ``S``, computing only the upper triangle of the product."""
    T = ca.mtimes(R, S)
    return symmetric([T[i, 0] * R[j, 0] + T[i, 1] * R[j, 1] + T[i, 2] * R[j, 2] for i, j in _UPPER])


def body_inertia(info: JointInfo) -> Inertia:
    """Constant inertia of the body of a joint about the joint origin: ``I_o = I_c - m [c]x^2``."""
    c = np.array(ca.DM(info.lever)).ravel()
    I_c = np.array(ca.DM(info.rotational_inertia))
    I_o = I_c + info.mass * (c @ c * np.eye(3) - np.outer(c, c))
    return Inertia(info.mass, clean_constant(info.mass * c.reshape(3, 1)), clean_constant(I_o))


def inertia_to_parent(Y: Inertia, R: ca.SX, p: ca.SX) -> Inertia:
    """Express ``Y`` (joint frame) in the parent frame, given ``liMi = (R, p)``.

    With :math:`h_r = R h` and :math:`I_r = R I R^T` (still about the joint origin), moving the origin by
    :math:`-p` gives :math:`h' = h_r + m p` and :math:`I' = I_r - m [p]_\\times^2 - [p]_\\times [h_r]_\\times
    - [h_r]_\\times [p]_\\times`, expanded with :math:`[a]_\\times [b]_\\times = b a^T - (a \\cdot b) I`.
    """
    h_r = ca.mtimes(R, Y.h)
    I_r = rotate_symmetric(R, Y.rotational)
    # A constant for revolute joints (fixed p); prismatic joints move p with q.
    shift = -Y.mass * (ca.mtimes(p, p.T) - ca.dot(p, p) * ca.SX.eye(3))
    ph = 2 * ca.dot(p, h_r)
    cross_terms = symmetric([(ph if i == j else 0) - h_r[i] * p[j] - p[i] * h_r[j] for i, j in _UPPER])
    return Inertia(Y.mass, h_r + Y.mass * p, I_r + shift + cross_terms)


def force_to_parent(R: ca.SX, p: ca.SX, f: ca.SX, n: ca.SX) -> tuple[ca.SX, ca.SX]:
    """Spatial force ``(f, n)`` from a joint frame to its parent: ``(R f, R n + p x R f)``."""
    f_parent = ca.mtimes(R, f)
    return f_parent, ca.mtimes(R, n) + cross(p, f_parent)


def inertia_times_subspace(Y: Inertia, info: JointInfo) -> tuple[ca.SX, ca.SX]:
    """``Y S`` for a 1-DoF joint of axis ``e``: revolute ``(e x h, I_o e)``, prismatic ``(m e, h x e)``."""
    e = clean_constant(info.axis_vector.reshape(3, 1))
    if info.kind == "revolute":
        return cross(e, Y.h), ca.mtimes(Y.rotational, e)
    return Y.mass * e, cross(Y.h, e)


def subspace_transpose_times(info: JointInfo, f: ca.SX, n: ca.SX) -> ca.SX:
    """``S^T (f, n)`` for a 1-DoF joint: ``e . n`` (revolute) or ``e . f`` (prismatic)."""
    e = clean_constant(info.axis_vector.reshape(3, 1))
    return ca.dot(e, n if info.kind == "revolute" else f)


def composite_inertias(model: SymbolicModel, data: SymbolicData) -> tuple[list, list[list]]:
    """Composite inertias of every subtree and the entries of the joint-space inertia matrix.

    Returns:
        ``(Yc, M)``: ``Yc[j]`` the :class:`Inertia` of the subtree of joint j in its frame (``Yc[1]``: the
        whole robot in the base frame), and ``M`` the nv x nv inertia matrix as nested lists of SX
        scalars (full, symmetric, structural zeros as ``0``).
    """
    nv = model.nv
    Yc = [None] + [body_inertia(info) for info in model.joints[1:]]
    M = [[0] * nv for _ in range(nv)]
    for info in reversed(model.joints[1:]):
        j = info.index
        if info.kind == "freeflyer":
            block = Yc[j].matrix()
            for r in range(6):
                for c in range(6):
                    M[info.idx_v + r][info.idx_v + c] = block[r, c]
            continue
        col = info.idx_v
        f, n = inertia_times_subspace(Yc[j], info)
        M[col][col] = subspace_transpose_times(info, f, n)
        # Carry the column I^c_j S_j up to every ancestor: M[anc, j] = S_anc^T (force in the anc frame).
        k = j
        while model.joints[k].parent != 0:
            f, n = force_to_parent(data.rotations[k], data.translations[k], f, n)
            k = model.joints[k].parent
            anc = model.joints[k]
            if anc.kind == "freeflyer":
                rows = [f[i] for i in range(3)] + [n[i] for i in range(3)]
                for r in range(6):
                    M[anc.idx_v + r][col] = M[col][anc.idx_v + r] = rows[r]
            else:
                M[anc.idx_v][col] = M[col][anc.idx_v] = subspace_transpose_times(anc, f, n)
        if info.parent != 0:
            Yc[info.parent] = Yc[info.parent] + inertia_to_parent(
                Yc[j], data.rotations[j], data.translations[j]
            )
    return Yc, M


def crba(model: SymbolicModel, q: ca.SX, data: SymbolicData | None = None) -> ca.SX:
    """Joint-space inertia matrix ``M(q)`` (nv x nv), full and symmetric (``pinocchio.crba`` fills the upper
    triangle only).

    Args:
        model: Symbolic model tables.
        q: Configuration (nq,).
        data: Output of ``forward_kinematics(model, q, ...)`` to reuse its joint transforms.

    Returns:
        ``M`` [kg, kg m, kg m^2]: kinetic energy ``v^T M v / 2`` with the base twist in the base frame, the
        armature (``model.armature``) on its diagonal.
    """
    data = forward_kinematics(model, q) if data is None else data
    _, M = composite_inertias(model, data)
    add_armature(model, M)
    return ca.vertcat(*[ca.horzcat(*row) for row in M])


def add_armature(model: SymbolicModel, M: list[list]) -> None:
    """Add ``model.armature`` to the diagonal of ``M`` (nested lists, in place), as ``pinocchio.crba`` does;
    zero entries add no operation."""
    for k, armature in enumerate(model.armature):
        if armature != 0.0:
            M[k][k] = M[k][k] + float(armature)
