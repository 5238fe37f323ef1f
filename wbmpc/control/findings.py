"""What a precheck reports: a :class:`Finding` names a problem of a solve request and its numbers."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import asdict, dataclass, field
from typing import Literal

__all__ = ["Finding", "Severity", "findings_to_dicts", "has_errors"]

Severity = Literal["warning", "error"]


@dataclass
class Finding:
    """One result of a precheck.

    Attributes:
        code: Short machine-readable name, e.g. ``"ee_force_exceeds_torque_limit"``.
        severity: ``"error"``: the command cannot be met as given (a limit is exceeded, the solve will fail
            or the plan will not track it); ``"warning"``: suspicious or close to a limit.
        message: One sentence naming the problem and its numbers.
        data: The numbers, JSON-serialisable (for logs and run summaries).
    """

    code: str
    severity: Severity
    message: str
    data: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return asdict(self)

    def __str__(self) -> str:
        return f"[{self.severity}] {self.code}: {self.message}"


def findings_to_dicts(findings: Iterable[Finding]) -> list[dict]:
    """Findings as plain dicts (for a plan's metadata or a run summary)."""
    return [f.to_dict() for f in findings]


def has_errors(findings: Iterable[Finding]) -> bool:
    """Whether any finding is an error."""
    return any(f.severity == "error" for f in findings)
