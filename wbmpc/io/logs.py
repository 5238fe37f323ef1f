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
                       :func:`wbmpc.control.diagnostics.solver_status`); ``reason`` (why it failed)
``solves/plan_q``, ``plan_v``, ``plan_tau``, ``plan_forces``  first nodes of each plan (S, n, ...)
``solves/plan_contact``  stance flags the plan used on its first stage (S, 4)
``solves/hold``        the static hold was applied (no converged plan existed yet)
=====================  =========================================================================
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

FORMAT_VERSION = 1


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
            n = len(table[time_key])
            for name, column in table.items():
                if len(column) != n:
                    raise ValueError(f"column {name!r} has {len(column)} rows, {time_key!r} has {n}")
            if not np.all(np.isfinite(table[time_key])):
                raise ValueError(f"time column {time_key!r} contains NaN or inf")


def save_log(log: RunLog, path: str | Path) -> Path:
    """Write ``log`` to ``path`` (``.npz`` appended if missing); returns the path."""
    log.validate()
    path = Path(path)
    if path.suffix != ".npz":
        path = path.with_suffix(path.suffix + ".npz")
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = {f"signals/{k}": np.asarray(v) for k, v in log.signals.items()}
    arrays |= {f"solves/{k}": np.asarray(v) for k, v in log.solves.items()}
    meta = {"format_version": FORMAT_VERSION, **log.meta}
    arrays["meta"] = np.array(json.dumps(meta, default=json_default))
    np.savez_compressed(path, **arrays)
    return path


def load_log(path: str | Path) -> RunLog:
    """Read a log written by :func:`save_log` (or converted from hardware to the same columns).

    Raises:
        FileNotFoundError: if ``path`` does not exist.
        ValueError: if the file is not a wbmpc log or is malformed.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no log file at {path}")
    with np.load(path, allow_pickle=False) as archive:
        if "meta" not in archive.files:
            raise ValueError(f"{path} is not a wbmpc log (no 'meta' entry)")
        log = RunLog(meta=json.loads(str(archive["meta"])))
        for key in archive.files:
            table, _, name = key.partition("/")
            if table == "signals":
                log.signals[name] = archive[key]
            elif table == "solves":
                log.solves[name] = archive[key]
    if log.meta.get("format_version", 0) > FORMAT_VERSION:
        raise ValueError(
            f"{path} has format version {log.meta['format_version']}; this wbmpc reads up to {FORMAT_VERSION}"
        )
    log.validate()
    return log


def json_default(value):
    """``json.dumps`` fallback for NumPy arrays and scalars and paths (anything else: its repr)."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    return repr(value)
