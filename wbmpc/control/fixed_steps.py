"""The real-time-iteration MPC: a fixed number of Fatrop iterations per warm tick, the iterate accepted.

:class:`FixedStepMPC` is a :class:`~wbmpc.control.mpc.WholeBodyMPC` on the direct driver
(``SolverSettings(direct=True)``) whose warm-start solver is a
:class:`~wbmpc.solver.direct.fixed_steps.FixedStepNlpsol` (how the steps are fixed, and what still fails, is
documented there). Cold solves (the first tick, a cold retry) converge as in :class:`WholeBodyMPC`.

Example:
    >>> mpc = FixedStepMPC(robot, OCPSettings(n_nodes=15), MPCConfig(), SolverSettings(compiled=True,
    ...                    direct=True), steps=1)
    >>> plan = mpc.solve(q_hat, v_hat, t)   # plan.status == "fixed_steps" after the first (cold) tick
"""

from __future__ import annotations

import numpy as np

from wbmpc.control.mpc import WholeBodyMPC
from wbmpc.solver.direct.adapter import DirectNlpsol
from wbmpc.solver.direct.fixed_steps import FIXED_STEPS_STATUS, FixedStepNlpsol

__all__ = ["FIXED_STEPS_STATUS", "FixedStepMPC"]


class FixedStepMPC(WholeBodyMPC):
    """:class:`WholeBodyMPC` whose warm ticks take ``steps`` Fatrop iterations (real-time iteration).

    Needs ``SolverSettings(direct=True)`` (the direct driver's primal-dual warm start). A warm tick's plan
    has status :data:`FIXED_STEPS_STATUS` when its iterate was accepted unconverged (``success`` True);
    ``"success"`` when Fatrop converged within the steps. The cold start and the cold retry converge.

    Args:
        robot, settings, config, solver: As :class:`WholeBodyMPC`.
        steps: Fatrop iterations per warm tick (>= 1).

    Raises:
        ValueError: ``solver`` without ``direct=True``, ``steps`` < 1, and :class:`WholeBodyMPC`'s.
    """

    def __init__(self, robot, settings=None, config=None, solver=None, *, steps: int = 1):
        if solver is None or not solver.direct_driver:
            raise ValueError("FixedStepMPC needs SolverSettings(direct=True) (the direct Fatrop driver)")
        if int(steps) != steps or steps < 1:
            raise ValueError(f"steps must be an integer >= 1, got {steps!r}")
        super().__init__(robot, settings, config, solver)
        self.steps = int(steps)

    def make_solver(self, name: str, cold: bool, max_iter: int | None = None):
        """The cold solvers as :class:`WholeBodyMPC`'s; the warm one a :class:`FixedStepNlpsol` (or the
        plugin fallback unchanged if the direct driver is unavailable)."""
        solver = super().make_solver(name, cold, max_iter)
        if cold or not isinstance(solver, DirectNlpsol):
            return solver
        return FixedStepNlpsol(self, name, max_iter, solver.driver, self.steps)

    def _run_solver(self, solver, args: dict):
        w, lam_g, report = super()._run_solver(solver, args)
        if not isinstance(solver, FixedStepNlpsol):
            return w, lam_g, report
        if report["success"] and solver.stats().get("fixed_steps_accepted"):
            report["status"] = FIXED_STEPS_STATUS
        elif not report["success"] and w is not None and not np.all(np.isfinite(w)):
            report["status"] = "non_finite_solution"
            report["reason"] = "the fixed-step iterate has NaN or inf"
        return w, lam_g, report
