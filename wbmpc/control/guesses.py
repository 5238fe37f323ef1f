"""Initial guesses of the MPC's solves: a cold start from the measured state, and the last plan shifted.

:func:`cold_guess` holds the measured state on every node with the static forces and torques of each
node's contacts; :func:`shifted_guess` interpolates the previous plan on the new solve's node times (the
configurations in the old plan's chart, linear in the tangent) and re-initialises the forces, since the
adaptive grid moves the contact switches between solves (paper, Sec. V-A). Both return the primal vector
of the OCP (:meth:`OCP.join <wbmpc.ocp.builder.OCP.join>`).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from wbmpc.control.config import MPCSolution
from wbmpc.model.robot import Robot
from wbmpc.model.statics import static_equilibrium
from wbmpc.ocp import OCP
from wbmpc.ocp.time_grid import interp_rows, interp_weights, node_times

__all__ = ["cold_guess", "shifted_guess"]


def cold_guess(ocp: OCP, robot: Robot, q_hat: np.ndarray, v_hat: np.ndarray, params: dict) -> np.ndarray:
    """A physically consistent start: hold the measured state, static forces and torques on every node.

    Args:
        ocp: The problem; robot: its robot.
        q_hat, v_hat: The measured state (nq,), (nv,).
        params: The solve's parameter blocks (``contact`` (n_feet, N-1), ``ee_force`` (3,) [N]).
    """
    N, nv = ocp.n_nodes, robot.nv
    contact = params["contact"] > 0.5
    ee_force = params["ee_force"] if robot.has_arm else None  # a robot without an arm has none
    forces, taus = [], []
    for k in range(N - 1):
        try:
            eq = static_equilibrium(robot, q_hat, contact[:, k], ee_force=ee_force)
            f, tau = eq.forces, eq.tau
        except ValueError:  # no stance foot on this node: no static solution, zero forces
            f, tau = np.zeros((robot.n_feet, 3)), np.zeros(robot.nj)
        if robot.has_arm:
            f = np.vstack([f, params["ee_force"]])
        forces.append(f)
        taus.append(tau)
    return ocp.join(
        q_hat,
        np.zeros((N, nv)),
        np.tile(v_hat, (N, 1)),
        np.zeros((N - 1, nv)),
        np.array(forces),
        np.array(taus),
    )


def shifted_guess(
    ocp: OCP,
    robot: Robot,
    time_steps: np.ndarray,
    previous: MPCSolution,
    q_hat: np.ndarray,
    t: float,
    params: dict,
) -> np.ndarray:
    """The previous plan interpolated on the node times of a solve at ``t`` [s] around ``q_hat``, with
    forces re-initialised to the targets (weight over the stance feet, zero on swing feet, the commanded
    arm force).

    Args:
        ocp: The problem; robot: its robot; time_steps: the solve's steps [s] (N-1,).
        previous: The last converged plan.
        q_hat: The measured configuration (nq,); node 0 of the guess.
        params: The solve's parameter blocks (``v_hat``, ``force_des``, ``ee_force``).
    """
    model = robot.model
    N = ocp.n_nodes
    t_new = node_times(time_steps, t)
    t_old = previous.node_times
    # Express the old configurations in the old chart and interpolate there (linear in the tangent).
    q_ref = previous.q[0]
    # The nodes' and the stages' interpolation weights, each computed once (shared by the arrays below).
    nodes = interp_weights(t_new, t_old)  # a plan has >= 2 nodes
    stages = interp_weights(t_new[:-1], t_old[:-1]) if len(t_old) > 2 else None  # one stage: held
    dq_old = np.array([pin.difference(model, q_ref, q) for q in previous.q])
    dq_interp = interp_rows(t_new, t_old, dq_old, nodes)
    q_new = [pin.integrate(model, q_ref, d) for d in dq_interp]
    dq = np.array([pin.difference(model, q_hat, q) for q in q_new])
    dq[0] = 0.0
    v = interp_rows(t_new, t_old, previous.v, nodes)
    v[0] = params["v_hat"]
    a = interp_rows(t_new[:-1], t_old[:-1], previous.a, stages)
    # Torques on every stage (held after the last planned one): formulations take what they use.
    tau_times = t_old[: len(previous.tau)]
    tau_weights = stages if len(tau_times) == len(t_old) - 1 else None  # else a shorter torque horizon
    tau = interp_rows(t_new[:-1], tau_times, previous.tau, tau_weights)
    forces = np.zeros((N - 1, len(robot.contact_frames), 3))
    forces[:, : robot.n_feet, 2] = params["force_des"].T
    if robot.has_arm:
        forces[:, -1] = params["ee_force"]
    return ocp.join(q_hat, dq, v, a, forces, tau)
