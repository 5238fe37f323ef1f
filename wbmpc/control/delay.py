"""Computation-delay compensation: plan from the state the robot will be in when the plan arrives.

A solve that starts from the measurement at ``t`` and takes ``d`` seconds hands the low level a plan whose
first node lies ``d`` in the past: the low level then starts it part-way, from a state the plan assumed
but the robot never had. With compensation the MPC is asked to plan from ``t + d`` instead, from the
measured configuration moved along the plan being executed, with the measured velocity,

.. math::  q_{pred} = q_{meas} \\oplus \\big(q^{plan}(t + d) \\ominus q^{plan}(t)\\big),\\qquad
           v_{pred} = v_{meas},

so the measurement's deviation from the plan is kept and the plan's own motion over the delay is added;
the contacts, swing phases and commands are those of ``t + d``. The velocity is not moved along the plan:
its change over the delay comes from the planned forces, which the real contacts do not deliver as
planned (on the emulated robot, predicting it too made warm starts need 30-40 iterations where the
configuration alone kept them at 3; ``docs/`` has the measurements). The expected delay of the next solve is
:class:`DelayEstimate`'s: a fixed delay, or a high quantile of the recent solve calls' wall times (a plan
that arrives earlier than predicted is used from its first node on; a later one part-way, as without
compensation).
"""

from __future__ import annotations

from collections import deque

import numpy as np
import pinocchio as pin

from wbmpc.ocp.time_grid import interp_rows

__all__ = ["DelayEstimate", "predict_state"]


def predict_state(
    model: pin.Model, plan, q_meas: np.ndarray, v_meas: np.ndarray, t: float, t_future: float
) -> tuple[np.ndarray, np.ndarray]:
    """The measured configuration at ``t`` moved along ``plan`` to ``t_future`` [s], with the measured
    velocity (see the module doc).

    Args:
        model: Pinocchio model (configuration space of the plan).
        plan: An :class:`~wbmpc.control.mpc.MPCSolution` (``q`` (N, nq), ``v`` (N, nv), ``node_times``).
        q_meas, v_meas: Measured configuration (nq,) and velocity (nv,) at ``t``.
        t, t_future: Measurement time and the time to predict [s]; outside the plan's nodes the plan is
            held at its end.

    Returns:
        ``(q_pred, v_pred)``.
    """
    times = np.asarray(plan.node_times, dtype=float)
    q_ref = plan.q[0]
    dq = np.array([pin.difference(model, q_ref, q) for q in plan.q])
    both = np.array([t, t_future], dtype=float)
    dq_now, dq_then = interp_rows(both, times, dq)
    q_now = pin.integrate(model, q_ref, dq_now)
    q_then = pin.integrate(model, q_ref, dq_then)
    q_pred = pin.integrate(model, q_meas, pin.difference(model, q_now, q_then))
    return q_pred, np.array(v_meas, dtype=float)


class DelayEstimate:
    """The delay [s] to expect from the next solve: fixed, or a quantile of the recent measured ones.

    Args:
        fixed: A fixed delay [s], or ``None`` to estimate it from :meth:`record`.
        window: Number of recent solves kept.
        quantile: Quantile of those (0..1) taken as the expectation (a late plan costs more than an early
            one, which is simply used from its first node).
        cap: Upper bound [s] of the estimate (a compensation far beyond the plan's first stages predicts
            poorly).

    Raises:
        ValueError: a negative fixed delay, a window < 1, a quantile outside [0, 1], a cap <= 0.
    """

    def __init__(
        self, fixed: float | None = None, window: int = 20, quantile: float = 0.8, cap: float = 0.05
    ):
        if fixed is not None and not (np.isfinite(fixed) and fixed >= 0):
            raise ValueError(f"DelayEstimate fixed must be a delay >= 0 [s] or None, got {fixed!r}")
        if int(window) != window or window < 1:
            raise ValueError(f"DelayEstimate window must be an integer >= 1, got {window!r}")
        if not 0.0 <= quantile <= 1.0:
            raise ValueError(f"DelayEstimate quantile must be in [0, 1], got {quantile!r}")
        if not cap > 0:
            raise ValueError(f"DelayEstimate cap must be > 0 [s], got {cap!r}")
        self.fixed, self.quantile, self.cap = fixed, float(quantile), float(cap)
        self._recent: deque = deque(maxlen=int(window))

    def record(self, seconds: float) -> None:
        """A solve call's measured wall time [s]."""
        if np.isfinite(seconds) and seconds >= 0:
            self._recent.append(float(seconds))

    def expected(self) -> float:
        """The delay [s] to plan for (0 before any measurement when not fixed)."""
        if self.fixed is not None:
            return min(self.fixed, self.cap)
        if not self._recent:
            return 0.0
        return min(float(np.quantile(np.asarray(self._recent), self.quantile)), self.cap)
