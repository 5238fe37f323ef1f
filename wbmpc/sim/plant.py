"""Closed-loop plant: rigid-contact forward dynamics of a floating-base robot.

The paper benchmarks its MPC in closed loop against "Pinocchio's forward dynamics with the scheduled feet in
rigid contact" rather than a physics engine. :class:`ContactPlant` is that plant: the feet that the gait
schedule marks as stance are held by bilateral rigid point contacts, everything else follows the
constrained multibody dynamics

.. math::

    M(q)\\,a + b(q, v) = S^T \\tau + J_c(q)^T \\lambda, \\qquad
    J_c a + \\dot J_c v = -K_d\\,J_c v - K_p\\,(p_c - p_c^{anchor}),

integrated with semi-implicit (symplectic) Euler at a fixed step. Contact is *scheduled*, not detected:
the plant never decides by itself that a foot touches the ground, and it never enforces unilaterality or
friction. Both are instead measured and reported (:attr:`ContactPlant.last_violations`) so that a closed-loop
run can say how physical its contact forces were.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from wbmpc import checks
from wbmpc.model.quaternion import tilt

__all__ = ["ContactPlant", "PlantState", "fallen"]

_VIOLATION_KINDS = ("pulling", "slipping", "penetrating")
#: Depth below the ground surface from which a swing foot counts as penetrating [m]; it keeps a foot that
#: just lifted off from its anchor (held there to ~1e-9 m by the Baumgarte terms) from being reported.
_PENETRATION_TOL = 1e-4


@dataclass
class PlantState:
    """Snapshot of the plant state.

    Attributes:
        q: Configuration, shape (nq,): base position [m], base quaternion (x, y, z, w), joint angles [rad].
        v: Generalized velocity, shape (nv,): base linear [m/s] and angular [rad/s] velocity in the base
            frame (Pinocchio's free-flyer convention), joint velocities [rad/s].
        t: Simulated time [s].
    """

    q: np.ndarray
    v: np.ndarray
    t: float


@dataclass
class _ContactPattern:
    """Pinocchio constraint objects for one set of stance feet (at most 2^n_feet of them are built)."""

    feet: np.ndarray  # indices (into foot_frames) of the stance feet, ascending
    models: pin.StdVec_RigidConstraintModel
    datas: pin.StdVec_RigidConstraintData
    data: pin.Data  # own Data: initConstraintDynamics sizes its KKT workspace to this constraint set


class Plant:
    """The plant protocol: what the closed loop calls on any plant (the rigid-contact plant, PyBullet, the
    emulated robot). Subclasses set ``_model``, ``_dt`` and ``_foot_names`` and implement :meth:`reset`,
    :meth:`step`, :meth:`contact_forces` and :attr:`foot_positions`; the rest has defaults for a plant
    without a scene (no bodies, no end-effector contact)."""

    _model: pin.Model
    _dt: float
    _foot_names: tuple[str, ...]

    @property
    def model(self) -> pin.Model:
        """The Pinocchio model whose conventions the state follows."""
        return self._model

    @property
    def nq(self) -> int:
        """Configuration size."""
        return self._model.nq

    @property
    def nv(self) -> int:
        """Velocity size (joint torques have nv - 6 entries)."""
        return self._model.nv

    @property
    def dt(self) -> float:
        """Integration step [s]."""
        return self._dt

    @property
    def foot_frames(self) -> tuple[str, ...]:
        """Foot frame names, in the order of the contact flags and force arrays."""
        return self._foot_names

    def reset(self, q: np.ndarray, v: np.ndarray, t: float = 0.0) -> PlantState:
        """Put the robot at configuration ``q`` (nq,) and velocity ``v`` (nv,) at time ``t`` [s]."""
        raise NotImplementedError

    def step(
        self,
        tau_joints: np.ndarray,
        contact: np.ndarray,
        external_wrench: np.ndarray | None = None,
        ee_force: np.ndarray | None = None,
    ) -> PlantState:
        """Advance one step ``dt`` with the joint torques [N m] (nv - 6,) held constant; ``contact`` (n_feet,)
        is the scheduled stance (imposed by a rigid-contact plant, ignored where contacts come from the
        physics); ``external_wrench`` (6,) [N, N m] on the base and ``ee_force`` (3,) [N] on the end
        effector are disturbances (world axes)."""
        raise NotImplementedError

    def contact_forces(self) -> np.ndarray:
        """World forces of the ground on the feet during the last step [N], shape (n_feet, 3)."""
        raise NotImplementedError

    @property
    def foot_positions(self) -> np.ndarray:
        """World positions of the foot frames at the current state [m], shape (n_feet, 3)."""
        raise NotImplementedError

    def foot_contacts(self, scheduled: np.ndarray | None = None) -> np.ndarray:
        """Feet on the ground, shape (n_feet,) bool. A plant that imposes its contacts returns ``scheduled``
        (the stance about to be applied), one that simulates them what the physics gives."""
        raise NotImplementedError

    def ee_contact_force(self) -> np.ndarray:
        """World force [N] of the scene on the end effector during the last step, shape (3,): zero here."""
        return np.zeros(3)

    @property
    def body_names(self) -> list[str]:
        """Names of the scene bodies (none here)."""
        return []

    def body_pose(self, name: str):
        """Position and orientation of a scene body; a plant without a scene has none."""
        raise ValueError(f"no scene body {name!r}: this plant has no scene")

    def close(self) -> None:
        """Release what the plant holds (a physics client); nothing here."""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class ContactPlant(Plant):
    """Rigid-contact forward dynamics of a floating-base robot, integrated with semi-implicit Euler.

    **Approach.** Each step calls Pinocchio's proximal constrained-dynamics solver
    (``pin.constraintDynamics`` with one ``pin.RigidConstraintModel`` per stance foot: ``CONTACT_3D``,
    ``LOCAL_WORLD_ALIGNED``, between the foot frame origin and a fixed anchor point in the world). It solves
    the KKT system

    .. math::

        \\begin{bmatrix} M & J_c^T \\\\ J_c & 0 \\end{bmatrix}
        \\begin{bmatrix} a \\\\ -\\lambda \\end{bmatrix} =
        \\begin{bmatrix} S^T\\tau + \\tau_{ext} - b \\\\ -\\gamma - K_d J_c v - K_p (p_c - p_c^{anchor})
        \\end{bmatrix}

    (``J_c``: stacked 3-row LOCAL_WORLD_ALIGNED foot Jacobians, ``gamma`` the classical foot acceleration
    drift) in one C++ call of about 25 us for this 22-DoF robot, including the Baumgarte terms, instead of
    assembling ``M``, ``b``, ``J_c``, ``gamma`` through a dozen Python calls and a dense solve. Its Baumgarte
    corrector and force convention were checked against that formula: the stance-foot classical acceleration
    equals ``-kd v_foot - kp (p_foot - anchor)`` and ``M a + b = tau + J_c^T lambda`` to 1e-12, so
    :attr:`last_contact_forces` are the world-frame forces exerted *by the ground on the robot*. The
    proximal regularisation (``mu`` = 1e-8) keeps the solve defined if the stance constraints become
    redundant; in regular cases the iterations converge in 2-3 steps to the exact KKT solution.

    **Contact events.** Anchors are set at touchdown (a foot whose flag goes from False to True): the foot
    position at that instant, with its height replaced by the ground surface ``ground_height +
    foot_radius`` (a foot scheduled early is pulled down to the ground, one scheduled late is pushed up).
    A touchdown also applies a perfectly inelastic impact (``pin.impulseDynamics``, restitution 0) to all
    stance feet of the new pattern, so their velocity is zero (to 1e-12) at the start of the step instead of
    being removed over several steps by the ``kd`` term with huge forces. At the end of that step an
    O(dt^2) integration residual is left (about 1e-6 m/s at 1 ms after a 0.5 m/s touchdown; 3e-7 at 0.5 ms).
    After :meth:`reset` every foot counts as in swing, so the first step's stance feet are touchdowns.

    **Integration.** ``v <- v + a dt``; ``q <- q (+) v dt`` (``pin.integrate``, i.e. on the SE(3) manifold for
    the base).

    **Unilaterality and friction** are not enforced by a bilateral contact. Each step they are checked and
    reported in :attr:`last_violations` and accumulated in :attr:`violation_counts`; they never raise.

    **External wrench.** A world-aligned force/torque on the base is rotated into the base frame and added
    to the free-flyer rows of the generalized force. This *is* Pinocchio's ``fext`` on the root joint: the
    free-flyer's motion subspace is the identity, so a local-frame joint wrench maps one-to-one onto
    ``tau[:6]`` (``constraintDynamics`` has no ``fext`` argument; ``pin.aba`` with ``fext`` gives the same
    accelerations, see the tests).

    Args:
        model: Pinocchio model whose first joint is a free-flyer; its ``gravity`` is used.
        foot_frames: Names of the contact frames (the foot centres), in the order of the ``contact`` flags.
        dt: Integration step [s], > 0 (1 ms = 1 kHz by default; the closed loop needs 500 Hz or faster).
        baumgarte: ``(kp [1/s^2], kd [1/s])`` gains of the contact drift correction. The default is critically
            damped (``kd = 2 sqrt(kp)``) with a 20 ms time constant. Semi-implicit Euler keeps the error
            dynamics stable only if ``kd dt < 2`` and ``kp dt^2 + 2 kd dt < 4``; other values raise.
        ground_height: Height of the flat ground [m].
        foot_radius: Radius of the foot spheres [m]. A foot frame is in ground contact when its height is
            ``ground_height + foot_radius``. For the Unitree B1 URDF the foot frames are the centres of the
            collision spheres, radius 0.04 m (the visual sphere is 0.03 m).
        mu: Friction coefficient used only to *report* slipping.

    Raises:
        ValueError: On a model without a free-flyer root, an unknown foot frame, ``dt <= 0``, negative or
            unstable Baumgarte gains, ``foot_radius < 0`` or ``mu < 0``.
    """

    def __init__(
        self,
        model: pin.Model,
        foot_frames: Sequence[str],
        dt: float = 0.001,
        baumgarte: tuple[float, float] = (2500.0, 100.0),
        ground_height: float = 0.0,
        foot_radius: float = 0.0,
        mu: float = 0.8,
    ) -> None:
        if model.njoints < 2 or model.joints[1].shortname() != "JointModelFreeFlyer":
            raise ValueError("model: the first joint must be a free-flyer (floating base)")
        dt = float(dt)
        if not np.isfinite(dt) or dt <= 0.0:
            raise ValueError(f"dt must be a finite positive step in seconds, got {dt}")
        kp, kd = (float(g) for g in baumgarte)
        if not (np.isfinite(kp) and np.isfinite(kd)) or kp < 0.0 or kd < 0.0:
            raise ValueError(f"baumgarte gains (kp, kd) must be finite and >= 0, got {baumgarte}")
        # Jury conditions of e'' = -kd e' - kp e discretised by semi-implicit Euler.
        if kd * dt >= 2.0 or kp * dt**2 + 2.0 * kd * dt >= 4.0:
            raise ValueError(
                f"baumgarte gains {baumgarte} are unstable at dt={dt}: "
                "need kd*dt < 2 and kp*dt^2 + 2*kd*dt < 4"
            )
        if not np.isfinite(foot_radius) or foot_radius < 0.0:
            raise ValueError(f"foot_radius must be >= 0 [m], got {foot_radius}")
        if not np.isfinite(mu) or mu < 0.0:
            raise ValueError(f"mu must be >= 0, got {mu}")
        if isinstance(foot_frames, str):
            raise ValueError("foot_frames must be a sequence of frame names, not a single string")
        self._foot_names = tuple(foot_frames)
        if not self._foot_names:
            raise ValueError("foot_frames must name at least one frame")
        for name in self._foot_names:
            if not model.existFrame(name):
                raise ValueError(f"foot_frames: unknown frame {name!r}")

        self._model = model
        self._data = model.createData()
        self._dt = dt
        self._kp, self._kd = kp, kd
        self._ground = float(ground_height)
        self._foot_radius = float(foot_radius)
        self._mu = float(mu)
        self._foot_ids = [model.getFrameId(name) for name in self._foot_names]
        self._foot_joints = [model.frames[f].parentJoint for f in self._foot_ids]
        self._foot_placements = [model.frames[f].placement for f in self._foot_ids]
        n = len(self._foot_ids)
        self._n_feet = n
        # mu > 0 regularises rank-deficient stance Jacobians; the proximal iterations of constraintDynamics
        # then recover the exact solution (2-3 iterations). impulseDynamics does a single regularised solve
        # (its error is ~mu |Lambda|), hence a much smaller mu there.
        self._prox = pin.ProximalSettings(1e-10, 1e-8, 20)
        self._prox_impulse = pin.ProximalSettings(1e-12, 1e-12, 1)
        self._patterns: dict[int, _ContactPattern] = {}
        self._tau = np.zeros(model.nv)

        self._q = pin.neutral(model)
        self._v = np.zeros(model.nv)
        self._t0 = 0.0
        self._steps = 0
        self._contact = np.zeros(n, dtype=bool)
        self._mask = 0  # bit i set <=> foot i in stance during the last step
        self._bits = 1 << np.arange(n)
        self._anchors = np.full((n, 3), np.nan)
        self._forces = np.zeros((n, 3))
        self._impulses = np.zeros((n, 3))
        self._violations = {k: np.zeros(n, dtype=bool) for k in _VIOLATION_KINDS}
        self._counts = {k: np.zeros(n, dtype=np.int64) for k in _VIOLATION_KINDS}
        self._foot_pos = np.zeros((n, 3))

    # ------------------------------------------------------------------ properties
    @property
    def state(self) -> PlantState:
        """Copy of the current state."""
        return PlantState(self._q.copy(), self._v.copy(), self.time)

    @property
    def time(self) -> float:
        """Simulated time [s] (``t0 + steps * dt``, so it does not accumulate round-off)."""
        return self._t0 + self._steps * self._dt

    @property
    def contact(self) -> np.ndarray:
        """Contact flags applied during the last step, shape (n_feet,) bool."""
        return self._contact.copy()

    @property
    def anchors(self) -> np.ndarray:
        """Touchdown anchors of the stance feet in the world [m], shape (n_feet, 3); NaN for swing feet."""
        return self._anchors.copy()

    @property
    def foot_positions(self) -> np.ndarray:
        """World positions of the foot frames at the current state [m], shape (n_feet, 3)."""
        return self._foot_pos.copy()

    @property
    def last_contact_forces(self) -> np.ndarray:
        """World-frame forces of the ground on the stance feet during the last step [N], shape (n_feet, 3).

        Rows of swing feet are zero.
        """
        return self._forces.copy()

    def contact_forces(self) -> np.ndarray:
        """World forces of the ground on the feet during the last step [N], shape (n_feet, 3) (zero rows
        for swing feet): :attr:`last_contact_forces`."""
        return self.last_contact_forces

    def foot_contacts(self, scheduled: np.ndarray | None = None) -> np.ndarray:
        """The stance this plant imposes: ``scheduled`` if given (the flags about to be applied), else
        those of the last step; shape (n_feet,) bool."""
        return np.asarray(self.contact if scheduled is None else scheduled, dtype=bool).copy()

    @property
    def last_impulses(self) -> np.ndarray:
        """World-frame touchdown impulses applied in the last step [N s], shape (n_feet, 3) (zero if none)."""
        return self._impulses.copy()

    @property
    def last_violations(self) -> dict[str, np.ndarray]:
        """Per-foot physical-validity flags of the last step, each shape (n_feet,) bool.

        * ``pulling``: stance foot with normal force ``f_z < 0`` (the ground would have to pull).
        * ``slipping``: stance foot with ``f_z >= 0`` and ``||f_xy|| > mu f_z`` (outside the friction cone;
          a pulling foot is reported as pulling only).
        * ``penetrating``: swing foot whose frame is below ``ground_height + foot_radius`` after the step
          by more than 0.1 mm (an unscheduled contact that the plant ignores).
        """
        return {k: flags.copy() for k, flags in self._violations.items()}

    @property
    def violation_counts(self) -> dict[str, np.ndarray]:
        """Cumulative per-foot number of steps with each violation since :meth:`reset`, shape (n_feet,)."""
        return {k: counts.copy() for k, counts in self._counts.items()}

    # ------------------------------------------------------------------ simulation
    def reset(self, q: np.ndarray, v: np.ndarray, t: float = 0.0) -> PlantState:
        """Set the state, put every foot in swing and clear the counters.

        Args:
            q: Configuration, shape (nq,); the base quaternion is normalised.
            v: Generalized velocity, shape (nv,).
            t: Simulated time [s].

        Returns:
            The new state (a copy).

        Raises:
            ValueError: On a wrong shape or a non-finite value in ``q``, ``v`` or ``t``.
        """
        q = checks.array("q", q, self._model.nq)
        v = checks.array("v", v, self._model.nv)
        if not np.isfinite(t):
            raise ValueError(f"t must be finite, got {t}")
        q = pin.normalize(self._model, q)
        if not np.all(np.isfinite(q)):
            raise ValueError("q: the base quaternion has zero norm")
        self._q, self._v = q, v.copy()
        self._t0, self._steps = float(t), 0
        self._contact[:] = False
        self._mask = 0
        self._anchors[:] = np.nan
        self._forces[:] = 0.0
        self._impulses[:] = 0.0
        for k in _VIOLATION_KINDS:
            self._violations[k][:] = False
            self._counts[k][:] = 0
        self._update_foot_positions()
        return self.state

    def step(
        self,
        tau_joints: np.ndarray,
        contact: np.ndarray,
        external_wrench: np.ndarray | None = None,
        ee_force: np.ndarray | None = None,
    ) -> PlantState:
        """Advance the plant by one step ``dt`` with the joint torques held constant.

        Args:
            tau_joints: Actuated joint torques [N m], shape (nv - 6,), in Pinocchio's joint order.
            contact: Stance flags, shape (n_feet,) bool (or 0/1), in the order of ``foot_frames``.
            external_wrench: Optional disturbance on the base, shape (6,): force [N] then torque [N m], with
                world-aligned axes, applied at (and taken about) the base joint origin.
            ee_force: Must be ``None``: the rigid plant has no scene to push the end effector.

        Returns:
            The state after the step (a copy).

        Raises:
            ValueError: On a wrong shape or a non-finite value in an argument.
            FloatingPointError: If the dynamics produce a non-finite state (e.g. absurd torques).
        """
        if ee_force is not None:
            raise ValueError("the rigid-contact plant has no scene: ee_force needs the PyBullet plant")
        model, n = self._model, self._n_feet
        tau = self._tau
        tau[6:] = checks.array("tau_joints", tau_joints, model.nv - 6)
        contact = _contact_flags(contact, n)
        if external_wrench is None:
            tau[:6] = 0.0
        else:
            wrench = checks.array("external_wrench", external_wrench, 6)
            rot = pin.Quaternion(self._q[3:7]).toRotationMatrix()  # base -> world
            tau[:3] = rot.T @ wrench[:3]
            tau[3:6] = rot.T @ wrench[3:]

        q, v = self._q, self._v
        touchdown = contact & ~self._contact
        self._anchors[~contact] = np.nan
        if touchdown.any():
            self._anchors[touchdown] = self._foot_pos[touchdown]  # foot positions at the current q
            self._anchors[touchdown, 2] = self._ground + self._foot_radius

        self._impulses[:] = 0.0
        self._forces[:] = 0.0
        mask = int(self._bits @ contact)
        if mask:
            pattern = self._pattern(mask)
            if mask != self._mask:
                # Anchors only change at touchdown, which always changes the pattern.
                for cm, i in zip(pattern.models, pattern.feet, strict=True):
                    cm.joint2_placement = pin.SE3(np.eye(3), self._anchors[i])
            if touchdown.any():
                v = pin.impulseDynamics(
                    model, pattern.data, q, v, pattern.models, pattern.datas, 0.0, self._prox_impulse
                )
                self._impulses[pattern.feet] = pattern.data.impulse_c.reshape(-1, 3)
            a = pin.constraintDynamics(
                model, pattern.data, q, v, tau, pattern.models, pattern.datas, self._prox
            )
            self._forces[pattern.feet] = pattern.data.lambda_c.reshape(-1, 3)
        else:
            a = pin.aba(model, self._data, q, v, tau)

        v = v + a * self._dt
        q = pin.integrate(model, q, v * self._dt)
        if not (np.isfinite(q).all() and np.isfinite(v).all()):
            raise FloatingPointError(f"plant state became non-finite at t={self.time + self._dt:.6f} s")
        self._q, self._v = q, v
        self._contact, self._mask = contact, mask
        self._steps += 1
        self._update_foot_positions()
        self._check_violations()
        return self.state

    # ------------------------------------------------------------------ internals
    def _pattern(self, mask: int) -> _ContactPattern:
        """Constraint models/datas for the stance set encoded in ``mask`` (bit i = foot i), built once."""
        pattern = self._patterns.get(mask)
        if pattern is not None:
            return pattern
        feet = np.array([i for i in range(self._n_feet) if mask >> i & 1])
        models = pin.StdVec_RigidConstraintModel()
        for i in feet:
            cm = pin.RigidConstraintModel(
                pin.ContactType.CONTACT_3D,
                self._model,
                self._foot_joints[i],
                self._foot_placements[i],
                0,  # the universe: the anchor placement is in the world frame
                pin.SE3.Identity(),
                pin.ReferenceFrame.LOCAL_WORLD_ALIGNED,
            )
            cm.name = self._foot_names[i]
            cm.setBaumgarteCorrectorParameters(pin.BaumgarteCorrectorParameters(self._kp, self._kd))
            models.append(cm)
        datas = pin.StdVec_RigidConstraintData()
        for cm in models:
            datas.append(cm.createData())
        data = self._model.createData()
        # The Python argument names of this binding are shuffled; the order is (model, data, models, datas).
        pin.initConstraintDynamics(self._model, data, models, datas)
        pattern = _ContactPattern(feet, models, datas, data)
        self._patterns[mask] = pattern
        return pattern

    def _update_foot_positions(self) -> None:
        model, data = self._model, self._data
        pin.forwardKinematics(model, data, self._q)
        self._foot_pos[:] = [pin.updateFramePlacement(model, data, f).translation for f in self._foot_ids]

    def _check_violations(self) -> None:
        f = self._forces
        normal = f[:, 2]  # flat horizontal ground: the normal is world z
        tangential = np.hypot(f[:, 0], f[:, 1])
        stance = self._contact
        pulling = stance & (normal < 0.0)
        slipping = stance & ~pulling & (tangential > self._mu * normal)
        penetrating = ~stance & (self._foot_pos[:, 2] < self._ground + self._foot_radius - _PENETRATION_TOL)
        for kind, flags in (("pulling", pulling), ("slipping", slipping), ("penetrating", penetrating)):
            self._violations[kind] = flags
            self._counts[kind] += flags


def fallen(
    state: PlantState, min_base_height: float = 0.25, max_tilt: float = 1.0, ground_height: float = 0.0
) -> bool:
    """Whether the robot has fallen.

    Args:
        state: Plant state (only ``q`` is used: base position and quaternion ``(x, y, z, w)``).
        min_base_height: Lowest admissible height of the base origin above the ground [m].
        max_tilt: Largest admissible tilt [rad]: angle between the base z axis and the world z axis,
            ``arccos(R_zz) = arccos(1 - 2 (q_x^2 + q_y^2))`` for a unit quaternion (roll and pitch, not yaw).
        ground_height: Height of the ground [m].

    Returns:
        True if the base is below ``ground_height + min_base_height`` or tilted by more than ``max_tilt``.
    """
    q = np.asarray(state.q, dtype=float)
    return bool(q[2] < ground_height + min_base_height or tilt(q) > max_tilt)


def _contact_flags(contact: np.ndarray, n: int) -> np.ndarray:
    """``contact`` as a bool vector of shape (n,), or ValueError."""
    arr = np.asarray(contact)
    if arr.shape != (n,):
        raise ValueError(f"contact must have shape ({n},), got {arr.shape}")
    if arr.dtype != bool:
        if not np.all((arr == 0) | (arr == 1)):
            raise ValueError(f"contact must be booleans (or 0/1), got {arr}")
        arr = arr.astype(bool)
    return arr.copy()
