"""The OCP's named constraint rows evaluated at a point: what a warm start violates, what binds at a solution.

Every path-constraint row of :class:`wbmpc.ocp.OCP` belongs to a named group per stage (``transition``,
``dynamics``, ``torque_limits``, ``friction_cone``, ``foot_velocity``, ``ee_velocity``,
``joint_position_limits``, ``joint_velocity_limits``, ...; :attr:`wbmpc.ocp.builder.StageInfo.rows`).
:class:`ConstraintInspector` evaluates the constraint vector ``g(w, p)`` and reports, per group,

* the largest bound violation ``max(lbg - g, g - ubg, 0)`` and the stage where it occurs (at the first
  iterate of a solve: how far the shifted warm start is from feasible, and where), and
* the inequality rows within a tolerance of a bound (at a solution: which limits are active).

The limit rows are scaled to unit slacks (``-1 <= (x - mid) / half <= 1``, see the builder), so one
tolerance fits them all; the dynamics and transition rows keep their units (N m, rad, rad/s).
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

__all__ = ["ConstraintInspector", "RowGroupReport"]


@dataclass(frozen=True)
class RowGroupReport:
    """One row group at one point.

    Attributes:
        max_violation: Largest bound violation of the group's rows (0 if feasible) [row units].
        stage: Stage of that row (-1 when nothing is violated).
        active: Inequality rows within the tolerance of a bound.
        rows: Number of rows in the group.
    """

    max_violation: float
    stage: int
    active: int
    rows: int


class ConstraintInspector:
    """Named constraint rows of an OCP evaluated at ``(w, p)`` (in-process; about a millisecond).

    Args:
        ocp: The :class:`wbmpc.ocp.OCP`.

    Raises:
        ValueError: ``ocp`` is not an OCP.
    """

    def __init__(self, ocp):
        if not hasattr(ocp, "nlp") or not hasattr(ocp, "stages"):
            raise ValueError(f"ocp must be a wbmpc.ocp.OCP, got {ocp!r}")
        self.ocp = ocp
        self._g = ca.Function("g", [ocp.nlp["x"], ocp.nlp["p"]], [ocp.nlp["g"]])
        self.lbg, self.ubg = np.asarray(ocp.lbg, float), np.asarray(ocp.ubg, float)
        rows: dict[str, list[int]] = {}
        stage_of = np.zeros(self.lbg.size, dtype=int)
        for info in ocp.stages:
            for name, rng in info.rows.items():
                rows.setdefault(name, []).extend(range(rng.start, rng.stop))
                stage_of[rng] = info.k
        self.groups = {name: np.asarray(index, dtype=int) for name, index in rows.items()}
        self.stage_of = stage_of
        self.inequality = self.lbg != self.ubg

    def evaluate(self, w: np.ndarray, p: np.ndarray) -> np.ndarray:
        """The constraint vector ``g(w, p)`` (n_g,).

        Raises:
            ValueError: ``w`` or ``p`` of the wrong size.
        """
        w, p = np.asarray(w, float).ravel(), np.asarray(p, float).ravel()
        if w.size != self.ocp.n_variables or p.size != self.ocp.nlp["p"].numel():
            raise ValueError(
                f"w must have {self.ocp.n_variables} and p {self.ocp.nlp['p'].numel()} entries, "
                f"got {w.size} and {p.size}"
            )
        return np.asarray(self._g(w, p)).ravel()

    def report(self, w: np.ndarray, p: np.ndarray, tol: float = 1e-3) -> dict[str, RowGroupReport]:
        """Violation and active rows of each group at ``(w, p)``.

        Args:
            w: Decision vector (n_w,).
            p: Parameter vector (n_p,).
            tol: Distance to a bound [row units] under which an inequality row counts as active.

        Returns:
            ``{group: RowGroupReport}`` in the OCP's row order.
        """
        g = self.evaluate(w, p)
        violation = np.maximum(0.0, np.maximum(self.lbg - g, g - self.ubg))
        near = self.inequality & (
            (np.abs(g - self.lbg) < tol) | (np.abs(self.ubg - g) < tol) | (violation > 0.0)
        )
        out = {}
        for name, index in self.groups.items():
            worst = int(index[np.argmax(violation[index])])
            out[name] = RowGroupReport(
                max_violation=float(violation[worst]),
                stage=int(self.stage_of[worst]) if violation[worst] > 0 else -1,
                active=int(np.sum(near[index])),
                rows=int(index.size),
            )
        return out

    def active_rows(self, w: np.ndarray, p: np.ndarray, group: str, tol: float = 1e-3) -> np.ndarray:
        """Indices (into the group's rows) of the inequality rows of ``group`` within ``tol`` of a bound.

        Raises:
            ValueError: an unknown group (the message lists the known ones).
        """
        if group not in self.groups:
            raise ValueError(f"unknown row group {group!r}; the OCP has {sorted(self.groups)}")
        g = self.evaluate(w, p)
        index = self.groups[group]
        near = self.inequality[index] & (
            (np.abs(g[index] - self.lbg[index]) < tol) | (np.abs(self.ubg[index] - g[index]) < tol)
        )
        return np.flatnonzero(near)
