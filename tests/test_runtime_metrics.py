"""Runtime metrics (wbmpc.runtime.metrics): percentiles against numpy, latency once per plan, dropped plans,
bounded memory, a JSON-ready summary."""

import json

import numpy as np
import pytest

from wbmpc.runtime.metrics import RuntimeMetrics, estimate_error


def test_percentiles_match_numpy_on_known_data():
    rng = np.random.default_rng(3)
    lateness = rng.lognormal(-9, 1, 5000)
    compute = rng.uniform(0.1e-3, 0.9e-3, 5000)
    metrics = RuntimeMetrics()
    for k, (late, comp) in enumerate(zip(lateness, compute, strict=True)):
        metrics.tick(lateness_s=late, overrun=k % 50 == 0, compute_s=comp, period_s=0.002 if k else None)
    summary = metrics.summary()
    for key, data in (("lateness_ms", lateness), ("compute_ms", compute)):
        expected = np.percentile(data, [50, 95, 99]) * 1e3
        got = summary[key]
        np.testing.assert_allclose([got["p50"], got["p95"], got["p99"]], expected, rtol=1e-12)
        assert got["max"] == pytest.approx(data.max() * 1e3) and got["mean"] == pytest.approx(
            data.mean() * 1e3
        )
        assert got["count"] == 5000
    assert summary["period_ms"]["count"] == 4999 and summary["period_ms"]["p99"] == pytest.approx(2.0)
    assert summary["overruns"] == 100 and summary["overrun_fraction"] == pytest.approx(0.02)
    assert summary["plan_age_ms"] is None and summary["latency_ms"] is None and summary["exact_percentiles"]


def test_latency_is_counted_once_per_plan_and_unused_plans_are_dropped():
    metrics = RuntimeMetrics()
    metrics.plan_received(1, observation_time_s=10.000)
    assert metrics.plan_used(1, 10.012) == pytest.approx(0.012)
    assert metrics.plan_used(1, 10.014) is None  # the same plan again: no second latency
    metrics.plan_received(2, 10.010)
    metrics.plan_received(3, 10.020)  # plan 2 replaced before any command used it
    metrics.plan_received(3, 10.020)  # the same plan polled again: ignored
    assert metrics.plan_used(2, 10.030) is None  # not the plan in use
    assert metrics.plan_used(3, 10.031) == pytest.approx(0.011)
    metrics.plan_received(4, 10.030)
    metrics.plan_rejected("epoch")
    metrics.plan_rejected("stale", 2)
    plans = metrics.summary()["plans"]
    assert plans == {
        "received": 4,
        "used": 2,
        "dropped": 1,
        "rejected": 3,
        "rejected_by_reason": {"epoch": 1, "stale": 2},
    }
    latency = metrics.summary()["latency_ms"]
    assert (
        latency["count"] == 2
        and latency["max"] == pytest.approx(12.0)
        and latency["p50"] == pytest.approx(11.5)
    )


def test_memory_is_bounded_and_the_summary_is_json():
    metrics = RuntimeMetrics(capacity=200, seed=1, max_events=2)
    rng = np.random.default_rng(0)
    data = rng.uniform(0.0, 1e-3, 20000)
    for x in data:
        metrics.tick(lateness_s=0.0, overrun=False, compute_s=x, plan_age_s=x / 2)
    series = metrics.series["compute"]
    assert len(series.values) == 200 and series.count == 20000 and not series.exact
    summary = metrics.summary()
    assert summary["compute_ms"]["max"] == pytest.approx(data.max() * 1e3)  # exact beyond the capacity
    assert summary["compute_ms"]["mean"] == pytest.approx(data.mean() * 1e3)
    assert summary["compute_ms"]["p50"] == pytest.approx(0.5, abs=0.12)  # a uniform sample's median
    assert not summary["exact_percentiles"]
    for k in range(5):
        metrics.watchdog_event(float("nan") if k == 0 else k, f"trip {k}")
    summary = metrics.summary()
    assert summary["watchdog_event_count"] == 5 and len(summary["watchdog_events"]) == 2
    assert summary["watchdog_events"][0] == {"time_s": None, "reason": "trip 0"}
    assert json.loads(json.dumps(summary, allow_nan=False)) == summary


@pytest.mark.parametrize(
    ("call", "name"),
    [
        (lambda: RuntimeMetrics(capacity=0), "capacity"),
        (lambda: RuntimeMetrics(max_events=-1), "max_events"),
        (lambda: RuntimeMetrics().tick(lateness_s=float("nan"), overrun=False, compute_s=0.0), "finite"),
        (lambda: RuntimeMetrics().tick(lateness_s=0.0, overrun=1, compute_s=0.0), "overrun"),
        (lambda: RuntimeMetrics().tick(lateness_s=0.0, overrun=False, compute_s=0.0, skipped=-1), "skipped"),
        (lambda: RuntimeMetrics().plan_received(1, float("inf")), "observation_time_s"),
        (lambda: RuntimeMetrics().plan_used(1, float("nan")), "now_s"),
    ],
)
def test_bad_arguments_are_named(call, name):
    with pytest.raises(ValueError, match=name):
        call()


def test_estimate_error_measures_tilt_and_height_against_the_truth_on_the_robots_clock():
    """A true base rolling at 0.02 rad/s under an estimate held level (what a wire that invented the
    identity orientation produced): the error is the roll itself; damping ticks are left out."""
    import pinocchio as pin

    true_t = np.arange(1, 1001) * 0.002  # the robot's clock: its physics starts at the first command
    roll = 0.02 * true_t
    true_base = np.zeros((true_t.size, 7))
    true_base[:, 2] = 0.52
    true_base[:, 3:7] = [pin.Quaternion(pin.rpy.rpyToMatrix(r, 0, 0)).coeffs() for r in roll]
    start = 0.5
    t = start + true_t[:-1] + 0.001  # controller ticks, half a period after the robot's samples
    q_hat = np.zeros((t.size, 23))
    q_hat[:, 2] = 0.53
    q_hat[:, 6] = 1.0
    damping = t > start + 1.5
    error = estimate_error(t, q_hat, damping, true_t, true_base, start)
    controlled = ~damping
    expected = 0.02 * (t[controlled] - start)
    assert error["samples"] == controlled.sum()
    assert error["tilt_rad"]["max"] == pytest.approx(expected.max(), abs=0.02 * 0.002)
    assert error["tilt_rad"]["p50"] == pytest.approx(np.median(expected), abs=0.02 * 0.002)
    assert error["height_m"]["p95"] == pytest.approx(0.01)
    assert estimate_error(t, q_hat, np.ones(t.size, bool), true_t, true_base, start) is None
