"""The optimal control problem of the whole-body MPC, built once and solved with runtime parameters.

One builder owns everything the dynamics formulations share: the time grid, the gait (contact and swing
constraints), the arm task, the joint and torque limits, the cost and the parameter vector. The dynamics
come from a formulation object (:mod:`wbmpc.formulations`).

Nodes ``k = 0 .. N-1`` ("N = 15" counts the terminal node); stages ``k < N-1`` have inputs. Per stage the
constraint rows are ordered for Fatrop's structure detection: first the gap-closing transition
``x_{k+1} - f(x_k, u_k, dt_k) = 0``, then the path constraints of stage ``k`` (functions of ``x_k, u_k``):

* node 0: the initial state ``dq_0 = 0``, ``v_0 = v_hat``;
* dynamics (RNEA): base rows ``= 0``; joint rows ``= tau_j`` and ``|tau_j| <= tau_max`` on the first ``n_tau``
  nodes;
* each foot ``i`` with contact flag ``c`` (a parameter): the force acting on the robot is ``c F_i`` so a
  swing foot carries no force; friction cone ``F_z >= 0``, ``mu^2 F_z^2 >= F_x^2 + F_y^2`` (relaxed by
  ``(1 - c)`` so that swing rows stay inactive instead of degenerate); for ``k >= 1`` the foot velocity
  in world axes: ``c v_xy + (1 - c) F_xy / W = 0`` (stance: no slip; swing: the unused force is pinned to 0)
  and ``v_z = (1 - c) v_z^ref`` (stance: no lift-off; swing: the cubic-spline reference);
* arm: end-effector force ``= F^cmd`` (world) at every node and, for ``k >= 1``, end-effector linear
  velocity in world axes (``LOCAL_WORLD_ALIGNED``) ``= v^cmd_k`` (world; constant over the horizon as
  in the paper, or one command per node, e.g. the future velocities of a reference trajectory);
* joint position and velocity limits for ``k >= 1`` (node 0 is the measurement).

Velocity rows are skipped at node 0 because ``v_0`` is fixed there: they would be constant rows that make
the constraint Jacobian rank deficient. The cost is the paper's quadratic tracking cost with runtime
diagonal weights ``Q`` and ``R`` and a terminal cost equal to the stage state cost.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from wbmpc import cpin
from wbmpc.formulations import InverseDynamics
from wbmpc.robot import Robot
from wbmpc.time_grid import symbolic_geometric_time_steps


@dataclass
class OCPSettings:
    """Structural settings: changing any of them rebuilds the problem.

    Attributes:
        n_nodes: Number of nodes including the terminal one (paper: 15).
        n_tau_nodes: Nodes ``k < n_tau_nodes`` carry joint torques and torque limits (paper: k <= 2).
        formulation: Dynamics formulation name.
    """

    n_nodes: int = 15
    n_tau_nodes: int = 3
    formulation: str = "inverse_dynamics"

    def __post_init__(self):
        if not isinstance(self.n_nodes, int | np.integer) or self.n_nodes < 3:
            raise ValueError(f"n_nodes must be an integer >= 3, got {self.n_nodes!r}")
        if not 1 <= self.n_tau_nodes <= self.n_nodes - 1:
            raise ValueError(
                f"n_tau_nodes must be in [1, n_nodes - 1 = {self.n_nodes - 1}], got {self.n_tau_nodes}"
            )


class ParameterLayout:
    """Named blocks of the OCP parameter vector: symbols for the builder, packing for the caller."""

    def __init__(self):
        self.blocks: dict[str, tuple[int, tuple[int, int]]] = {}
        self.symbols: dict[str, ca.SX] = {}
        self.size = 0

    def add(self, name: str, rows: int, cols: int = 1) -> ca.SX:
        sym = ca.SX.sym(name, rows, cols)
        self.blocks[name] = (self.size, (rows, cols))
        self.symbols[name] = sym
        self.size += rows * cols
        return sym

    @property
    def vector(self) -> ca.SX:
        return ca.vertcat(*[ca.vec(s) for s in self.symbols.values()])

    def pack(self, values: dict[str, np.ndarray]) -> np.ndarray:
        """Stack numeric values (column-major for matrices) into the parameter vector.

        Raises:
            ValueError: for a missing or unknown block, a wrong shape or a non-finite value.
        """
        missing = set(self.blocks) - set(values)
        unknown = set(values) - set(self.blocks)
        if missing or unknown:
            raise ValueError(f"parameter blocks missing: {sorted(missing)}, unknown: {sorted(unknown)}")
        out = np.empty(self.size)
        for name, (start, (rows, cols)) in self.blocks.items():
            value = np.asarray(values[name], dtype=float)
            if value.size != rows * cols or (value.ndim == 2 and value.shape != (rows, cols)):
                raise ValueError(f"parameter {name!r} must have shape ({rows}, {cols}), got {value.shape}")
            if not np.all(np.isfinite(value)):
                raise ValueError(f"parameter {name!r} contains NaN or inf")
            out[start : start + rows * cols] = value.reshape(rows, cols).ravel(order="F")
        return out

    def unpack(self, p: np.ndarray, name: str) -> np.ndarray:
        start, (rows, cols) = self.blocks[name]
        block = np.asarray(p)[start : start + rows * cols]
        return block.reshape(rows, cols, order="F") if cols > 1 else block.copy()


@dataclass
class StageInfo:
    """Sizes and offsets of one stage in the decision vector and the constraint vector."""

    k: int
    nx: int
    nu: int
    x_offset: int
    u_offset: int | None
    has_torque: bool
    g_offset: int = 0
    ng: int = 0
    rows: dict[str, slice] = field(default_factory=dict)  # named path-constraint rows (absolute)


class OCP:
    """The whole-body MPC problem as a CasADi NLP with stage-interleaved variables.

    Args:
        robot: The robot (foot frames, arm end effector, limits).
        settings: Structural settings.

    Attributes:
        nlp: ``{"x", "p", "f", "g"}`` for ``casadi.nlpsol``.
        lbg, ubg: Constant constraint bounds.
        equality: Per constraint row, True for an equality.
        params: The parameter layout.
        stages: Stage sizes and offsets, nodes 0..N-1.
    """

    def __init__(self, robot: Robot, settings: OCPSettings | None = None):
        self.robot = robot
        self.settings = settings or OCPSettings()
        self.smodel = cpin.SymbolicModel(robot.model)
        if self.settings.formulation != "inverse_dynamics":
            raise ValueError(
                f"unknown formulation {self.settings.formulation!r}; available: ['inverse_dynamics']"
            )
        self.formulation = InverseDynamics(self.smodel, len(robot.contact_frames))
        self.n_feet = robot.n_feet
        self.nv, self.nq, self.nj = robot.nv, robot.nq, robot.nj
        self.nf = 3 * len(robot.contact_frames)
        self._build()

    # --- layout --------------------------------------------------------------------------------------------
    @property
    def n_nodes(self) -> int:
        return self.settings.n_nodes

    @property
    def nu_max(self) -> int:
        return self.formulation.nu(True)

    def _declare_parameters(self) -> ParameterLayout:
        n_stages = self.n_nodes - 1
        P = ParameterLayout()
        P.add("q_hat", self.nq)  # measured configuration
        P.add("v_hat", self.nv)  # measured velocity
        P.add("dq_des", self.nv)  # desired configuration as a tangent increment from q_hat
        P.add("v_des", self.nv)  # desired velocity (base twist in the base frame, joints)
        P.add("dt_min", 1)
        P.add("dt_max", 1)
        P.add("contact", self.n_feet, n_stages)  # 1 stance, 0 swing, per stage
        P.add("swing_vz", self.n_feet, n_stages)  # vertical foot velocity reference [m/s]
        P.add("force_des", self.n_feet, n_stages)  # vertical force target per foot [N]
        P.add("ee_velocity", 3, n_stages)  # commanded end-effector linear velocity per stage, world [m/s]
        P.add("ee_force", 3)  # commanded force on the robot at the end effector, world axes [N]
        P.add("mu", 1)  # friction coefficient
        P.add("Q", 2 * self.nv)
        P.add("R", self.nu_max)
        return P

    # --- construction -------------------------------------------------------------------------------------
    def _build(self) -> None:
        form, S = self.formulation, self.settings
        P = self._declare_parameters()
        p = P.symbols
        n_stages = self.n_nodes - 1
        dts = symbolic_geometric_time_steps(self.n_nodes, p["dt_min"], p["dt_max"])
        stages = [
            form.stage(str(k), p["q_hat"], has_input=k < n_stages, has_torque=k < S.n_tau_nodes)
            for k in range(self.n_nodes)
        ]
        x_parts, g_parts, lbg, ubg, eq = [], [], [], [], []
        infos: list[StageInfo] = []
        offset = n_rows = 0
        cost = 0
        for k, st in enumerate(stages):
            has_input = st.u is not None
            info = StageInfo(
                k=k,
                nx=form.nx,
                nu=st.u.numel() if has_input else 0,
                x_offset=offset,
                u_offset=offset + form.nx if has_input else None,
                has_torque=st.tau is not None,
                g_offset=n_rows,
            )
            x_parts += [st.x, st.u] if has_input else [st.x]
            offset += info.nx + info.nu
            stage_p = self.stage_parameter_slices(p, k, dts[k] if has_input else None)
            x_next = stages[k + 1].x if has_input else None
            stage_cost, rows = self.stage_terms(k, st, x_next, p, stage_p)
            cost += stage_cost
            for name, expr, lo, hi in rows:
                n = expr.numel()
                g_parts.append(expr)
                lbg.extend(lo)
                ubg.extend(hi)
                eq.extend(bool(a == b) for a, b in zip(lo, hi, strict=True))
                info.rows[name] = slice(n_rows, n_rows + n)
                n_rows += n
            info.ng = n_rows - info.g_offset
            infos.append(info)

        self.params = P
        self.stages = infos
        self.dts_function = ca.Function("dts", [p["dt_min"], p["dt_max"]], [ca.vertcat(*dts)])
        self.nlp = {"x": ca.vertcat(*x_parts), "p": P.vector, "f": cost, "g": ca.vertcat(*g_parts)}
        self.lbg, self.ubg = np.array(lbg), np.array(ubg)
        self.equality = eq
        self.n_variables = self.nlp["x"].numel()
        self.n_constraints = self.nlp["g"].numel()

    # --- one stage -----------------------------------------------------------------------------------------
    STAGE_PARAMETERS = ("dt", "contact", "swing_vz", "force_des", "ee_velocity")

    def stage_parameter_sizes(self) -> dict[str, int]:
        """Sizes of the per-stage parameter blocks (the rest of the parameters are shared by all stages)."""
        return {
            "dt": 1,
            "contact": self.n_feet,
            "swing_vz": self.n_feet,
            "force_des": self.n_feet,
            "ee_velocity": 3,
        }

    def stage_parameter_slices(self, p: dict, k: int, dt) -> dict | None:
        """Per-stage parameters of stage ``k`` sliced from the full blocks (``None`` at the terminal node)."""
        if dt is None:
            return None
        return {
            "dt": dt,
            "contact": p["contact"][:, k],
            "swing_vz": p["swing_vz"][:, k],
            "force_des": p["force_des"][:, k],
            "ee_velocity": p["ee_velocity"][:, k],
        }

    def stage_terms(self, k: int, st, x_next, p: dict, sp: dict | None) -> tuple[ca.SX, list]:
        """Cost and constraint rows of stage ``k``, functions of its own variables only.

        Args:
            k: Node index (decides the stage type: initial, torque, plain or terminal node).
            st: The stage variables (:class:`wbmpc.formulations.StageVariables`).
            x_next: State of node ``k + 1`` (for the transition), ``None`` at the terminal node.
            p: Shared parameter blocks (symbols).
            sp: Per-stage parameters (``dt``, ``contact``, ``swing_vz``, ``force_des``, ``ee_velocity``).

        Returns:
            ``(cost, rows)`` with rows ``(name, expression, lower bounds, upper bounds)`` in Fatrop order.
        """
        robot, form = self.robot, self.formulation
        weight = robot.mass * robot.gravity
        big_force = 10.0 * weight
        has_input = st.u is not None
        rows = []

        def add(name, expr, lo, hi):
            expr = ca.vec(expr)
            n = expr.numel()
            rows.append(
                (
                    name,
                    expr,
                    np.broadcast_to(np.asarray(lo, float), (n,)),
                    np.broadcast_to(np.asarray(hi, float), (n,)),
                )
            )

        # Cost: quadratic tracking with runtime diagonal weights (terminal = stage state cost).
        cost = ca.dot(p["Q"], (st.x - ca.vertcat(p["dq_des"], p["v_des"])) ** 2)
        if has_input:
            contact = sp["contact"]
            u_des = ca.vertcat(
                ca.SX.zeros(self.nv),
                *[ca.vertcat(0, 0, sp["force_des"][i]) for i in range(self.n_feet)],
                *([p["ee_force"]] if robot.has_arm else []),
                ca.SX.zeros(self.nj) if st.tau is not None else ca.SX(0, 1),
            )
            cost += ca.dot(p["R"][: st.u.numel()], (st.u - u_des) ** 2)
            # Gap-closing transition first (Fatrop structure detection).
            add("transition", x_next - form.transition(st, sp["dt"]), 0, 0)
        if k == 0:
            add("initial_state", ca.vertcat(st.dq, st.v - p["v_hat"]), 0, 0)

        data = form.kinematics(st) if has_input else cpin.forward_kinematics(self.smodel, st.q, st.v)
        if has_input:
            F = st.forces
            applied = {frame: contact[i] * F[3 * i : 3 * i + 3] for i, frame in enumerate(robot.foot_frames)}
            if robot.has_arm:
                applied[robot.ee_frame] = F[3 * self.n_feet : 3 * self.n_feet + 3]
            add("dynamics", form.dynamics_constraints(st, data, applied), 0, 0)
            if st.tau is not None:
                tau_max = robot.joint_torque_limits
                add("torque_limits", st.tau, -tau_max, tau_max)
            cone = []
            for i in range(self.n_feet):
                fx, fy, fz = F[3 * i], F[3 * i + 1], F[3 * i + 2]
                relax = 1 - contact[i]
                cone += [
                    (fz + relax * big_force) / weight,
                    (p["mu"] ** 2 * fz**2 - fx**2 - fy**2 + relax * big_force**2) / weight**2,
                ]
            add("friction_cone", ca.vertcat(*cone), 0, np.inf)
            if robot.has_arm:
                add("ee_force", F[3 * self.n_feet :] - p["ee_force"], 0, 0)
            if k >= 1:
                foot_rows = []
                for i, frame in enumerate(robot.foot_frames):
                    vel = cpin.frame_velocity(data, frame, cpin.LOCAL_WORLD_ALIGNED).linear
                    c = contact[i]
                    foot_rows += [
                        c * vel[0:2] + (1 - c) * F[3 * i : 3 * i + 2] / weight,
                        vel[2] - (1 - c) * sp["swing_vz"][i],
                    ]
                add("foot_velocity", ca.vertcat(*foot_rows), 0, 0)
        if k >= 1:
            if robot.has_arm and has_input:
                ee_vel = cpin.frame_velocity(data, robot.ee_frame, cpin.LOCAL_WORLD_ALIGNED).linear
                add("ee_velocity", ee_vel - sp["ee_velocity"], 0, 0)
            lo_q, hi_q = robot.joint_position_limits
            v_max = robot.joint_velocity_limits
            add("joint_position_limits", st.q[7:], lo_q, hi_q)
            add("joint_velocity_limits", st.v[6:], -v_max, v_max)
        return cost, rows

    # --- helpers for solvers and controllers -----------------------------------------------------------
    def stage_sizes(self) -> dict[str, list[int]]:
        """Expected Fatrop stage sizes: ``nx``, ``nu`` and path-constraint rows ``ng`` per node."""
        nx = [s.nx for s in self.stages]
        nu = [s.nu for s in self.stages]
        # Fatrop counts the transition rows (nx of the next node) as dynamics, not as path constraints.
        ng = [s.ng - (s.nx if s.u_offset is not None else 0) for s in self.stages]
        return {"nx": nx, "nu": nu, "ng": ng}

    def split(self, w: np.ndarray) -> dict[str, np.ndarray]:
        """Split a primal vector into per-node arrays: ``dq``, ``v`` (N, nv), ``a`` (N-1, nv),
        ``forces`` (N-1, n_c, 3) and ``tau`` (n_tau, nj)."""
        w = np.asarray(w, dtype=float).ravel()
        nv, n_c = self.nv, self.nf // 3
        dq = np.array([w[s.x_offset : s.x_offset + nv] for s in self.stages])
        v = np.array([w[s.x_offset + nv : s.x_offset + 2 * nv] for s in self.stages])
        inputs = [w[s.u_offset : s.u_offset + s.nu] for s in self.stages if s.u_offset is not None]
        a = np.array([u[:nv] for u in inputs])
        forces = np.array([u[nv : nv + self.nf].reshape(n_c, 3) for u in inputs])
        tau = np.array([u[nv + self.nf :] for u in inputs if u.size > nv + self.nf])
        return {"dq": dq, "v": v, "a": a, "forces": forces, "tau": tau}

    def join(self, dq, v, a, forces, tau) -> np.ndarray:
        """Inverse of :meth:`split`."""
        parts = []
        for s in self.stages:
            parts += [dq[s.k], v[s.k]]
            if s.u_offset is not None:
                parts += [a[s.k], np.ravel(forces[s.k])]
                if s.has_torque:
                    parts.append(tau[s.k])
        return np.concatenate(parts)
