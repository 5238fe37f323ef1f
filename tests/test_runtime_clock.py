"""Absolute-deadline loop (wbmpc.runtime.clock): no drift under jittery sleeps, overruns counted and skipped,
the spin bounded, the tick history; a short run on the real clock checked for invariants only."""

import random

import numpy as np
import pytest

from wbmpc.runtime.clock import DeadlineLoop, FakeClock

PERIOD_NS = 2_000_000


def run(loop, clock, n, work_s=0.0005):
    ticks = []
    for _ in range(n):
        ticks.append(loop.wait_next())
        clock.advance(work_s)
        loop.tick_done()
    return ticks


def test_deadlines_do_not_drift_under_jittery_sleeps():
    rng = random.Random(1)
    clock = FakeClock(start_ns=10**9, jitter=lambda: rng.uniform(0.0, 300e-6))
    loop = DeadlineLoop(0.002, clock_ns=clock.now_ns, sleep=clock.sleep)
    ticks = run(loop, clock, 2000)
    t0 = loop.t0_ns
    assert [t.index for t in ticks] == list(range(2000))
    assert all(t.deadline_ns == t0 + t.index * PERIOD_NS for t in ticks)
    lateness = np.array([t.lateness_s for t in ticks])
    assert lateness.min() >= 0.0 and lateness.max() < 300e-6 + 5e-6  # one oversleep at most, never summed
    assert loop.overruns == 0 and loop.skipped == 0
    # The same sleeps after each tick's work (sleep(period)) drift by every oversleep.
    naive = FakeClock(start_ns=10**9, jitter=lambda: rng.uniform(0.0, 300e-6))
    for _ in range(2000):
        naive.advance(0.0005)
        naive.sleep(0.0015)
    drift = (naive.t_ns - 10**9) - 2000 * PERIOD_NS
    assert drift > 0.2e9  # ~0.3 s lost in 4 s, against < 0.3 ms for the deadline loop's last tick
    assert ticks[-1].wake_ns - (t0 + 1999 * PERIOD_NS) < 0.3e6


def test_the_spin_is_bounded_and_optional():
    clock = FakeClock(read_ns=1000)
    loop = DeadlineLoop(0.002, clock_ns=clock.now_ns, sleep=clock.sleep, spin_s=200e-6)
    run(loop, clock, 3)
    # Each sleep stops 200 us before the deadline (less the clock reads), then ~200 reads of 1 us spin.
    assert all(1.29e-3 <= s <= 1.3e-3 for s in clock.sleeps[1:]), clock.sleeps
    reads_before = clock.t_ns
    tick = loop.wait_next()
    assert tick.lateness_s <= 1.5e-6
    assert clock.t_ns - reads_before < 1.3e-3 * 1e9 + 205 * 1000  # the sleep plus a spin of <= 200 us
    loop.tick_done()
    nospin = FakeClock()
    loop = DeadlineLoop(0.002, clock_ns=nospin.now_ns, sleep=nospin.sleep, spin_s=0.0)
    ticks = run(loop, nospin, 5)
    assert all(t.lateness_s <= 1.5e-6 for t in ticks)  # one clock read late
    assert len(nospin.sleeps) == 4


def test_an_overrun_skips_to_the_next_future_deadline():
    clock = FakeClock()
    loop = DeadlineLoop(0.002, clock_ns=clock.now_ns, sleep=clock.sleep)
    loop.wait_next()
    clock.advance(0.011)  # tick 0 works 11 ms: ticks 1-5 due at 2-10 ms are missed
    loop.tick_done()
    tick = loop.wait_next()
    assert (tick.index, tick.skipped, tick.overrun) == (6, 5, True)
    assert tick.deadline_ns == loop.t0_ns + 6 * PERIOD_NS and tick.wake_ns >= tick.deadline_ns
    assert (loop.overruns, loop.skipped) == (1, 5)
    clock.advance(0.003)  # late by 1 ms (< a period) for tick 7: it runs at once, no overrun
    loop.tick_done()
    tick = loop.wait_next()
    assert (tick.index, tick.skipped, tick.overrun) == (7, 0, False)
    assert 0.9e-3 < tick.lateness_s < 1.1e-3
    loop.tick_done()
    tick = loop.wait_next()
    assert (tick.index, tick.skipped) == (8, 0) and tick.deadline_ns == loop.t0_ns + 8 * PERIOD_NS
    assert (loop.ticks, loop.overruns, loop.skipped) == (4, 1, 5)


def test_the_history_is_a_ring_of_the_last_ticks():
    clock = FakeClock()
    loop = DeadlineLoop(0.002, clock_ns=clock.now_ns, sleep=clock.sleep, history=8)
    run(loop, clock, 20, work_s=0.0007)
    loop.wait_next()  # an open tick: its compute time is NaN
    history = loop.history()
    assert list(history["index"]) == list(range(13, 21))
    assert np.all(history["deadline_ns"] == loop.t0_ns + history["index"] * PERIOD_NS)
    assert np.all(history["wake_ns"] >= history["deadline_ns"])
    assert np.allclose(history["compute_s"][:-1], 0.0007, atol=2e-6) and np.isnan(history["compute_s"][-1])
    assert np.all(history["skipped"] == 0) and np.all(history["lateness_s"] >= 0)


def test_two_loops_with_phases_keep_their_offset_on_one_clock():
    """Started at different moments, a loop at phase 0 and one at half a period tick on the clock's grid,
    1 ms apart, for good (the emulated robot and the controller taking turns on a CPU)."""
    clock = FakeClock(start_ns=1_234_567, read_ns=100)
    robot = DeadlineLoop(0.002, clock_ns=clock.now_ns, sleep=clock.sleep, phase_s=0.0)
    controller = DeadlineLoop(0.002, clock_ns=clock.now_ns, sleep=clock.sleep, phase_s=0.001)
    first = robot.wait_next()
    assert first.deadline_ns % 2_000_000 == 0 and first.deadline_ns >= 1_234_567
    robot.tick_done()
    clock.advance(0.0123)  # the controller comes up later
    wakes = [controller.wait_next().deadline_ns]
    controller.tick_done()
    for _ in range(5):
        for loop in (robot, controller):
            tick = loop.wait_next()
            wakes.append(tick.deadline_ns) if loop is controller else None
            assert tick.deadline_ns % 2_000_000 == (1_000_000 if loop is controller else 0)
            clock.advance(0.0003)
            loop.tick_done()
    assert np.all(np.diff(wakes) == 2_000_000)
    unphased = DeadlineLoop(0.002, clock_ns=clock.now_ns, sleep=clock.sleep)
    start = clock.t_ns
    assert unphased.wait_next().deadline_ns - start <= 1000  # at once


def test_misuse_and_bad_arguments():
    clock = FakeClock()
    loop = DeadlineLoop(0.002, clock_ns=clock.now_ns, sleep=clock.sleep)
    with pytest.raises(RuntimeError, match="tick_done"):
        loop.tick_done()
    loop.wait_next()
    with pytest.raises(RuntimeError, match="tick_done"):
        loop.wait_next()
    for kwargs, name in (
        ({"period_s": 0.0}, "period_s"),
        ({"period_s": float("nan")}, "period_s"),
        ({"period_s": 0.002, "spin_s": -1e-6}, "spin_s"),
        ({"period_s": 0.002, "spin_s": 0.01}, "spin_s"),
        ({"period_s": 0.002, "history": 0}, "history"),
        ({"period_s": 0.002, "clock_ns": 5}, "clock_ns"),
        ({"period_s": 0.002, "phase_s": 0.002}, "phase_s"),
        ({"period_s": 0.002, "phase_s": -1e-6}, "phase_s"),
    ):
        with pytest.raises(ValueError, match=name):
            DeadlineLoop(**kwargs)
    with pytest.raises(ValueError, match="read_ns"):
        FakeClock(read_ns=0)


def test_a_short_run_on_the_real_clock_keeps_its_invariants():
    loop = DeadlineLoop(0.002)
    for _ in range(100):  # ~0.2 s
        loop.wait_next()
        loop.tick_done()
    h = loop.history()
    assert np.all(np.diff(h["index"]) >= 1) and h["index"][0] == 0
    assert np.all(h["deadline_ns"] == loop.t0_ns + h["index"] * PERIOD_NS)
    assert np.all(h["wake_ns"] >= h["deadline_ns"]) and np.all(h["lateness_s"] >= 0)
    assert np.all(np.diff(h["wake_ns"]) > 0) and np.all(h["compute_s"] >= 0)
    assert loop.ticks == 100 and h["index"][-1] + 1 == loop.ticks + loop.skipped
    assert np.all(h["skipped"][1:] == np.diff(h["index"]) - 1)
    assert loop.overruns == int(np.count_nonzero(h["skipped"]))
