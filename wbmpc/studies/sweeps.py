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


# ----------------------------------------------- PyBullet studies: robustness, payload, nodes, time steps
# The experiments' settings (wbmpc.studies.experiments): PyBullet at 2 kHz, MPC at 80 Hz, compiled Fatrop with
# 15 nodes (quick: in-process, 10 nodes), 500 Hz interpolation, pure feed-forward torques, ground truth.
_ROBOT: dict = {}  # per worker process: the B1 + Z1 model (the experiments' MPC cache is keyed by it)
ROBUSTNESS_MAGNITUDES = tuple(round(0.1 * i, 1) for i in range(11))  # 0 to 1.0 m/s
ROBUSTNESS_PHASES = tuple(i / 8 for i in range(8))  # fractions of the trot period after a lift-off
DIRECTIONS = {"lateral": (0.0, 1.0, 0.0), "forward": (1.0, 0.0, 0.0)}
# Sensor noise of the seeded cases: encoders, a state estimator's base errors (std per channel).
NOISE = {
    "joint_position": 1e-3,
    "joint_velocity": 0.05,
    "base_position": 2e-3,
    "base_orientation": 2e-3,
    "base_velocity": 0.02,
}


def _experiment_setup(case: dict, **mpc_kwargs):
    """(experiments module, robot, nodes, MPC config) for a PyBullet case (``quick``, ``nodes``, ``compiled``
    override the experiments' defaults: compiled with 15 nodes, quick in-process with 10)."""
    from dataclasses import replace

    from wbmpc.model.robot import load_b1_z1
    from wbmpc.studies import experiments as ex

    if "robot" not in _ROBOT:
        _ROBOT["robot"] = load_b1_z1()
    quick, robot, nodes, config = ex._setup(bool(case.get("quick", False)), _ROBOT["robot"], **mpc_kwargs)
    nodes = int(case.get("nodes", nodes))
    if "compiled" in case:
        config = replace(config, compiled=bool(case["compiled"]))
    # MPC options a case may switch (comparisons)
    for name in ("kick_recovery", "kick_recovery_phase", "kick_recovery_hold", "kick_ee_release"):
        if name in case and hasattr(config, name):
            config = replace(config, **{name: case[name]})
    return ex, robot, nodes, config


def _sensor(case: dict):
    """Sensor noise of a case: none for ``seed`` None or negative, else :data:`NOISE` with that seed."""
    from wbmpc.sim.sensing import SensorNoise

    seed = case.get("seed")
    if seed is None or seed < 0:
        return None
    return SensorNoise(**NOISE, seed=int(seed))


def _delay(case: dict):
    delay = case.get("delay", 0.0)
    return "off" if delay in (None, 0, 0.0, "off") else delay


def _solver_results(result) -> dict:
    s = result.summary
    diagnostics = s.get("diagnostics") or {}
    return {
        "converged_fraction": s["converged_fraction"],
        "fallbacks": s["fallbacks"],
        "iterations_mean": s["iterations_mean"],
        "iterations_max": s["iterations_max"],
        "solve_ms_median": s["solve_ms"]["median"],
        "solve_ms_p95": s["solve_ms"]["p95"],
        "failure_reasons": diagnostics.get("failure_reasons") or {},
        "sim_duration_s": s["duration_s"],
    }


def robustness_case(case: dict) -> dict:
    """A base kick while trotting in place in PyBullet (as ``experiments.robustness_sweep``).

    Parameters read (defaults): ``magnitude`` [m/s] of the velocity kick (a
    :class:`~wbmpc.sim.disturbances.Kick`), ``direction`` ("lateral": world +y, "forward": +x), ``phase``
    (fraction of the 0.8 s trot period after the FR/RL pair's lift-off at ``lift_off`` [s]; 0.5: the FL/RR
    pair's), ``lift_off`` (1.2: the first FR/RL lift-off after 1.5 periods from the standing start; the same
    pair lifts off every 0.8 s, e.g. 2.0 as in experiment 2),
    ``delay`` (0: off, else seconds of fixed computation delay), ``seed`` (None: ground truth, else
    :data:`NOISE` with that seed, and the 50 Hz joint-velocity filter), ``quick`` (False: compiled solver;
    True: in-process), ``nodes`` (15), ``after`` [s] simulated after the kick (full 2.0, quick 0.5),
    ``kick_recovery``, ``kick_recovery_phase``, ``kick_recovery_hold``, ``kick_ee_release`` (the MPC's
    defaults; None switches the abort or the end-effector release off).

    Results: ``fell``, ``max_tilt_rad``, peak base speed along the kick, ``recovery_time_s`` (speed along the
    kick below 0.1 m/s for good, ``None`` if never), lateral/forward displacement, peak calf torque over its
    limit after the kick (all four calves, applied torques, and the plan's first-node torques), solver
    numbers, and the MPC's swing aborts.
    """
    import numpy as np
    import pinocchio as pin

    from wbmpc.sim.disturbances import Kick

    # 15 nodes in quick mode too (in-process): a 10-node horizon (0.37 s) falls short of the swing it aborts.
    ex, robot, nodes, config = _experiment_setup({"nodes": 15, **case}, gait=_trot())
    quick = bool(case.get("quick", False))
    magnitude = float(case.get("magnitude", 0.8))
    direction = np.asarray(DIRECTIONS[case.get("direction", "lateral")])
    t0 = float(case.get("lift_off", 1.2))  # an FR/RL lift-off (every 0.8 s from 1.2 s)
    if abs((t0 - 1.2) / ex.GAIT_PERIOD - round((t0 - 1.2) / ex.GAIT_PERIOD)) > 1e-9 or t0 < 1.2 - 1e-9:
        raise ValueError(f"lift_off = {t0} s is not an FR/RL lift-off (1.2 s + k 0.8 s)")
    t_kick = t0 + float(case.get("phase", 0.0)) * ex.GAIT_PERIOD
    after = float(case.get("after", 0.5 if quick else 2.0))
    noise = _sensor(case)
    loop = ex._base_loop(
        duration=t_kick + after,
        disturbances=(Kick(t_kick, tuple(magnitude * direction)),) if magnitude > 0 else (),
        delay=_delay(case),
        sensor_noise=noise,
        velocity_cutoff_hz=50.0 if noise is not None else None,
    )
    mpc = ex._mpc(robot, nodes, config)
    mpc.verbose = False
    aborts_before = mpc.stats.get("swing_aborts", 0)
    result = ex.run_closed_loop(mpc, loop, progress=False)
    a = result.log.arrays()
    t = a["t"]
    v_world = np.array(
        [pin.Quaternion(q[3:7]).toRotationMatrix() @ v[:3] for q, v in zip(a["q"], a["v"], strict=True)]
    )
    along = v_world @ direction
    after_kick = t >= t_kick
    calves = [i for i, n in enumerate(robot.joint_names) if "calf" in n]
    limits = robot.joint_torque_limits[calves]
    slow = np.abs(along) < 0.1
    recovery = None
    if after_kick.any() and not result.fell:
        # the first time after the kick from which the speed along the kick stays below 0.1 m/s
        fast = np.nonzero(after_kick & ~slow)[0]
        last_fast = fast[-1] if fast.size else np.nonzero(after_kick)[0][0] - 1
        if last_fast + 1 < len(t):
            recovery = float(t[last_fast + 1] - t_kick)
    solve_t = np.asarray(a["solve_t"])
    plan_tau = np.asarray(a["plan_tau"])
    planned = plan_tau[solve_t >= t_kick][:, calves] if plan_tau.size else np.zeros((0, len(calves)))
    k0 = np.nonzero(after_kick)[0][0] if after_kick.any() else len(t)
    return {
        "fell": bool(result.fell),
        "max_tilt_rad": result.summary["max_tilt_rad"],
        "peak_speed_along_kick": float(np.max(np.abs(along[after_kick]))) if after_kick.any() else None,
        "recovery_time_s": recovery,
        "displacement_along_kick_m": float((a["q"][-1, :3] - a["q"][k0 - 1 if k0 else 0, :3]) @ direction),
        "calf_torque_ratio": float(np.max(np.abs(a["tau"][after_kick][:, calves]) / limits))
        if after_kick.any()
        else None,
        "calf_torque_ratio_plan": float(np.max(np.abs(planned) / limits)) if planned.size else None,
        "swing_aborts": int(mpc.stats.get("swing_aborts", 0) - aborts_before),
        "t_kick": t_kick,
        **_solver_results(result),
    }


def _trot():
    from wbmpc.ocp.gait import make_gait
    from wbmpc.studies.experiments import GAIT_PERIOD

    return make_gait("trot", GAIT_PERIOD)


def warm_experiment_cache(cases: list[dict]) -> None:
    """Warm-up of the PyBullet studies: build (or load) the compiled library of each horizon once."""
    from wbmpc.solver import codegen

    for nodes in sorted({int(_experiment_setup(c)[2]) for c in cases if _experiment_setup(c)[3].compiled}):
        _, robot, _, config = _experiment_setup({"nodes": nodes})
        from wbmpc.ocp import OCP, OCPSettings

        codegen.build(OCP(robot, OCPSettings(n_nodes=nodes)), tuple(config.compile_flags), progress=False)


def _robustness_study(quick: bool) -> list[dict]:
    if quick:  # the lift-off kick and a mid-swing one, both directions at 0.8 m/s, no delay, no noise
        return grid(
            magnitude=[0.8], direction=["lateral", "forward"], phase=[0.0, 0.25], delay=[0.0], seed=[None],
            quick=[True],
        )  # fmt: skip
    return grid(
        magnitude=list(ROBUSTNESS_MAGNITUDES),
        direction=list(DIRECTIONS),
        phase=list(ROBUSTNESS_PHASES),
        delay=[0.0, 0.0125],
        seed=[0, 1, 2],
    )


def payload_case(case: dict) -> dict:
    """Pull a tethered sliding load (``experiments.pulling_load``): ``mass`` [kg], ``walking`` (trot
    backwards at 0.1 m/s; False: stand, the arm pulls back at 5 cm/s), ``quick``. Success: no fall and the
    load moves at least half the commanded displacement."""
    ex, robot, nodes, config = _experiment_setup(case)
    quick = bool(case.get("quick", False))
    mass = float(case.get("mass", 10.0))
    walking = bool(case.get("walking", True))
    result, force = ex._pull_run(robot, nodes, config, quick, mass, walking, progress=False)
    report = ex._pull_report(result, walking, mass, force)
    report.pop("mass_kg", None)
    report.pop("walking", None)
    return {
        **report,
        "commanded_force_n": [float(f) for f in report["commanded_force_n"]],
        **_solver_results(result),
    }


def _payload_study(quick: bool) -> list[dict]:
    if quick:
        return grid(mass=[10.0], walking=[False, True], quick=[True])
    return grid(mass=[float(m) for m in range(10, 32, 2)], walking=[False, True])


def nodes_case(case: dict) -> dict:
    """Arm tracking while trotting at 0.2 m/s (``experiments.arm_tracking``) with ``nodes`` nodes, the same
    10-100 ms geometric steps: solve time and tracking. ``duration`` [s] (full 4.0, quick 0.6), ``quick``."""
    from wbmpc.control.arm_task import ArmReference

    ex, robot, nodes, config = _experiment_setup(case, gait=_trot())
    quick = bool(case.get("quick", False))
    loop = ex._base_loop(
        duration=float(case.get("duration", 0.6 if quick else 4.0)),
        base_velocity=(0.2, 0.0, 0.0),
        arm_reference=ArmReference(ramp=0.3 if quick else 1.0),
    )
    mpc = ex._mpc(robot, nodes, config)
    mpc.verbose = False
    result = ex.run_closed_loop(mpc, loop, progress=False)
    s = result.summary
    return {
        "fell": bool(result.fell),
        "max_tilt_rad": s["max_tilt_rad"],
        "ee_rms_cm": None if s["ee_rms_m"] is None else 100 * s["ee_rms_m"],
        "ee_max_error_cm": None if s["ee_max_error_m"] is None else 100 * s["ee_max_error_m"],
        "speed_m_per_s": s["distance_travelled_m"] / max(s["duration_s"], 1e-9),
        "solve_ms_mean": s["solve_ms"]["mean"],
        "horizon_s": float(sum(mpc.time_steps())),
        **_solver_results(result),
    }


def _nodes_study(quick: bool) -> list[dict]:
    if quick:
        return grid(nodes=[5, 8], quick=[True])
    return grid(nodes=[5, 10, 15, 20, 25, 30])


def time_steps_case(case: dict) -> dict:
    """Base drift trotting in place with computation delay (``experiments.time_steps_drift``): ``grid``
    ("adaptive": geometric 10-100 ms, "uniform": the same horizon in equal steps, 40 ms with the default 15
    nodes; quick: 10 nodes), ``delay`` [s]
    (0: off), ``seed`` (sensor noise, None: ground truth), Kd = 5, 50 Hz velocity filter; ``duration``
    (full 10 s, quick 0.6 s)."""
    from dataclasses import replace

    import numpy as np

    from wbmpc.ocp.time_grid import geometric_time_steps

    ex, robot, _, config = _experiment_setup(case, gait=_trot())
    quick = bool(case.get("quick", False))
    nodes = int(case.get("nodes", 10 if quick else 15))
    uniform = float(sum(geometric_time_steps(nodes, 0.01, 0.1))) / (nodes - 1)  # same horizon (N = 15: 40 ms)
    dt_min, dt_max = {"adaptive": (0.01, 0.1), "uniform": (uniform, uniform)}[case.get("grid", "adaptive")]
    config = replace(config, dt_min=dt_min, dt_max=dt_max)
    loop = ex._base_loop(
        duration=float(case.get("duration", 0.6 if quick else 10.0)),
        kd=5.0,
        delay=_delay(case),
        velocity_cutoff_hz=50.0,
        sensor_noise=_sensor(case),
    )
    mpc = ex._mpc(robot, nodes, config)
    mpc.verbose = False
    result = ex.run_closed_loop(mpc, loop, progress=False)
    q = result.log.arrays()["q"]
    d = result.summary["duration_s"] or 1.0
    return {
        "fell": bool(result.fell),
        "drift_cm_per_s": float(100 * np.linalg.norm(q[-1, :2] - q[0, :2]) / d),
        "drift_x_cm": float(100 * (q[-1, 0] - q[0, 0])),
        "drift_y_cm": float(100 * (q[-1, 1] - q[0, 1])),
        "max_tilt_rad": result.summary["max_tilt_rad"],
        "horizon_s": float(sum(mpc.time_steps())),
        **_solver_results(result),
    }


def _time_steps_study(quick: bool) -> list[dict]:
    if quick:
        return grid(grid=["adaptive", "uniform"], delay=[0.0125], seed=[0], quick=[True])
    return grid(grid=["adaptive", "uniform"], delay=[0.0, 0.0125, 0.025, 0.05], seed=[0, 1, 2])


# ------------------------------------------------------------------------------------------ study figures
def robustness_figures(rows: list[dict], directory: str | Path) -> list[Path]:
    """Heatmaps of a robustness table over kick magnitude x gait phase: survival (mean over seeds) and the
    peak calf torque over its limit, one figure per direction (rows: delays; columns: the two). A table that
    compares the swing abort on and off (a ``kick_recovery`` column with numbers and empty cells, empty
    meaning off) gets one figure per setting: ``robustness_<direction>[_recovery_off|_recovery_<value>].png``.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    done = [r for r in rows if r["status"] in ("ok", "fell")]
    settings = sorted({r.get("kick_recovery") for r in done}, key=str)
    compare = len(settings) > 1
    paths = []
    for direction in sorted({r.get("direction", "lateral") for r in done}):
        for setting in settings:
            mine = [
                r
                for r in done
                if r.get("direction", "lateral") == direction and r.get("kick_recovery") == setting
            ]
            if not mine:
                continue
            suffix = "" if not compare else "_recovery_off" if setting is None else f"_recovery_{setting:g}"
            tag = "" if not compare else ", swing abort off" if setting is None else ", swing abort on"
            delays = sorted({r.get("delay") or 0.0 for r in mine})
            n_m, n_p = len({r["magnitude"] for r in mine}), len({r["phase"] for r in mine})
            fig = Figure(figsize=(2 * (1.8 + 0.75 * n_p), 0.9 + (1.0 + 0.4 * n_m) * len(delays)))
            fig.set_layout_engine("constrained")
            axes = fig.subplots(len(delays), 2, squeeze=False)
            for i, delay in enumerate(delays):
                cell = [r for r in mine if (r.get("delay") or 0.0) == delay]
                label = "no delay" if not delay else f"delay {1e3 * delay:g} ms"
                heatmap(cell, lambda r: float(r["status"] == "ok"), x="phase", y="magnitude", ax=axes[i, 0],
                        cmap="RdYlGn", title=f"survival, {label}")  # fmt: skip
                heatmap(cell, "calf_torque_ratio", x="phase", y="magnitude", ax=axes[i, 1], cmap="magma",
                        title=f"peak calf torque / limit, {label}")  # fmt: skip
                for ax in axes[i]:
                    ax.images[0].set_clim(0.0, 1.0)
                    ax.title.set_fontsize(9)
                    ax.set(xlabel="gait phase of the kick", ylabel="kick [m/s]")
            fig.suptitle(f"{direction} kick while trotting in place{tag}", fontsize=10)
            path = directory / f"robustness_{direction}{suffix}.png"
            fig.savefig(path, dpi=110)
            paths.append(path)
    return paths


def robustness_report(rows: list[dict], up_to: float = 0.8) -> dict:
    """Survival rates of a robustness table: overall, up to ``up_to`` m/s, per magnitude, at the lift-offs."""
    done = [r for r in rows if r["status"] in ("ok", "fell")]

    def rate(sel):
        return None if not sel else sum(r["status"] == "ok" for r in sel) / len(sel)

    return {
        "cases": len(done),
        "errors": len(rows) - len(done),
        "survival": rate(done),
        f"survival_up_to_{up_to:g}": rate([r for r in done if r["magnitude"] <= up_to + 1e-9]),
        "survival_lift_off": rate([r for r in done if r["phase"] in (0.0, 0.5)]),
        "survival_by_magnitude": {
            f"{m:g}": rate([r for r in done if r["magnitude"] == m])
            for m in sorted({r["magnitude"] for r in done})
        },
        "survival_by_direction": {
            d: rate([r for r in done if r.get("direction") == d])
            for d in sorted({r.get("direction") for r in done})
        },
        "survival_by_direction_and_magnitude": {
            f"{d} {m:g}": rate([r for r in done if r.get("direction") == d and r["magnitude"] == m])
            for d in sorted({r.get("direction") for r in done})
            for m in sorted({r["magnitude"] for r in done if r.get("direction") == d})
        },
        # lift_off: the FR/RL lift-off the phases count from (rows without the column: 1.2 s)
        "survival_by_lift_off": {
            f"{lo:g}": rate([r for r in done if (r.get("lift_off") or 1.2) == lo])
            for lo in sorted({r.get("lift_off") or 1.2 for r in done})
        },
        "falls": sorted(
            [
                (r.get("direction"), r["magnitude"], r["phase"], r.get("delay"), r.get("seed"))
                for r in done
                if r["status"] == "fell"
            ],
            key=str,
        ),  # fmt: skip
    }


def time_steps_summary(rows: list[dict]) -> list[dict]:
    """Per grid and delay: runs, falls, and the base drift [cm/s] of the runs that stood (mean, std, min,
    max over the seeds), sorted by delay then grid."""
    import numpy as np

    out = []
    keys = sorted({(float(r["delay"]), r["grid"]) for r in rows if r.get("grid") is not None})
    for delay, g in keys:
        mine = [r for r in rows if r.get("grid") == g and float(r["delay"]) == delay]
        stood = [
            float(r["drift_cm_per_s"])
            for r in mine
            if not r.get("fell") and r.get("drift_cm_per_s") is not None
        ]
        out.append(
            {
                "grid": g,
                "delay_ms": 1e3 * delay,
                "runs": len(mine),
                "fell": sum(bool(r.get("fell")) for r in mine),
                "drift_mean": float(np.mean(stood)) if stood else None,
                "drift_std": float(np.std(stood, ddof=1)) if len(stood) > 1 else None,
                "drift_min": min(stood) if stood else None,
                "drift_max": max(stood) if stood else None,
            }
        )
    return out


def time_steps_figures(rows: list[dict], directory: str | Path) -> list[Path]:
    """Base drift over delay, adaptive vs uniform grid: mean and min-max over the seeds of the runs that
    stood; a delay where runs fell is marked with how many."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import numpy as np
    from matplotlib.figure import Figure

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    fig = Figure(figsize=(5.5, 3.2), layout="constrained")
    ax = fig.subplots()
    summary = time_steps_summary(rows)
    for i, g in enumerate(("adaptive", "uniform")):
        mine = [s for s in summary if s["grid"] == g]
        stood = [s for s in mine if s["drift_mean"] is not None]
        if stood:
            x = np.array([s["delay_ms"] for s in stood]) + (i - 0.5) * 0.8  # side by side
            mean = np.array([s["drift_mean"] for s in stood])
            err = [mean - [s["drift_min"] for s in stood], np.array([s["drift_max"] for s in stood]) - mean]
            ax.errorbar(x, mean, yerr=err, marker="o", capsize=3, label=g, color=f"C{i}")
        for s in mine:
            if s["fell"]:
                ax.annotate(
                    f"{g}: {s['fell']}/{s['runs']} fell", (s["delay_ms"], 0.05 + 0.1 * i),
                    xycoords=("data", "axes fraction"), ha="center", fontsize=7, color=f"C{i}",
                )  # fmt: skip
    if summary:
        delays = [s["delay_ms"] for s in summary]
        ax.set_xlim(min(delays) - 4, max(delays) + 8)
    ax.set(xlabel="computation delay [ms]", ylabel="base drift [cm/s]", title="Adaptive vs uniform steps")
    ax.legend(fontsize=8)
    path = directory / "time_steps.png"
    fig.savefig(path, dpi=110)
    return [path]


def _xy_figure(rows: list[dict], x: str, ys: tuple[str, ...], name: str, directory: str | Path, by=None):
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    fig = Figure(figsize=(5.5, 2.2 * len(ys)), layout="constrained")
    axes = fig.subplots(len(ys), 1, squeeze=False)[:, 0]
    groups = sorted({r.get(by) for r in rows}, key=str) if by else [None]
    for ax, y in zip(axes, ys, strict=True):
        for g in groups:
            mine = sorted(
                [r for r in rows if (by is None or r.get(by) == g) and r.get(y) is not None],
                key=lambda r: r[x],
            )
            ax.plot(
                [r[x] for r in mine], [float(r[y]) for r in mine], "o-", label=f"{by}={g}" if by else None
            )
        ax.set(xlabel=x, ylabel=y)
        if by:
            ax.legend(fontsize=8)
    path = directory / f"{name}.png"
    fig.savefig(path, dpi=110)
    return [path]


def payload_figures(rows: list[dict], directory: str | Path) -> list[Path]:
    """Load displacement and success over the load mass, standing and walking."""
    return _xy_figure(rows, "mass", ("load_displacement_m", "success"), "payload", directory, by="walking")


def nodes_figures(rows: list[dict], directory: str | Path) -> list[Path]:
    """Solve time and end-effector tracking over the node count."""
    return _xy_figure(rows, "nodes", ("solve_ms_median", "ee_rms_cm", "iterations_mean"), "nodes", directory)


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


# name -> (cases(quick), case function, warm-up)
STUDIES = {
    "demo": (_demo_study, demo_case, None),
    "closed_loop": (_closed_loop_study, closed_loop_case, warm_closed_loop_cache),
    "robustness": (_robustness_study, robustness_case, warm_experiment_cache),
    "payload": (_payload_study, payload_case, warm_experiment_cache),
    "nodes": (_nodes_study, nodes_case, warm_experiment_cache),
    "time_steps": (_time_steps_study, time_steps_case, warm_experiment_cache),
}
# name -> f(rows, directory) -> figure paths, drawn after the sweep (CLI) into data/output/sweeps/
FIGURES = {
    "robustness": robustness_figures,
    "payload": payload_figures,
    "nodes": nodes_figures,
    "time_steps": time_steps_figures,
}
# Full runs of these studies write their tables to data/results/sweeps/ (committed summaries).
RESULT_STUDIES = ("robustness", "payload", "nodes", "time_steps")


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
    parser.add_argument("--figures", type=Path, help="figure folder (default data/output/sweeps)")
    parser.add_argument("--no-figures", action="store_true", help="do not draw the study's figures")
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
    folder = (
        "data/results/sweeps" if args.study in RESULT_STUDIES and not args.quick else "data/output/sweeps"
    )
    output = args.output or REPO_ROOT / folder / f"{args.study}{'_quick' if args.quick else ''}.csv"
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
    if args.study in module.FIGURES and not args.no_figures:
        rows = read_table(output)
        for path in module.FIGURES[args.study](rows, args.figures or REPO_ROOT / "data/output/sweeps"):
            print(f"figure: {path}")
        if args.study == "robustness":
            print(json.dumps(module.robustness_report(rows), indent=2))
    return run


if __name__ == "__main__":
    main()
