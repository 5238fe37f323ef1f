"""The 500 Hz joint-level controller between two MPC solutions (paper, Sec. V-B).

Between MPC updates the first nodes of the latest plan are interpolated linearly,

.. math::
    \\tau_{ff}(t) = \\tau_k^* + \\frac{\\tau_{k+1}^* - \\tau_k^*}{\\delta t_k}(t - t_k),\\quad
    q_{des}(t) = q_k^* + v_k^*(t - t_k),\\quad v_{des}(t) = v_k^* + a_k^*(t - t_k),

on the interval ``[t_k, t_{k+1}]`` that contains ``t`` (node 0 first; if no new plan arrived by ``t_1``
the controller moves on to the interval of node 1, and so on: the references over the whole horizon, the
feed-forward while torques exist, held at the last torque node beyond), and a PD term closes the loop at
joint level:

.. math::  \\tau = \\tau_{ff} + K_p (q_{des} - q) + K_d (v_{des} - v) + \\tau_f(v_{des}).

The last term is an optional friction feed-forward (``friction=``, e.g. the joint friction of a
calibration file, :meth:`wbmpc.model.calibration.Calibration.joint_friction`), part of the feed-forward
torque of :meth:`LowLevelController.reference` (so that a motor drive given that feed-forward adds it too):
:math:`\\tau_f(v) = c \\tanh(v / v_s) + b v` (:class:`wbmpc.model.friction.JointFriction`), evaluated at
the *desired* joint rate: the planned motion's friction, free of the measured rate's noise and of the
chatter a feedback on its sign would cause near zero. Without ``friction`` the term is 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wbmpc.control.mpc import MPCSolution
from wbmpc.model.friction import JointFriction


@dataclass
class JointCommand:
    """Interpolated joint references at one instant (joint space only, nj each).

    Attributes:
        tau_ff: Feed-forward torque [N m]: the plan's, plus the friction feed-forward if any.
        q_des: Desired joint positions [rad]; v_des: desired joint rates [rad/s].
        tau_friction: The friction feed-forward part of ``tau_ff`` [N m] (``None``: no friction given).
    """

    tau_ff: np.ndarray
    q_des: np.ndarray
    v_des: np.ndarray
    tau_friction: np.ndarray | None = None


class LowLevelController:
    """Interpolates the latest MPC plan and applies joint PD feedback.

    Args:
        kp: Joint stiffness [N m/rad], scalar or (nj,).
        kd: Joint damping [N m s/rad], scalar or (nj,).
        torque_limits: Symmetric limits [N m] (nj,) the motor command is clipped to (the motors' own limit).
        friction: Motor friction to compensate (:class:`~wbmpc.model.friction.JointFriction`, nj joints)
            by the feed-forward ``c tanh(v_des / v_s) + b v_des`` before clipping; ``None``: none.

    Raises:
        ValueError: for negative or non-finite gains, or a ``friction`` that is not a ``JointFriction``.

    Attributes:
        violations: Number of commands that exceeded ``torque_limits`` before clipping.
        last_reference: The interpolated references behind the last :meth:`torque` command.
    """

    def __init__(
        self,
        kp=0.0,
        kd=0.0,
        torque_limits: np.ndarray | None = None,
        friction: JointFriction | None = None,
    ):
        for name, gain in (("kp", kp), ("kd", kd)):
            try:
                values = np.asarray(gain, dtype=float)
            except (TypeError, ValueError):
                raise ValueError(f"{name} must be a gain >= 0 or an array of them, got {gain!r}") from None
            if values.ndim > 1 or not np.all(np.isfinite(values)) or np.any(values < 0):
                raise ValueError(f"{name} must be finite gains >= 0 (scalar or (nj,)), got {gain!r}")
        if friction is not None and not isinstance(friction, JointFriction):
            raise ValueError(
                "friction must be a JointFriction (e.g. Calibration.joint_friction(robot)) or None, "
                f"got {friction!r}"
            )
        self.kp, self.kd = kp, kd
        self.torque_limits = torque_limits
        self.friction = friction
        self.plan: MPCSolution | None = None
        self._times = None
        self.violations = 0
        self.last_reference: JointCommand | None = None

    def update(self, plan: MPCSolution) -> None:
        """Hand over a new plan (the controller keeps interpolating the last one until then).

        Raises:
            ValueError: if the plan's joint count differs from the friction feed-forward's.
        """
        if self.friction is not None and np.shape(plan.tau)[-1] != self.friction.nj:
            raise ValueError(
                f"the plan has {np.shape(plan.tau)[-1]} joint torques but the friction feed-forward "
                f"{self.friction.nj} joints"
            )
        self.plan = plan
        self._times = plan.node_times  # once per plan, not at every tick

    def reference(self, t: float) -> JointCommand:
        """Interpolated feed-forward torque and joint references at time ``t`` [s]; the feed-forward includes
        the friction feed-forward at ``v_des`` (also for a motor drive that closes the PD loop itself)."""
        plan = self.plan
        if plan is None:
            raise RuntimeError("LowLevelController has no MPC plan yet: call update() first")
        times = self._times
        n_tau = len(plan.tau)
        # The feed-forward: on the last interval with a torque at both ends, held at its end beyond it.
        k = int(np.clip(np.searchsorted(times, t, side="right") - 1, 0, max(n_tau - 2, 0)))
        if n_tau >= 2:
            s = min(t - times[k], plan.dts[k])
            tau_ff = plan.tau[k] + (plan.tau[k + 1] - plan.tau[k]) * s / plan.dts[k]
        else:
            tau_ff = plan.tau[0]
        # The joint references: on the interval that holds t, over the whole horizon (q, v and a exist at
        # every node), held at the horizon's end. Extrapolating the torque intervals' last one instead lets
        # v_des = v_k + a_k (t - t_k) grow without bound while a slow solve keeps an old plan in use (a
        # swing leg's reference reached 8 rad/s in 0.16 s on the wall clock).
        j = int(np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(plan.a) - 1))
        s = min(t - times[j], plan.dts[j])
        q_des = plan.q[j][7:] + plan.v[j][6:] * s
        v_des = plan.v[j][6:] + plan.a[j][6:] * s
        if self.friction is None:
            return JointCommand(tau_ff, q_des, v_des)
        friction = self.friction.torque(v_des)
        return JointCommand(tau_ff + friction, q_des, v_des, friction)

    def torque(self, t: float, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Motor torque command (nj,) [N m] at time ``t`` for the measured joint state in ``q``, ``v``."""
        ref = self.last_reference = self.reference(t)
        tau = ref.tau_ff + self.kp * (ref.q_des - q[7:]) + self.kd * (ref.v_des - v[6:])
        if self.torque_limits is not None:
            self.violations += int(np.any(np.abs(tau) > self.torque_limits * (1 + 1e-6)))
            tau = np.clip(tau, -self.torque_limits, self.torque_limits)
        return tau
