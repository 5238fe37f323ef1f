"""MPC time grid: geometric (or uniform) step sizes over the prediction horizon.

Convention used throughout wbmpc: "N nodes" counts the terminal node, so a grid of N nodes has N - 1
intervals. The paper uses N = 15 nodes with geometrically growing steps

    dt_k = dt_min * gamma**k,  k = 0..N-2,  gamma = (dt_max / dt_min)**(1 / (N - 2)),

so that dt_0 = dt_min and dt_{N-2} = dt_max exactly. With 10 ms -> 100 ms this gives a horizon of about
0.56 s: fine resolution where the first control is applied, coarse resolution far ahead.
"""

from __future__ import annotations

import math
import numbers

import casadi as ca
import numpy as np


def _check_n_nodes(n_nodes) -> int:
    # bool is an Integral subclass but passing True/False is certainly a bug.
    if isinstance(n_nodes, bool) or not isinstance(n_nodes, numbers.Integral):
        raise ValueError(f"n_nodes must be an integer, got {n_nodes!r}")
    if n_nodes < 2:
        raise ValueError(f"n_nodes must be >= 2 (one interval), got {n_nodes}")
    return int(n_nodes)


def _check_dt(name: str, value) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{name} must be a real number, got {value!r}") from err
    if not math.isfinite(value) or value <= 0.0:
        raise ValueError(f"{name} must be finite and > 0 [s], got {value}")
    return value


def geometric_time_steps(n_nodes: int, dt_min: float, dt_max: float) -> np.ndarray:
    """Geometric step sizes dt_k = dt_min * (dt_max / dt_min)**(k / (N - 2)), k = 0..N-2.

    Args:
        n_nodes: Number of nodes N >= 2, terminal node included.
        dt_min: First step [s], > 0.
        dt_max: Last step [s], >= dt_min (equal gives a uniform grid).

    Returns:
        Array (N - 1,) of steps [s]; the last one equals dt_max exactly. For N == 2 there is a single
        interval and the result is [dt_min] (the growth ratio is undefined; dt_max is ignored).

    Raises:
        ValueError: Non-integer or < 2 n_nodes, non-positive / non-finite dt, or dt_max < dt_min.
    """
    n = _check_n_nodes(n_nodes)
    dt_min, dt_max = _check_dt("dt_min", dt_min), _check_dt("dt_max", dt_max)
    if dt_max < dt_min:
        raise ValueError(f"dt_max ({dt_max}) must be >= dt_min ({dt_min})")
    if n == 2:
        return np.array([dt_min])
    k = np.arange(n - 1)
    dts = dt_min * (dt_max / dt_min) ** (k / (n - 2))
    dts[-1] = dt_max  # remove the rounding of the power so the last step is exact
    return dts


def uniform_time_steps(n_nodes: int, dt: float) -> np.ndarray:
    """Uniform steps: array (N - 1,) filled with dt [s] (N = n_nodes >= 2, dt > 0)."""
    n = _check_n_nodes(n_nodes)
    return np.full(n - 1, _check_dt("dt", dt))


def node_times(dts, t0: float = 0.0) -> np.ndarray:
    """Times of the N nodes: t_0 = t0, t_{k+1} = t_k + dt_k [s].

    Args:
        dts: Array (N - 1,) of positive steps [s].
        t0: Time of the first node [s].

    Returns:
        Array (N,) of node times.
    """
    dts = np.asarray(dts, dtype=float)
    if dts.ndim != 1 or dts.size == 0:
        raise ValueError(f"dts must be a non-empty 1-D array, got shape {dts.shape}")
    # One reduction and a scalar test (this runs several times per control tick): min > 0 refuses NaN
    # and steps <= 0; with every step > 0 the sum is finite exactly when every step is.
    offsets = np.cumsum(dts) if dts.min() > 0.0 else None
    if offsets is None or not math.isfinite(offsets[-1]):
        raise ValueError("dts must be finite and > 0 [s]")
    if not math.isfinite(float(t0)):
        raise ValueError(f"t0 must be finite, got {t0}")
    return float(t0) + np.concatenate(([0.0], offsets))


def symbolic_geometric_time_steps(n_nodes: int, dt_min, dt_max) -> list:
    """CasADi version of `geometric_time_steps` for runtime OCP parameters dt_min, dt_max.

    Same formula dt_k = dt_min * (dt_max / dt_min)**(k / (N - 2)), so dt_min == dt_max gives uniform steps
    without recompiling the solver. The values cannot be checked here (they are symbols); the numeric
    version validates them.

    Args:
        n_nodes: Number of nodes N >= 2 (a Python integer: it fixes the problem structure).
        dt_min: CasADi SX/MX scalar (or float), first step [s].
        dt_max: CasADi SX/MX scalar (or float), last step [s].

    Returns:
        List of N - 1 CasADi scalar expressions; [dt_min] for N == 2.
    """
    n = _check_n_nodes(n_nodes)
    if n == 2:
        return [dt_min]
    ratio = dt_max / dt_min
    # k = 0 and k = N-2 are written without the power so they are exactly dt_min and dt_max.
    return [dt_min] + [dt_min * ca.power(ratio, k / (n - 2)) for k in range(1, n - 2)] + [dt_max]


def horizon_for(n_nodes: int, dt_min: float, dt_max: float) -> float:
    """Horizon length sum_k dt_k [s] of the geometric grid (about 0.56 s for 15 nodes, 10 -> 100 ms)."""
    return float(np.sum(geometric_time_steps(n_nodes, dt_min, dt_max)))


def interp_weights(t_new: np.ndarray, t_old: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rows ``i`` (len(t_new),) and weights ``w`` (len(t_new), 1) of :func:`interp_rows` from
    ``t_old`` (len >= 2, increasing) to ``t_new``: ``(1 - w) * rows[i] + w * rows[i + 1]`` (held at the
    ends). Computed once for several arrays sampled on the same times."""
    # np.minimum/maximum: np.clip's wrapper costs more than the interpolation at these sizes
    i = np.minimum(np.maximum(np.searchsorted(t_old, t_new, side="right") - 1, 0), len(t_old) - 2)
    t0 = t_old[i]
    w = np.minimum(np.maximum((t_new - t0) / (t_old[i + 1] - t0), 0.0), 1.0)[:, None]
    return i, w


def interp_row(t: float, t_old: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """:func:`interp_rows` at the one time ``t`` [s]: the row (n,), the same numbers, without the array
    bookkeeping (a few microseconds, for a check that runs every control tick)."""
    rows = np.asarray(rows)
    if len(t_old) == 1:
        return rows[0].copy()
    i = min(max(int(np.searchsorted(t_old, t, side="right")) - 1, 0), len(t_old) - 2)
    t0 = float(t_old[i])
    w = min(max((float(t) - t0) / (float(t_old[i + 1]) - t0), 0.0), 1.0)
    return (1.0 - w) * rows[i] + w * rows[i + 1]


def interp_rows(
    t_new: np.ndarray,
    t_old: np.ndarray,
    rows: np.ndarray,
    weights: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Linear interpolation of each column of ``rows`` (len(t_old), n) at ``t_new`` (held at the ends).

    ``weights``: :func:`interp_weights` of these times, if already computed (the result is the same)."""
    rows = np.asarray(rows)
    if rows.size == 0:
        return rows
    if len(t_old) == 1:
        return np.repeat(rows[:1], len(t_new), axis=0)
    i, w = interp_weights(t_new, t_old) if weights is None else weights
    return (1.0 - w) * rows[i] + w * rows[i + 1]
