"""Parameter sweeps on Dask ``distributed``: a grid of cases, one function per case, a tidy CSV table.

A sweep is a list of cases (dicts of parameters, each with a stable ``case_id``, see :func:`grid`) and a
*case function*: a module-level function that takes one case dict and returns a flat dict of results. The
function runs on the workers of a Dask cluster (a :class:`distributed.LocalCluster` with one single-threaded
worker process per core by default, or an existing cluster given by its scheduler address) and every
finished case becomes one row of a CSV table, appended as soon as it completes:

``case_id, <parameters>, <results>, status, error, wall_s, worker``

``status`` is ``"ok"``, ``"fell"`` (the results say ``fell=True``), ``"error"`` (the case raised; ``error``
holds the message) or ``"worker-died"`` (the worker process running the case exited or crashed, e.g.
``os._exit`` or a segfault; the nanny restarts it and the sweep goes on). A case is never retried: the local
scheduler runs with ``allowed-failures=0`` and the tasks with ``retries=0``, so a crashing case kills one
worker once instead of three. Re-running a sweep with the same table skips the cases already in it
(resume); rows cut short by an interrupted write are dropped and rerun.

Example::

    from wbmpc.studies.sweeps import closed_loop_case, grid, heatmap, read_table, run_sweep
    from wbmpc.studies.sweeps import warm_closed_loop_cache

    cases = grid(speed=[0.0, 0.2], yaw_rate=[0.0, 0.2], duration=[0.5])
    run_sweep(cases, closed_loop_case, "data/output/sweeps/trot.csv", warmup=warm_closed_loop_cache)
    heatmap(read_table("data/output/sweeps/trot.csv"), "max_tilt_rad", x="speed", y="yaw_rate")

On an existing cluster (``dask scheduler`` + ``dask worker --nthreads 1`` on each machine, with wbmpc
installed and the same code): pass ``scheduler="tcp://HOST:8786"`` (CLI ``--scheduler``). Start that
scheduler with ``DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES=0`` (as :func:`local_cluster` does), or a
crashing case is retried on up to three workers before it is recorded; the workers should run with
``OMP_NUM_THREADS=1`` etc. The client keeps no more cases in flight than the cluster has worker threads:
the scheduler fails every task assigned to a worker that dies, so no case waits on a worker behind another.

The compiled solver: :func:`wbmpc.solver.codegen.build` serialises builds of one key with a file lock in
the cache
folder, so workers sharing that folder never build the same library twice; ``warmup`` (e.g.
:func:`warm_closed_loop_cache`) runs once on one worker before the cases are submitted, so the library is
built once while no case waits on the lock with a worker tied up.

CLI: ``python -m wbmpc.studies.sweeps --help``.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import hashlib
import itertools
import json
import logging
import math
import os
import platform
import re
import sys
import tempfile
import time
import traceback
import uuid
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]
ID = "case_id"
META = ("status", "error", "wall_s", "worker")
STATUSES = ("ok", "fell", "error", "worker-died")
# One BLAS/OpenMP thread per worker: the workers already fill the cores, nested threads only oversubscribe.
THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
_MAX_ERROR_CHARS = 500


# --------------------------------------------------------------------------------------------------- cases
def _plain(value):
    """A JSON/CSV-friendly scalar: numpy scalars to Python, tuples to lists."""
    if hasattr(value, "item") and callable(value.item) and getattr(value, "ndim", 0) == 0:
        return value.item()
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    return value


def case_id(params: dict) -> str:
    """Stable id of a case: a hash of its parameters (names and values, any order; ``case_id`` ignored).

    Args:
        params: The case's parameters (JSON-serialisable scalars).

    Returns:
        12 hexadecimal characters, the same in every process and on every machine.
    """
    canonical = {k: _plain(v) for k, v in params.items() if k != ID}
    text = json.dumps(canonical, sort_keys=True, separators=(",", ":"), default=repr)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def grid(**axes) -> list[dict]:
    """All combinations of the given parameter values, as case dicts with their ``case_id``.

    Example: ``grid(magnitude=[0.4, 0.8], phase=[0.0, 0.25], seed=[0])`` gives 4 cases such as
    ``{"case_id": "…", "magnitude": 0.4, "phase": 0.0, "seed": 0}`` (the last axis varies fastest).

    Args:
        **axes: Parameter name to a list of values (a single scalar or string is one value).

    Returns:
        The cases.
    """
    names = list(axes)
    values = [
        list(v) if isinstance(v, Iterable) and not isinstance(v, str | bytes | dict) else [v]
        for v in axes.values()
    ]
    cases = []
    for combo in itertools.product(*values):
        params = {name: _plain(value) for name, value in zip(names, combo, strict=True)}
        cases.append({ID: case_id(params), **params})
    ids = Counter(c[ID] for c in cases)
    if len(ids) != len(cases):
        raise ValueError(
            f"repeated parameter values give repeated cases: {[i for i, n in ids.items() if n > 1]}"
        )
    return cases


# --------------------------------------------------------------------------------------------------- table
def _parse(text: str | None):
    """Inverse of the CSV writer for the scalars a row holds (``""`` is ``None``)."""
    if text is None or text == "":
        return None
    if text in ("True", "False"):
        return text == "True"
    if re.fullmatch(r"[-+]?\d+", text):
        return int(text)
    if "_" not in text:  # float() accepts "1_0", which would not write back as the same text
        with contextlib.suppress(ValueError):
            return float(text)
    return text


def _read(path: Path) -> tuple[list[str], list[dict], int]:
    """Columns, complete rows and number of broken rows (cut short by an interrupted write) of a table."""
    if not path.is_file() or path.stat().st_size == 0:
        return [], [], 0
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        columns = list(reader.fieldnames or [])
        rows, broken = [], 0
        for raw in reader:
            if None in raw or None in raw.values() or raw.get("status") not in STATUSES:
                broken += 1
                continue
            rows.append({k: _parse(v) for k, v in raw.items()})
    return columns, rows, broken


def read_table(path: str | Path) -> list[dict]:
    """The rows of a sweep table (parsed back to ``int``, ``float``, ``bool``, ``str`` or ``None``).

    Args:
        path: The CSV file (missing: no rows).
    """
    return _read(Path(path))[1]


def _columns(rows: list[dict], columns: Iterable[str] = ()) -> list[str]:
    """``case_id``, then parameters and results in first-seen order, then the bookkeeping columns."""
    seen = dict.fromkeys([ID, *columns])
    for row in rows:
        seen.update(dict.fromkeys(row))
    return [ID] + [c for c in seen if c != ID and c not in META] + list(META)


def write_table(path: str | Path, rows: list[dict], columns: Iterable[str] = ()) -> Path:
    """Write ``rows`` as a sweep table, atomically (a reader never sees half a table).

    Args:
        path: The CSV file.
        rows: Row dicts (missing cells are written empty).
        columns: Columns to keep first, in this order (e.g. the current header).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    with os.fdopen(fd, "w", newline="") as f:
        writer = csv.DictWriter(f, _columns(rows, columns), restval="")
        writer.writeheader()
        writer.writerows(rows)
    os.replace(tmp, path)
    return path


class _Appender:
    """Appends rows to a table one at a time; rewrites it when a row brings new columns."""

    def __init__(self, path: Path, columns: list[str]):
        self.path, self.columns = path, columns

    def append(self, row: dict) -> None:
        if self.columns and set(row) <= set(self.columns):
            with open(self.path, "a", newline="") as f:
                csv.DictWriter(f, self.columns, restval="").writerow(row)
            return
        _, rows, _ = _read(self.path)
        write_table(self.path, [*rows, row], self.columns)
        self.columns = _columns([*rows, row], self.columns)


# --------------------------------------------------------------------------------------- worker side
def _message(exc: BaseException) -> str:
    text = " ".join("".join(traceback.format_exception_only(type(exc), exc)).split())
    return text[:_MAX_ERROR_CHARS]


def _worker_name() -> str:
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):  # not on a Dask worker (a serial loop)
        return f"local:{os.getpid()}"


def _flat(results, case: dict) -> dict:
    """The case function's results as CSV cells; nested values become JSON text."""
    if results is None:
        return {}
    if not isinstance(results, dict):
        raise TypeError(f"a case function must return a dict, got {type(results).__name__}")
    flat = {}
    for key, value in results.items():
        key = str(key)
        if key in case or key in META:
            raise ValueError(f"result {key!r} has the name of a parameter or of a table column")
        value = _plain(value)
        if isinstance(value, list | dict) or hasattr(value, "tolist"):
            value = json.dumps(value.tolist() if hasattr(value, "tolist") else value)
        flat[key] = value
    return flat


def execute(fn: Callable[[dict], dict], case: dict) -> dict:
    """Run one case and return its table row; an exception becomes an ``"error"`` row (never raised).

    This is what runs on a worker; it also serves a serial loop (``[execute(fn, c) for c in cases]``).

    Args:
        fn: The case function.
        case: The case dict (with ``case_id``).
    """
    start = time.perf_counter()
    try:
        results = _flat(fn(dict(case)), case)
        status, error = ("fell" if results.get("fell") is True else "ok"), ""
    except (Exception, SystemExit) as exc:  # recorded in the table; the sweep goes on
        results, status, error = {}, "error", _message(exc)
    wall = time.perf_counter() - start
    return {
        **case,
        **results,
        "status": status,
        "error": error,
        "wall_s": round(wall, 4),
        "worker": _worker_name(),
    }


# --------------------------------------------------------------------------------------- client side
@contextlib.contextmanager
def _environ(values: dict[str, str]) -> Iterator[None]:
    """Set environment variables for the duration of the block, then restore the previous values."""
    old = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


@contextlib.contextmanager
def local_cluster(workers: int | None = None, silence_logs: int = logging.CRITICAL):
    """A :class:`distributed.Client` on a new ``LocalCluster``, closed on exit.

    One worker process per core (``workers`` overrides), one thread each, BLAS/OpenMP pinned to one thread
    (:data:`THREAD_ENV`, set before the worker processes start), no dashboard (no port to collide with),
    ``allowed-failures=0`` so that a case that kills its worker is not run again, and ``worker-saturation=1``
    so that a worker holds only the case it runs (a worker's death fails every task assigned to it).

    Args:
        workers: Number of worker processes (default: the cores this process may use).
        silence_logs: Log level of the cluster's loggers (a dying worker logs errors; the table records it).
    """
    import dask
    from distributed import Client, LocalCluster

    # Dask lets the client's environment override pre-spawn-environ; set it while the nannies start.
    pre_spawn = {**dask.config.get("distributed.nanny.pre-spawn-environ"), **THREAD_ENV}
    config = {
        "distributed.nanny.pre-spawn-environ": pre_spawn,
        "distributed.scheduler.allowed-failures": 0,
        # One task on a worker at a time (run_sweep also limits the cases in flight to the threads).
        "distributed.scheduler.worker-saturation": 1.0,
    }
    with _environ(THREAD_ENV), dask.config.set(config):
        cluster = LocalCluster(
            n_workers=workers or _cores(),
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=silence_logs,
            scheduler_kwargs={"allowed_failures": 0},
            env=THREAD_ENV,
        )
    with cluster, Client(cluster) as client:
        yield client


@contextlib.contextmanager
def connect(scheduler: str | None = None, workers: int | None = None, client=None):
    """The client a sweep runs on: ``client`` as is, a client of ``scheduler``, or a new local cluster.

    Args:
        scheduler: Address of an existing scheduler, e.g. ``"tcp://HOST:8786"``.
        workers: Worker processes of the local cluster (ignored with ``scheduler`` or ``client``).
        client: An open :class:`distributed.Client` (left open).
    """
    if client is not None:
        yield client
    elif scheduler:
        from distributed import Client

        with Client(scheduler) as remote:
            yield remote
    else:
        with local_cluster(workers) as local:
            yield local


@dataclass
class SweepRun:
    """What a call of :func:`run_sweep` did.

    Attributes:
        path: The table.
        rows: The rows this call added, in completion order.
        skipped: Number of cases already in the table (not run).
        wall_s: Wall time of the call [s] (cluster start included).
    """

    path: Path
    rows: list[dict] = field(default_factory=list)
    skipped: int = 0
    wall_s: float = 0.0

    @property
    def counts(self) -> dict[str, int]:
        """Rows of this call by status."""
        return dict(Counter(r["status"] for r in self.rows))


def _failure_row(case: dict, exc: BaseException) -> dict:
    from distributed import KilledWorker

    if isinstance(exc, KilledWorker):
        worker = getattr(exc.last_worker, "address", str(exc.last_worker))
        message = "the worker process died while running the case (exit, crash or memory limit)"
        return {**case, "status": "worker-died", "error": message, "wall_s": None, "worker": worker}
    return {**case, "status": "error", "error": _message(exc), "wall_s": None, "worker": None}


def run_sweep(
    cases: Iterable[dict],
    fn: Callable[[dict], dict],
    output: str | Path,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    client=None,
    warmup: Callable[[list[dict]], object] | None = None,
    resume: bool = True,
    retry_failed: bool = False,
    progress: bool = True,
) -> SweepRun:
    """Run ``fn`` on every case not yet in the table ``output``, appending one row per case as it finishes.

    Args:
        cases: Case dicts (from :func:`grid`; a case without ``case_id`` gets one).
        fn: Module-level case function (workers import it by name): ``fn(case) -> flat dict``. A result
            ``fell=True`` gives status ``"fell"``.
        output: The CSV table (created, or extended).
        scheduler: Address of an existing Dask scheduler; default: a new local cluster.
        workers: Worker processes of the local cluster (default: one per core).
        client: An open :class:`distributed.Client` to use (e.g. several sweeps on one cluster).
        warmup: Module-level ``warmup(pending_cases)`` run once on one worker before the cases (e.g. build
            the compiled solver); if it raises, nothing is submitted and the error propagates.
        resume: Skip cases whose id is in the table; ``False`` starts a new table.
        retry_failed: With ``resume``, run again the cases recorded as ``"error"`` or ``"worker-died"``.
        progress: Show a tqdm progress bar.

    Returns:
        The rows added, the number skipped and the wall time.
    """
    from distributed import as_completed
    from tqdm.auto import tqdm

    start = time.perf_counter()
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    cases = [c if ID in c else {ID: case_id(c), **c} for c in cases]
    columns, rows, broken = _read(output) if resume else ([], [], 0)
    if retry_failed:
        rows = [r for r in rows if r["status"] in ("ok", "fell")]
    if broken or retry_failed or not resume:
        write_table(output, rows, columns)  # drop broken or failed rows; a fresh table for resume=False
        columns = _columns(rows, columns)
    done = {r[ID] for r in rows}
    pending = list({c[ID]: c for c in cases if c[ID] not in done}.values())  # a repeated case runs once
    run = SweepRun(output, skipped=len({c[ID] for c in cases} & done))
    if pending:
        table = _Appender(output, columns)
        with connect(scheduler, workers, client) as cl:
            if warmup is not None:
                cl.submit(warmup, pending, pure=False, retries=0).result()
            tag = uuid.uuid4().hex[:6]  # keys unique per call: no clash with an earlier sweep's futures
            queue, futures, finished = iter(pending), {}, as_completed()
            threads = {"n": 0, "at": -math.inf}

            def submit_more(refresh: bool = False):
                # No more cases in flight than worker threads: a worker's death fails every task assigned
                # to it, so a case must not wait on a worker behind another one. Never none in flight.
                # The thread count is asked again after a death and at most every 0.5 s (a round trip).
                if refresh or time.monotonic() - threads["at"] > 0.5:
                    threads.update(n=sum(cl.nthreads().values()), at=time.monotonic())
                room = threads["n"] - len(futures)
                for case in itertools.islice(queue, max(room, 0 if futures else 1)):
                    future = cl.submit(execute, fn, case, key=f"case-{case[ID]}-{tag}", pure=False, retries=0)
                    futures[future] = case
                    finished.add(future)

            bar = tqdm(total=len(pending), desc=f"sweep {output.stem}", unit="case", disable=not progress)
            try:
                submit_more()
                for future in finished:
                    case = futures.pop(future)
                    try:
                        row = future.result()
                    except Exception as exc:  # KilledWorker, a lost connection, an unpicklable result
                        row = _failure_row(case, exc)
                    future.release()
                    submit_more(refresh=row["status"] == "worker-died")
                    table.append(row)
                    run.rows.append(row)
                    bar.update()
                    bar.set_postfix(run.counts, refresh=False)
            finally:
                bar.close()
                cl.cancel(list(futures))  # on an interrupt: the finished rows are in the table already
    run.wall_s = time.perf_counter() - start
    return run


# --------------------------------------------------------------------------------------------------- figure
def heatmap(
    rows: list[dict],
    value: str | Callable[[dict], float],
    x: str,
    y: str,
    *,
    agg: Callable | None = None,
    ax=None,
    cmap: str = "viridis",
    title: str | None = None,
    annotate: bool = True,
):
    """Heatmap of a result over two parameters (other parameters, e.g. seeds, are aggregated).

    Rows without the value (failed cases) are left out; a cell with no value is grey. Example: success rate
    over a robustness grid: ``heatmap(rows, lambda r: r["status"] == "ok", x="phase", y="magnitude")``.

    Args:
        rows: Table rows (:func:`read_table`).
        value: A column name, or a function of a row giving a number (``None``: no value).
        x, y: Parameter columns of the horizontal and vertical axes.
        agg: Aggregation of the values of one cell (default: mean).
        ax: Axes to draw into (default: a new figure).
        cmap: Colour map.
        title: Axes title (default: the value's name).
        annotate: Write each cell's value.

    Returns:
        The matplotlib figure.
    """
    import matplotlib.pyplot as plt
    import numpy as np

    get = value if callable(value) else (lambda row: row.get(value))
    agg = agg or np.mean

    def key(v):
        return (isinstance(v, str), v if not isinstance(v, str) else str(v))

    xs = sorted({r[x] for r in rows}, key=key)
    ys = sorted({r[y] for r in rows}, key=key)
    cells = {}
    for row in rows:
        v = get(row)
        if v is not None and not (isinstance(v, float) and math.isnan(v)):
            cells.setdefault((row[y], row[x]), []).append(float(v))
    table = np.full((len(ys), len(xs)), np.nan)
    for i, yv in enumerate(ys):
        for j, xv in enumerate(xs):
            if (yv, xv) in cells:
                table[i, j] = agg(cells[(yv, xv)])
    if ax is None:
        fig, ax = plt.subplots(figsize=(1.2 + 0.9 * len(xs), 1.0 + 0.6 * len(ys)), layout="constrained")
    else:
        fig = ax.figure
    colours = plt.get_cmap(cmap).with_extremes(bad="lightgrey")
    image = ax.imshow(np.ma.masked_invalid(table), cmap=colours, origin="lower", aspect="auto")
    fig.colorbar(image, ax=ax)
    ax.set_xticks(range(len(xs)), [f"{v:g}" if isinstance(v, float) else str(v) for v in xs])
    ax.set_yticks(range(len(ys)), [f"{v:g}" if isinstance(v, float) else str(v) for v in ys])
    name = value if isinstance(value, str) else getattr(value, "__name__", "value")
    ax.set(xlabel=x, ylabel=y, title=title or name)
    if annotate:
        for (i, j), v in np.ndenumerate(table):
            if not np.isnan(v):
                ax.text(j, i, f"{v:.3g}", ha="center", va="center", fontsize=8, color="white")
    return fig


# ------------------------------------------------------------------------------------------ case functions
def noop_case(case: dict) -> dict:
    """Does nothing: times the scheduling overhead of a sweep."""
    return {}


def demo_case(case: dict) -> dict:
    """A trivial case for tests and demonstrations.

    Parameters read: ``x`` (number, result ``y = 2 x``), ``action`` (``"raise"``: a ValueError, ``"exit"``:
    the process exits (``os._exit(1)``), ``"segfault"``: a null-pointer read, ``"fall"``: ``fell=True``),
    ``sleep`` [s].
    """
    time.sleep(case.get("sleep", 0.0))
    action = case.get("action")
    if action == "raise":
        raise ValueError(f"case {case[ID]} raised on purpose")
    if action == "exit":
        os._exit(1)
    if action == "segfault":
        import ctypes

        ctypes.string_at(0)
    return {
        "y": 2 * case.get("x", 0),
        "fell": action == "fall",
        "pid": os.getpid(),
        **{k.lower(): os.environ.get(k) for k in THREAD_ENV},
    }


def build_case(case: dict) -> dict:
    """Build (or load) the compiled NLP of a small B1 problem in ``case["cache_dir"]`` (cache sharing tests).

    Results: ``rebuilt`` (this call compiled the library), ``key``, ``build_s``.
    """
    from wbmpc.model.robot import load_b1
    from wbmpc.ocp import OCP, OCPSettings
    from wbmpc.solver import codegen

    ocp = OCP(load_b1(), OCPSettings(n_nodes=case.get("nodes", 3), n_tau_nodes=1))
    built = codegen.build(ocp, ("-O0",), directory=case["cache_dir"], progress=False)
    return {"rebuilt": built.rebuilt, "key": built.key, "build_s": built.build_s}


def warm_build_cache(cases: list[dict]) -> None:
    """Warm-up of :func:`build_case`: build each distinct library of the cases once."""
    for params in {(c["cache_dir"], c.get("nodes", 3)) for c in cases}:
        build_case({ID: "warmup", "cache_dir": params[0], "nodes": params[1]})


_MPCS: dict = {}  # per worker process: building the problem and loading the solver take seconds


def _closed_loop_mpc(nodes: int, compiled: bool):
    from wbmpc.control.mpc import MPCConfig, WholeBodyMPC
    from wbmpc.model.robot import load_b1_z1
    from wbmpc.ocp import OCPSettings

    key = (nodes, compiled)
    if key not in _MPCS:
        _MPCS[key] = WholeBodyMPC(load_b1_z1(), OCPSettings(n_nodes=nodes), MPCConfig(compiled=compiled))
        _MPCS[key].verbose = False
    return _MPCS[key]


def closed_loop_case(case: dict) -> dict:
    """A short closed-loop run on the rigid plant (the benchmark case of the sweep engine).

    Parameters read (defaults): ``gait`` ("trot"), ``speed`` (0.0 m/s forward), ``yaw_rate`` (0.0 rad/s),
    ``duration`` (0.5 s), ``nodes`` (15), ``compiled`` (True: the cached Fatrop library).
    """
    from dataclasses import replace

    from wbmpc.ocp.gait import make_gait
    from wbmpc.sim.closed_loop import ClosedLoopConfig, run_closed_loop

    mpc = _closed_loop_mpc(case.get("nodes", 15), case.get("compiled", True))
    mpc.config = replace(mpc.config, gait=make_gait(case.get("gait", "trot"), 0.8))
    mpc.reset()
    config = ClosedLoopConfig(
        duration=case.get("duration", 0.5),
        plant="rigid",
        arm_reference=None,
        base_velocity=(case.get("speed", 0.0), 0.0, 0.0),
        base_yaw_rate=case.get("yaw_rate", 0.0),
    )
    result = run_closed_loop(mpc, config, progress=False)
    s = result.summary
    return {
        "fell": bool(result.fell),
        "max_tilt_rad": s["max_tilt_rad"],
        "solve_ms_mean": s["solve_ms"]["mean"],
        "iterations_mean": s["iterations_mean"],
        "converged_fraction": s["converged_fraction"],
        "sim_duration_s": s["duration_s"],
    }


def warm_closed_loop_cache(cases: list[dict]) -> None:
    """Warm-up of :func:`closed_loop_case`: build the compiled library of each horizon once."""
    from wbmpc.solver import codegen

    for nodes in sorted({c.get("nodes", 15) for c in cases if c.get("compiled", True)}):
        mpc = _closed_loop_mpc(nodes, True)
        mpc.compiled_nlp = codegen.build(mpc.ocp, tuple(mpc.config.compile_flags), progress=False)


# --------------------------------------------------------------------------------------------- benchmark
def benchmark(path: str | Path, workers: int = 2, scheduler_cases: int = 200, progress: bool = False) -> dict:
    """Speed-up of a sweep over the serial loop on the same cases, and the per-case scheduling overhead.

    Eight :func:`closed_loop_case` runs (trot, 0.5 s, 15 nodes, compiled: a few seconds each) run first in a
    serial loop in this process, then on a ``workers``-worker local cluster; then ``scheduler_cases``
    :func:`noop_case` cases time the engine's own cost per case. Writes the numbers as JSON to ``path``.
    """
    cases = grid(speed=[0.0, 0.1, 0.2, 0.3], yaw_rate=[0.0, 0.2], duration=[0.5])
    out = {"machine": {"cores": _cores(), "platform": platform.platform(), "python": sys.version.split()[0]}}
    out["machine"]["load_average_before"] = os.getloadavg()
    start = time.perf_counter()
    warm_closed_loop_cache(cases)
    out["warmup_s"] = time.perf_counter() - start
    start = time.perf_counter()
    serial = [execute(closed_loop_case, c) for c in cases]
    out["serial_s"] = time.perf_counter() - start
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        with local_cluster(workers) as client:
            startup = time.perf_counter() - start
            run = run_sweep(cases, closed_loop_case, Path(tmp, "cases.csv"), client=client, progress=progress)
            noop = run_sweep(
                grid(i=list(range(scheduler_cases))),
                noop_case,
                Path(tmp, "noop.csv"),
                client=client,
                progress=progress,
            )
        total = time.perf_counter() - start
    import dask
    import distributed

    out |= {
        "versions": {"dask": dask.__version__, "distributed": distributed.__version__},
        "cases": len(cases),
        "case": "closed_loop_case: trot, rigid plant, 0.5 s, 15 nodes, compiled Fatrop",
        "workers": workers,
        "serial_case_s": [r["wall_s"] for r in serial],
        "parallel_case_s": [r["wall_s"] for r in run.rows],
        "statuses": run.counts,
        "cluster_startup_s": startup,
        "parallel_s": run.wall_s,
        "parallel_with_startup_s": startup + run.wall_s,
        "speedup": out["serial_s"] / run.wall_s,
        "speedup_with_startup": out["serial_s"] / (startup + run.wall_s),
        # Busy share of the workers: below 1 by scheduling gaps; a speed-up below `workers` with a high
        # utilisation means each case ran slower in parallel (shared cores, memory bandwidth, other load).
        "worker_utilisation": sum(r["wall_s"] for r in run.rows) / (workers * run.wall_s),
        "parallel_over_serial_case_time": sum(r["wall_s"] for r in run.rows)
        / sum(r["wall_s"] for r in serial),
        "noop_cases": scheduler_cases,
        "noop_total_s": noop.wall_s,
        "overhead_per_case_ms": 1e3 * noop.wall_s / scheduler_cases,
        "total_s": total,
    }
    out["machine"]["load_average_after"] = os.getloadavg()
    Path(path).write_text(json.dumps(out, indent=2))
    return out


# --------------------------------------------------------------------------------------------------- CLI
def _closed_loop_study(quick: bool) -> list[dict]:
    if quick:
        return grid(speed=[0.0, 0.2], duration=[0.5])
    return grid(speed=[0.0, 0.1, 0.2, 0.3], yaw_rate=[0.0, 0.2], duration=[2.0])


def _demo_study(quick: bool) -> list[dict]:
    return grid(x=list(range(4 if quick else 20)), sleep=[0.1])


# name -> (cases(quick), case function, warm-up); the robustness, payload and node sweeps plug in here.
STUDIES = {
    "demo": (_demo_study, demo_case, None),
    "closed_loop": (_closed_loop_study, closed_loop_case, warm_closed_loop_cache),
}


def main(argv: list[str] | None = None) -> SweepRun | dict:
    """Command line: run a study (a grid, a case function) as a sweep, or the engine's benchmark."""
    parser = argparse.ArgumentParser(
        prog="python -m wbmpc.studies.sweeps",
        description="Run a parameter sweep on Dask: one row per case in a CSV table, resumable.",
    )
    parser.add_argument("study", nargs="?", default="demo", choices=sorted(STUDIES), help="what to sweep")
    parser.add_argument("--scheduler", help="address of an existing Dask scheduler (tcp://HOST:PORT)")
    parser.add_argument("--workers", type=int, help="worker processes of the local cluster (default: cores)")
    parser.add_argument("--output", type=Path, help="CSV table (default data/output/sweeps/<study>.csv)")
    parser.add_argument("--quick", action="store_true", help="a small grid and short runs")
    parser.add_argument("--no-resume", action="store_true", help="start a new table")
    parser.add_argument("--retry-failed", action="store_true", help="rerun the error and worker-died cases")
    parser.add_argument(
        "--benchmark", type=Path, metavar="JSON", help="measure speed-up and overhead instead"
    )
    args = parser.parse_args(argv)
    # Under ``-m`` this module is __main__: hand the workers functions of the importable module instead.
    module = sys.modules.get("wbmpc.studies.sweeps") or __import__("wbmpc.studies.sweeps", fromlist=["main"])
    if args.benchmark:
        result = module.benchmark(args.benchmark, workers=args.workers or 2, progress=True)
        print(json.dumps({k: v for k, v in result.items() if not isinstance(v, list | dict)}, indent=2))
        return result
    make_cases, fn, warmup = module.STUDIES[args.study]
    output = args.output or REPO_ROOT / "data/output/sweeps" / f"{args.study}.csv"
    run = module.run_sweep(
        make_cases(args.quick),
        fn,
        output,
        scheduler=args.scheduler,
        workers=args.workers,
        warmup=warmup,
        resume=not args.no_resume,
        retry_failed=args.retry_failed,
    )
    print(f"{output}: {len(run.rows)} cases run {run.counts}, {run.skipped} skipped, {run.wall_s:.1f} s")
    return run


if __name__ == "__main__":
    main()
