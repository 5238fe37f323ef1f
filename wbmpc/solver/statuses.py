"""Why a solve failed: a solver's ``stats()`` (Fatrop through CasADi 3.8.2, or IPOPT) or the exception it
raised, as a short name and a one-sentence reason.

Fatrop's status through CasADi 3.8.2 (which ships libfatrop 1.1.8): ``stats["return_status"]`` is the
return value of Fatrop's C interface ``fatrop_ocp_c_solve``, only 0 (success), 1 (anything else) or -1
(an exception caught inside Fatrop). The actual reason is ``stats["fatrop"]["return_flag"]``, the integer
value of Fatrop's ``IpSolverReturnFlag`` enum (``include/fatrop/ip_algorithm/ip_algorithm.hpp``)::

    0 Success  1 MaxIterExceeded  2 StopAtAcceptablePoint  3 LocalInfeasibility
    4 LineSearchFailed  5 ErrorInStepComputation  6 Unknown

Example:
    >>> name, reason = solver_status("fatrop", solver.stats())
"""

from __future__ import annotations

# --- solver status ------------------------------------------------------------------------------------------
SUCCESS = "success"

# IpSolverReturnFlag of Fatrop >= 1.0 (the enum order is the integer value).
FATROP_FLAGS: dict[int, tuple[str, str]] = {
    0: (SUCCESS, "Fatrop converged to the requested tolerance."),
    1: ("max_iter_exceeded", "Fatrop reached its iteration cap before converging."),
    2: (
        "acceptable_point",
        "Fatrop stopped at a point that meets only its acceptable (looser) tolerance.",
    ),
    3: (
        "local_infeasibility",
        "Fatrop's restoration phase failed: the constraints look locally infeasible.",
    ),
    4: (
        "line_search_failed",
        "Fatrop's line search found no acceptable step (the restoration phase failed too): the problem "
        "is probably infeasible or badly scaled near the current iterate.",
    ),
    5: (
        "step_computation_error",
        "Fatrop could not compute a search direction (linear solve failed or gave NaN).",
    ),
    6: ("fatrop_unknown", "Fatrop stopped for an unspecified reason."),
}

# IPOPT ApplicationReturnStatus strings as CasADi reports them in stats()["return_status"].
IPOPT_STATUSES: dict[str, tuple[str, str]] = {
    "Solve_Succeeded": (SUCCESS, "IPOPT converged to the requested tolerance."),
    "Solved_To_Acceptable_Level": (
        "acceptable_point",
        "IPOPT stopped at a point that meets only its acceptable (looser) tolerance.",
    ),
    "Infeasible_Problem_Detected": (
        "infeasible",
        "IPOPT converged to a point of local infeasibility: the constraints cannot all be met.",
    ),
    "Search_Direction_Becomes_Too_Small": (
        "search_direction_too_small",
        "IPOPT's search direction became too small to make progress.",
    ),
    "Diverging_Iterates": ("diverging", "IPOPT's iterates diverged (variables grew without bound)."),
    "User_Requested_Stop": ("user_stop", "A callback asked IPOPT to stop."),
    "Feasible_Point_Found": ("feasible_point", "IPOPT found a feasible point (square problem)."),
    "Maximum_Iterations_Exceeded": (
        "max_iter_exceeded",
        "IPOPT reached its iteration cap before converging.",
    ),
    "Restoration_Failed": (
        "restoration_failed",
        "IPOPT's feasibility restoration phase failed: the problem is probably infeasible near the "
        "current iterate.",
    ),
    "Error_In_Step_Computation": (
        "step_computation_error",
        "IPOPT could not compute a search direction (linear solver failure).",
    ),
    "Maximum_CpuTime_Exceeded": ("max_time_exceeded", "IPOPT reached its CPU-time limit."),
    "Maximum_WallTime_Exceeded": ("max_time_exceeded", "IPOPT reached its wall-time limit."),
    "Not_Enough_Degrees_Of_Freedom": (
        "too_few_degrees_of_freedom",
        "The problem has more equality constraints than variables.",
    ),
    "Invalid_Problem_Definition": ("invalid_problem", "IPOPT rejected the problem definition."),
    "Invalid_Option": ("invalid_option", "IPOPT rejected one of its options."),
    "Invalid_Number_Detected": (
        "invalid_number",
        "IPOPT got NaN or inf from a function evaluation (check the state, parameters and initial guess).",
    ),
    "Unrecoverable_Exception": ("solver_exception", "IPOPT raised an unrecoverable exception."),
    "NonIpopt_Exception_Thrown": (
        "solver_exception",
        "A function called by IPOPT raised an exception.",
    ),
    "Insufficient_Memory": ("insufficient_memory", "IPOPT ran out of memory."),
    "Internal_Error": ("internal_error", "IPOPT reported an internal error."),
}


def solver_status(solver: str, stats: dict) -> tuple[str, str]:
    """A short name and a one-sentence reason for a solver's return status.

    Args:
        solver: ``"fatrop"`` or ``"ipopt"`` (the nlpsol plugin name).
        stats: ``casadi.Function.stats()`` of the solver after the call.

    Returns:
        ``(name, reason)``; ``name`` is ``"success"`` for a converged solve. An unknown code gives
        ``"<solver>_status_<raw code>"`` so the raw code is never lost.
    """
    solver = solver.lower()
    raw = stats.get("return_status")
    if solver == "fatrop":
        inner = stats.get("fatrop") if isinstance(stats.get("fatrop"), dict) else {}
        flag = inner.get("return_flag")
        if raw == -1 or raw == "-1":  # Fatrop's C interface caught an exception before a flag was set
            return "solver_exception", "Fatrop raised an internal exception (its C interface returned -1)."
        if flag is not None:
            try:
                flag = int(flag)
            except (TypeError, ValueError):
                return f"fatrop_status_{flag}", f"Fatrop returned the unknown flag {flag!r}."
            if flag in FATROP_FLAGS:
                return FATROP_FLAGS[flag]
            return (
                f"fatrop_status_{flag}",
                f"Fatrop returned the unknown flag {flag} (return_status {raw!r}).",
            )
        # No detailed flag (stats from another plugin version): only the C return value is known.
        if raw in (0, "0") or (raw is None and stats.get("success")):
            return FATROP_FLAGS[0]
        if raw in (1, "1"):
            return "fatrop_failed", "Fatrop did not converge (its stats give no detailed return flag)."
        return f"fatrop_status_{raw}", f"Fatrop returned the unknown status {raw!r}."
    if solver == "ipopt":
        if isinstance(raw, str) and raw in IPOPT_STATUSES:
            return IPOPT_STATUSES[raw]
        return f"ipopt_status_{raw}", f"IPOPT returned the unknown status {raw!r}."
    if stats.get("success"):
        return SUCCESS, f"{solver} reported success."
    return f"{solver}_status_{raw}", f"{solver} returned status {raw!r}."


def exception_status(exc: BaseException) -> tuple[str, str]:
    """A short name and a one-sentence reason for an exception raised by a solver call.

    Args:
        exc: The exception (CasADi raises ``RuntimeError`` with the evaluation error in its message).

    Returns:
        ``("nan_in_evaluation", ...)`` when the message mentions NaN or inf, ``"evaluation_error"`` for a
        failed function evaluation, else ``"solver_exception"``; the reason quotes the first message line.
    """
    text = str(exc).strip()
    first = text.splitlines()[0] if text else type(exc).__name__
    if len(first) > 160:
        first = first[:157] + "..."
    lower = text.lower()
    if (
        "nan" in lower.split()
        or "nan detected" in lower
        or "inf detected" in lower
        or "invalid number" in lower
    ):
        return "nan_in_evaluation", f"A function evaluation returned NaN or inf: {first}"
    if "failed" in lower and ("eval" in lower or "function::call" in lower):
        return "evaluation_error", f"A function evaluation failed: {first}"
    return "solver_exception", f"The solver raised {type(exc).__name__}: {first}"
