"""What a wall-clock run measured: loop timing, plan ages and end-to-end latency, plan and watchdog counts.

:class:`RuntimeMetrics` takes one :meth:`~RuntimeMetrics.tick` per controller tick (loop period, lateness,
overrun flag, compute time, age of the plan in use), one :meth:`~RuntimeMetrics.plan_received` per plan
accepted from the MPC worker and a :meth:`~RuntimeMetrics.plan_used` per command written, and
:meth:`~RuntimeMetrics.summary` gives a JSON-ready dict (milliseconds; p50/p95/p99/max per series).

End-to-end latency: from the measurement a plan was made from (its observation time) to the first command
written with that plan, once per plan. A plan replaced by a newer one before any command used it is dropped.

Memory is bounded: each series keeps at most ``capacity`` samples (65536 by default: 131 s at 500 Hz; 512 kB
per series). Up to that count its percentiles are exact; beyond, they are those of a uniform random sample
of the whole run (reservoir sampling, Algorithm R, seeded), while count, mean and max stay exact. At most
``max_events`` watchdog events are kept (all are counted).
"""

from __future__ import annotations

import math
import random

import numpy as np

from wbmpc import checks
from wbmpc.model.quaternion import base_z_axis

__all__ = ["RuntimeMetrics", "Series", "aligned_truth", "estimate_error", "tilt_errors"]

SERIES = ("period", "lateness", "compute", "plan_age", "latency")


class Series:
    """A bounded sample of one time series [s] (see the module notes).

    Args:
        capacity: Samples kept (>= 1).
        rng: The reservoir's random source (``random.Random``).
    """

    def __init__(self, capacity: int, rng: random.Random):
        self.values = np.empty(checks.integer("capacity", capacity, low=1))
        self.rng = rng
        self.count, self.total, self.max = 0, 0.0, -math.inf

    def add(self, x: float) -> None:
        """Add one sample (finite, else ValueError)."""
        if not math.isfinite(x):
            raise ValueError(f"a time series sample must be finite, got {x!r}")
        capacity = len(self.values)
        if self.count < capacity:
            self.values[self.count] = x
        elif (j := self.rng.randrange(self.count + 1)) < capacity:
            self.values[j] = x
        self.count += 1
        self.total += x
        self.max = max(self.max, x)

    @property
    def exact(self) -> bool:
        """Whether every sample is kept (the percentiles are exact)."""
        return self.count <= len(self.values)

    def kept(self) -> np.ndarray:
        return self.values[: min(self.count, len(self.values))]

    def summary(self, scale: float = 1e3) -> dict | None:
        """``count``, ``mean``, ``p50``, ``p95``, ``p99``, ``max`` times ``scale`` (ms by default); ``None``
        without samples. The percentiles are numpy's (linear interpolation) of the samples kept."""
        if self.count == 0:
            return None
        p50, p95, p99 = (float(p) * scale for p in np.percentile(self.kept(), [50, 95, 99]))
        mean, top = self.total / self.count * scale, self.max * scale
        return {"count": self.count, "mean": mean, "p50": p50, "p95": p95, "p99": p99, "max": top}


class RuntimeMetrics:
    """Accumulates a controller's per-tick timing and its plans' fate (see the module notes).

    Args:
        capacity: Samples kept per series (>= 1).
        seed: Seed of the reservoir sampling.
        max_events: Watchdog events kept (>= 0).

    Raises:
        ValueError: a bad argument (named).

    Attributes:
        series: Name -> :class:`Series` (``period``, ``lateness``, ``compute``, ``plan_age``, ``latency``).
        ticks, overruns, skipped_ticks: Counts of ticks, overrun ticks and ticks the loop skipped.
        plans_received, plans_used, plans_dropped: Plans accepted, used by a command at least once, and
            replaced before any command used them; plans_rejected: reason -> count.
        events: The first ``max_events`` watchdog events ``(time [s], reason)``; event_count: all of them.
    """

    def __init__(self, capacity: int = 65536, *, seed: int = 0, max_events: int = 100):
        rng = random.Random(checks.integer("seed", seed))
        self.series = {name: Series(capacity, rng) for name in SERIES}
        self.max_events = checks.integer("max_events", max_events, low=0)
        self.ticks = self.overruns = self.skipped_ticks = 0
        self.plans_received = self.plans_used = self.plans_dropped = 0
        self.plans_rejected: dict[str, int] = {}
        self.events: list[tuple[float, str]] = []
        self.event_count = 0
        self._pending: tuple[int, float] | None = None  # (seq, observation time) of a plan not used yet
        self._last_seq: int | None = None  # the newest plan received

    def tick(
        self,
        *,
        lateness_s: float,
        overrun: bool,
        compute_s: float,
        period_s: float | None = None,
        plan_age_s: float | None = None,
        skipped: int = 0,
    ) -> None:
        """Record one controller tick (times [s]; ``period_s``: since the previous tick's wake-up, ``None``
        on the first; ``plan_age_s``: of the plan in use, ``None`` without one; ``skipped``: ticks the loop
        skipped before this one).

        Raises:
            ValueError: a non-finite time, a non-bool ``overrun``, a negative ``skipped``.
        """
        if not isinstance(overrun, bool | np.bool_):
            raise ValueError(f"overrun must be True or False, got {overrun!r}")
        if isinstance(skipped, bool) or not isinstance(skipped, int | np.integer) or skipped < 0:
            raise ValueError(f"skipped must be an int >= 0, got {skipped!r}")
        for name, value in (("lateness", lateness_s), ("compute", compute_s), ("period", period_s)):
            if value is not None:
                self.series[name].add(float(value))
        if plan_age_s is not None:
            self.series["plan_age"].add(float(plan_age_s))
        self.ticks += 1
        self.overruns += bool(overrun)
        self.skipped_ticks += int(skipped)

    def plan_received(self, seq: int, observation_time_s: float) -> None:
        """A new plan ``seq`` was accepted, planned from the measurement of ``observation_time_s`` [s] (the
        clock of :meth:`plan_used`'s ``now_s``). A plan received before it was used counts as dropped; the
        same ``seq`` again is ignored.

        Raises:
            ValueError: a non-finite observation time.
        """
        observation_time_s = checks.number("observation_time_s", observation_time_s, unit="s")
        if seq == self._last_seq:
            return
        if self._pending is not None:
            self.plans_dropped += 1
        self._pending, self._last_seq = (seq, observation_time_s), seq
        self.plans_received += 1

    def plan_used(self, seq: int, now_s: float) -> float | None:
        """A command using plan ``seq`` was written at ``now_s`` [s]; the first time for a plan, records and
        returns its end-to-end latency [s], else ``None``.

        Raises:
            ValueError: a non-finite ``now_s``.
        """
        now_s = checks.number("now_s", now_s, unit="s")
        if self._pending is None or self._pending[0] != seq:
            return None
        latency = now_s - self._pending[1]
        self.series["latency"].add(latency)
        self._pending = None
        self.plans_used += 1
        return latency

    def plan_rejected(self, reason: str = "other", count: int = 1) -> None:
        """Count ``count`` plans rejected for ``reason`` (e.g. ``"stale"``, ``"epoch"``, ``"torn"``)."""
        self.plans_rejected[reason] = self.plans_rejected.get(reason, 0) + checks.integer(
            "count", count, low=0
        )

    def watchdog_event(self, time_s: float, reason: str) -> None:
        """Record a watchdog trip (e.g. each new entry of :attr:`wbmpc.runtime.watchdog.Watchdog.events`)."""
        self.event_count += 1
        if len(self.events) < self.max_events:
            self.events.append((float(time_s), str(reason)))

    def summary(self) -> dict:
        """A JSON-ready dict: ``ticks``, ``overruns``, ``overrun_fraction``, ``skipped_ticks``, the series as
        ``<name>_ms`` (:meth:`Series.summary`, ``None`` when empty), ``plans`` (received, used, dropped,
        rejected, rejected_by_reason), ``watchdog_events`` (time_s, reason), ``watchdog_event_count`` and
        ``exact_percentiles`` (False once a series outgrew its capacity)."""
        out = {
            "ticks": self.ticks,
            "overruns": self.overruns,
            "overrun_fraction": self.overruns / self.ticks if self.ticks else 0.0,
            "skipped_ticks": self.skipped_ticks,
        }
        out.update({f"{name}_ms": series.summary() for name, series in self.series.items()})
        out["plans"] = {
            "received": self.plans_received,
            "used": self.plans_used,
            "dropped": self.plans_dropped,
            "rejected": sum(self.plans_rejected.values()),
            "rejected_by_reason": dict(self.plans_rejected),
        }
        out["watchdog_events"] = [
            {"time_s": t if math.isfinite(t) else None, "reason": r} for t, r in self.events
        ]
        out["watchdog_event_count"] = self.event_count
        out["exact_percentiles"] = all(series.exact for series in self.series.values())
        return out


def aligned_truth(
    t: np.ndarray, true_t: np.ndarray, true_base: np.ndarray, true_start: float
) -> tuple[np.ndarray, np.ndarray]:
    """The emulated robot's true base at each controller tick.

    Only a simulated robot knows its true base: the emulated robot's process keeps it once per period.
    Its clock starts with its physics, at the first command; ``true_start`` [s] is that moment on the
    run's clock (the controller's first tick), so the two series are aligned to about one robot period.

    Args:
        t: Controller tick times [s] (n,); true_t: the robot's times since its physics started [s] (m,),
        m >= 1; true_base: its true ``q[:7]`` (m, 7); true_start: when its physics started [s].

    Returns:
        ``(inside, base)``: which ticks lie within the robot's record (n,), and the true base at each tick
        (n, 7) (the nearest later sample; held at the ends).
    """
    t, true_t = np.asarray(t, dtype=float), np.asarray(true_t, dtype=float) + true_start
    inside = (t >= true_t[0]) & (t <= true_t[-1])
    index = np.searchsorted(true_t, t).clip(0, len(true_t) - 1)
    return inside, np.asarray(true_base, dtype=float)[index]


def tilt_errors(q_hat: np.ndarray, q_true: np.ndarray) -> np.ndarray:
    """Angles [rad] between the base z axes of two series of configurations (or base poses ``q[:7]``),
    shape (n, >= 7)."""
    cos = np.sum(base_z_axis(q_hat) * base_z_axis(q_true), axis=-1)
    return np.arccos(np.clip(cos, -1.0, 1.0))


def estimate_error(
    t: np.ndarray,
    q_hat: np.ndarray,
    damping: np.ndarray,
    true_t: np.ndarray,
    true_base: np.ndarray,
    true_start: float,
) -> dict | None:
    """How far the controller's base estimate was from the emulated robot's true base, while controlled
    (:func:`aligned_truth`).

    Args:
        t: Controller tick times [s] (n,); q_hat: the estimates (n, nq); damping: the ticks in damping (n,).
        true_t, true_base, true_start: The robot's record (:func:`aligned_truth`).

    Returns:
        ``tilt_rad`` (the angle between the estimated and the true base z axes) and ``height_m`` (estimated
        minus true base height), each with ``p50``, ``p95``, ``max`` (absolute values), and ``samples``;
        ``None`` without a controlled tick inside the robot's record.
    """
    if not len(true_t):
        return None
    inside, truth = aligned_truth(t, true_t, true_base, true_start)
    controlled = inside & ~np.asarray(damping, dtype=bool)
    if not np.any(controlled):
        return None
    rows, truth = np.asarray(q_hat, dtype=float)[controlled], truth[controlled]
    tilt = tilt_errors(rows, truth)
    height = np.abs(rows[:, 2] - truth[:, 2])

    def stats(values):
        p50, p95 = np.percentile(values, [50, 95])
        return {"p50": float(p50), "p95": float(p95), "max": float(np.max(values))}

    return {"tilt_rad": stats(tilt), "height_m": stats(height), "samples": int(controlled.sum())}
