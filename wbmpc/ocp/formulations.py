"""Dynamics formulations: the small objects that plug the equations of motion into the OCP builder.

A formulation owns its state/input layout, its state transition and its dynamics path constraints;
everything else (gait, contacts, arm task, limits, cost, time grid, parameters) belongs to
:class:`wbmpc.ocp.OCP`. The six formulations of the paper's Table I:

* ``inverse_dynamics``: x = [dq, v], u = [a, F, tau_j*], path RNEA(q, v, a, F) = [0; tau_j];
* ``forward_dynamics``: x = [dq, v], u = [tau_j, F], transition a = ABA(q, v, [0; tau_j], F);
* ``centroidal_velocity``: x = [h/m, dq], u = [v, F], path A(q) v / m = h/m;
* ``centroidal_velocity_nobase``: x = [h/m, dq], u = [v_j, F], transition v_b = A_b^-1 (h - A_j v_j);
* ``centroidal_acceleration``: x = [dq, v], u = [a, F], path A a + Adot v = hdot(q, F);
* ``centroidal_acceleration_nobase``: x = [dq, v], u = [a_j, F], transition
  a_b = A_b^-1 (hdot - Adot v - A_j a_j).

(* joint torques only on the first ``n_tau`` nodes.) ``dq`` is the tangent increment of the configuration
relative to the measured one (``q = q_hat (+) dq``), ``h`` the centroidal momentum (world axes, about the
centre of mass; stored divided by the mass so its linear part is the CoM velocity [m/s]). All transitions
are explicit Euler: ``dq' = dq + v dt``, ``v' = v + a dt``, ``h' = h + hdot dt``.

Torque limits on the first ``n_tau`` nodes bound the decision variables ``tau_j`` where they exist
(inverse and forward dynamics) and the quasi-static estimate ``tau_j = g_j(q) - J_c,j^T F``
(:func:`wbmpc.cpin.static_torque_estimate`) for the centroidal formulations, like the paper.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np
import pinocchio as pin

from wbmpc import cpin


@dataclass
class StageVariables:
    """Symbolic quantities of one stage, named for what they are (all world/base conventions of Pinocchio).

    Attributes:
        x: State vector of the stage (decision variables).
        u: Input vector of the stage, or ``None`` at the terminal node.
        dq: Tangent increment (nv,) relative to the measured configuration.
        q: Configuration (nq,) ``q_hat (+) dq``.
        v: Generalised velocity (nv,): a state, an input, or an expression of them; ``None`` where the
            formulation has none (the terminal node of the centroidal-velocity formulations).
        a: Generalised acceleration (nv,): an input, or an expression set by the formulation once the
            contact forces are known (``None`` where the formulation has none).
        forces: Stacked 3-D contact forces (3 n_c,) as decision variables, or ``None``.
        tau: Joint torques (nj,) as decision variables, or ``None``.
        torque_limited: Whether the stage carries torque limits (the first ``n_tau`` nodes).
        blocks: Named parts of ``x`` and ``u`` (e.g. ``"h"``, ``"a_j"``).
    """

    x: ca.SX
    u: ca.SX | None
    dq: ca.SX
    q: ca.SX
    v: ca.SX | None
    a: ca.SX | None = None
    forces: ca.SX | None = None
    tau: ca.SX | None = None
    torque_limited: bool = False
    blocks: dict[str, ca.SX] = field(default_factory=dict)


class Formulation:
    """Common layout logic; subclasses define the blocks and the dynamics.

    Args:
        smodel: Symbolic model of the robot (``smodel.model`` is the numeric Pinocchio model).
        contact_frames: Frames of the 3-D contact forces (feet, then the arm end effector).
    """

    name = ""
    label = ""
    states = "[q, v]"
    inputs = ""
    constraint = ""
    path_constraint = True
    base_in_input = True
    #: The velocity is an input, so velocity-level task rows also apply at node 0.
    velocity_is_input = False

    def __init__(self, smodel: cpin.SymbolicModel, contact_frames: list[str]):
        self.smodel = smodel
        self.model = smodel.model
        self.contact_frames = list(contact_frames)
        self.nv = smodel.nv
        self.nj = smodel.nv - 6
        self.nf = 3 * len(self.contact_frames)
        #: Size of the force block of the weights ``R = [a, F, tau_j]`` (every contact frame, also those
        #: whose force is a parameter rather than an input).
        self.n_force_weights = self.nf
        self.mass = float(sum(inertia.mass for inertia in self.model.inertias))

    # --- layout ---------------------------------------------------------------------------------------
    def state_blocks(self) -> list[tuple[str, int]]:
        return [("dq", self.nv), ("v", self.nv)]

    def input_blocks(self, torque_limited: bool) -> list[tuple[str, int]]:
        raise NotImplementedError

    @property
    def nx(self) -> int:
        return sum(n for _, n in self.state_blocks())

    def nu(self, torque_limited: bool) -> int:
        return sum(n for _, n in self.input_blocks(torque_limited))

    def input_names(self, torque_limited: bool) -> list[str]:
        """Block names of the input vector, in order."""
        return [name for name, _ in self.input_blocks(torque_limited)]

    def stage(self, name: str, q_hat: ca.SX, has_input: bool, torque_limited: bool) -> StageVariables:
        """Create the decision variables of one stage and the force-free quantities derived from them."""
        x = ca.SX.sym(f"x_{name}", self.nx)
        blocks = _split(x, self.state_blocks())
        u = None
        if has_input:
            u = ca.SX.sym(f"u_{name}", self.nu(torque_limited))
            blocks |= _split(u, self.input_blocks(torque_limited))
        dq = blocks["dq"]
        st = StageVariables(
            x=x,
            u=u,
            dq=dq,
            q=cpin.integrate(self.smodel, q_hat, dq),
            v=blocks.get("v"),
            a=blocks.get("a"),
            forces=blocks.get("F"),
            tau=blocks.get("tau"),
            torque_limited=torque_limited and has_input,
            blocks=blocks,
        )
        self._derive(st)
        return st

    def _derive(self, st: StageVariables) -> None:
        """Hook: set force-free derived quantities (e.g. the base velocity)."""

    # --- dynamics -------------------------------------------------------------------------------------
    def kinematics(self, st: StageVariables) -> cpin.SymbolicData:
        """Forward kinematics shared by the dynamics and the task constraints of the stage."""
        return cpin.forward_kinematics(self.smodel, st.q, st.v, st.a if st.u is not None else None)

    def acceleration(self, st: StageVariables, data: cpin.SymbolicData, applied: dict) -> ca.SX | None:
        """Generalised acceleration of the stage (computed once, then cached in ``st.a``)."""
        return st.a

    def transition(self, st: StageVariables, dt: ca.SX, data: cpin.SymbolicData, applied: dict) -> ca.SX:
        """Explicit Euler in the chart of the measured configuration: ``[dq + v dt, v + a dt]``."""
        a = self.acceleration(st, data, applied)
        return ca.vertcat(st.dq + st.v * dt, st.v + a * dt)

    def dynamics_constraints(self, st: StageVariables, data: cpin.SymbolicData, applied: dict) -> ca.SX:
        """Path constraint rows ``= 0`` (none for the transition-embedded formulations)."""
        return ca.SX(0, 1)

    def torque_expression(self, st: StageVariables, data: cpin.SymbolicData, applied: dict) -> ca.SX:
        """The joint torques bounded by the torque limits of a torque-limited stage."""
        if st.tau is not None:
            return st.tau
        return cpin.static_torque_estimate(self.smodel, st.q, applied, data=data)

    def regularization(self, st: StageVariables) -> list[tuple[ca.SX, slice]]:
        """Input terms penalised with ``R`` towards zero: ``(expression, slice of R = [a, F, tau_j])``."""
        terms = []
        if "a" in st.blocks:
            terms.append((st.blocks["a"], slice(0, self.nv)))
        if "a_j" in st.blocks:
            terms.append((st.blocks["a_j"], slice(6, self.nv)))
        if st.tau is not None:
            start = self.nv + self.n_force_weights
            terms.append((st.tau, slice(start, start + self.nj)))
        return terms

    def initial_state(self, st: StageVariables, q_hat: ca.SX, v_hat: ca.SX) -> ca.SX:
        """Rows fixing node 0 to the measurement (``= 0``)."""
        return ca.vertcat(st.dq, st.v - v_hat)

    def dynamics_function(self) -> ca.Function:
        """The dynamics constraint alone, as a function of its own symbols (for instruction counts)."""
        raise NotImplementedError

    def n_instructions(self) -> int:
        """Instructions of :meth:`dynamics_function` (the paper's "instructions per constraint")."""
        return int(self.dynamics_function().n_instructions())

    # --- numeric packing --------------------------------------------------------------------------------
    def state_values(self, q: np.ndarray, dq: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Numeric state of a node from the configuration ``q``, its increment ``dq`` and velocity ``v``."""
        return np.concatenate([dq, v])

    def input_values(self, v, a, forces, tau, torque_limited: bool) -> np.ndarray:
        """Numeric input of a stage from physical quantities (``tau`` may be ``None`` if unused)."""
        values = {
            "a": a,
            "a_j": a[6:],
            "v": v,
            "v_j": v[6:],
            "F": np.ravel(forces),
            "tau": tau if tau is not None else np.zeros(self.nj),
        }
        return np.concatenate([values[name] for name, _ in self.input_blocks(torque_limited)])

    # --- helpers ------------------------------------------------------------------------------------------
    def _symbols(self):
        q = ca.SX.sym("q", self.smodel.nq)
        v, a = ca.SX.sym("v", self.nv), ca.SX.sym("a", self.nv)
        F = ca.SX.sym("F", self.nf)
        forces = {frame: F[3 * i : 3 * i + 3] for i, frame in enumerate(self.contact_frames)}
        return q, v, a, F, forces

    def describe(self) -> dict:
        """The Table I row of this formulation (without timings)."""
        return {
            "formulation": self.name,
            "label": self.label,
            "states": self.states,
            "inputs": self.inputs,
            "dynamics_constraint": self.constraint,
            "base_in_input": self.base_in_input,
            "path_constraint": self.path_constraint,
            "instructions": self.n_instructions(),
        }


class InverseDynamics(Formulation):
    """Whole-body inverse dynamics (the paper's method): RNEA path constraint

    .. math::  [0_6;\\ \\tau_j] = \\mathrm{RNEA}(q_k, v_k, a_k, F_k) = M a + b - J_c^T F.
    """

    name = "inverse_dynamics"
    label = "Whole-body inverse dynamics"
    inputs = "[a, F, tau_j]"
    constraint = "[0; tau_j] = M a + b - J_c^T F (RNEA)"

    def input_blocks(self, torque_limited):
        return [("a", self.nv), ("F", self.nf)] + ([("tau", self.nj)] if torque_limited else [])

    def dynamics_constraints(self, st, data, applied):
        """Base rows = 0, and joint rows = tau_j where the torques are variables."""
        tau = cpin.rnea(self.smodel, st.q, st.v, st.a, applied, data=data)
        if st.tau is None:
            return tau[:6]
        return ca.vertcat(tau[:6], tau[6:] - st.tau)

    def dynamics_function(self):
        q, v, a, F, forces = self._symbols()
        return ca.Function("rnea", [q, v, a, F], [cpin.rnea(self.smodel, q, v, a, forces)])


class ForwardDynamics(Formulation):
    """Whole-body forward dynamics: the articulated-body algorithm inside the transition,

    .. math::  a_k = \\mathrm{ABA}(q_k, v_k, [0_6; \\tau_{j,k}], F_k) = M^{-1}([0; \\tau_j] + J_c^T F - b).

    The joint torques are inputs at every node; the torque limits bound them on the first ``n_tau`` nodes.
    """

    name = "forward_dynamics"
    label = "Whole-body forward dynamics"
    inputs = "[tau_j, F]"
    constraint = "a = M^-1 ([0; tau_j] + J_c^T F - b) (ABA)"
    path_constraint = False
    base_in_input = False

    def input_blocks(self, torque_limited):
        return [("tau", self.nj), ("F", self.nf)]

    def kinematics(self, st):
        return cpin.forward_kinematics(self.smodel, st.q, st.v)

    def acceleration(self, st, data, applied):
        if st.a is None:
            st.a = cpin.aba(self.smodel, st.q, st.v, ca.vertcat(ca.SX.zeros(6), st.tau), applied)
        return st.a

    def dynamics_function(self):
        q, v, _, F, forces = self._symbols()
        tau = ca.SX.sym("tau_j", self.nj)
        a = cpin.aba(self.smodel, q, v, ca.vertcat(ca.SX.zeros(6), tau), forces)
        return ca.Function("aba", [q, v, tau, F], [a])


class CentroidalVelocity(Formulation):
    """Centroidal dynamics at the velocity level with full kinematics (Dai et al.):

    state ``[h/m, dq]``, input ``[v, F]`` (with the base) or ``[v_j, F]`` (without), transitions
    ``h' = h + hdot(q, F) dt`` and ``dq' = dq + v dt``, and the momentum consistency

    .. math::  A(q) v = h \\quad \\text{(path constraint)} \\qquad\\text{or}\\qquad
               v_b = A_b^{-1}(h - A_j v_j) \\quad \\text{(in the transition)}.
    """

    name = "centroidal_velocity"
    label = "Centroidal velocity"
    states = "[h_com, q]"
    inputs = "[v, F]"
    constraint = "h_com = A v = [A_b A_j] [v_b; v_j]"
    velocity_is_input = True

    def state_blocks(self):
        return [("h", 6), ("dq", self.nv)]

    def input_blocks(self, torque_limited):
        return [("v", self.nv), ("F", self.nf)]

    def kinematics(self, st):
        return cpin.forward_kinematics(self.smodel, st.q, st.v)

    def transition(self, st, dt, data, applied):
        hdot = cpin.centroidal_momentum_rate(self.smodel, st.q, applied, data=data)
        return ca.vertcat(st.blocks["h"] + hdot * (dt / self.mass), st.dq + st.v * dt)

    def dynamics_constraints(self, st, data, applied):
        return cpin.centroidal_momentum(self.smodel, st.q, st.v, data=data) / self.mass - st.blocks["h"]

    def initial_state(self, st, q_hat, v_hat):
        h_hat = cpin.centroidal_momentum(self.smodel, q_hat, v_hat) / self.mass
        return ca.vertcat(st.blocks["h"] - h_hat, st.dq)

    def dynamics_function(self):
        q, v, _, _, _ = self._symbols()
        h = ca.SX.sym("h", 6)
        return ca.Function("cmm", [q, v, h], [cpin.centroidal_momentum(self.smodel, q, v) - h])

    def state_values(self, q, dq, v):
        data = self.model.createData()
        h = pin.computeCentroidalMomentum(self.model, data, q, v)
        return np.concatenate([h.linear / self.mass, h.angular / self.mass, dq])


class CentroidalVelocityNoBase(CentroidalVelocity):
    """Centroidal velocity without the base in the input: ``v_b = A_b^{-1}(h - A_j v_j)``."""

    name = "centroidal_velocity_nobase"
    label = "Centroidal velocity (no base input)"
    inputs = "[v_j, F]"
    constraint = "v_b = A_b^-1 (h_com - A_j v_j)"
    path_constraint = False
    base_in_input = False

    def input_blocks(self, torque_limited):
        return [("v_j", self.nj), ("F", self.nf)]

    def stage(self, name, q_hat, has_input, torque_limited):
        st = super().stage(name, q_hat, has_input, torque_limited)
        if has_input:
            h = st.blocks["h"] * self.mass
            v_b = cpin.centroidal_base_velocity(self.smodel, st.q, h, st.blocks["v_j"])
            st.v = ca.vertcat(v_b, st.blocks["v_j"])
        return st

    def dynamics_constraints(self, st, data, applied):
        return ca.SX(0, 1)

    def dynamics_function(self):
        q = ca.SX.sym("q", self.smodel.nq)
        h, v_j = ca.SX.sym("h", 6), ca.SX.sym("v_j", self.nj)
        v_b = cpin.centroidal_base_velocity(self.smodel, q, h, v_j)
        return ca.Function("base_velocity", [q, h, v_j], [v_b])


class CentroidalAcceleration(Formulation):
    """Centroidal dynamics at the acceleration level with full kinematics:

    state ``[dq, v]``, input ``[a, F]`` (with the base) or ``[a_j, F]`` (without), and

    .. math::  A(q) a + \\dot A(q, v) v = \\dot h(q, F) \\quad \\text{(path constraint), or}

    .. math::  a_b = A_b^{-1}(\\dot h - \\dot A v - A_j a_j) \\quad \\text{(in the transition)}.

    It is the base part of the equations of motion written with the centroidal momentum matrix.
    """

    name = "centroidal_acceleration"
    label = "Centroidal acceleration"
    inputs = "[a, F]"
    constraint = "hdot_com = Adot v + [A_b A_j] [a_b; a_j]"

    def input_blocks(self, torque_limited):
        return [("a", self.nv), ("F", self.nf)]

    def kinematics(self, st):
        return cpin.forward_kinematics(self.smodel, st.q, st.v)

    def _residual(self, q, v, a, forces, data=None):
        A = cpin.centroidal_map(self.smodel, q, data=data)
        dA = cpin.centroidal_map_time_variation(self.smodel, q, v)
        hdot = cpin.centroidal_momentum_rate(self.smodel, q, forces, data=data)
        return (ca.mtimes(A, a) + ca.mtimes(dA, v) - hdot) / self.mass

    def dynamics_constraints(self, st, data, applied):
        return self._residual(st.q, st.v, st.a, applied, data)

    def dynamics_function(self):
        q, v, a, F, forces = self._symbols()
        return ca.Function("centroidal_rate", [q, v, a, F], [self._residual(q, v, a, forces)])


class CentroidalAccelerationNoBase(CentroidalAcceleration):
    """Centroidal acceleration without the base in the input: ``a_b = A_b^{-1}(hdot - Adot v - A_j a_j)``."""

    name = "centroidal_acceleration_nobase"
    label = "Centroidal acceleration (no base input)"
    inputs = "[a_j, F]"
    constraint = "a_b = A_b^-1 (hdot_com - Adot v - A_j a_j)"
    path_constraint = False
    base_in_input = False

    def input_blocks(self, torque_limited):
        return [("a_j", self.nj), ("F", self.nf)]

    def _base_acceleration(self, q, v, a_j, forces, data=None):
        return cpin.centroidal_base_acceleration(self.smodel, q, v, a_j, forces, data=data)

    def acceleration(self, st, data, applied):
        if st.a is None:
            a_j = st.blocks["a_j"]
            st.a = ca.vertcat(self._base_acceleration(st.q, st.v, a_j, applied, data), a_j)
        return st.a

    def dynamics_constraints(self, st, data, applied):
        return ca.SX(0, 1)

    def dynamics_function(self):
        q, v, _, F, forces = self._symbols()
        a_j = ca.SX.sym("a_j", self.nj)
        return ca.Function("base_acceleration", [q, v, a_j, F], [self._base_acceleration(q, v, a_j, forces)])


FORMULATIONS: dict[str, type[Formulation]] = {
    cls.name: cls
    for cls in (
        InverseDynamics,
        ForwardDynamics,
        CentroidalVelocity,
        CentroidalVelocityNoBase,
        CentroidalAcceleration,
        CentroidalAccelerationNoBase,
    )
}


def make_formulation(name: str, smodel: cpin.SymbolicModel, contact_frames: list[str]) -> Formulation:
    """The formulation object called ``name`` (see :data:`FORMULATIONS`).

    Raises:
        ValueError: for an unknown name.
    """
    if name not in FORMULATIONS:
        raise ValueError(f"unknown formulation {name!r}; available: {list(FORMULATIONS)}")
    return FORMULATIONS[name](smodel, contact_frames)


def _split(vector: ca.SX, blocks: list[tuple[str, int]]) -> dict[str, ca.SX]:
    out, i = {}, 0
    for name, n in blocks:
        out[name] = vector[i : i + n]
        i += n
    return out
