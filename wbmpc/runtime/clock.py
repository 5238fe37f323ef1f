"""Absolute deadlines on the monotonic clock: the controller's fixed-rate loop (e.g. 500 Hz).

Tick ``k`` is due at ``t0 + k * period`` (integer nanoseconds), ``t0`` the time of the first
:meth:`DeadlineLoop.wait_next` (or, with a ``phase_s``, the next instant after it at that phase of the
clock's own grid of periods, so that two processes' loops tick at a chosen offset from each other): a late
wake-up delays one tick, never the ones after it (sleeping ``period`` after each tick would add every
oversleep to all later ticks). :meth:`DeadlineLoop.wait_next` sleeps with
``sleep`` until ``spin_s`` before the deadline, then spins on the clock (``time.sleep`` oversleeps by
50-100 us on a stock Linux kernel; a spin of at most ``spin_s`` buys that back for a little CPU).

Overrun policy: a tick found more than one full period after its deadline (the previous tick's work, or the
process, stalled) is counted as an overrun; the loop then skips to the next deadline still in the future and
waits for it, so that it keeps its phase and never runs a burst of late ticks to catch up. The returned
:class:`Tick` says how many ticks were skipped. A tick later than its deadline by up to one period runs at
once (its lateness is reported).

:class:`FakeClock` (``now_ns`` and ``sleep`` that advances it, optionally by a jitter) makes tests
deterministic: ``DeadlineLoop(0.002, clock_ns=clock.now_ns, sleep=clock.sleep)``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from wbmpc import checks

__all__ = ["DeadlineLoop", "FakeClock", "Tick"]


class FakeClock:
    """A deterministic clock for tests: time moves only when told.

    Args:
        start_ns: The initial time [ns].
        read_ns: Time each :meth:`now_ns` call takes [ns] (> 0 so that a spin on the clock ends).
        jitter: ``jitter()`` -> extra seconds each :meth:`sleep` oversleeps (e.g. a seeded random draw);
            ``None``: exact sleeps.

    Raises:
        ValueError: a negative ``start_ns`` or a ``read_ns`` not > 0.
    """

    def __init__(self, start_ns: int = 0, read_ns: int = 1000, jitter: Callable[[], float] | None = None):
        self.t_ns = checks.integer("start_ns", start_ns, low=0)
        self.read_ns = checks.integer("read_ns", read_ns, low=1)
        self.jitter = jitter
        self.sleeps: list[float] = []  # the durations asked of sleep() [s]

    def now_ns(self) -> int:
        """The current time [ns] (each call advances it by ``read_ns``)."""
        self.t_ns += self.read_ns
        return self.t_ns

    def sleep(self, seconds: float) -> None:
        """Advance by ``seconds`` (>= 0) plus the jitter's draw."""
        self.sleeps.append(seconds)
        extra = self.jitter() if self.jitter is not None else 0.0
        self.t_ns += round(max(seconds, 0.0) * 1e9) + max(round(extra * 1e9), 0)

    def advance(self, seconds: float) -> None:
        """Let ``seconds`` pass (a tick's work)."""
        self.t_ns += round(seconds * 1e9)


@dataclass(frozen=True)
class Tick:
    """One tick of a :class:`DeadlineLoop`.

    Attributes:
        index: Tick index ``k`` (its deadline is ``t0 + k * period``); skipped ticks' indices never appear.
        deadline_ns: The deadline [ns, the loop's clock]; wake_ns: when :meth:`DeadlineLoop.wait_next`
            returned [ns].
        lateness_s: ``wake - deadline`` [s] (>= 0 but for a clock that reads backwards).
        skipped: Ticks skipped before this one (their deadlines passed by more than a period).
        overrun: ``skipped > 0``.
    """

    index: int
    deadline_ns: int
    wake_ns: int
    lateness_s: float
    skipped: int

    @property
    def overrun(self) -> bool:
        return self.skipped > 0


class DeadlineLoop:
    """A fixed-rate loop on absolute deadlines (see the module notes for the overrun policy).

    Usage::

        loop = DeadlineLoop(0.002)
        while running:
            tick = loop.wait_next()
            ...  # the tick's work
            loop.tick_done()

    Args:
        period_s: The period [s] (> 0, at most 10 s).
        clock_ns: The clock [ns], ``time.monotonic_ns`` by default (a :meth:`FakeClock.now_ns` in tests).
        sleep: ``sleep(seconds)``, ``time.sleep`` by default.
        spin_s: How long before a deadline to stop sleeping and spin on the clock [s] (0: never spin).
        history: Ticks kept in the ring buffer of :meth:`history` (the most recent ones).
        phase_s: Start on the clock's grid: the first deadline is the first instant at or after the first
            :meth:`wait_next` whose time is ``phase_s`` past a whole number of periods (0 <= phase_s <
            period); ``None``: at once. Two loops of one period on one clock then keep that offset: on a
            shared CPU they take turns instead of waking together.

    Raises:
        ValueError: a bad argument (named).

    Attributes:
        ticks: Ticks run; overruns: ticks that found their deadline missed by more than a period;
        skipped: ticks skipped in all; max_lateness_s: the largest lateness seen [s].
    """

    def __init__(
        self,
        period_s: float,
        clock_ns: Callable[[], int] = time.monotonic_ns,
        sleep: Callable[[float], None] = time.sleep,
        *,
        spin_s: float = 200e-6,
        history: int = 4096,
        phase_s: float | None = None,
    ):
        period_s = checks.number("period_s", period_s, low=0.0, high=10.0, low_open=True, unit="s")
        self.period_ns = max(round(period_s * 1e9), 1)
        self.phase_ns = None
        if phase_s is not None:
            phase_s = checks.number("phase_s", phase_s, low=0.0, high=period_s, high_open=True, unit="s")
            self.phase_ns = round(phase_s * 1e9) % self.period_ns
        self.spin_ns = round(checks.number("spin_s", spin_s, low=0.0, high=period_s, unit="s") * 1e9)
        capacity = checks.integer("history", history, low=1)
        if not callable(clock_ns) or not callable(sleep):
            raise ValueError(f"clock_ns and sleep must be callables, got {clock_ns!r} and {sleep!r}")
        self.clock_ns, self.sleep = clock_ns, sleep
        self.t0_ns: int | None = None
        self.ticks = self.overruns = self.skipped = 0
        self.max_lateness_s = 0.0
        self._next = 0  # index of the next deadline
        self._current: Tick | None = None
        self._ring = {
            "index": np.zeros(capacity, np.int64),
            "deadline_ns": np.zeros(capacity, np.int64),
            "wake_ns": np.zeros(capacity, np.int64),
            "lateness_s": np.zeros(capacity),
            "compute_s": np.full(capacity, np.nan),
            "skipped": np.zeros(capacity, np.int64),
        }

    @property
    def period_s(self) -> float:
        return self.period_ns / 1e9

    def deadline_ns(self, index: int) -> int:
        """The deadline of tick ``index`` [ns] (``t0 + index * period``; the loop must have started)."""
        if self.t0_ns is None:
            raise RuntimeError("the loop has not started: call wait_next() first")
        return self.t0_ns + index * self.period_ns

    def wait_next(self) -> Tick:
        """Wait for the next deadline and return its :class:`Tick` (the first call starts the loop at once).

        Raises:
            RuntimeError: the previous tick was not closed with :meth:`tick_done`.
        """
        if self._current is not None:
            raise RuntimeError("call tick_done() at the end of each tick before wait_next()")
        now = self.clock_ns()
        if self.t0_ns is None:
            self.t0_ns = now if self.phase_ns is None else now + (self.phase_ns - now) % self.period_ns
        index = self._next
        deadline = self.deadline_ns(index)
        skipped = 0
        if now - deadline > self.period_ns:  # overrun: go on at the next deadline still ahead
            future = (now - self.t0_ns) // self.period_ns + 1
            skipped, index = future - index, future
            deadline = self.deadline_ns(index)
            self.overruns += 1
            self.skipped += skipped
        while (remaining := deadline - now) > self.spin_ns:
            self.sleep((remaining - self.spin_ns) / 1e9)
            now = self.clock_ns()
        while now < deadline:
            now = self.clock_ns()
        tick = Tick(index, deadline, now, (now - deadline) / 1e9, skipped)
        self._next, self._current = index + 1, tick
        self.max_lateness_s = max(self.max_lateness_s, tick.lateness_s)
        slot = self.ticks % len(self._ring["index"])
        for key in ("index", "deadline_ns", "wake_ns", "lateness_s", "skipped"):
            self._ring[key][slot] = getattr(tick, key)
        self._ring["compute_s"][slot] = np.nan
        self.ticks += 1
        return tick

    def tick_done(self) -> float:
        """Close the current tick; returns its compute time [s] (from its wake-up to now).

        Raises:
            RuntimeError: no tick in progress.
        """
        if self._current is None:
            raise RuntimeError("tick_done() without a tick in progress (call wait_next() first)")
        compute = (self.clock_ns() - self._current.wake_ns) / 1e9
        self._ring["compute_s"][(self.ticks - 1) % len(self._ring["index"])] = compute
        self._current = None
        return compute

    def history(self) -> dict[str, np.ndarray]:
        """The recorded ticks, oldest first (the last ``history`` of them): ``index``, ``deadline_ns``,
        ``wake_ns``, ``lateness_s``, ``compute_s`` (NaN while a tick is open) and ``skipped``, each (n,)."""
        capacity = len(self._ring["index"])
        n = min(self.ticks, capacity)
        order = (np.arange(n) + (self.ticks - n)) % capacity
        return {key: values[order].copy() for key, values in self._ring.items()}
