"""Solve times of a run against the real-time budget (12.5 ms at 80 Hz): statistics and histogram data."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

BUDGET_S = 0.0125  # one MPC period at 80 Hz [s]


@dataclass
class SolveJitter:
    """Solve times of a run against a real-time budget.

    Attributes:
        solve_ms: Solve times [ms] (the cold first solve left out unless asked for).
        edges_ms: Histogram bin edges [ms]; counts: solves per bin.
        budget_ms: The budget [ms].
        fraction_over: Share of the solves longer than the budget.
        median_ms, p95_ms, max_ms: Statistics [ms].
        period_ms: Intervals between consecutive solve starts [ms] (the loop's actual period).
    """

    solve_ms: np.ndarray
    edges_ms: np.ndarray
    counts: np.ndarray
    budget_ms: float
    fraction_over: float
    median_ms: float
    p95_ms: float
    max_ms: float
    period_ms: np.ndarray

    def summary(self) -> dict:
        """Scalars as a JSON-ready dict."""
        return {
            "solves": int(self.solve_ms.size),
            "budget_ms": self.budget_ms,
            "fraction_over_budget": self.fraction_over,
            "median_ms": self.median_ms,
            "p95_ms": self.p95_ms,
            "max_ms": self.max_ms,
            "period_median_ms": float(np.median(self.period_ms)) if self.period_ms.size else None,
        }


def solve_time_jitter(log, budget: float = BUDGET_S, bin_ms: float | None = None, skip_cold: bool = True):
    """Solve-time distribution and the share of solves over the budget.

    Args:
        log: Run log with the solve columns ``solve_time`` [s] and ``solve_t`` [s] (``/mpc/diagnostics``).
        budget: Real-time budget [s] (one MPC period, 12.5 ms at 80 Hz).
        bin_ms: Histogram bin width [ms]; ``None``: a tenth of the budget, widened to at most 60 bins.
        skip_cold: Leave out the first (cold-started) solve.

    Returns:
        :class:`SolveJitter`.
    """
    times = 1e3 * np.asarray(log["solve_time"], dtype=float)
    stamps = 1e3 * np.asarray(log["solve_t"], dtype=float)
    if skip_cold and times.size > 1:
        times = times[1:]
    if times.size == 0:
        raise ValueError("the log has no solves (no /mpc/diagnostics messages)")
    budget_ms = 1e3 * float(budget)
    top = max(float(times.max()), budget_ms)
    width = bin_ms or max(budget_ms / 10.0, top / 60.0)
    edges = np.arange(0.0, top + width, width)
    counts, edges = np.histogram(times, bins=edges)
    return SolveJitter(
        solve_ms=times,
        edges_ms=edges,
        counts=counts,
        budget_ms=budget_ms,
        fraction_over=float(np.mean(times > budget_ms)),
        median_ms=float(np.median(times)),
        p95_ms=float(np.percentile(times, 95)),
        max_ms=float(times.max()),
        period_ms=np.diff(stamps),
    )
