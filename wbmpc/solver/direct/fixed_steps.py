"""A fixed number of Fatrop iterations per warm solve, the iterate accepted (real-time iteration).

:class:`FixedStepNlpsol` is the warm-start solver of :class:`wbmpc.control.fixed_steps.FixedStepMPC`, a
``WholeBodyMPC`` on the direct driver (``SolverSettings(direct=True)``): it stops after ``steps``
Fatrop iterations (Newton steps of the barrier problem) from the primal-dual warm start and hands the MPC
the iterate as a usable plan although Fatrop did not converge: its ``stats()`` reports ``success`` and the
MPC names the plan's status :data:`FIXED_STEPS_STATUS` (``"fixed_steps"``).

How the steps are fixed: not with ``max_iter``. Fatrop 1.1.8 with ``max_iter = 0`` takes no step and with
``max_iter = 1`` takes two (its reported iteration count is 2, and the dynamics residual falls 49 -> 3.6e-4,
the two-step sequence; measured on a recorded trot tick), so one step cannot be had that way. Its acceptable-
point test can: with ``tol_acceptable`` and ``constr_viol_tol`` infinite every iterate is acceptable, and
``acceptable_iter = steps + 1`` consecutive acceptable iterates (iterate 0 included) stop it after exactly
``steps`` iterations with flag ``StopAtAcceptablePoint`` (or ``Success`` if it converged first). The shared
driver gets Fatrop's defaults back after each fixed-step call, so the MPC's cold solves are unchanged. The
iterate also becomes the next tick's warm start (primal, constraint and bound
multipliers, barrier parameter): the real-time iteration of Diehl et al., on Fatrop's interior-point steps.

What still fails as before (the MPC's fallback and cold retry run unchanged): a non-finite iterate (NaN or
inf in the primal or the multipliers: status ``non_finite_solution``), a Fatrop flag other than
success / iteration cap / acceptable point (line search or step computation failed, infeasibility), the
driver raising. Cold solves (the first tick, a cold retry) converge as in ``WholeBodyMPC``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from wbmpc.solver.direct.adapter import DirectNlpsol
from wbmpc.solver.direct.driver import DirectResult

#: The plan status of an accepted fixed-step iterate.
FIXED_STEPS_STATUS = "fixed_steps"
#: Fatrop flags whose iterate is accepted after the fixed steps: success, iteration cap, acceptable point.
ACCEPTED_FLAGS = (0, 1, 2)
#: Fatrop 1.1.8's defaults of the acceptable-point options (``ip_convergence_check.hpp``), restored after a
#: fixed-step call on the shared driver.
FATROP_ACCEPTABLE_DEFAULTS = {"tol_acceptable": 1e-6, "acceptable_iter": 15, "constr_viol_tol": 1e-4}
# "Infinite" acceptable tolerances (every iterate is acceptable).
_ANY = 1e30


def fixed_step_solve(driver, p, w0, steps: int, **solve_kwargs) -> DirectResult:
    """Exactly ``steps`` Fatrop iterations of ``driver`` (a
    :class:`~wbmpc.solver.direct.driver.DirectFatrop`) from ``w0`` (fewer if it converges first); the
    driver's acceptable-point options are Fatrop's defaults again afterwards.

    Args:
        driver: The direct driver; p, w0: parameters and initial primal (NLP order).
        steps: Fatrop iterations (>= 1).
        **solve_kwargs: :meth:`DirectFatrop.solve`'s (``mu_init``, ``duals``, ...).

    Returns:
        Fatrop's result as it is (flag 2, ``acceptable_point``, ``success`` False after the steps).

    Raises:
        ValueError: ``steps`` < 1, and :meth:`DirectFatrop.solve`'s.
    """
    if int(steps) != steps or steps < 1:
        raise ValueError(f"steps must be an integer >= 1, got {steps!r}")
    try:
        driver.set_option("tol_acceptable", _ANY)
        driver.set_option("constr_viol_tol", _ANY)
        driver.set_option("acceptable_iter", int(steps) + 1)
        return driver.solve(p, w0, **solve_kwargs)
    finally:
        for name, value in FATROP_ACCEPTABLE_DEFAULTS.items():
            driver.set_option(name, value)


def usable_iterate(result: DirectResult) -> bool:
    """Whether a fixed-step result may be applied: an accepted flag and finite primal and multipliers."""
    finite = all(np.all(np.isfinite(v)) for v in (result.w, result.lam_g, result.z_l, result.z_u))
    return result.flag in ACCEPTED_FLAGS and bool(finite)


class _FixedStepDriver:
    """The MPC's shared :class:`~wbmpc.solver.direct.driver.DirectFatrop`, with a usable fixed-step iterate
    marked ``success`` (so :class:`DirectNlpsol` keeps it as the next warm start). Everything else
    (``options``, ``set_option``, ``last``) is the shared driver's."""

    def __init__(self, driver, steps: int):
        object.__setattr__(self, "_driver", driver)
        object.__setattr__(self, "steps", int(steps))
        object.__setattr__(self, "accepted", False)

    def solve(self, p, w0, **kwargs) -> DirectResult:
        result = fixed_step_solve(self._driver, p, w0, self.steps, **kwargs)
        accepted = usable_iterate(result)
        object.__setattr__(self, "accepted", accepted and result.flag != 0)
        if accepted and not result.success:
            result = replace(result, success=True, status=FIXED_STEPS_STATUS, reason="")
        elif not accepted and result.flag in ACCEPTED_FLAGS:
            result = replace(
                result,
                success=False,
                status="non_finite_solution",
                reason="the fixed-step iterate has NaN or inf",
            )
        return result

    def __getattr__(self, name):
        return getattr(self._driver, name)

    def __setattr__(self, name, value):
        setattr(self._driver, name, value)


class FixedStepNlpsol(DirectNlpsol):
    """The warm-start solver of a :class:`~wbmpc.control.fixed_steps.FixedStepMPC`: ``steps`` Fatrop
    iterations, the iterate accepted.

    Its ``stats()`` is :class:`DirectNlpsol`'s with ``success`` True for a usable iterate (see
    :func:`usable_iterate`) and ``fixed_steps`` (the step count) and ``fixed_steps_accepted`` (True when
    Fatrop had not converged: the plan is an unconverged iterate); Fatrop's own ``return_flag`` is kept.

    Args:
        mpc: The MPC; name: its name; max_iter: Fatrop's iteration cap (default the warm solves'; not
            reached: the acceptable-point test stops first).
        driver: The MPC's shared direct driver.
        steps: Fatrop iterations per solve (>= 1).

    Raises:
        ValueError: ``steps`` < 1.
    """

    def __init__(self, mpc, name: str, max_iter: int | None, driver, steps: int):
        if int(steps) != steps or steps < 1:
            raise ValueError(f"steps must be an integer >= 1, got {steps!r}")
        super().__init__(mpc, name, False, max_iter, _FixedStepDriver(driver, steps))
        self.steps = int(steps)

    def __call__(self, **kwargs) -> dict:
        out = super().__call__(**kwargs)
        self._stats = {
            **self._stats,
            "fixed_steps": self.steps,
            "fixed_steps_accepted": bool(self.driver.accepted and self._stats.get("success")),
        }
        return out
