"""The sweep engine: grids of cases, the tidy table, running cases on Dask workers."""

from __future__ import annotations

import contextlib
import csv
import hashlib
import itertools
import json
import logging
import math
import os
import re
import tempfile
import time
import traceback
import uuid
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[3]
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
