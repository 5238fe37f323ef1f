"""Run logs in one documented columnar format, shared by simulation runs and (later) hardware logs.

A log is two tables of equal-length columns plus metadata:

* ``signals``: sampled at the low-level rate (500 Hz), time column ``t`` [s];
* ``solves``: one row per MPC solve, time column ``solve_t`` [s] (the measurement time of the solve) and
  ``apply_t`` [s] (when its plan reached the low level: later than ``solve_t`` with computation delay);
* ``meta``: JSON-serialisable run description (robot, joint and frame names, config, summary).

File format: a NumPy ``.npz`` archive (zip of ``.npy`` arrays, compressed), one array per column named
``signals/<column>`` or ``solves/<column>`` and a JSON string ``meta``. Why this format: every column is a
typed n-d array read without parsing (a 10 s run at 500 Hz loads in milliseconds), matrices per sample
(e.g. ``q`` (T, nq), ``foot_forces`` (T, 4, 3)) need no flattening, it needs nothing beyond NumPy, and any
tool that reads ``.npy`` (NumPy, Julia's NPZ.jl, MATLAB's npy readers) can open it. A hardware log converted
to the same columns is analysed by the same code (:func:`load_log`).

Streaming (long runs, :class:`LogWriter`): while a run goes on, its rows are written every chunk (e.g. 1 s
of simulated time) to ``<log>.npz.parts/chunk_000000.npz``, ``chunk_000001.npz``, ... (each chunk an
``.npz`` with the same column names, written to a temporary name and renamed, so a chunk on disk is always
complete) next to ``<log>.npz.parts/meta.json``; memory holds one chunk at most. At the end of the run, and
when it is interrupted (Ctrl-C or an exception: the rows so far are written, then the error goes on), the
chunks are consolidated into the single ``<log>.npz`` above, one column at a time streamed chunk by chunk
into the archive (peak memory: one chunk of one column), and the folder is removed. Extra ``meta`` keys of
streamed logs: ``partial`` (True if the run stopped before its end), ``t_reached`` (last sample time [s]),
``interrupted`` (what stopped it), ``chunks``. A ``.parts`` folder left by a killed process (never
consolidated) is read by :func:`load_log` too, given either the folder or the ``.npz`` path it was meant
for, and marked ``partial``; :func:`consolidate` turns it into the ``.npz``.

Errors name the file and the fix: a directory that is no ``.parts`` folder, a file that is not a ``.npz``
archive (its first bytes are checked; nothing is ever unpickled, and numpy's advice to load with
``allow_pickle`` is never passed on), a column of Python objects, a meta field of the wrong type
(:func:`check_meta`: ``format_version``, ``partial``, ``t_reached``, ``chunks``, ...), and, when writing, a
file where a folder of the path should be.

Columns written by :func:`wbmpc.sim.closed_loop.run_closed_loop` (units SI, world axes unless stated):

=====================  =========================================================================
``signals/t``          time [s] (T,)
``signals/q``, ``v``   true configuration (T, nq) and velocity (T, nv) (Pinocchio conventions)
``signals/q_meas``,    what the controller saw: noise and the 50 Hz joint-velocity filter applied
``signals/v_meas``
``signals/tau``        applied joint torques [N m] (T, nj) (after clipping)
``signals/tau_ff``     feed-forward part [N m] (T, nj)
``signals/contact_plan``  contact flags of the gait schedule (T, 4)
``signals/contact_sim``   feet touching the ground in the simulator (T, 4)
``signals/foot_forces``   ground reaction forces measured by the simulator [N] (T, 4, 3)
``signals/foot_height``   height of each foot sphere's bottom above the ground [m] (T, 4) (< 0: below it)
``signals/ee_position``   end-effector position [m] (T, 3); ``ee_reference`` its reference (NaN if none)
``signals/ee_force_sim``  force of the environment on the end effector measured by the simulator [N]
``signals/base_velocity_cmd``  commanded base linear velocity [m/s] (T, 3), heading frame
``signals/ee_force_cmd``  commanded end-effector force [N] (T, 3)
``solves/solve_time``  wall time of the solve [s]; ``iterations``; ``success``; ``fallback``;
                       ``violation`` (max constraint violation); ``status`` (named solver status,
                       :func:`wbmpc.solver.statuses.solver_status`); ``reason`` (why it failed)
``solves/plan_q``, ``plan_v``, ``plan_tau``, ``plan_forces``  first nodes of each plan (S, n, ...)
``solves/plan_contact``  stance flags the plan used on its first stage (S, 4)
``solves/hold``        the static hold was applied (no converged plan existed yet)
=====================  =========================================================================
"""

from __future__ import annotations

import json
import os
import shutil
import zipfile
import zlib
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

FORMAT_VERSION = 1
TABLES = (("signals", "t"), ("solves", "solve_t"))  # (table, its time column)
_NPY = np.lib.format


@dataclass
class RunLog:
    """A run's log: ``signals`` (low-level rate), ``solves`` (MPC rate) and ``meta``.

    Columns are reachable as ``log.signals["q"]`` or ``log["q"]`` (signals first, then solves).
    """

    signals: dict[str, np.ndarray] = field(default_factory=dict)
    solves: dict[str, np.ndarray] = field(default_factory=dict)
    meta: dict = field(default_factory=dict)

    def __getitem__(self, name: str) -> np.ndarray:
        if name in self.signals:
            return self.signals[name]
        if name in self.solves:
            return self.solves[name]
        raise KeyError(f"no column {name!r}; signals: {sorted(self.signals)}, solves: {sorted(self.solves)}")

    @property
    def duration(self) -> float:
        t = self.signals.get("t")
        return float(t[-1] - t[0]) if t is not None and t.size > 1 else 0.0

    @property
    def partial(self) -> bool:
        """The run stopped before its end (interrupted, or a streamed log never consolidated)."""
        return bool(self.meta.get("partial", False))

    def validate(self) -> None:
        """Check the tables: a time column each, equal lengths, finite times.

        Raises:
            ValueError: naming the offending column.
        """
        for table, time_key in ((self.signals, "t"), (self.solves, "solve_t")):
            if not table:
                continue
            if time_key not in table:
                raise ValueError(f"log table without its time column {time_key!r}")
            for name, column in table.items():
                if np.ndim(column) == 0:
                    raise ValueError(
                        f"column {name!r} is a scalar ({column!r}): every column needs one row per sample "
                        "(put single values in meta)"
                    )
            n = len(table[time_key])
            for name, column in table.items():
                if len(column) != n:
                    raise ValueError(f"column {name!r} has {len(column)} rows, {time_key!r} has {n}")
            times = np.asarray(table[time_key])
            if times.dtype.kind not in "iuf":
                raise ValueError(
                    f"time column {time_key!r} must hold numbers (seconds), got dtype {times.dtype}"
                )
            if not np.all(np.isfinite(times)):
                raise ValueError(f"time column {time_key!r} contains NaN or inf")
        check_meta(self.meta, "the log's meta")


def _npz_path(path: str | Path) -> Path:
    path = Path(path)
    return path if path.suffix == ".npz" else path.with_suffix(path.suffix + ".npz")


def parts_folder(path: str | Path) -> Path:
    """The chunk folder of a streamed log: ``<log>.npz.parts``."""
    path = _npz_path(path)
    return path.with_name(path.name + ".parts")


def _flat(log: RunLog) -> dict[str, np.ndarray]:
    arrays = {f"signals/{k}": np.asarray(v) for k, v in log.signals.items()}
    return arrays | {f"solves/{k}": np.asarray(v) for k, v in log.solves.items()}


def _meta_array(meta: dict) -> np.ndarray:
    return np.array(json.dumps({"format_version": FORMAT_VERSION, **meta}, default=json_default))


def save_log(log: RunLog, path: str | Path) -> Path:
    """Write ``log`` to ``path`` (``.npz`` appended if missing); returns the path."""
    log.validate()
    path = _npz_path(path)
    _make_parent(path, "log")
    if path.is_dir():
        raise IsADirectoryError(
            f"cannot write the log {path}: it is a folder; give a file name (e.g. {path / 'log.npz'})"
        )
    np.savez_compressed(path, **_flat(log), meta=_meta_array(log.meta))
    return path


def _make_parent(path: Path, what: str) -> None:
    """``mkdir -p`` of ``path``'s folder; if a file is in the way, say which one and what to do."""
    for ancestor in (path.parent, *path.parent.parents):
        if ancestor.exists():
            if not ancestor.is_dir():
                raise NotADirectoryError(
                    f"cannot write the {what} {path}: {ancestor} is a file, not a folder; "
                    f"choose an output path outside it, or move or remove {ancestor}"
                )
            break
    path.parent.mkdir(parents=True, exist_ok=True)


# meta fields wbmpc reads back: name -> (accepts the value, what it must be)
_META_FIELDS = {
    "format_version": (
        lambda v: _is_int(v) and v >= 0,
        f"an integer >= 0 (this wbmpc writes {FORMAT_VERSION})",
    ),
    "partial": (lambda v: isinstance(v, bool), "true or false"),
    "t_reached": (lambda v: v is None or _is_number(v), "a number of seconds or null"),
    "chunks": (lambda v: _is_int(v) and v >= 0, "an integer >= 0"),
    "interrupted": (lambda v: v is None or isinstance(v, str), "a string or null"),
    "summary": (lambda v: v is None or isinstance(v, dict), "an object or null"),
    "requested_duration_s": (lambda v: v is None or _is_number(v), "a number of seconds or null"),
    "joint_names": (
        lambda v: v is None or (isinstance(v, list | tuple) and all(isinstance(n, str) for n in v)),
        "a list of joint names",
    ),
}


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def check_meta(meta, where: str) -> None:
    """Check the type of each meta field wbmpc reads back (:data:`_META_FIELDS`).

    Raises:
        ValueError: naming the field, ``where`` it is and what it must be.
    """
    if not isinstance(meta, dict):
        raise ValueError(f"{where}: meta must be a dict, got {type(meta).__name__}")
    for name, (accepts, expected) in _META_FIELDS.items():
        if name in meta and not accepts(meta[name]):
            value = meta[name]
            raise ValueError(
                f"{where}: meta field {name!r} must be {expected}, got {value!r} ({type(value).__name__}); "
                f"fix that field (e.g. rewrite the log with wbmpc.io.logs.save_log from a RunLog whose "
                f"meta[{name!r}] has the right type)"
            )


def load_log(path: str | Path) -> RunLog:
    """Read a log written by :func:`save_log` or :class:`LogWriter` (or converted from hardware).

    ``path`` may also be a ``.parts`` folder of a streamed log that was never consolidated (the process was
    killed), or the ``.npz`` path it was meant for: the chunks are read and ``meta["partial"]`` is True.

    Raises:
        FileNotFoundError: if neither ``path`` nor its ``.parts`` folder exists.
        ValueError: if the file is truncated or corrupt, its ``meta`` entry is not JSON, or it is not a
            wbmpc log; the message names the file.
    """
    path = Path(path)
    if path.is_dir():
        if _is_parts_folder(path):
            return _load_parts(path)
        logs = sorted(p.name for p in path.glob("*.npz"))[:5]
        inside = f"logs in it: {', '.join(logs)}" if logs else "it holds no .npz log"
        raise IsADirectoryError(
            f"{path} is a directory, not a log file: give the path of a .npz log ({inside}) "
            "or of a streamed log's .parts folder"
        )
    if not path.exists():
        if parts_folder(path).is_dir():
            return _load_parts(parts_folder(path))
        raise FileNotFoundError(f"no log file at {path} (nor a streamed-log folder {parts_folder(path)})")
    _check_archive_head(path)
    try:
        with np.load(path, allow_pickle=False) as archive:
            if "meta" not in archive.files:
                raise ValueError(f"{path} is not a wbmpc log (no 'meta' entry)")
            meta = _parse_meta(str(_read_entry(archive, "meta", path)), f"{path} (entry 'meta')")
            log = RunLog(meta=meta)
            for key in archive.files:
                table, _, name = key.partition("/")
                if table == "signals":
                    log.signals[name] = _read_entry(archive, key, path)
                elif table == "solves":
                    log.solves[name] = _read_entry(archive, key, path)
    except (zipfile.BadZipFile, zlib.error, EOFError) as exc:
        raise ValueError(f"{path} is truncated or corrupt (not a complete .npz log): {_reason(exc)}") from exc
    except ValueError as exc:
        if str(path) in str(exc):
            raise
        raise ValueError(f"{path} is truncated or corrupt (not a complete .npz log): {_reason(exc)}") from exc
    check_meta(log.meta, str(path))
    if log.meta.get("format_version", 0) > FORMAT_VERSION:
        raise ValueError(
            f"{path} has format version {log.meta['format_version']}; this wbmpc reads up to {FORMAT_VERSION}"
            " (update wbmpc to read it)"
        )
    try:
        log.validate()
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from exc
    return log


def _is_parts_folder(path: Path) -> bool:
    """A streamed log's chunk folder: named ``*.parts`` or holding ``meta.json`` / ``chunk_*.npz``."""
    return path.suffix == ".parts" or (path / "meta.json").is_file() or bool(_chunk_files(path))


_ZIP_MAGIC, _NPY_MAGIC = b"PK", b"\x93NUMPY"


def _check_archive_head(path: Path) -> None:
    """Refuse, by its first bytes, a file that is not a ``.npz`` archive (never read as a pickle)."""
    with open(path, "rb") as f:
        head = f.read(8)
    if not head:
        raise ValueError(
            f"{path} is empty (0 bytes): the process writing it was probably killed before writing; "
            "re-run to write the log again, or remove the file"
        )
    if head.startswith(_NPY_MAGIC):
        raise ValueError(
            f"{path} is a single .npy array, not a .npz log: logs are .npz archives written by "
            "wbmpc.io.logs.save_log (one array per column plus a 'meta' entry)"
        )
    if not head.startswith(_ZIP_MAGIC):
        raise ValueError(
            f"{path} is not a .npz log: it does not start like a zip archive (first bytes {head!r}); it is "
            "corrupt or another kind of file. wbmpc never loads pickled data: re-write the log with "
            "wbmpc.io.logs.save_log"
        )


def _read_entry(archive, key: str, path: Path) -> np.ndarray:
    """One array of the archive; an object (pickled) array is refused by name, never unpickled."""
    try:
        return archive[key]
    except ValueError as exc:
        if "allow_pickle" in str(exc) or "pickle" in str(exc):
            raise ValueError(
                f"{path}: entry {key!r} holds Python objects (pickled data), which wbmpc logs never contain "
                "and never load: store that column as numbers or strings (np.asarray(values, dtype=float) "
                "or dtype=str) and re-write the log with wbmpc.io.logs.save_log"
            ) from None
        raise


def _reason(exc: BaseException) -> str:
    """numpy's error text without its advice to unpickle (a log is never loaded with allow_pickle)."""
    text = str(exc)
    if "pickle" in text:
        return "its contents are not valid .npz arrays"
    return text


def _parse_meta(text: str, where: str) -> dict:
    try:
        meta = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{where}: the meta entry is not valid JSON ({exc})") from exc
    if not isinstance(meta, dict):
        raise ValueError(f"{where}: the meta entry is JSON but not an object (got {type(meta).__name__})")
    return meta


# ---------------------------------------------------------------------------------------------- streaming
class LogWriter:
    """Streams a log to ``<path>.parts/`` in chunks and consolidates it into ``path`` (see the module doc).

    Args:
        path: The final ``.npz`` log (``.npz`` appended if missing). An existing log or chunk folder of the
            same name is removed first (they belong to an earlier run).
        meta: Metadata known at the start (written to ``meta.json`` at once, so a killed run keeps it).
    """

    def __init__(self, path: str | Path, meta: dict | None = None):
        self.path = _npz_path(path)
        self.parts = parts_folder(self.path)
        self.meta = dict(meta or {})
        self.chunks = 0
        self.t_reached: float | None = None
        self.closed = False
        if self.parts.exists():
            shutil.rmtree(self.parts)
        _make_parent(self.path, "log")
        if self.path.is_dir():
            raise IsADirectoryError(f"cannot write the log {self.path}: it is a folder; give a file name")
        self.path.unlink(missing_ok=True)
        self.parts.mkdir(parents=True)
        start = {"format_version": FORMAT_VERSION, **self.meta, "partial": True, "interrupted": _KILLED}
        (self.parts / "meta.json").write_text(json.dumps(start, default=json_default))

    def write_chunk(self, log: RunLog) -> Path | None:
        """Write the rows of ``log`` (one chunk) as the next chunk file; ``None`` if it has no rows."""
        log.validate()
        if not len(log.signals.get("t", ())) and not len(log.solves.get("solve_t", ())):
            return None
        target = self.parts / f"chunk_{self.chunks:06d}.npz"
        temporary = target.with_name(target.name + ".tmp")
        with open(temporary, "wb") as f:
            np.savez_compressed(f, **_flat(log))
        os.replace(temporary, target)  # a chunk on disk is always complete
        self.chunks += 1
        t = log.signals.get("t")
        if t is not None and len(t):
            self.t_reached = float(t[-1])
        return target

    def close(
        self,
        summarize: Callable[[Mapping[str, np.ndarray]], dict] | None = None,
        interrupted: str | None = None,
    ) -> dict:
        """Consolidate the chunks into the ``.npz`` log and remove the chunk folder.

        Args:
            summarize: ``f(columns) -> dict`` stored as ``meta["summary"]``; ``columns`` reads each column
                from the consolidated file when asked (:class:`LazyColumns`). If it raises on an
                interrupted run, the log is still written (``meta["summary_error"]`` says why).
            interrupted: What stopped the run early (``meta["partial"]`` is then True), or ``None``.

        Returns:
            The metadata written.
        """
        if self.closed:
            raise RuntimeError(f"log {self.path} is already closed")
        self.closed = True
        temporary = self.path.with_name(self.path.name + ".tmp")
        _write_columns(_scan_parts(self.parts), temporary)
        meta = {
            **self.meta,
            "partial": interrupted is not None,
            "t_reached": self.t_reached,
            "chunks": self.chunks,
        }
        if interrupted is not None:
            meta["interrupted"] = interrupted
        if summarize is not None:
            try:
                meta["summary"] = summarize(LazyColumns(temporary))
            except Exception as exc:  # noqa: BLE001 - an interrupted run's log matters more than its summary
                if interrupted is None:
                    temporary.unlink(missing_ok=True)
                    raise
                meta["summary"], meta["summary_error"] = None, f"{type(exc).__name__}: {exc}"
        _append_meta(temporary, meta)
        os.replace(temporary, self.path)
        shutil.rmtree(self.parts)
        return {"format_version": FORMAT_VERSION, **meta}


_KILLED = "the process ended before the streamed log was consolidated (killed?)"


class LazyColumns(Mapping):
    """Columns of an ``.npz`` log by name (signals first, then solves), each read from disk when asked.

    Nothing is cached, so memory holds only the columns the caller keeps.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        with zipfile.ZipFile(self.path) as archive:
            names = [n.removesuffix(".npy") for n in archive.namelist()]
        self._keys = {}
        for table in ("solves", "signals"):  # signals win a name clash, as in RunLog.__getitem__
            self._keys |= {n.partition("/")[2]: n for n in names if n.startswith(table + "/")}

    def __getitem__(self, name: str) -> np.ndarray:
        with np.load(self.path, allow_pickle=False) as archive:
            return archive[self._keys[name]]

    def __iter__(self) -> Iterator[str]:
        return iter(self._keys)

    def __len__(self) -> int:
        return len(self._keys)


def _chunk_files(parts: Path) -> list[Path]:
    return sorted(parts.glob("chunk_*.npz"))


@dataclass
class _Column:
    """Where one column's rows are: (chunk file, rows) pieces, and its consolidated row shape and dtype."""

    pieces: list = field(default_factory=list)
    row_shape: tuple | None = None
    dtypes: list = field(default_factory=list)
    empty: tuple | None = None  # (shape, dtype) of a zero-row piece, for columns that never get rows

    @property
    def rows(self) -> int:
        return sum(n for _, n in self.pieces)

    @property
    def dtype(self) -> np.dtype:
        return np.result_type(*self.dtypes) if self.dtypes else np.dtype(self.empty[1])


def _scan_parts(parts: Path) -> dict[str, _Column]:
    """Read the array headers of every chunk (no data) and plan the consolidated columns.

    A column keeps only if its rows add up to its table's time column (as :meth:`RunLog.validate` wants).
    """
    columns: dict[str, _Column] = {}
    for chunk in _chunk_files(parts):
        try:
            with zipfile.ZipFile(chunk) as archive:
                for info in archive.infolist():
                    key = info.filename.removesuffix(".npy")
                    with archive.open(info) as f:
                        version = _NPY.read_magic(f)
                        read = _NPY.read_array_header_1_0 if version == (1, 0) else _NPY.read_array_header_2_0
                        shape, _, dtype = read(f)
                    column = columns.setdefault(key, _Column())
                    if not shape or shape[0] == 0:
                        column.empty = column.empty or (shape, dtype)
                        continue
                    if column.row_shape is not None and column.row_shape != shape[1:]:
                        raise ValueError(
                            f"{chunk}: column {key!r} has rows of shape {shape[1:]}, "
                            f"earlier chunks {column.row_shape}"
                        )
                    column.row_shape = shape[1:]
                    column.dtypes.append(dtype)
                    column.pieces.append((chunk, shape[0]))
        except (zipfile.BadZipFile, zlib.error, EOFError) as exc:
            raise ValueError(f"chunk {chunk} of a streamed log is truncated or corrupt: {exc}") from exc
    keep = {}
    for table, time_key in TABLES:
        time_column = columns.get(f"{table}/{time_key}")
        if time_column is None:
            continue
        n = time_column.rows
        keep |= {k: c for k, c in columns.items() if k.startswith(table + "/") and c.rows == n}
    return keep


def _write_columns(columns: dict[str, _Column], path: Path) -> None:
    """Write the planned columns to a compressed ``.npz``, one column at a time, one chunk piece at a time."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, allowZip64=True) as archive:
        for key, column in columns.items():
            dtype = column.dtype
            shape = (column.rows, *column.row_shape) if column.pieces else column.empty[0]
            header = {"descr": _NPY.dtype_to_descr(dtype), "fortran_order": False, "shape": shape}
            with archive.open(f"{key}.npy", "w", force_zip64=True) as out:
                _NPY.write_array_header_2_0(out, header)
                for chunk, _ in column.pieces:
                    with np.load(chunk, allow_pickle=False) as piece:
                        out.write(np.ascontiguousarray(piece[key], dtype=dtype).tobytes())


def _load_parts_meta(parts: Path) -> dict:
    """The metadata of a never-consolidated streamed log: ``meta.json``, partial, time reached, chunks."""
    meta_file = parts / "meta.json"
    meta = _parse_meta(meta_file.read_text(), str(meta_file)) if meta_file.exists() else {}
    check_meta(meta, str(meta_file))
    meta["partial"] = True
    meta.setdefault("interrupted", _KILLED)
    chunks = _chunk_files(parts)
    meta["chunks"] = len(chunks)
    meta["t_reached"] = None
    for chunk in reversed(chunks):
        with np.load(chunk, allow_pickle=False) as piece:
            if "signals/t" in piece.files and piece["signals/t"].size:
                meta["t_reached"] = float(piece["signals/t"][-1])
                break
    return meta


def _load_parts(parts: Path) -> RunLog:
    """A never-consolidated streamed log, read into memory and marked partial."""
    log = RunLog(meta=_load_parts_meta(parts))
    for key, column in _scan_parts(parts).items():
        if column.pieces:
            arrays = []
            for chunk, _ in column.pieces:
                with np.load(chunk, allow_pickle=False) as piece:
                    arrays.append(piece[key])
            value = np.concatenate(arrays).astype(column.dtype, copy=False)
        else:
            value = np.zeros(column.empty[0], column.empty[1])
        table, _, name = key.partition("/")
        (log.signals if table == "signals" else log.solves)[name] = value
    log.validate()
    return log


def consolidate(path: str | Path) -> Path:
    """Turn the ``.parts`` folder a killed run left into its ``.npz`` log (marked partial); returns the path.

    Args:
        path: The ``.parts`` folder or the ``.npz`` log it was meant for.
    """
    path = Path(path)
    path = path.with_suffix("") if path.suffix == ".parts" else _npz_path(path)
    parts = parts_folder(path)
    if not parts.is_dir():
        raise FileNotFoundError(f"no streamed-log folder {parts}")
    meta = _load_parts_meta(parts)
    temporary = path.with_name(path.name + ".tmp")
    _write_columns(_scan_parts(parts), temporary)
    _append_meta(temporary, meta)
    os.replace(temporary, path)
    shutil.rmtree(parts)
    return path


def _append_meta(path: Path, meta: dict) -> None:
    with zipfile.ZipFile(path, "a", compression=zipfile.ZIP_DEFLATED, allowZip64=True) as archive:
        with archive.open("meta.npy", "w") as f:
            _NPY.write_array(f, _meta_array(meta), allow_pickle=False)


def json_default(value):
    """``json.dumps`` fallback for NumPy arrays and scalars and paths (anything else: its repr)."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    return repr(value)
