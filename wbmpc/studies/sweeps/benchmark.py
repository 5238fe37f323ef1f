"""Speed-up of the sweep engine over a serial loop, the machine's ceiling, the per-case overhead."""

from __future__ import annotations

import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

from wbmpc.studies.sweeps.cases import closed_loop_case, noop_case, warm_closed_loop_cache
from wbmpc.studies.sweeps.engine import (
    THREAD_ENV,
    _cores,
    _environ,
    execute,
    grid,
    local_cluster,
    run_sweep,
)

# --------------------------------------------------------------------------------------------- benchmark
BENCHMARK_CASE = "closed_loop_case: trot, rigid plant, 0.5 s, 15 nodes, compiled Fatrop"


def _warm(cases: list[dict]) -> None:
    """Build or load the libraries of ``cases`` and run one case: the first solve of a process loads the
    library and builds the MPC, which a sweep pays once per worker."""
    warm_closed_loop_cache(cases)
    execute(closed_loop_case, cases[0])


def _serial_pass(cases: list[dict]) -> list[float]:
    """Warm up this process, then run ``cases`` one after the other: wall time per case [s]."""
    _warm(cases)
    return [execute(closed_loop_case, c)["wall_s"] for c in cases]


def _concurrent_passes(cases: list[dict], processes: int) -> list[list[float]]:
    """``processes`` plain processes (no Dask) each running every case at the same time: what the
    machine itself gives when its cores all work (shared caches, memory, clock, other tenants)."""
    import concurrent.futures
    import multiprocessing

    with (
        _environ(THREAD_ENV),
        concurrent.futures.ProcessPoolExecutor(
            processes, mp_context=multiprocessing.get_context("spawn")
        ) as pool,
    ):
        return list(pool.map(_serial_pass, [cases] * processes))


def benchmark(path: str | Path, workers: int = 2, scheduler_cases: int = 200, progress: bool = False) -> dict:
    """Speed-up of a sweep over the serial loop on the same cases, the machine's own ceiling, and the
    per-case scheduling overhead.

    Sixteen :func:`closed_loop_case` runs (trot, 0.5 s, 15 nodes, compiled: about 3 s each) run in a
    serial loop in this process, then on a ``workers``-worker local cluster whose workers are warmed up
    first (problem built, library loaded: a sweep pays that once per worker, reported apart); then
    ``scheduler_cases`` :func:`noop_case` cases time the engine's own cost per case. The ceiling: the
    same cases in ``workers`` plain processes at once, each case timed against its serial time (a
    speed-up below ``workers`` with this ratio near 1 is Dask's; with this ratio above 1 it is the
    machine's). Writes the numbers as JSON to ``path``.
    """
    import numpy as np

    cases = grid(speed=[0.0, 0.1, 0.2, 0.3], yaw_rate=[0.0, 0.1, 0.2, 0.3], duration=[0.5])
    out = {"machine": {"cores": _cores(), "platform": platform.platform(), "python": sys.version.split()[0]}}
    out["machine"]["load_average_before"] = os.getloadavg()
    start = time.perf_counter()
    _warm(cases)
    out["warmup_s"] = time.perf_counter() - start
    start = time.perf_counter()
    serial = [execute(closed_loop_case, c) for c in cases]
    out["serial_s"] = time.perf_counter() - start
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        with local_cluster(workers) as client:
            startup = time.perf_counter() - start
            start = time.perf_counter()
            client.run(_warm, cases)  # on every worker
            worker_warmup = time.perf_counter() - start
            run = run_sweep(cases, closed_loop_case, Path(tmp, "cases.csv"), client=client, progress=progress)
            noop = run_sweep(
                grid(i=list(range(scheduler_cases))),
                noop_case,
                Path(tmp, "noop.csv"),
                client=client,
                progress=progress,
            )
        total = time.perf_counter() - start
    start = time.perf_counter()
    concurrent = _concurrent_passes(cases, workers)
    concurrent_s = time.perf_counter() - start
    import dask
    import distributed

    serial_case = np.array([r["wall_s"] for r in serial])
    parallel_case = np.array([r["wall_s"] for r in run.rows])
    contention = float(np.mean([np.sum(times) for times in concurrent]) / serial_case.sum())
    out |= {
        "versions": {"dask": dask.__version__, "distributed": distributed.__version__},
        "cases": len(cases),
        "case": BENCHMARK_CASE,
        "workers": workers,
        "serial_case_s": serial_case.tolist(),
        "parallel_case_s": parallel_case.tolist(),
        "statuses": run.counts,
        "cluster_startup_s": startup,
        "worker_warmup_s": worker_warmup,
        "parallel_s": run.wall_s,
        "parallel_with_startup_s": startup + worker_warmup + run.wall_s,
        "speedup": out["serial_s"] / run.wall_s,
        "speedup_with_startup": out["serial_s"] / (startup + worker_warmup + run.wall_s),
        # Busy share of the workers: below 1 by scheduling gaps and the tail of the last cases.
        "worker_utilisation": parallel_case.sum() / (workers * run.wall_s),
        # Each case's time in the sweep over its serial time: above 1 when cores slow each other down.
        "parallel_over_serial_case_time": parallel_case.sum() / serial_case.sum(),
        # The same with plain processes (no Dask): the machine's own slow-down with all cores busy.
        "concurrent_processes_over_serial_case_time": contention,
        "concurrent_processes_s": concurrent_s,
        "machine_ceiling_speedup": workers / contention,
        "speedup_over_machine_ceiling": out["serial_s"] / run.wall_s / (workers / contention),
        "noop_cases": scheduler_cases,
        "noop_total_s": noop.wall_s,
        "overhead_per_case_ms": 1e3 * noop.wall_s / scheduler_cases,
        "total_s": total,
    }
    out["machine"]["load_average_after"] = os.getloadavg()
    Path(path).write_text(json.dumps(out, indent=2))
    return out
