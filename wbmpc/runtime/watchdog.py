"""The controller's watchdog: when plans stop coming or the loop keeps missing deadlines, the damping mode.

:meth:`Watchdog.check` runs once per control tick. It trips when the plan in use is older than
``max_plan_age_s``, when no plan arrived within ``startup_grace_s`` of the first check, when
``max_consecutive_overruns`` ticks in a row overran (an isolated overrun does not trip), or when told so by
:meth:`Watchdog.trip` (a NaN observation, a dead MPC worker). A trip is latched until :meth:`Watchdog.reset`:
the first reason is kept, recorded once in :attr:`Watchdog.events`, and later causes are not reported.

The damping mode (:meth:`wbmpc.runtime.robot.MotorCommand.damping_mode`) is the motor command
``kp = 0``, ``kd > 0``, zero feed-forward torque and zero position and rate setpoints: each drive applies
``kd * (0 - dq)``, a torque against the joint's motion that slows the robot down (it sinks gently instead
of holding a stale plan's torques).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from wbmpc import checks

__all__ = ["Watchdog", "WatchdogState"]


@dataclass(frozen=True)
class WatchdogState:
    """What :meth:`Watchdog.check` found.

    Attributes:
        tripped: Whether the damping mode must be on (latched).
        reason: Why it tripped (a sentence; ``""`` while not tripped).
        tripped_at_s: When it tripped [s] (``None`` while not tripped).
        just_tripped: True on the one check (or :meth:`Watchdog.trip`) that tripped it.
        plan_age_s: Age of the plan in use [s] at this check (``None`` without a plan).
        consecutive_overruns: Overrun ticks in a row up to this one.
    """

    tripped: bool
    reason: str
    tripped_at_s: float | None
    just_tripped: bool
    plan_age_s: float | None
    consecutive_overruns: int


def _s(seconds: float) -> str:
    """Seconds for a sentence: two decimals, or three significant digits below 0.1 s."""
    return f"{seconds:.2f}" if abs(seconds) >= 0.1 else f"{seconds:.3g}"


class Watchdog:
    """Trips (latched) when the plan in use gets too old or the loop overruns tick after tick.

    Args:
        max_plan_age_s: Largest age of the plan in use [s] (``now - plan_time``), e.g. a few MPC periods.
        max_consecutive_overruns: Overrun ticks in a row that trip it (>= 1).
        startup_grace_s: Time from the first check [s] within which a first plan must arrive; ``None``: the
            same as ``max_plan_age_s``.

    Raises:
        ValueError: an argument out of range (named).

    Attributes:
        events: ``(time [s], reason)`` of every trip, in order (one per trip; :meth:`reset` keeps them).
    """

    def __init__(
        self, max_plan_age_s: float, max_consecutive_overruns: int, *, startup_grace_s: float | None = None
    ):
        self.max_plan_age_s = checks.number(
            "max_plan_age_s", max_plan_age_s, low=0.0, low_open=True, unit="s"
        )
        self.max_consecutive_overruns = checks.integer(
            "max_consecutive_overruns", max_consecutive_overruns, low=1
        )
        grace = self.max_plan_age_s if startup_grace_s is None else startup_grace_s
        self.startup_grace_s = checks.number("startup_grace_s", grace, low=0.0, low_open=True, unit="s")
        self.events: list[tuple[float, str]] = []
        self._last_s: float | None = None  # the last check's time
        self.reset()

    def reset(self) -> None:
        """Clear the latch and the counters (after the operator or the controller resets); the next check
        starts a new startup grace."""
        self.tripped, self.reason, self.tripped_at_s = False, "", None
        self.consecutive_overruns = 0
        self._start_s: float | None = None

    def trip(self, reason: str, now_s: float | None = None) -> WatchdogState:
        """Trip for an outside cause (a NaN observation, a dead worker): ``reason`` is a sentence for the log,
        ``now_s`` [s] the time (``None``: the last check's). A no-op but for the returned state if tripped.

        Raises:
            ValueError: an empty ``reason`` or a non-finite ``now_s``.
        """
        if not isinstance(reason, str) or not reason.strip():
            raise ValueError(f"reason must be a non-empty sentence, got {reason!r}")
        if now_s is not None:
            now_s = checks.number("now_s", now_s, unit="s")
        just = self._latch(reason, now_s if now_s is not None else self._last_s)
        return self._state(just, None)

    def check(self, now_s: float, plan_time_s: float | None, overrun: bool) -> WatchdogState:
        """One tick's check.

        Args:
            now_s: The time [s] (the clock of ``plan_time_s``).
            plan_time_s: Time of the plan in use [s]: its measurement time (node 0's ``t``) or its arrival,
                as the caller decides (a re-sent fallback plan keeps its old time); ``None``: no plan yet.
            overrun: Whether this tick overran (:attr:`wbmpc.runtime.clock.Tick.overrun`).

        Raises:
            ValueError: a non-finite time or a non-bool ``overrun``.
        """
        now_s = checks.number("now_s", now_s, unit="s")
        if plan_time_s is not None:
            plan_time_s = checks.number("plan_time_s", plan_time_s, unit="s")
        if not isinstance(overrun, bool | np.bool_):
            raise ValueError(f"overrun must be True or False, got {overrun!r}")
        self._last_s = now_s
        if self._start_s is None:
            self._start_s = now_s
        self.consecutive_overruns = self.consecutive_overruns + 1 if overrun else 0
        age = None if plan_time_s is None else now_s - plan_time_s
        reason = ""
        if age is not None and age > self.max_plan_age_s:
            reason = f"no new plan for {_s(age)} s (limit {_s(self.max_plan_age_s)} s)"
        elif age is None and now_s - self._start_s > self.startup_grace_s:
            waited = now_s - self._start_s
            reason = f"no plan received {_s(waited)} s after start (limit {_s(self.startup_grace_s)} s)"
        elif self.consecutive_overruns >= self.max_consecutive_overruns:
            reason = (
                f"{self.consecutive_overruns} control ticks in a row overran their deadline "
                f"(limit {self.max_consecutive_overruns})"
            )
        just = bool(reason) and self._latch(reason, now_s)
        return self._state(just, age)

    def _latch(self, reason: str, now_s: float | None) -> bool:
        if self.tripped:
            return False
        self.tripped, self.reason, self.tripped_at_s = True, reason, now_s
        self.events.append((math.nan if now_s is None else now_s, reason))
        return True

    def _state(self, just: bool, age: float | None) -> WatchdogState:
        at = self.tripped_at_s
        return WatchdogState(self.tripped, self.reason, at, just, age, self.consecutive_overruns)
