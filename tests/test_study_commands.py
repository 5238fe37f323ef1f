"""Command lines of the studies that had no run-path test: the soak benchmark, the real-time benchmark, and
the sweeps against a Dask scheduler started on its own (as on a cluster), each on a tiny run."""

import json
import os
import subprocess
import sys
import time

import numpy as np
import pytest

from wbmpc.io.logs import load_log
from wbmpc.studies import realtime, soak
from wbmpc.studies.sweeps import cli as sweeps_cli
from wbmpc.studies.sweeps import read_table

PLANT_DT, LOW_LEVEL_DT = 0.0005, 0.002


# --- soak ------------------------------------------------------------------------------------------------
def test_soak_streams_its_log_and_samples_the_memory(tmp_path):
    """0.3 s streamed and 0.18 s in memory, RSS every 0.1 s of simulated time: the JSON on disk is the
    result, the streamed log is complete and readable, and the growth figures follow from the samples."""
    log, output = tmp_path / "soak" / "log.npz", tmp_path / "soak.json"
    argv = ["--minutes", "0.005", "--compare-minutes", "0.003", "--nodes", "4", "--every", "0.1"]
    result = soak.main([*argv, "--log", str(log), "--output", str(output)])
    assert json.loads(output.read_text()) == json.loads(json.dumps(result))
    streamed, in_memory = result["runs"]
    assert streamed["streamed_log"] and not in_memory["streamed_log"]
    for run, seconds in ((streamed, 0.3), (in_memory, 0.18)):
        assert run["stopped_early"] is None
        assert abs(run["simulated_s"] - (seconds - LOW_LEVEL_DT)) < 1e-9  # the last logged low-level step
        assert run["summary"]["converged_fraction"] == 1.0 and not run["summary"]["fell"]
        t = np.array([s["t_sim_s"] for s in run["rss_samples"]])
        rss = np.array([s["rss_mb"] for s in run["rss_samples"]])
        assert t[0] == 0.0 and np.all(np.diff(t) >= 0.1 - 1e-9) and t[-1] < seconds
        assert len(t) == int(np.ceil(seconds / 0.1 - 1e-9)) and np.all(rss > 0)
        grown = run["rss_growth_after_first_minute"]  # shorter than a minute: measured from the start
        assert grown["growth_mb"] == pytest.approx(rss[-1] - rss[0])
        assert grown["max_above_start_mb"] == pytest.approx(rss.max() - rss[0])
    assert (
        result["streamed_growth_after_first_minute_mb"]
        == streamed["rss_growth_after_first_minute"]["growth_mb"]
    )
    assert result["within_target"] == (
        abs(result["streamed_growth_after_first_minute_mb"]) <= soak.TARGET_GROWTH_MB
    )
    run_log = load_log(log)
    assert not run_log.meta.get("partial") and not streamed["log_partial"]
    assert len(run_log["t"]) == round(0.3 / LOW_LEVEL_DT)
    np.testing.assert_allclose(np.diff(run_log["t"]), LOW_LEVEL_DT, rtol=0, atol=1e-12)


def test_soak_out_of_wall_time_keeps_a_partial_log(tmp_path):
    """A wall-time budget of 0 stops the streamed run at its first sample: the result says so and the
    streamed log on disk is marked partial (the run does not raise)."""
    log, output = tmp_path / "log.npz", tmp_path / "soak.json"
    argv = ["--minutes", "0.005", "--compare-minutes", "0", "--nodes", "4", "--max-wall-minutes", "0"]
    result = soak.main([*argv, "--log", str(log), "--output", str(output)])
    (run,) = result["runs"]
    assert run["stopped_early"].startswith("wall-time budget of 0 s used up") and run["log_partial"]
    assert load_log(log).meta["partial"]


# --- real time -------------------------------------------------------------------------------------------
def test_realtime_runs_a_variant_in_its_own_process(tmp_path):
    """One turn of the in-process variant on the generic BLASFEO (3 solves, the first discarded): the
    worker process honoured the variant (generic BLASFEO, the default layout's 1140 variables)."""
    output = tmp_path / "real_time.json"
    argv = ["--variant", "in-process, generic", "--rounds", "1", "--steps", "2", "--warmup", "1"]
    out = realtime.main([*argv, "--output", str(output)])
    assert json.loads(output.read_text()) == json.loads(json.dumps(out))
    result = out["variants"]["in-process, generic"]
    assert result["solves"] == 2 and result["converged_fraction"] == 1.0
    assert result["blasfeo"] == "generic" and result["decision_variables"] == 1140
    assert result["build_s"] is None and result["compile_flags"] is None  # nothing compiled
    assert 0 < result["median_ms"] <= result["max_ms"] and result["mean_ms"] == result["turn_means_ms"][0]
    assert 1.0 <= result["iterations_mean"] <= 30
    assert {"evaluations", "solver", "total"} <= set(result["profile_mean_ms"])


def test_realtime_interleaves_the_variants_and_pools_the_rounds(tmp_path, monkeypatch):
    """With the worker replaced by a stand-in: round after round every variant takes a turn, the solve times
    of the turns are pooled per variant, and the ratio to the baseline is of the pooled means."""
    calls = []

    def fake_turn(variant, steps, warmup, baseline):
        calls.append(variant)
        base = 10.0 if variant == "baseline compiled" else 4.0
        ms = base + np.arange(steps) + len(calls)  # distinct per turn
        return {
            "solve_ms": ms.tolist(),
            "mean_ms": float(ms.mean()),
            "iterations_mean": 3.0,
            "converged_fraction": 1.0,
            "profile_mean_ms": {"total": float(ms.mean())},
            "blasfeo": "generic",
            "decision_variables": 1140,
        }

    monkeypatch.setattr(realtime, "run_turn", fake_turn)
    checkout = tmp_path / "old"
    (checkout / "wbmpc").mkdir(parents=True)
    (checkout / "wbmpc" / "__init__.py").write_text("")
    variants = ["in-process, generic", "baseline compiled"]
    argv = [
        "--rounds",
        "2",
        "--steps",
        "3",
        "--baseline",
        str(checkout),
        "--output",
        str(tmp_path / "r.json"),
    ]
    out = realtime.main([*argv, *(a for v in variants for a in ("--variant", v))])
    assert calls == variants * 2
    ours, baseline = (out["variants"][v] for v in variants)
    pooled = np.concatenate([4.0 + np.arange(3) + 1, 4.0 + np.arange(3) + 3])  # turns 1 and 3
    assert ours["solves"] == 6 and ours["mean_ms"] == pytest.approx(pooled.mean())
    assert ours["p95_ms"] == pytest.approx(np.percentile(pooled, 95))
    assert ours["mean_ratio_to_baseline_compiled"] == pytest.approx(ours["mean_ms"] / baseline["mean_ms"])
    assert baseline["mean_ratio_to_baseline_compiled"] == 1.0


# --- sweeps on a scheduler started on its own --------------------------------------------------------------
def _wait_for(condition, what, timeout=120.0):
    """Poll ``condition()`` until true (a readiness wait for processes starting up, not a measurement)."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise RuntimeError(f"{what} did not come up within {timeout:.0f} s")
        time.sleep(0.2)


def _stop(process):
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(timeout=20)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=20)


@pytest.fixture
def external_scheduler(tmp_path):
    """A Dask scheduler and one worker (no nanny: the worker is the process started here) on 127.0.0.1,
    started as separate processes as on a cluster; both stopped afterwards. Yields (address, worker pid)."""
    scheduler_file = tmp_path / "scheduler.json"
    logs = {name: open(tmp_path / f"{name}.log", "w") for name in ("scheduler", "worker")}  # noqa: SIM115
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    common = ["--no-dashboard", "--scheduler-file", str(scheduler_file)]
    processes = []
    try:
        processes.append(
            subprocess.Popen(
                [sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port", "0"]
                + common
                + ["--idle-timeout", "300s"],  # gone by itself should the teardown never run
                stdout=logs["scheduler"],
                stderr=subprocess.STDOUT,
                env=env,
            )
        )
        _wait_for(scheduler_file.exists, "the scheduler")
        address = json.loads(scheduler_file.read_text())["address"]
        worker = subprocess.Popen(
            [sys.executable, "-m", "distributed.cli.dask_worker", "--host", "127.0.0.1", "--nthreads", "1"]
            + ["--no-nanny", "--name", "external-0", "--death-timeout", "60"]
            + common,
            stdout=logs["worker"],
            stderr=subprocess.STDOUT,
            env=env,
        )
        processes.append(worker)
        from distributed import Client

        with Client(address, timeout=60) as client:
            client.wait_for_workers(1, timeout=120)
        yield address, worker.pid
    finally:
        for process in reversed(processes):
            _stop(process)
        for f in logs.values():
            f.close()


def test_the_sweeps_command_line_runs_on_a_separately_started_scheduler(external_scheduler, tmp_path):
    """``python -m wbmpc.studies.sweeps demo --quick --scheduler tcp://...``: every case ran on the worker
    started here (its address and process id), none in this process or a local cluster of its own; run
    again, the table is resumed and nothing is recomputed."""
    address, worker_pid = external_scheduler
    table = tmp_path / "demo.csv"
    run = sweeps_cli.main(["demo", "--quick", "--scheduler", address, "--output", str(table), "--no-figures"])
    assert run.counts == {"ok": 4} and run.skipped == 0
    rows = read_table(table)
    assert sorted(r["x"] for r in rows) == [0, 1, 2, 3]
    for row in rows:
        assert row["y"] == 2 * row["x"] and row["error"] is None and row["status"] == "ok"
        assert row["pid"] == worker_pid != os.getpid()
        assert row["worker"].startswith("tcp://127.0.0.1:")
    again = sweeps_cli.main(
        ["demo", "--quick", "--scheduler", address, "--output", str(table), "--no-figures"]
    )
    assert again.skipped == 4 and not again.rows


def test_soak_growth_of_a_run_too_short_for_a_slope_is_valid_json():
    """One RSS sample: no slope (``None``, not NaN, which strict JSON refuses); no sample: a clear error."""
    import json

    one = soak.growth([{"t_sim_s": 0.0, "rss_mb": 100.0}])
    assert one["slope_mb_per_sim_minute"] is None and one["growth_mb"] == 0.0
    json.dumps(one, allow_nan=False)
    two = soak.growth([{"t_sim_s": 0.0, "rss_mb": 100.0}, {"t_sim_s": 30.0, "rss_mb": 101.0}])
    assert two["slope_mb_per_sim_minute"] == pytest.approx(2.0)  # 1 MB in half a simulated minute
    with pytest.raises(ValueError, match="at least one RSS sample"):
        soak.growth([])
