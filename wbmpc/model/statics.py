"""Static equilibrium of a standing robot: contact forces that carry it and joint torques that hold it.

With v = a = 0 the equations of motion :math:`M(q) a + b(q, v) = [0; \\tau] + J_c(q)^T F` reduce to

.. math::

    g(q) = \\begin{bmatrix} 0 \\\\ \\tau \\end{bmatrix} + \\sum_c J_c(q)^T F_c ,

where :math:`g = \\partial V / \\partial q` is the generalised gravity and :math:`J_c` the
``LOCAL_WORLD_ALIGNED`` linear Jacobian (3, nv) of contact frame c, so :math:`F_c` is a world-frame 3-D
force [N] acting on the robot at the frame origin. The first six rows (unactuated base) are Newton-Euler
for the whole robot, linear in the forces:

.. math::  A F_s = g_b(q) - J_{e,b}^T F_e, \\qquad A = [J_{c,b}^T]_{c \\in \\text{stance}}
           \\in R^{6 \\times 3 n_s}

(subscript b: the six base columns; e: the end effector, whose force :math:`F_e` is given). The remaining
rows give the joint torques that hold the robot, :math:`\\tau = g_j(q) - J_j^T F`.

Example:
    >>> robot = load_b1_z1()
    >>> eq = static_equilibrium(robot, robot.q_nominal, [True] * 4)
    >>> eq.forces[:, 2].sum()  # ~ m g = 597.5 N
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from wbmpc import checks
from wbmpc.model.robot import FRONT_FEET, Robot

# FRONT_FEET as slices of the FOOT_NAMES rows (basic indexing: the force targets are computed every tick).
_FRONT, _REAR = slice(0, 2), slice(2, 4)
if FRONT_FEET.tolist() != [True, True, False, False]:
    raise ImportError("wbmpc.model.statics: _FRONT/_REAR no longer match FRONT_FEET")


def default_force_distribution(contact, mass: float, gravity: float = 9.81, front_ratio: float = 0.5):
    """Nominal vertical contact forces [N] carrying the weight m g over the stance feet.

    With front and rear feet in stance, front_ratio * m g is shared equally by the front stance feet and
    (1 - front_ratio) * m g by the rear ones; if only front (or only rear) feet are in stance they carry
    all of m g. Swing feet get 0, and so does every foot when none is in stance.

    Args:
        contact: Bool array (4,) or (4, n), True = stance, FOOT_NAMES order.
        mass: Total robot mass m [kg], > 0.
        gravity: g [m/s^2], > 0.
        front_ratio: Share of the weight on the front feet, in [0, 1].

    Returns:
        Array with the shape of `contact`; each column sums to m g if any foot is in stance.
    """
    contact = np.asarray(contact)
    if (
        contact.shape[:1] != (4,)
        or contact.ndim > 2
        or (contact.dtype != bool and not ((contact == 0) | (contact == 1)).all())
    ):
        raise ValueError(f"contact must be a bool array of shape (4,) or (4, n), got shape {contact.shape}")
    weight = checks.number("mass", mass, low=0.0, low_open=True, unit="kg")
    weight *= checks.number("gravity", gravity, low=0.0, low_open=True, unit="m/s^2")
    checks.number("front_ratio", front_ratio, low=0.0, high=1.0)
    c = contact.astype(bool).reshape(4, -1)
    # Rows in FOOT_NAMES order: the front feet are rows 0-1 (FRONT_FEET); slices, as this runs every tick.
    n_front, n_rear = c[_FRONT].sum(axis=0), c[_REAR].sum(axis=0)
    both = (n_front > 0) & (n_rear > 0)
    w_front = np.where(both, front_ratio, (n_front > 0).astype(float)) * weight
    w_rear = np.where(both, 1.0 - front_ratio, (n_rear > 0).astype(float)) * weight
    per_front = w_front / np.maximum(n_front, 1)
    per_rear = w_rear / np.maximum(n_rear, 1)
    forces = np.empty(c.shape)
    forces[_FRONT] = per_front
    forces[_REAR] = per_rear
    forces *= c
    return forces.reshape(contact.shape)


@dataclass
class StaticEquilibrium:
    """Contact forces and joint torques of a robot at rest (v = a = 0).

    Attributes:
        forces: Foot forces (n_feet, 3) [N], world frame, acting on the robot; zero for swing feet.
        tau: Joint torques (nj,) [N m] holding the robot: :math:`\\tau = g_j(q) - J_j^T F`.
        base_residual: Unbalanced base wrench (6,) :math:`g_b(q) - J_b^T F` in the base frame
            ([N] then [N m]); ~1e-12 when the stance can carry the robot, larger when it cannot
            (e.g. two feet whose connecting line does not pass under the centre of mass).
        ee_force: End-effector force (3,) [N], world frame, acting on the robot (zeros if none).
        contact: Stance flags (n_feet,) bool, True = the foot carries force.
    """

    forces: np.ndarray
    tau: np.ndarray
    base_residual: np.ndarray
    ee_force: np.ndarray
    contact: np.ndarray

    @property
    def residual_norm(self) -> float:
        """Euclidean norm of ``base_residual`` (mixed units, [N] and [N m])."""
        return float(np.linalg.norm(self.base_residual))

    @property
    def total_force(self) -> np.ndarray:
        """Sum (3,) [N] of all external forces on the robot (feet and end effector); = (0, 0, m g) at rest."""
        return self.forces.sum(axis=0) + self.ee_force


def static_equilibrium(
    robot: Robot,
    q,
    contact,
    ee_force=None,
    reference_forces=None,
    weight: float = 1e-6,
) -> StaticEquilibrium:
    """Foot forces closest to a reference that keep the robot at rest, and the joint torques that hold it.

    Solves the equality-constrained least-squares problem on the stance-foot forces :math:`F_s`

    .. math::  \\min_{F_s} \\tfrac12 \\|F_s - F_s^{ref}\\|^2 \\quad \\text{s.t.} \\quad A F_s = r,
               \\qquad r = g_b(q) - J_{e,b}^T F_e ,

    whose KKT solution is :math:`F_s = F_s^{ref} + A^+ (r - A F_s^{ref})` (the minimum-norm correction,
    :math:`A^+ = A^T (A A^T)^{-1}` for a full-rank A), computed by SVD. Wrench directions the stance
    cannot resist (singular values :math:`\\sigma_i^2 \\le` ``weight`` :math:`\\sigma_{max}^2`, e.g. the
    moment about the line through two feet) are left unbalanced and show up in ``base_residual``.
    Friction cones and torque limits are not imposed; check them with :func:`check_friction` and
    ``robot.joint_torque_limits``.

    Args:
        robot: The robot.
        q: Configuration (nq,), unit base quaternion.
        contact: Stance flags (n_feet,) bool in ``robot.foot_frames`` order; at least one True.
        ee_force: Fixed world-frame force (3,) [N] on the end effector (e.g. (0, 0, -50): the arm carries
            a 5 kg load); ``None`` for no force. Needs a robot with an arm.
        reference_forces: Desired foot forces (n_feet, 3) [N], world frame; rows of swing feet are ignored.
            Default: the vertical split of m g, ``default_force_distribution`` with
            ``robot.front_force_ratio`` of it on the front feet.
        weight: Relative regularisation of the KKT solve: directions with
            :math:`\\sigma_i^2 \\le` weight :math:`\\sigma_{max}^2` are treated as unsupported. In (0, 1).

    Returns:
        The forces, holding torques and base residual.

    Raises:
        ValueError: wrong shape or non-finite input (the message names the argument), no foot in stance,
            an end-effector force on a robot without an arm, or ``weight`` outside (0, 1).
    """
    model = robot.model
    q = checks.array("q", q, (model.nq,))
    if abs(np.linalg.norm(q[3:7]) - 1.0) > 1e-6:
        norm = np.linalg.norm(q[3:7])
        raise ValueError(f"q: base quaternion q[3:7] must have unit norm, got norm {norm:.6g}")
    contact = _contact_flags(contact, robot.n_feet)
    if ee_force is not None and not robot.has_arm:
        raise ValueError(f"ee_force: robot {robot.name!r} has no end effector")
    F_e = np.zeros(3) if ee_force is None else checks.array("ee_force", ee_force, (3,))
    if reference_forces is None:
        reference = _default_reference(robot, contact)
    else:
        reference = checks.array("reference_forces", reference_forces, (robot.n_feet, 3))
    if not 0.0 < float(weight) < 1.0:
        raise ValueError(f"weight must be in (0, 1), got {weight}")

    data = model.createData()
    g = pin.computeGeneralizedGravity(model, data, q).copy()
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    J_feet = [_linear_jacobian(model, data, robot.frame_id(f)) for f in robot.foot_frames]
    JtF_e = np.zeros(model.nv)
    if robot.has_arm:
        JtF_e = _linear_jacobian(model, data, robot.frame_id(robot.ee_frame)).T @ F_e

    stance = np.flatnonzero(contact)
    A = np.hstack([J_feet[i][:, :6].T for i in stance])  # (6, 3 n_s)
    r = g[:6] - JtF_e[:6]
    x_ref = reference[stance].ravel()
    U, S, Vt = np.linalg.svd(A, full_matrices=False)
    keep = S**2 > weight * S[0] ** 2
    x = x_ref + Vt[keep].T @ ((U[:, keep].T @ (r - A @ x_ref)) / S[keep])

    forces = np.zeros((robot.n_feet, 3))
    forces[stance] = x.reshape(-1, 3)
    # Generalised force of the contacts J_c^T F; the holding torque is g - J^T F (not J^T F - g).
    JtF = sum(J.T @ f for J, f in zip(J_feet, forces, strict=True)) + JtF_e
    residual = g - JtF
    return StaticEquilibrium(
        forces=forces, tau=residual[6:], base_residual=residual[:6], ee_force=F_e, contact=contact
    )


def check_friction(forces, mu: float, tol: float = 1e-9) -> np.ndarray:
    """Which forces lie in the friction cone of flat ground (normal +z).

    A force f is inside when :math:`f_z \\ge 0` and :math:`\\sqrt{f_x^2 + f_y^2} \\le \\mu f_z` (within
    ``tol`` [N]); a zero force (swing foot) is inside.

    Args:
        forces: World-frame forces (n, 3) [N] on the robot (or a single (3,) force).
        mu: Friction coefficient, > 0.
        tol: Absolute tolerance [N].

    Returns:
        Bool array (n,) (or a bool for a single force), True = inside the cone.

    Raises:
        ValueError: ``forces`` is not (n, 3) / (3,) or not finite, or ``mu`` is not a positive number.
    """
    forces = np.asarray(forces, dtype=float)
    single = forces.shape == (3,)
    if single:
        forces = forces[None, :]
    if forces.ndim != 2 or forces.shape[1] != 3:
        raise ValueError(f"forces must have shape (n, 3) or (3,), got {np.shape(forces)}")
    if not np.all(np.isfinite(forces)):
        raise ValueError("forces must be finite (no NaN or inf)")
    if not (np.isfinite(mu) and mu > 0.0):
        raise ValueError(f"mu must be a finite positive number, got {mu}")
    tangential = np.linalg.norm(forces[:, :2], axis=1)
    inside = (forces[:, 2] >= -tol) & (tangential <= mu * forces[:, 2] + tol)
    return bool(inside[0]) if single else inside


# --- helpers ---------------------------------------------------------------------------------------------
def _linear_jacobian(model: pin.Model, data: pin.Data, frame_id: int) -> np.ndarray:
    """Rows (3, nv) of the LOCAL_WORLD_ALIGNED frame Jacobian: world-frame velocity of the frame origin."""
    return pin.getFrameJacobian(model, data, frame_id, pin.LOCAL_WORLD_ALIGNED)[:3].copy()


def _contact_flags(contact, n_feet: int) -> np.ndarray:
    flags = np.asarray(contact)
    if flags.shape != (n_feet,) or not np.all((flags == 0) | (flags == 1)):
        raise ValueError(f"contact must be {n_feet} booleans (one per foot), got {contact!r}")
    flags = flags.astype(bool)
    if not flags.any():
        raise ValueError("contact: at least one foot must be in contact")
    return flags


def _default_reference(robot: Robot, contact: np.ndarray) -> np.ndarray:
    """Vertical split of m g over the stance feet (front/rear share ``robot.front_force_ratio``)."""
    reference = np.zeros((robot.n_feet, 3))
    m, g = robot.mass, robot.gravity
    if robot.n_feet == 4:
        reference[:, 2] = default_force_distribution(contact, m, g, robot.front_force_ratio)
    else:  # not a quadruped: equal shares
        reference[contact, 2] = m * g / contact.sum()
    return reference
