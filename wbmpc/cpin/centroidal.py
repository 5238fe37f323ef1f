"""Centroidal dynamics and static torques in CasADi (mirrors of Pinocchio's centroidal algorithms).

The centroidal momentum :math:`h_G = (m \\dot c, k_G) = A_G(q) v` stacks the linear momentum [kg m/s] and
the angular momentum about the centre of mass c [kg m^2/s], both in world axes (``pinocchio.
computeCentroidalMap``). Its rate only depends on the external forces, the joint torques being internal:

.. math::  \\dot h_G = A_G a + \\dot A_G v = \\begin{bmatrix} m g + \\sum_c F_c \\\\
           \\sum_c (p_c - c) \\times F_c \\end{bmatrix}.

The map is built from the composite-inertia columns of :func:`~wbmpc.cpin.crba.composite_inertias`: the
base rows of ``M`` are the momentum map in the base frame about the base origin, so only a shift to the
centre of mass and one rotation to world axes remain.
"""

from __future__ import annotations

import casadi as ca

from wbmpc.cpin.crba import body_inertia, composite_inertias, force_to_parent
from wbmpc.cpin.kinematics import SymbolicData, forward_kinematics
from wbmpc.cpin.model import SymbolicModel
from wbmpc.cpin.spatial import clean_constant, cross


def _base_momentum_map(model: SymbolicModel, data: SymbolicData) -> tuple[ca.SX, ca.SX]:
    """Centroidal map in base axes, ``A_b`` (6, nv), and the centre of mass in the base frame (3, 1) [m].

    Column k of the base rows of ``M`` is the momentum ``(f, n)`` of unit velocity k, in the base frame
    about the base origin; about the centre of mass the moment is ``n - c_b x f``.
    """
    Yc, M = composite_inertias(model, data)
    c_b = Yc[1].h / Yc[1].mass
    base = model.joints[1].idx_v
    columns = []
    for col in range(model.nv):
        f = ca.vertcat(*[M[base + i][col] for i in range(3)])
        n = ca.vertcat(*[M[base + 3 + i][col] for i in range(3)])
        columns.append(ca.vertcat(f, n - cross(c_b, f)))
    return ca.horzcat(*columns), c_b


def _rotate_rows(R: ca.SX, X: ca.SX) -> ca.SX:
    """``blkdiag(R, R) X`` for a (6, n) matrix: linear rows then angular rows to world axes."""
    return ca.vertcat(ca.mtimes(R, X[0:3, :]), ca.mtimes(R, X[3:6, :]))


def centroidal_map(model: SymbolicModel, q: ca.SX, data: SymbolicData | None = None) -> ca.SX:
    """Centroidal momentum matrix ``A_G(q)`` (6, nv) (``pinocchio.computeCentroidalMap``).

    Args:
        model: Symbolic model tables.
        q: Configuration (nq,).
        data: Output of ``forward_kinematics(model, q, ...)`` to reuse its joint transforms.

    Returns:
        ``A_G`` such that ``A_G v`` is the linear momentum [kg m/s] then the angular momentum about the
        centre of mass [kg m^2/s], world axes. It does not depend on the base position.
    """
    data = forward_kinematics(model, q) if data is None else data
    A_b, _ = _base_momentum_map(model, data)
    return _rotate_rows(data.rotations[1], A_b)


def centroidal_momentum(model: SymbolicModel, q: ca.SX, v: ca.SX, data: SymbolicData | None = None) -> ca.SX:
    """Centroidal momentum ``h_G = A_G(q) v`` (6,) (``pinocchio.computeCentroidalMomentum``).

    Summed body by body rather than through ``A_G``: the momenta :math:`I_i v_i` (joint frames) are carried
    to the base like RNEA forces, then shifted to the centre of mass and rotated once,
    :math:`h_G = \\mathrm{blkdiag}(R_b, R_b) (f, n - c_b \\times f)`.

    Args:
        model: Symbolic model tables.
        q: Configuration (nq,).
        v: Generalised velocity (nv,).
        data: Output of ``forward_kinematics(model, q, v, ...)`` to reuse.

    Returns:
        Linear momentum [kg m/s] then angular momentum about the centre of mass [kg m^2/s], world axes.
    """
    data = forward_kinematics(model, q, v) if data is None else data
    if data.v is None:
        raise ValueError("centroidal_momentum needs forward_kinematics(model, q, v)")
    Yc, _ = composite_inertias(model, data)  # only the first moments are used (c_b)
    n = len(model.joints)
    f: list = [None] * n
    m: list = [None] * n
    for info in model.joints[1:]:
        Y, vi = body_inertia(info), data.v[info.index]
        f[info.index] = Y.mass * vi.linear - cross(Y.h, vi.angular)
        m[info.index] = cross(Y.h, vi.linear) + ca.mtimes(Y.rotational, vi.angular)
    for info in reversed(model.joints[2:]):
        j = info.index
        f_par, m_par = force_to_parent(data.rotations[j], data.translations[j], f[j], m[j])
        f[info.parent], m[info.parent] = f[info.parent] + f_par, m[info.parent] + m_par
    c_b = Yc[1].h / Yc[1].mass
    R_b = data.rotations[1]
    return ca.vertcat(ca.mtimes(R_b, f[1]), ca.mtimes(R_b, m[1] - cross(c_b, f[1])))


def centroidal_map_time_variation(model: SymbolicModel, q: ca.SX, v: ca.SX) -> ca.SX:
    """Time derivative of the centroidal map along ``v``, ``dA_G/dt`` (6, nv) (``pinocchio.dccrba``,
    ``data.dAg``): ``dh_G/dt = A_G a + (dA_G/dt) v``.

    With ``A_G = blkdiag(R_b, R_b) A_b(q_j)``, ``A_b`` depending on the joint positions ``q_j`` only, and
    :math:`\\dot R_b = R_b [\\omega]_\\times` (``omega = v[3:6]``, base angular velocity in the base frame):

    .. math::  \\frac{d A_G}{dt} = \\mathrm{blkdiag}(R_b, R_b) \\left( \\mathrm{blkdiag}([\\omega]_\\times,
               [\\omega]_\\times) A_b + \\sum_k \\frac{\\partial A_b}{\\partial q_k} \\dot q_k \\right),

    the last term by forward-mode differentiation of ``A_b`` (one directional derivative).

    Note:
        ``pinocchio.computeCentroidalMapTimeVariation`` (pin 4.1.0) adds ``A_G,lin x c_dot`` to the
        angular rows with ``c_dot = data.vcom[0]`` read from ``data`` but never computed by it: on a
        fresh ``Data`` (``vcom = 0``) its angular rows differ from ``dA_G/dt`` by ``[c_dot]x A_G,lin``
        (a term that vanishes in the product with v, since ``c_dot x m c_dot = 0``); after
        ``computeCentroidalMomentum(q, v)`` on the same data, or with ``pinocchio.dccrba``, it matches.

    Args:
        model: Symbolic model tables.
        q: Configuration (nq,).
        v: Generalised velocity (nv,).

    Returns:
        The (6, nv) matrix [kg/s, kg m/s, kg m^2/s].
    """
    # jtimes needs purely symbolic arguments: build on fresh symbols, then call on (q, v) (inlined).
    qs, vs = ca.SX.sym("q", model.nq), ca.SX.sym("v", model.nv)
    data = forward_kinematics(model, qs)
    A_b, _ = _base_momentum_map(model, data)
    qdot = [0] * model.nq  # A_b does not depend on the base pose, so its direction stays zero
    for info in model.joints[1:]:
        if info.kind != "freeflyer":
            qdot[info.idx_q] = vs[info.idx_v]
    dA_b = ca.jtimes(A_b, qs, ca.vertcat(*qdot))
    base = model.joints[1].idx_v
    omega = vs[base + 3 : base + 6]
    # d/dt (R_b x) = R_b (omega x x + dx/dt) for both 3-row halves of every column.
    spin = ca.vertcat(
        *[
            ca.horzcat(*[cross(omega, A_b[rows, k]) for k in range(model.nv)])
            for rows in (slice(0, 3), slice(3, 6))
        ]
    )
    dA = _rotate_rows(data.rotations[1], spin + dA_b)
    return ca.Function("centroidal_map_time_variation", [qs, vs], [dA])(q, v)


def _contact_levers(model: SymbolicModel, data: SymbolicData, frame: str) -> tuple[int, dict]:
    """Frame origin in each supporting joint frame: ``{joint: r_j (3, 1) [m]}`` from the frame's joint up
    to the base, by ``r_parent = R_j r_j + p_j``."""
    joint, _, p_f = model.frame(frame)
    levers = {}
    r, k = p_f, joint
    while k != 0:
        levers[k] = r
        if model.joints[k].parent == 0:
            break
        r = ca.mtimes(data.rotations[k], r) + data.translations[k]
        k = model.joints[k].parent
    return joint, levers


def centroidal_momentum_rate(
    model: SymbolicModel,
    q: ca.SX,
    forces: dict[str, ca.SX] | None = None,
    gravity=None,
    data: SymbolicData | None = None,
) -> ca.SX:
    """Rate of the centroidal momentum under gravity and external point forces (6,).

    .. math::  \\dot h_G = \\begin{bmatrix} m g + \\sum_c F_c \\\\ \\sum_c (p_c - c) \\times F_c
               \\end{bmatrix},

    with :math:`p_c - c = R_b (r_{c,b} - c_b)` from the contact-frame origins and the centre of mass in the
    base frame (no world placement of any other joint is needed).

    Args:
        model: Symbolic model tables.
        q: Configuration (nq,).
        forces: ``{frame name: world-frame force (3,) [N]}`` on the robot at the frame origins.
        gravity: Gravity (3,) [m/s^2], world frame; default ``model.gravity``.
        data: Output of ``forward_kinematics(model, q, ...)`` to reuse.

    Returns:
        ``[N; N m]``: net external force then moment about the centre of mass, world axes.
    """
    data = forward_kinematics(model, q) if data is None else data
    gravity = model.gravity if gravity is None else ca.reshape(ca.SX(gravity), 3, 1)  # numpy or SX
    Yc, _ = composite_inertias(model, data)
    c_b = Yc[1].h / Yc[1].mass
    R_b = data.rotations[1]
    force = model.total_mass * gravity
    moment = ca.SX.zeros(3, 1)
    for frame, F in (forces or {}).items():
        _, levers = _contact_levers(model, data, frame)
        force = force + F
        moment = moment + cross(ca.mtimes(R_b, levers[1] - c_b), F)
    return ca.vertcat(force, moment)


def _static_generalized_force(
    model: SymbolicModel, data: SymbolicData, forces: dict[str, ca.SX] | None
) -> list:
    """``g(q) - J_c(q)^T F`` (nv) as SX scalars, i.e. ``rnea(q, 0, 0, F)``, without velocities.

    At rest the RNEA wrench of the subtree of joint j, in its frame, is
    :math:`(-m_j g_j - \\sum_c F_{c,j},\\; -h_j \\times g_j - \\sum_c r_{c,j} \\times F_{c,j})`, with
    :math:`m_j, h_j` the subtree mass and first moment, :math:`g_j` gravity and :math:`F_{c,j}`, :math:`r_
    {c,j}` the contact forces and frame origins in the joint frame; row j is its projection on the joint
    axis. Rotating only 3-vectors down the tree is cheaper than carrying 6-D wrenches up as RNEA does.
    """
    Yc, _ = composite_inertias(model, data)
    n = len(model.joints)
    g: list = [None] * n
    wrench_f: list = [None] * n
    wrench_n: list = [None] * n
    for info in model.joints[1:]:
        j = info.index
        # Gravity in the joint frame: rotate down the tree (R^T g of the parent).
        g[j] = ca.mtimes(data.rotations[j].T, model.gravity if info.parent == 0 else g[info.parent])
        wrench_f[j] = -Yc[j].mass * g[j]
        wrench_n[j] = -cross(Yc[j].h, g[j])
    for frame, F in (forces or {}).items():
        joint, levers = _contact_levers(model, data, frame)
        local = F
        for k in model.support(joint):
            local = ca.mtimes(data.rotations[k].T, local)
            wrench_f[k] = wrench_f[k] - local
            wrench_n[k] = wrench_n[k] - cross(levers[k], local)
    tau: list = [None] * model.nv
    for info in model.joints[1:]:
        j = info.index
        if info.kind == "freeflyer":
            for k in range(3):
                tau[info.idx_v + k] = wrench_f[j][k]
                tau[info.idx_v + 3 + k] = wrench_n[j][k]
            continue
        e = clean_constant(info.axis_vector.reshape(3, 1))
        tau[info.idx_v] = ca.dot(e, wrench_n[j] if info.kind == "revolute" else wrench_f[j])
    return tau


def generalized_gravity(model: SymbolicModel, q: ca.SX, data: SymbolicData | None = None) -> ca.SX:
    """Generalised gravity ``g(q) = rnea(q, 0, 0)`` (nv,) (``pinocchio.computeGeneralizedGravity``).

    Returns:
        Base wrench in the base frame ([N], [N m]) then joint torques [N m] that hold the robot at rest
        without contacts; ``g = dV/dq`` for the potential energy ``V``.
    """
    data = forward_kinematics(model, q) if data is None else data
    return ca.vertcat(*_static_generalized_force(model, data, None))


def static_torque_estimate(
    model: SymbolicModel, q: ca.SX, forces: dict[str, ca.SX], data: SymbolicData | None = None
) -> ca.SX:
    """Joint torques that hold the robot at rest under contact forces: ``tau = g_j(q) - J_{c,j}^T F`` (nj,).

    The joint rows of ``rnea(q, 0, 0, F) = [0; tau]`` at a static equilibrium: with :math:`M a + b =
    [0; \\tau] + J_c^T F` and :math:`v = a = 0`, :math:`\\tau = g_j - J_{c,j}^T F` (not
    :math:`J_{c,j}^T F - g_j`). Centroidal formulations use it as the torque estimate.

    Args:
        model: Symbolic model tables.
        q: Configuration (nq,).
        forces: ``{frame name: world-frame force (3,) [N]}`` on the robot at the frame origins.
        data: Output of ``forward_kinematics(model, q, ...)`` to reuse.

    Returns:
        Joint torques (nv - 6,) [N m], Pinocchio joint order.
    """
    data = forward_kinematics(model, q) if data is None else data
    return ca.vertcat(*_static_generalized_force(model, data, forces)[6:])


def _solve3(M: ca.SX, b: ca.SX) -> ca.SX:
    """``M^-1 b`` for a 3x3 symbolic matrix by Cramer's rule (smaller than a symbolic QR)."""
    c0, c1, c2 = M[:, 0], M[:, 1], M[:, 2]
    det = ca.dot(c0, cross(c1, c2))
    return ca.vertcat(ca.dot(b, cross(c1, c2)), ca.dot(c0, cross(b, c2)), ca.dot(c0, cross(c1, b))) / det


def _solve_base_block(model: SymbolicModel, A_b: ca.SX, rhs: ca.SX) -> ca.SX:
    """Solve ``A_b[:, :6] x_b = rhs`` (base axes) using the block structure of the base columns.

    The base columns of the centroidal map in base axes about the centre of mass are
    ``[[m I, -m [c]x], [0, I_c]]`` (a base translation carries no angular momentum about the centre of
    mass; ``I_c`` is the locked composite inertia), so ``omega = I_c^-1 k`` and
    ``v = (p + m [c]x omega) / m``: one 3x3 solve instead of a 6x6 inverse.
    """
    omega = _solve3(A_b[3:6, 3:6], rhs[3:6])
    linear = (rhs[0:3] - ca.mtimes(A_b[0:3, 3:6], omega)) / model.total_mass
    return ca.vertcat(linear, omega)


def _to_base_axes(R: ca.SX, world: ca.SX) -> ca.SX:
    return ca.vertcat(ca.mtimes(R.T, world[0:3]), ca.mtimes(R.T, world[3:6]))


def centroidal_base_velocity(
    model: SymbolicModel, q: ca.SX, h: ca.SX, v_j: ca.SX, data: SymbolicData | None = None
) -> ca.SX:
    """Base velocity that gives the centroidal momentum ``h`` with joint velocities ``v_j`` (6,).

    .. math::  v_b = A_b^{-1} (h_G - A_j v_j), \\qquad A_G = [A_b\\ A_j].

    Args:
        model: Symbolic model tables.
        q: Configuration (nq,).
        h: Centroidal momentum (6,) [kg m/s, kg m^2/s], world axes, about the centre of mass.
        v_j: Joint velocities (nv - 6,).
        data: Output of ``forward_kinematics(model, q, ...)`` to reuse.

    Returns:
        The base twist in the base frame (linear [m/s] then angular [rad/s]), Pinocchio's convention.
    """
    data = forward_kinematics(model, q) if data is None else data
    A_b, _ = _base_momentum_map(model, data)
    rhs = _to_base_axes(data.rotations[1], h) - ca.mtimes(A_b[:, 6:], v_j)
    return _solve_base_block(model, A_b, rhs)


def centroidal_base_acceleration(
    model: SymbolicModel,
    q: ca.SX,
    v: ca.SX,
    a_j: ca.SX,
    forces: dict[str, ca.SX] | None = None,
    data: SymbolicData | None = None,
) -> ca.SX:
    """Base acceleration from the centroidal momentum rate (6,).

    .. math::  a_b = A_b^{-1} (\\dot h_G(q, F) - \\dot A_G v - A_j a_j).

    Args:
        model: Symbolic model tables.
        q: Configuration (nq,).
        v: Generalised velocity (nv,).
        a_j: Joint accelerations (nv - 6,).
        forces: ``{frame name: world-frame force (3,) [N]}`` on the robot at the frame origins.
        data: Output of ``forward_kinematics(model, q, ...)`` to reuse.

    Returns:
        The base part of ``a`` (6,): derivative of the base twist in the base frame, such that
        ``rnea(q, v, [a_b; a_j], forces)[:6] == 0``.
    """
    data = forward_kinematics(model, q) if data is None else data
    A_b, _ = _base_momentum_map(model, data)
    hdot = centroidal_momentum_rate(model, q, forces, data=data)
    dA_v = ca.mtimes(centroidal_map_time_variation(model, q, v), v)
    rhs = _to_base_axes(data.rotations[1], hdot - dA_v) - ca.mtimes(A_b[:, 6:], a_j)
    return _solve_base_block(model, A_b, rhs)
