"""Where a solve's time went, from a solver's statistics (``nlpsol.stats()`` or the direct driver's)."""

from __future__ import annotations

__all__ = ["solver_timings"]


def solver_timings(stats: dict, wall: float) -> dict:
    """Where a solve's time went [s]: derivative evaluations, the solver's own work, Python overhead."""
    evaluations = sum(v for k, v in stats.items() if k.startswith("t_wall_nlp_"))
    fatrop = stats.get("fatrop") if isinstance(stats.get("fatrop"), dict) else {}
    # Fatrop reports its own total; otherwise CasADi's, when it records one.
    total = float(fatrop.get("time_total", stats.get("t_wall_total", wall)))
    out = {
        "wall": wall,
        "evaluations": float(evaluations),
        "hessian": float(stats.get("t_wall_nlp_hess_l", 0.0)),
        "jacobian": float(stats.get("t_wall_nlp_jac_g", 0.0)),
        "solver": total - float(evaluations),
        "overhead": wall - total,
    }
    if fatrop:  # Fatrop's own split of its work
        out["search_direction"] = float(fatrop.get("compute_sd_time", 0.0))
        out["initialization"] = float(fatrop.get("initialization_time", 0.0))
    return out
