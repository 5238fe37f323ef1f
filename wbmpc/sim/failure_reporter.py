"""The closed loop's failure reporter: one line the first time a solver failure reason or a precheck finding
occurs in a run, every occurrence counted for the run summary.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import TextIO

from wbmpc.control.prechecks import Finding
from wbmpc.solver.statuses import SUCCESS, solver_status


# --- closed-loop reporting -------------------------------------------------------------------------------
class FailureReporter:
    """Print one line the first time each failure reason (or finding code) occurs; count them all.

    Meant for a closed loop, where the same failure may repeat on every tick. Keys are the short names
    (:func:`solver_status` names, finding codes), so a reason whose numbers change between ticks prints
    once.

    Args:
        stream: Where to print (``sys.stdout`` at print time by default).
        prefix: Start of every printed line.
        enabled: ``False`` counts without printing.
    """

    def __init__(self, stream: TextIO | None = None, prefix: str = "wbmpc", enabled: bool = True):
        self.stream = stream
        self.prefix = prefix
        self.enabled = enabled
        self.failures: dict[str, int] = {}
        self.findings: dict[str, int] = {}
        self.first_time: dict[str, float] = {}
        self.reasons: dict[str, str] = {}

    def report(self, t: float, name: str, reason: str = "") -> bool:
        """Count a failed solve at time ``t`` [s]; print it if ``name`` is new. Returns whether it printed.

        A ``"success"`` name is ignored.
        """
        if name == SUCCESS:
            return False
        return self._count(self.failures, t, name, reason, "solve failed")

    def report_status(self, t: float, success: bool, solver: str, stats: dict) -> tuple[str, str]:
        """Name a solve's status with :func:`solver_status`, report it if it failed, and return it."""
        name, reason = solver_status(solver, stats)
        if not success:
            self.report(t, name if name != SUCCESS else "not_converged", reason)
        return name, reason

    def report_findings(self, t: float, findings: Sequence[Finding]) -> int:
        """Count precheck findings at time ``t`` [s]; print each new code once. Returns how many printed."""
        printed = 0
        for f in findings:
            printed += self._count(self.findings, t, f.code, f.message, f"precheck {f.severity}")
        return printed

    def summary(self) -> dict:
        """Counts for the run summary: ``{"failures": n, "failure_reasons": {name: count}, "findings":
        {code: count}, "first_time": {name: t}, "reasons": {name: first reason}}``."""
        return {
            "failures": int(sum(self.failures.values())),
            "failure_reasons": dict(self.failures),
            "findings": dict(self.findings),
            "first_time": dict(self.first_time),
            "reasons": dict(self.reasons),
        }

    def _count(self, counts: dict, t: float, name: str, reason: str, kind: str) -> bool:
        new = name not in counts
        counts[name] = counts.get(name, 0) + 1
        if not new:
            return False
        self.first_time.setdefault(name, float(t))
        self.reasons.setdefault(name, reason)
        if self.enabled:
            stream = self.stream if self.stream is not None else sys.stdout
            text = f": {reason}" if reason else ""
            print(
                f"{self.prefix} t={t:.3f} s: {kind}: {name}{text} (further occurrences counted, not printed)",
                file=stream,
            )
        return True
