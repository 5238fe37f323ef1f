"""The OCP in Fatrop's own layout: per-stage functions of ``(u_k, x_k)`` and the row and variable maps.

Fatrop's OCP interface (``fatrop/ocp/ocp_abstract.hpp``) asks, per stage ``k``, for

* the dynamics ``x_{k+1} = F_k(u_k, x_k)``: their residual ``b_k = F_k - x_{k+1}`` and the transposed
  Jacobian ``[B_k^T; A_k^T]`` (rows ordered ``u`` then ``x``);
* the path equalities ``g_k(u_k, x_k) = 0`` and inequalities ``L_k <= h_k(u_k, x_k) <= U_k`` with their
  transposed Jacobians;
* the cost ``L_k``, its gradient and the Hessian of the stage Lagrangian
  ``sigma L_k + lam_dyn^T F_k + lam_eq^T g_k + lam_ineq^T h_k`` in ``(u_k, x_k)``.

Everything here is built from :func:`wbmpc.solver.codegen.stage_functions` (the OCP's own stage
definition: the same rows, bounds and cost as the casadi-plugin path), so no physics is duplicated. The
NLP's transition rows are ``x_{k+1} - F_k(z_k)``; :func:`stage_problem` checks that they are explicit (their
Jacobian in ``x_{k+1}`` is the identity) and recovers ``F_k`` from them.

Variable split: the NLP orders each stage as ``[x_k, u_k]``. Where node 0's state is the measurement (a
parameter, the default layout), the NLP's stage 0 has inputs only; like the casadi plugin's structure
detection (:meth:`wbmpc.ocp.OCP.stage_sizes`), its first ``nx_1`` entries become Fatrop's ``x_0``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from wbmpc.ocp import OCP
from wbmpc.ocp.time_grid import symbolic_geometric_time_steps
from wbmpc.solver import codegen

#: Order of the per-kind functions in the compiled table (``fatrop_direct.cpp`` indexes them so).
FUNCTIONS = ("res", "jac", "cost", "grad", "hess")
KINDS = ("initial", "torque", "plain", "terminal")


@dataclass
class StageLayout:
    """One stage in Fatrop's layout and where its variables and rows sit in the NLP.

    Attributes:
        k: Node index.
        kind: Stage type (:func:`wbmpc.solver.codegen.stage_kind`).
        nx, nu: Fatrop's state and input sizes of the stage.
        n_dyn: Dynamics rows (``nx`` of node ``k + 1``; 0 at the terminal node).
        w_offset: Start of the stage's variables ``[x_k, u_k]`` in the NLP's primal vector.
        g_offset: Start of the stage's rows in the NLP's constraint vector.
        eq_rows, ineq_rows: NLP row indices (absolute) of the path equalities and inequalities, in Fatrop's
            order.
    """

    k: int
    kind: str
    nx: int
    nu: int
    n_dyn: int
    w_offset: int
    g_offset: int
    eq_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    ineq_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, int))


def stage_layouts(ocp: OCP) -> list[StageLayout]:
    """Fatrop's view of every stage of ``ocp`` (sizes, NLP offsets, equality / inequality rows).

    Raises:
        ValueError: a stage whose path rows have both bounds infinite (Fatrop has no such row).
    """
    sizes = ocp.stage_sizes()
    equality = np.asarray(ocp.equality, bool)
    out = []
    for info in ocp.stages:
        k = info.k
        n_dyn = ocp.stages[k + 1].nx if info.u_offset is not None else 0
        rows = np.arange(info.g_offset + n_dyn, info.g_offset + info.ng)
        free = ~np.isfinite(ocp.lbg[rows]) & ~np.isfinite(ocp.ubg[rows])
        if np.any(free):
            raise ValueError(f"stage {k} has constraint rows without bounds: {rows[free].tolist()}")
        out.append(
            StageLayout(
                k=k,
                kind=codegen.stage_kind(ocp, k),
                nx=sizes["nx"][k],
                nu=sizes["nu"][k],
                n_dyn=n_dyn,
                w_offset=info.x_offset,
                g_offset=info.g_offset,
                eq_rows=rows[equality[rows]],
                ineq_rows=rows[~equality[rows]],
            )
        )
    return out


def stage_problem(ocp: OCP, layout: StageLayout) -> dict[str, ca.Function]:
    """The five SX functions of one stage type in Fatrop's layout (see the module docstring).

    Inputs of every function: ``u`` (nu,), ``x`` (nx,), ``p`` (the OCP's parameter vector), ``s`` (the
    stage parameters ``[dt, contact, swing_vz, force_des, ee_velocity]``); ``hess`` also takes
    ``sigma`` (objective scale), ``lam_dyn`` (n_dyn,), ``lam_eq`` (n_eq,), ``lam_ineq`` (n_ineq,).
    Outputs: ``res``: ``F`` (n_dyn,), ``g`` (n_eq,), ``h`` (n_ineq,); ``jac``: ``F_t`` (nu+nx, n_dyn) =
    ``[B^T; A^T]``, ``G_t`` (nu+nx, n_eq), ``H_t`` (nu+nx, n_ineq); ``cost``; ``grad`` (nu+nx,); ``hess``
    (nu+nx, nu+nx). Vectors may be structurally sparse too (a row that is identically 0): the driver
    scatters every output by its sparsity (``<name>_sparsity_out``).

    Raises:
        ValueError: the transition rows are not explicit in ``x_{k+1}`` (Fatrop needs ``x_{k+1} = F``).
    """
    kind, k = layout.kind, layout.k
    fns = codegen.stage_functions(ocp, kind, k)
    fg = fns["fg"]
    p = ca.SX.sym("p", fg.size1_in(2))
    s = ca.SX.sym("s", fg.size1_in(3))
    u, x = ca.SX.sym("u", layout.nu), ca.SX.sym("x", layout.nx)
    z = ca.vertcat(x, u)  # the NLP's stage order
    if z.numel() != fg.size1_in(0):
        raise ValueError(f"stage {k} ({kind}): Fatrop split {layout.nx}+{layout.nu} != {fg.size1_in(0)}")
    x_next = ca.SX.sym("x_next", fg.size1_in(1))
    cost, g = fg(z, x_next, p, s)
    n_dyn = layout.n_dyn
    dyn = g[:n_dyn]
    if n_dyn:
        jac_next = ca.jacobian(dyn, x_next)
        if ca.depends_on(jac_next, ca.vertcat(z, x_next, p, s)) or not np.array_equal(
            np.array(ca.evalf(jac_next)), np.eye(n_dyn)
        ):
            raise ValueError(f"stage {k} ({kind}): the transition rows are not x_next - F(z)")
    # F_k from the rows x_{k+1} - F_k(z): evaluate them at x_{k+1} = 0.
    F = -ca.substitute(dyn, x_next, ca.SX.zeros(x_next.numel()))
    local = np.arange(n_dyn, g.numel())
    eq_local = (layout.eq_rows - layout.g_offset).tolist()
    ineq_local = (layout.ineq_rows - layout.g_offset).tolist()
    assert sorted(eq_local + ineq_local) == local.tolist()
    # Equalities are g = c with a constant c: Fatrop wants g - c = 0.
    g_eq = g[eq_local] - ocp.lbg[layout.eq_rows] if eq_local else ca.SX(0, 1)
    h = g[ineq_local] if ineq_local else ca.SX(0, 1)
    ux = ca.vertcat(u, x)
    sigma = ca.SX.sym("sigma")
    lam_dyn, lam_eq, lam_ineq = (
        ca.SX.sym(n, e.numel()) for n, e in (("lam_dyn", F), ("lam_eq", g_eq), ("lam_ineq", h))
    )
    lagrangian = sigma * cost + ca.dot(lam_dyn, F) + ca.dot(lam_eq, g_eq) + ca.dot(lam_ineq, h)
    hess = ca.hessian(lagrangian, ux)[0]
    ins, names = [u, x, p, s], ["u", "x", "p", "s"]
    prefix = f"wbmpc_direct_{kind}"
    # Matrices keep their sparsity (the driver scatters the nonzeros into zero-initialised dense blocks);
    # common subexpressions are merged (fewer instructions than the plugin's functions of the same rows).
    opts = {"cse": True}
    return {
        "res": ca.Function(f"{prefix}_res", ins, [F, g_eq, h], names, ["F", "g", "h"], opts),
        "jac": ca.Function(
            f"{prefix}_jac",
            ins,
            [ca.jacobian(F, ux).T, ca.jacobian(g_eq, ux).T, ca.jacobian(h, ux).T],
            names,
            ["F_t", "G_t", "H_t"],
            opts,
        ),
        "cost": ca.Function(f"{prefix}_cost", ins, [cost], names, ["L"], opts),
        "grad": ca.Function(f"{prefix}_grad", ins, [ca.densify(ca.gradient(cost, ux))], names, ["rq"], opts),
        "hess": ca.Function(
            f"{prefix}_hess",
            [*ins, sigma, lam_dyn, lam_eq, lam_ineq],
            [hess],
            [*names, "sigma", "lam_dyn", "lam_eq", "lam_ineq"],
            ["RSQ"],
            opts,
        ),
    }


def stage_parameters_function(ocp: OCP) -> ca.Function:
    """``p -> S`` (n_s, N-1): every stage's parameters ``[dt, contact, swing_vz, force_des, ee_velocity]``
    from the OCP's parameter vector, as the casadi-plugin path computes them (geometric time steps)."""
    P = ca.SX.sym("p", ocp.params.size)
    blocks = ocp.params.blocks
    dts = symbolic_geometric_time_steps(ocp.n_nodes, P[blocks["dt_min"][0]], P[blocks["dt_max"][0]])
    columns = []
    for k in range(ocp.n_nodes - 1):
        parts = [dts[k]]
        for name in ("contact", "swing_vz", "force_des", "ee_velocity"):
            start, (rows, _) = blocks[name]
            parts.append(P[start + k * rows : start + (k + 1) * rows])
        columns.append(ca.vertcat(*parts))
    return ca.Function("wbmpc_direct_stage_params", [P], [ca.horzcat(*columns)], ["p"], ["S"])
