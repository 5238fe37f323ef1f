"""Dynamics formulations: the small objects that plug the equations of motion into the OCP builder.

A formulation owns its state/input layout and its dynamics constraints; everything else (gait, contacts,
arm task, limits, cost, time grid, parameters) belongs to :class:`wbmpc.ocp.OCPBuilder`.

The paper's method is :class:`InverseDynamics`: state ``x = [dq, v]`` (tangent increment of the
configuration relative to the measured one, and the generalised velocity), input
``u = [a, F, tau_j]`` with the joint torques only on the first ``n_tau`` nodes, kinematic explicit-Euler
transitions and the RNEA path constraint

.. math::  [0_6;\\ \\tau_j] = \\mathrm{RNEA}(q_k, v_k, a_k, F_k).
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

from wbmpc import cpin


@dataclass
class StageVariables:
    """Symbolic quantities of one stage, named for what they are (all world/base conventions of Pinocchio).

    Attributes:
        x: State vector of the stage (decision variables).
        u: Input vector of the stage, or ``None`` at the terminal node.
        dq: Tangent increment (nv,) relative to the measured configuration.
        q: Configuration (nq,) ``q_hat (+) dq``.
        v: Generalised velocity (nv,).
        a: Generalised acceleration (nv,) or ``None``.
        forces: Stacked 3-D contact forces (3 n_c,) as decision variables, or ``None``.
        tau: Joint torques (nj,) or ``None`` where they are not decision variables.
    """

    x: ca.SX
    u: ca.SX | None
    dq: ca.SX
    q: ca.SX
    v: ca.SX
    a: ca.SX | None = None
    forces: ca.SX | None = None
    tau: ca.SX | None = None


class InverseDynamics:
    """Whole-body inverse dynamics (the paper's formulation).

    Args:
        smodel: Symbolic model of the robot.
        n_contacts: Number of 3-D contact forces (feet + arm end effector).
    """

    name = "inverse_dynamics"
    description = "whole-body inverse dynamics: x = [q, v], u = [a, F, tau_j], RNEA path constraint"

    def __init__(self, smodel: cpin.SymbolicModel, n_contacts: int):
        self.smodel = smodel
        self.nv = smodel.nv
        self.nj = smodel.nv - 6
        self.nf = 3 * n_contacts

    @property
    def nx(self) -> int:
        return 2 * self.nv

    def nu(self, has_torque: bool) -> int:
        return self.nv + self.nf + (self.nj if has_torque else 0)

    def input_names(self, has_torque: bool) -> list[str]:
        """Block names of the input vector, in order."""
        return ["a", "F"] + (["tau"] if has_torque else [])

    def stage(self, name: str, q_hat: ca.SX, has_input: bool, has_torque: bool) -> StageVariables:
        """Create the decision variables of one stage and the quantities derived from them."""
        x = ca.SX.sym(f"x_{name}", self.nx)
        dq, v = x[: self.nv], x[self.nv :]
        q = cpin.integrate(self.smodel, q_hat, dq)
        if not has_input:
            return StageVariables(x=x, u=None, dq=dq, q=q, v=v)
        u = ca.SX.sym(f"u_{name}", self.nu(has_torque))
        a = u[: self.nv]
        forces = u[self.nv : self.nv + self.nf]
        tau = u[self.nv + self.nf :] if has_torque else None
        return StageVariables(x=x, u=u, dq=dq, q=q, v=v, a=a, forces=forces, tau=tau)

    def transition(self, stage: StageVariables, dt: ca.SX) -> ca.SX:
        """Explicit Euler in the chart of the measured configuration: ``[dq + v dt, v + a dt]``."""
        return ca.vertcat(stage.dq + stage.v * dt, stage.v + stage.a * dt)

    def kinematics(self, stage: StageVariables) -> cpin.SymbolicData:
        """Forward kinematics shared by the dynamics and the task constraints of the stage."""
        return cpin.forward_kinematics(self.smodel, stage.q, stage.v, stage.a)

    def dynamics_constraints(
        self, stage: StageVariables, data: cpin.SymbolicData, applied_forces: dict[str, ca.SX]
    ) -> ca.SX:
        """RNEA path constraint: base rows = 0, and joint rows = tau_j where the torques are variables."""
        tau = cpin.rnea(self.smodel, stage.q, stage.v, stage.a, applied_forces, data=data)
        if stage.tau is None:
            return tau[:6]
        return ca.vertcat(tau[:6], tau[6:] - stage.tau)

    def n_dynamics_constraints(self, has_torque: bool) -> int:
        return 6 + (self.nj if has_torque else 0)
