"""The optimal control problem of the whole-body MPC, built once and solved with runtime parameters.

One builder owns everything the dynamics formulations share: the time grid, the gait (contact and swing
constraints), the arm task, the joint and torque limits, the cost and the parameter vector. The dynamics
come from a formulation object (:mod:`wbmpc.ocp.formulations`).

Nodes ``k = 0 .. N-1`` ("N = 15" counts the terminal node); stages ``k < N-1`` have inputs. Per stage the
constraint rows are ordered for Fatrop's structure detection: first the gap-closing transition
``x_{k+1} - f(x_k, u_k, dt_k) = 0``, then the path constraints of stage ``k`` (functions of ``x_k, u_k``):

* node 0: the initial state ``dq_0 = 0``, ``v_0 = v_hat`` (only with
  ``OCPSettings.initial_state_variables``; by default node 0's state is not a decision variable but the
  measurement itself, substituted into the stage-0 rows, so stage 0 has inputs only);
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
import pinocchio as pin

from wbmpc import cpin
from wbmpc.model.robot import Robot
from wbmpc.ocp.formulations import FORMULATIONS, make_formulation
from wbmpc.ocp.time_grid import symbolic_geometric_time_steps

MAX_NODES = 100  # beyond this the build and the first solve take minutes and gigabytes


@dataclass
class OCPSettings:
    """Structural settings: changing any of them rebuilds the problem.

    Attributes:
        n_nodes: Number of nodes including the terminal one (paper: 15).
        n_tau_nodes: Nodes ``k < n_tau_nodes`` carry joint torques and torque limits (paper: k <= 2).
        formulation: Dynamics formulation name, one of :data:`wbmpc.ocp.formulations.FORMULATIONS`.
        ee_force_input: Keep the commanded end-effector force as a decision variable pinned by an
            equality row on every stage, as in the paper's layout (its Table I counts those variables).
            ``False`` (default) enters the command as the parameter it is: 3 inputs and 3 equality rows
            fewer per stage, the same optimum.
        initial_state_variables: Keep node 0's state as decision variables pinned to the measurement by
            equality rows, as in the paper's layout. ``False`` (default) enters it as the parameter it is:
            ``nx`` variables and ``nx`` equality rows fewer, the same optimum, and Fatrop's Riccati
            recursion no longer eliminates them on every iteration (15 % of its search-direction time).
        torque_limit_fraction: Share (0, 1] of the motors' torque limits the plan may use on its torque
            nodes (1: the limits themselves, the paper); below 1 the rest is headroom for the low level's
            feedback on a real or emulated robot, whose drives clip at the limit.
    """

    n_nodes: int = 15
    n_tau_nodes: int = 3
    formulation: str = "inverse_dynamics"
    ee_force_input: bool = False
    initial_state_variables: bool = False
    torque_limit_fraction: float = 1.0

    def __post_init__(self):
        if (
            not isinstance(self.n_nodes, int | np.integer)
            or isinstance(self.n_nodes, bool)
            or self.n_nodes < 3
        ):
            raise ValueError(f"n_nodes must be an integer >= 3, got {self.n_nodes!r}")
        if self.n_nodes > MAX_NODES:
            raise ValueError(
                f"n_nodes = {self.n_nodes} is above {MAX_NODES}: the problem grows linearly (N = 1000 took "
                "419 s and 11.4 GB for its first solve); the paper uses 15"
            )
        if (
            not isinstance(self.n_tau_nodes, int | np.integer)
            or isinstance(self.n_tau_nodes, bool)
            or not 1 <= self.n_tau_nodes <= self.n_nodes - 1
        ):
            raise ValueError(
                f"n_tau_nodes must be in [1, n_nodes - 1 = {self.n_nodes - 1}], got {self.n_tau_nodes}"
            )
        if self.formulation not in FORMULATIONS:
            raise ValueError(f"unknown formulation {self.formulation!r}; available: {list(FORMULATIONS)}")
        fraction = self.torque_limit_fraction
        if (
            isinstance(fraction, bool)
            or not isinstance(fraction, int | float | np.number)
            or not 0 < fraction <= 1
        ):
            raise ValueError(f"OCPSettings.torque_limit_fraction must be in (0, 1], got {fraction!r}")
        for name in ("ee_force_input", "initial_state_variables"):
            value = getattr(self, name)
            if not isinstance(value, bool | np.bool_):
                raise ValueError(f"OCPSettings.{name} must be True or False, got {value!r}")


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
            out[start : start + rows * cols] = value.reshape(rows, cols).ravel(order="F")
        if not np.isfinite(out).all():  # one check of the whole vector; the block is named when it fails
            for name, (start, (rows, cols)) in self.blocks.items():
                if not np.isfinite(out[start : start + rows * cols]).all():
                    raise ValueError(f"parameter {name!r} contains NaN or inf")
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

    One class on purpose (about 400 lines): the variable layout, the parameter blocks, the rows of every
    stage and their bounds are built together and indexed into each other; the dynamics formulations are
    the small objects plugged in (:mod:`wbmpc.ocp.formulations`).

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
        if not isinstance(robot, Robot):
            raise ValueError(f"robot must be a wbmpc.model.robot.Robot (see load_robot), got {robot!r}")
        if robot.n_feet != 4:
            raise ValueError(
                f"robot {robot.name!r} has {robot.n_feet} foot frames {list(robot.foot_frames)}; the OCP's "
                "gaits schedule 4 feet (FL, FR, RL, RR): give load_robot four foot_frames"
            )
        if settings is not None and not isinstance(settings, OCPSettings):
            raise ValueError(f"settings must be an OCPSettings, got {settings!r}")
        self.robot = robot
        self.settings = settings or OCPSettings()
        self.smodel = cpin.SymbolicModel(robot.model)
        # Frames whose forces are decision variables: the feet, and the end effector in the paper's layout.
        ee_input = robot.has_arm and self.settings.ee_force_input
        self.force_frames = list(robot.contact_frames) if ee_input else list(robot.foot_frames)
        self.formulation = make_formulation(self.settings.formulation, self.smodel, self.force_frames)
        self.n_feet = robot.n_feet
        self.nv, self.nq, self.nj = robot.nv, robot.nq, robot.nj
        self.nf = 3 * len(robot.contact_frames)
        self.formulation.n_force_weights = self.nf
        self._build()

    # --- layout --------------------------------------------------------------------------------------------
    @property
    def n_nodes(self) -> int:
        return self.settings.n_nodes

    @property
    def n_weights_input(self) -> int:
        """Size of ``R``: weights of ``[a, F, tau_j]`` whatever the formulation's inputs are."""
        return self.nv + self.nf + self.nj

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
        P.add("R", self.n_weights_input)
        return P

    # --- construction -------------------------------------------------------------------------------------
    def _build(self) -> None:
        form, S = self.formulation, self.settings
        P = self._declare_parameters()
        p = P.symbols
        n_stages = self.n_nodes - 1
        dts = symbolic_geometric_time_steps(self.n_nodes, p["dt_min"], p["dt_max"])
        stages = [
            form.stage(str(k), p["q_hat"], has_input=k < n_stages, torque_limited=k < S.n_tau_nodes)
            for k in range(self.n_nodes)
        ]
        x_parts, g_parts, lbg, ubg, eq = [], [], [], [], []
        infos: list[StageInfo] = []
        offset = n_rows = 0
        cost = 0
        for k, st in enumerate(stages):
            has_input = st.u is not None
            nx = 0 if k == 0 and self.initial_state_is_parameter else form.nx
            info = StageInfo(
                k=k,
                nx=nx,
                nu=st.u.numel() if has_input else 0,
                x_offset=offset,
                u_offset=offset + nx if has_input else None,
                has_torque=st.torque_limited,
                g_offset=n_rows,
            )
            x_parts.append(self.stage_decision_variables(k, st))
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
        # Node 0's state as an expression of the parameters where it is one (else rows pin it: any form).
        x0, self.initial_state_function = None, None
        if self.initial_state_is_parameter:
            x0 = self.initial_state_value(stages[0], p)
            self.initial_state_function = ca.Function("x0", [P.vector], [x0], ["p"], ["x0"])
        self.plan_function = self._plan_function(stages, P, dts, x0)
        self._plan_reader = None
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
            st: The stage variables (:class:`wbmpc.ocp.formulations.StageVariables`).
            x_next: State of node ``k + 1`` (for the transition), ``None`` at the terminal node.
            p: Shared parameter blocks (symbols).
            sp: Per-stage parameters (``dt``, ``contact``, ``swing_vz``, ``force_des``, ``ee_velocity``).

        Returns:
            ``(cost, rows)`` with rows ``(name, expression, lower bounds, upper bounds)`` in Fatrop order.
        """
        robot, form = self.robot, self.formulation
        weight = robot.mass * robot.gravity
        has_input = st.u is not None
        rows = []

        def add(name, expr, lo, hi):
            expr = ca.vec(expr)
            n = expr.numel()
            if n == 0:
                return
            rows.append(
                (
                    name,
                    expr,
                    np.broadcast_to(np.asarray(lo, float), (n,)),
                    np.broadcast_to(np.asarray(hi, float), (n,)),
                )
            )

        # Cost: quadratic tracking of [dq, v] with runtime diagonal weights (terminal = stage state cost);
        # v is a state or an input depending on the formulation (none at a centroidal-velocity terminal).
        if st.v is not None:
            cost = ca.dot(p["Q"], (ca.vertcat(st.dq, st.v) - ca.vertcat(p["dq_des"], p["v_des"])) ** 2)
        else:
            cost = ca.dot(p["Q"][: self.nv], (st.dq - p["dq_des"]) ** 2)
        data = form.kinematics(st) if has_input else cpin.forward_kinematics(self.smodel, st.q, st.v)
        if has_input:
            contact = sp["contact"]
            F = st.forces
            ee_input = F.numel() > 3 * self.n_feet
            f_des = ca.vertcat(
                *[ca.vertcat(0, 0, sp["force_des"][i]) for i in range(self.n_feet)],
                *([p["ee_force"]] if ee_input else []),
            )
            R = p["R"]  # weights of [a, F of every contact frame, tau] whatever the layout
            cost += ca.dot(R[self.nv : self.nv + F.numel()], (F - f_des) ** 2)
            for expr, weights in form.regularization(st):
                cost += ca.dot(R[weights], expr**2)
            applied = self.applied_forces(st, contact, p["ee_force"])
            # Gap-closing transition first (Fatrop structure detection).
            add("transition", x_next - form.transition(st, sp["dt"], data, applied), 0, 0)
        if k == 0 and not self.initial_state_is_parameter:
            add("initial_state", form.initial_state(st, p["q_hat"], p["v_hat"]), 0, 0)
        velocity_rows = k >= 1 or form.velocity_is_input  # v_0 is fixed by the measurement otherwise
        if has_input:
            add("dynamics", form.dynamics_constraints(st, data, applied), 0, 0)
            if st.torque_limited:
                tau_max = self.settings.torque_limit_fraction * robot.joint_torque_limits
                # Rows scaled to O(1) slacks (here and below): Fatrop starts every bound multiplier at 1, so a
                # slack of 100 N m costs extra iterations until s z reaches the barrier parameter.
                tau = form.torque_expression(st, data, applied)
                add("torque_limits", *_unit_rows(tau, -tau_max, tau_max))
            cone = []
            for i in range(self.n_feet):
                fx, fy, fz = F[3 * i], F[3 * i + 1], F[3 * i + 2]
                relax = 1 - contact[i]  # a swing foot's rows: inactive with a unit slack
                cone += [
                    fz / weight + relax,
                    (p["mu"] ** 2 * fz**2 - fx**2 - fy**2) / weight**2 + relax,
                ]
            add("friction_cone", ca.vertcat(*cone), 0, np.inf)
            if ee_input:
                add("ee_force", F[3 * self.n_feet :] - p["ee_force"], 0, 0)
            if velocity_rows:
                foot_rows = []
                for i, frame in enumerate(robot.foot_frames):
                    vel = cpin.frame_velocity(data, frame, cpin.LOCAL_WORLD_ALIGNED).linear
                    c = contact[i]
                    foot_rows += [
                        c * vel[0:2] + (1 - c) * F[3 * i : 3 * i + 2] / weight,
                        vel[2] - (1 - c) * sp["swing_vz"][i],
                    ]
                add("foot_velocity", ca.vertcat(*foot_rows), 0, 0)
                if robot.has_arm:
                    ee_vel = cpin.frame_velocity(data, robot.ee_frame, cpin.LOCAL_WORLD_ALIGNED).linear
                    add("ee_velocity", ee_vel - sp["ee_velocity"], 0, 0)
        if k >= 1:
            lo_q, hi_q = robot.joint_position_limits
            add("joint_position_limits", *_unit_rows(st.q[7:], lo_q, hi_q))
        if velocity_rows and st.v is not None:
            v_max = robot.joint_velocity_limits
            add("joint_velocity_limits", *_unit_rows(st.v[6:], -v_max, v_max))
        if k == 0 and self.initial_state_is_parameter:  # node 0's state is the measurement
            x0 = self.initial_state_value(st, p)
            exprs = ca.substitute([cost, *[expr for _, expr, _, _ in rows]], [st.x], [x0])
            cost = exprs[0]
            rows = [(name, e, lo, hi) for (name, _, lo, hi), e in zip(rows, exprs[1:], strict=True)]
        return cost, rows

    @property
    def initial_state_is_parameter(self) -> bool:
        """Whether node 0's state is the measurement (a parameter) rather than pinned decision variables."""
        return not self.settings.initial_state_variables

    def stage_decision_variables(self, k: int, st) -> ca.SX:
        """Decision variables of stage ``k`` in NLP order: ``[x_k, u_k]``, ``u_0`` alone when node 0's
        state is the measurement, ``x_k`` alone at the terminal node."""
        x = ca.SX(0, 1) if k == 0 and self.initial_state_is_parameter else st.x
        return ca.vertcat(x, st.u) if st.u is not None else x

    def initial_state_value(self, st, p: dict) -> ca.SX:
        """Node 0's state as an expression of the parameters: the solution ``x_0 = c(p)`` of the
        formulation's initial-state rows ``x_0 - c(p) = 0``.

        Raises:
            ValueError: if the formulation's initial-state rows are not of that form (identity in
                ``x_0``, free of the inputs), so that the state cannot be substituted.
        """
        rows = self.formulation.initial_state(st, p["q_hat"], p["v_hat"])
        jac = ca.jacobian(rows, st.x)
        inputs = st.u if st.u is not None else ca.SX(0, 1)
        symbols = ca.vertcat(st.x, inputs, *[ca.vec(value) for value in p.values()])
        if (
            rows.numel() != st.x.numel()
            or (inputs.numel() and ca.depends_on(rows, inputs))
            or ca.depends_on(jac, symbols)
            or not np.array_equal(np.array(ca.evalf(jac)), np.eye(st.x.numel()))
        ):
            raise ValueError(
                f"formulation {self.formulation.name!r}: initial_state() must return x_0 - c(p) to enter "
                "node 0's state as a parameter; use OCPSettings(initial_state_variables=True)"
            )
        return -ca.substitute(rows, st.x, ca.SX.zeros(st.x.numel()))

    def applied_forces(self, st, contact, ee_force) -> dict[str, ca.SX]:
        """Forces acting on the robot per contact frame: ``c_i F_i`` on the feet (a swing foot carries
        none), the arm force as is (its decision variable in the paper's layout, else the command)."""
        F = st.forces
        applied = {frame: contact[i] * F[3 * i : 3 * i + 3] for i, frame in enumerate(self.robot.foot_frames)}
        if self.robot.has_arm:
            n = 3 * self.n_feet
            applied[self.robot.ee_frame] = F[n : n + 3] if F.numel() > n else ee_force
        return applied

    def _plan_function(self, stages, P: ParameterLayout, dts, x0: ca.SX) -> ca.Function:
        """``(w, p) -> (dq, v, a, forces, tau)``: the physical plan of any formulation.

        ``v`` where the formulation has none (the terminal node of centroidal velocity) repeats the last
        one; ``a`` is the formulation's acceleration or, at the velocity level, the finite difference of
        the joint velocities with the base acceleration the contact forces imply (so that the RNEA base
        rows vanish and the torques are consistent with the planned forces); ``tau`` is the torque
        variables where they exist, else the RNEA torques of the plan on the torque-limited nodes (what
        the low-level controller applies).
        """
        p = P.symbols
        v = [st.v for st in stages]
        for k in range(1, len(v)):
            if v[k] is None:
                v[k] = v[k - 1]
        a, forces, tau = [], [], []
        for k, st in enumerate(stages[:-1]):
            applied = self.applied_forces(st, p["contact"][:, k], p["ee_force"])
            a_k = st.a
            if a_k is None:  # velocity level: joint accelerations by finite differences, base from the forces
                a_j = (v[k + 1][6:] - v[k][6:]) / dts[k]
                a_b = cpin.centroidal_base_acceleration(self.smodel, st.q, v[k], a_j, applied)
                a_k = ca.vertcat(a_b, a_j)
            a.append(a_k)
            forces.append(ca.vertcat(*applied.values()))
            if st.tau is not None:
                tau.append(st.tau)
            elif st.torque_limited:
                tau.append(cpin.rnea(self.smodel, st.q, v[k], a_k, applied)[6:])
        w = ca.vertcat(*[self.stage_decision_variables(k, st) for k, st in enumerate(stages)])
        outputs = [
            ca.horzcat(*[st.dq for st in stages]),
            ca.horzcat(*v),
            ca.horzcat(*a),
            ca.horzcat(*forces),
            ca.horzcat(*tau),
        ]
        if self.initial_state_is_parameter:
            outputs = ca.substitute(outputs, [stages[0].x], [x0])
        return ca.Function("plan", [w, P.vector], outputs, ["w", "p"], ["dq", "v", "a", "forces", "tau"])

    def plan(self, w: np.ndarray, p: np.ndarray) -> dict[str, np.ndarray]:
        """The physical plan of a primal vector ``w``: ``dq``, ``v`` (N, nv), ``a`` (N-1, nv), ``forces``
        (N-1, 3 n_contacts), ``tau`` (torque nodes, nj); :attr:`plan_function` read by NumPy where it
        can be (:class:`~wbmpc.ocp.plan_reader.PlanReader`, built on first use)."""
        return self._reader()(w, p)

    def _reader(self):
        if self._plan_reader is None:
            from wbmpc.ocp.plan_reader import PlanReader

            self._plan_reader = PlanReader(self.plan_function)
        return self._plan_reader

    # --- helpers for solvers and controllers -----------------------------------------------------------
    def stage_sizes(self) -> dict[str, list[int]]:
        """Expected Fatrop stage sizes: ``nx``, ``nu`` and path-constraint rows ``ng`` per node."""
        nx = [s.nx for s in self.stages]
        nu = [s.nu for s in self.stages]
        if nx[0] == 0:  # node 0's state is a parameter: Fatrop's detection calls u_0's first nx_1 entries x_0
            nx[0] = min(nx[1], nu[0])
            nu[0] -= nx[0]
        # Fatrop counts the transition rows (nx of the next node) as dynamics, not as path constraints.
        ng = [
            s.ng - (self.stages[i + 1].nx if s.u_offset is not None else 0) for i, s in enumerate(self.stages)
        ]
        return {"nx": nx, "nu": nu, "ng": ng}

    def split(self, w: np.ndarray, p: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Split a primal vector into the formulation's named blocks, stacked over the nodes that have
        them (e.g. ``dq``, ``v`` (N, nv); ``a``, ``F`` (N-1, ...); ``tau`` (stages with torques, nj)).

        Args:
            w: Primal vector (``n_variables``,).
            p: Parameter vector: node 0's state is computed from it when it is not a decision variable
                (required then).
        """
        w = np.asarray(w, dtype=float).ravel()
        if w.shape != (self.n_variables,):
            raise ValueError(f"w must have shape ({self.n_variables},), got {w.shape}")
        form = self.formulation
        out: dict[str, list] = {}
        for s in self.stages:
            values, blocks = [w[s.x_offset : s.x_offset + s.nx]], form.state_blocks()
            if s.nx == 0:
                if p is None:
                    raise ValueError("split(w, p) needs p: node 0's state is the measurement, not in w")
                values = [np.array(self.initial_state_function(p)).ravel()]
            if s.u_offset is not None:
                values.append(w[s.u_offset : s.u_offset + s.nu])
                blocks = blocks + form.input_blocks(s.has_torque)
            flat, i = np.concatenate(values), 0
            for name, n in blocks:
                out.setdefault(name, []).append(flat[i : i + n])
                i += n
        return {name: np.array(values) for name, values in out.items()}

    def join(self, q_hat, dq, v, a, forces, tau) -> np.ndarray:
        """Primal vector from physical quantities (the inverse of the plan function): a NumPy scatter
        where the formulation's variables are the plan's entries (:meth:`PlanReader.scatter
        <wbmpc.ocp.plan_reader.PlanReader.scatter>`), else per stage.

        Args:
            q_hat: Measured configuration (nq,).
            dq, v: (N, nv) increments and velocities; a: (N-1, nv); forces: (N-1, n_c, 3) [N];
            tau: (n, nj) joint torques of the first ``n`` stages (missing rows are zero).
        """
        reader = self._reader()
        forces = np.asarray(forces, dtype=float)
        # The plan's forces hold every contact frame; a caller's decision-variable forces only go by stage.
        if reader.can_scatter and forces.shape[1:] == (len(self.robot.contact_frames), 3):
            return reader.scatter({"dq": dq, "v": v, "a": a, "forces": forces, "tau": tau})
        return self.join_by_stage(q_hat, dq, v, a, forces, tau)

    def join_by_stage(self, q_hat, dq, v, a, forces, tau) -> np.ndarray:
        """:meth:`join` stage by stage, through the formulation's ``state_values`` / ``input_values``."""
        form, model = self.formulation, self.robot.model
        parts = []
        for s in self.stages:
            q = pin.integrate(model, q_hat, dq[s.k]) if form.velocity_is_input else None
            if s.nx:  # node 0's state is the measurement unless it is a decision variable
                parts.append(form.state_values(q, dq[s.k], v[s.k]))
            if s.u_offset is not None:
                tau_k = tau[s.k] if s.k < len(tau) else None
                f_k = np.asarray(forces[s.k])[: len(self.force_frames)]  # decision-variable forces only
                parts.append(form.input_values(v[s.k], a[s.k], f_k, tau_k, s.has_torque))
        return np.concatenate(parts)


def _unit_rows(expr: ca.SX, lower: np.ndarray, upper: np.ndarray) -> tuple[ca.SX, np.ndarray, np.ndarray]:
    """``lower <= expr <= upper`` rewritten as ``-1 <= (expr - mid) / half <= 1`` per row (rows with an
    infinite or huge range are left as they are). The same feasible set, with slacks of order one."""
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    with np.errstate(over="ignore", invalid="ignore"):
        mid, half = (upper + lower) / 2, (upper - lower) / 2
    finite = np.isfinite(mid) & np.isfinite(half) & (half > 0) & (half < 1e6)
    mid, half = np.where(finite, mid, 0.0), np.where(finite, half, 1.0)
    return (expr - mid) / half, (lower - mid) / half, (upper - mid) / half
