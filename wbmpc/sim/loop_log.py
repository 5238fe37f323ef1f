"""The closed loop's record: the per-tick and per-solve columns, streamed to disk or kept in memory, and the
run's result (:class:`ClosedLoopResult`: the log, the summary, whether the robot fell).
"""

from __future__ import annotations

import shutil
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from wbmpc.io.logs import LogWriter, RunLog, load_log, save_log


@dataclass
class ClosedLoopLog:
    """Time series of a run (low-level rate) and per-solve records (MPC rate).

    Held in memory by default. A streamed log (:meth:`streaming`) writes its rows to disk every
    ``chunk_steps`` plant steps (:class:`wbmpc.io.logs.LogWriter`) and empties its lists, per-solve
    ``timings`` included (``plans`` are not kept); after the run :attr:`path` is the consolidated ``.npz``
    log, and :meth:`arrays` and :meth:`run_log` read it from there.
    """

    t: list = field(default_factory=list)
    q: list = field(default_factory=list)
    v: list = field(default_factory=list)
    tau: list = field(default_factory=list)
    tau_ff: list = field(default_factory=list)
    contact: list = field(default_factory=list)
    ee_position: list = field(default_factory=list)
    ee_reference: list = field(default_factory=list)
    solve_t: list = field(default_factory=list)
    solve_time: list = field(default_factory=list)
    iterations: list = field(default_factory=list)
    success: list = field(default_factory=list)
    fallback: list = field(default_factory=list)
    violation: list = field(default_factory=list)
    status: list = field(default_factory=list)
    reason: list = field(default_factory=list)
    ee_command: list = field(default_factory=list)
    timings: list = field(default_factory=list)
    plans: list = field(default_factory=list)
    q_meas: list = field(default_factory=list)
    v_meas: list = field(default_factory=list)
    contact_sim: list = field(default_factory=list)
    foot_forces: list = field(default_factory=list)
    ee_force_sim: list = field(default_factory=list)
    base_velocity_cmd: list = field(default_factory=list)
    base_yaw_rate_cmd: list = field(default_factory=list)
    ee_force_cmd: list = field(default_factory=list)
    apply_t: list = field(default_factory=list)
    plan_q: list = field(default_factory=list)
    plan_v: list = field(default_factory=list)
    plan_tau: list = field(default_factory=list)
    plan_forces: list = field(default_factory=list)
    scene_positions: list = field(default_factory=list)
    foot_height: list = field(default_factory=list)
    plan_contact: list = field(default_factory=list)
    hold: list = field(default_factory=list)
    path: Path | None = field(default=None, repr=False)  # the .npz log on disk, once a streamed run ends
    writer: LogWriter | None = field(default=None, repr=False)  # streaming: where the chunks go
    chunk_steps: int = 0  # streaming: plant steps per chunk
    summarize: Callable[[Mapping], dict] | None = field(default=None, repr=False)  # set by the run

    SOLVE_COLUMNS = (
        "solve_t",
        "apply_t",
        "solve_time",
        "iterations",
        "success",
        "fallback",
        "violation",
        "status",
        "reason",
        "ee_command",
        "plan_q",
        "plan_v",
        "plan_tau",
        "plan_forces",
        "plan_contact",
        "hold",
    )

    @classmethod
    def streaming(cls, path, chunk_steps: int, meta: dict | None = None) -> ClosedLoopLog:
        """A log written to ``path`` (``.npz``) in chunks of ``chunk_steps`` plant steps as the run goes."""
        if chunk_steps < 1:
            raise ValueError(f"a log chunk must hold at least one plant step, got {chunk_steps}")
        return cls(writer=LogWriter(path, meta), chunk_steps=chunk_steps)

    @classmethod
    def columns(cls) -> tuple[str, ...]:
        """Names of the logged series (list fields; ``plans`` and per-solve ``timings`` dicts excluded)."""
        skip = ("plans", "timings")
        return tuple(f.name for f in fields(cls) if f.default_factory is list and f.name not in skip)

    def arrays(self) -> dict[str, np.ndarray]:
        """Every series as a numpy array (read from disk for a streamed log; empty if never logged)."""
        if self.path is not None:
            run = load_log(self.path)
            return {k: np.asarray([]) for k in self.columns()} | run.solves | run.signals
        return {k: np.asarray(getattr(self, k)) for k in self.columns()}

    def run_log(self, meta: dict | None = None) -> RunLog:
        """The columnar log (:class:`wbmpc.io.logs.RunLog`): low-level-rate signals, one row per solve."""
        if self.path is not None:
            run = load_log(self.path)
            run.meta |= dict(meta or {})
            return run
        arrays = self.arrays()
        n_solves = len(self.solve_t)
        solves = {k: arrays[k] for k in self.SOLVE_COLUMNS if len(arrays[k]) == n_solves}
        solves["status"] = np.asarray([str(x) for x in self.status], dtype=str)
        solves["reason"] = np.asarray([str(x) for x in self.reason], dtype=str)
        skip = set(self.SOLVE_COLUMNS)
        signals = {k: v for k, v in arrays.items() if k not in skip and len(v) == len(self.t)}
        return RunLog(signals=signals, solves=solves, meta=dict(meta or {}))

    def tick(self, step: int) -> None:
        """Called at each plant step before anything of it is logged: a streamed log writes a chunk."""
        if self.writer is not None and step and step % self.chunk_steps == 0:
            self.flush()

    def flush(self) -> None:
        """Write the rows held in memory as the next chunk and empty every list (streamed log)."""
        self.writer.write_chunk(self.run_log())
        for name in (*self.columns(), "plans", "timings"):
            getattr(self, name).clear()

    def finish(self, summarize: Callable[[Mapping], dict], interrupted: str | None = None) -> dict | None:
        """End of the run: its summary, from memory or (streamed) from the consolidated log on disk.

        Args:
            summarize: ``f(columns) -> summary`` (columns by name, as :meth:`arrays`).
            interrupted: What stopped a streamed run early (stored in its ``meta``), or ``None``.
        """
        if self.writer is None:
            return summarize(self.arrays())
        if interrupted is not None:
            self._trim_unfinished_rows()
        self.flush()
        names = self.columns()
        meta = self.writer.close(lambda columns: summarize(_Columns(columns, names)), interrupted)
        self.path, self.writer = self.writer.path, None
        return meta.get("summary")

    def abort(self, exc: BaseException) -> None:
        """An exception stopped the run: a streamed log writes what it has, marked partial (then re-raise)."""
        if self.writer is None or self.writer.closed:
            return
        what = f"{type(exc).__name__}: {exc}"
        if isinstance(exc, KeyboardInterrupt):
            what = "KeyboardInterrupt (Ctrl-C)"
        try:
            self.finish(self.summarize or (lambda columns: None), interrupted=what)
        except Exception as error:  # noqa: BLE001 - the original exception is the one to raise
            exc.add_note(f"the partial log {self.writer.path} could not be written: {error!r}")

    def _trim_unfinished_rows(self) -> None:
        """Drop the rows an interruption left half-appended (a table's columns end at its shortest)."""
        solve_columns = [k for k in self.SOLVE_COLUMNS if getattr(self, k)]
        signal_columns = [k for k in self.columns() if k not in self.SOLVE_COLUMNS and getattr(self, k)]
        for names in (solve_columns, signal_columns):
            n = min((len(getattr(self, k)) for k in names), default=0)
            for k in names:
                del getattr(self, k)[n:]
        del self.timings[len(self.solve_t) :]
        del self.plans[len(self.solve_t) :]


class _Columns(Mapping):
    """Columns read from disk, with the log's never-filled series as empty arrays (as in memory)."""

    def __init__(self, columns: Mapping, names: Sequence[str]):
        self._columns, self._names = columns, tuple(names)

    def __getitem__(self, name: str) -> np.ndarray:
        if name in self._columns:
            return self._columns[name]
        if name in self._names:
            return np.asarray([])
        raise KeyError(name)

    def __iter__(self):
        return iter(dict.fromkeys((*self._names, *self._columns)))

    def __len__(self) -> int:
        return len(dict.fromkeys((*self._names, *self._columns)))


@dataclass
class ClosedLoopResult:
    log: ClosedLoopLog
    summary: dict
    fell: bool

    def run_log(self) -> RunLog:
        """The columnar log with the summary as metadata."""
        return self.log.run_log({"summary": self.summary})

    def save(self, path) -> str:
        """Write the columnar log (``.npz``, see :mod:`wbmpc.io.logs`); returns the path.

        A streamed run's log is already on disk (``result.log.path``): it is copied.
        """
        if self.log.path is None:
            return str(save_log(self.run_log(), path))
        target = Path(path) if Path(path).suffix == ".npz" else Path(f"{path}.npz")
        if target.resolve() != self.log.path.resolve():
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(self.log.path, target)
        return str(target)
