"""Latest-only records in shared memory between the controller and the MPC worker (OCS2's MPC/MRT split).

:class:`LatestSlot`: one fixed-layout record of named float64 arrays in a
:class:`multiprocessing.shared_memory.SharedMemory` segment, written by one process, copied by others (no
queue: a reader that falls behind skips records); :class:`PlanChannel` (MPC plans, shapes of a
:class:`PlanLayout`) and :class:`ObservationChannel` (the measured state and the commands) are slots.

Seqlock: at byte 64 of the segment a uint64 header (sequence counter, epoch, write time
``time.monotonic_ns``, CRC-32), at 128 the layout as JSON (checked on attach), then the data. The writer
stores the counter odd, then the header words and the data (one ``memcpy``), then the counter even (a
record's sequence number is the counter over 2). A reader loads the counter, copies header words and data,
loads the counter again and keeps the copy only if both loads are equal and even; else it retries.

Memory ordering: numpy loads and stores the aligned 8-byte counter whole (atomic on x86-64 and aarch64); the
compiler cannot move memory accesses across the interpreter's opaque calls into numpy and zlib. On x86-64
(TSO) stores become visible to other cores in program order and loads are not reordered with loads: all a
seqlock needs (glibc's ``memcpy`` uses non-temporal stores only for copies of megabytes, and fences them).
On weakly ordered CPUs (aarch64) Python cannot issue the barriers; there the record's CRC-32
(``checksum=True``, the default; ~5 us per 12 kB) catches a torn copy but for a collision (2**-32). Before
Python 3.13 a process that is not a ``multiprocessing`` child unregisters a segment it attaches from its own
resource tracker (which would unlink it at exit).
"""

from __future__ import annotations

import json
import multiprocessing
import struct
import sys
import time
import zlib
from collections import namedtuple
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from multiprocessing import resource_tracker
from multiprocessing.shared_memory import SharedMemory
from typing import TYPE_CHECKING

import numpy as np

from wbmpc import checks

if TYPE_CHECKING:
    from wbmpc.control.config import MPCSolution

_MAGIC, _JSON_AT = b"WBMPCSL1", 128
_SEQ, _EPOCH, _TIME, _CRC = range(4)  # record-header words (uint64) from byte 64
_CREATED: set[str] = set()  # the segments this process created (its tracker's registrations to keep)

#: Statuses of wbmpc.solver.statuses and wbmpc.control.mpc sent as their index (append only); others: "other".
STATUSES = tuple(
    """other success hold max_iter_exceeded acceptable_point local_infeasibility line_search_failed
    step_computation_error fatrop_unknown fatrop_failed infeasible search_direction_too_small diverging
    user_stop feasible_point restoration_failed max_time_exceeded too_few_degrees_of_freedom invalid_problem
    invalid_option invalid_number solver_exception insufficient_memory internal_error nan_in_evaluation
    evaluation_error non_finite_solution absurd_measurement""".split()
)

SlotDescription = namedtuple("SlotDescription", "name layout")
SlotDescription.__doc__ = "What attaches to a slot (picklable): the segment ``name`` and ``layout`` (JSON)."
SlotRecord = namedtuple("SlotRecord", "seq epoch write_time_ns values")
SlotRecord.__doc__ = "A consistent copy of a slot: seq, epoch, write_time_ns [ns], values (name -> array)."
PlanMeta = namedtuple("PlanMeta", "seq epoch observation_seq observation_time write_time_ns")
PlanMeta.__doc__ = "A plan's seq, epoch, source observation_seq and observation_time [s], write_time_ns [ns]."


class LatestSlot:
    """One latest-only record of named float64 arrays in shared memory (the seqlock of the module notes).

    Make one with :meth:`create` or :meth:`attach`; a pickled slot attaches when unpickled (how a "spawn" or
    "forkserver" child gets it). One process writes a slot: two concurrent writers break the seqlock.

    Attributes:
        fields: Name -> shape; finite: the finite-only fields; spec: the layout as stored in the segment.
        torn_reads: Read attempts thrown away: a write in progress, or one overlapping the copy (counter
            changed, CRC mismatch). failed_reads: reads that gave up after ``max_retries`` attempts (64).
    """

    max_retries = 64
    _hdr = _data = None

    @staticmethod
    def _open_existing(name: str) -> SharedMemory:
        if sys.version_info >= (3, 13):
            return SharedMemory(name=name, track=False)
        shm = SharedMemory(name=name)
        if multiprocessing.parent_process() is None and shm._name not in _CREATED:  # own tracker: keep it
            resource_tracker.unregister(shm._name, "shared_memory")
        return shm

    @staticmethod
    def _data_at(spec: dict) -> int:
        return _JSON_AT + -(-len(json.dumps(spec, sort_keys=True).encode()) // 64) * 64

    def __init__(self, shm: SharedMemory, spec: dict, owner: bool):
        self._shm, self.spec, self.owner = shm, spec, owner
        self.fields = {name: tuple(shape) for name, shape in spec["fields"]}
        self.finite, self.checksum = frozenset(spec["finite"]), spec["checksum"]
        self._slices, at = {}, 0
        for name, shape in self.fields.items():
            self._slices[name] = slice(at, at := at + int(np.prod(shape, dtype=np.int64)))
        self._hdr = np.ndarray((4,), np.uint64, shm.buf, 64)
        self._data = np.ndarray((at,), np.float64, shm.buf, self._data_at(spec))
        self._stage = np.empty(at)
        self.torn_reads = self.failed_reads = 0

    @staticmethod
    def _spec(fields: Mapping, finite, checksum: bool, meta: dict | None) -> dict:
        out = []
        for name, shape in fields.items():
            shape = (shape,) if isinstance(shape, int | np.integer) else tuple(shape)
            if not isinstance(name, str) or any(not isinstance(n, int | np.integer) or n < 0 for n in shape):
                raise ValueError(f"slot field {name!r}: the shape must be a tuple of ints >= 0, got {shape}")
            out.append([name, [int(n) for n in shape]])
        finite = list(fields) if finite is True else sorted(finite or ())
        if unknown := set(finite) - set(fields):
            raise ValueError(f"finite names unknown fields {sorted(unknown)} of {list(fields)}")
        return {"fields": out, "finite": finite, "checksum": bool(checksum), "meta": meta or {}}

    @classmethod
    def create(cls, fields: Mapping, name=None, *, finite=False, checksum=True, meta=None):
        """Allocate a slot (no record until the first :meth:`write`).

        Args:
            fields: Name -> shape (tuple of ints; an int for a vector, ``()`` a scalar), in storage order.
            name: Segment name; ``None`` picks a free one (:attr:`name`). meta: a JSON-able dict to store.
            finite: True (every field), False, or the names of the fields :meth:`write` refuses NaN/inf in.
            checksum: Store a CRC-32 per record, checked on read (the torn-copy guard off x86-64).

        Raises:
            ValueError: a malformed name or shape, an unknown ``finite`` name.
            FileExistsError: a segment ``name`` exists already.
        """
        spec = LatestSlot._spec(fields, finite, checksum, meta)
        text = json.dumps(spec, sort_keys=True).encode()
        size = LatestSlot._data_at(spec) + 8 * sum(int(np.prod(s, dtype=np.int64)) for _, s in spec["fields"])
        shm = SharedMemory(name=name, create=True, size=size)
        _CREATED.add(shm._name)
        shm.buf[_JSON_AT : _JSON_AT + len(text)] = text
        shm.buf[0:16] = _MAGIC + struct.pack("<Q", len(text))
        return cls(shm, spec, True)

    @classmethod
    def attach(cls, name: str | SlotDescription, **expect):
        """Attach to a slot made by :meth:`create`: by name, or by description (then with the same layout);
        ``expect`` goes to a channel's constructor (e.g. ``layout=`` of a :class:`PlanChannel`).

        Raises:
            FileNotFoundError: no segment of that name.
            ValueError: the segment is no slot, or its layout is not the expected one (both shown).
        """
        described = isinstance(name, SlotDescription)
        expected, name = (json.loads(name.layout), name.name) if described else (None, name)
        shm = LatestSlot._open_existing(name)
        try:
            if shm.size < _JSON_AT or bytes(shm.buf[0:8]) != _MAGIC:
                raise ValueError(f"shared memory {name!r} is not a LatestSlot")
            spec = json.loads(bytes(shm.buf[_JSON_AT : _JSON_AT + struct.unpack("<Q", shm.buf[8:16])[0]]))
            if expected is not None and expected != spec:
                raise ValueError(f"slot {name!r} has the layout {spec}, this process expects {expected}")
            return cls(shm, spec, False, **expect)
        except BaseException:
            shm.close()
            raise

    name = property(lambda self: self._shm.name, doc="The segment's name.")
    description = property(lambda self: SlotDescription(self.name, json.dumps(self.spec, sort_keys=True)))

    @property
    def seq(self) -> int:
        """Sequence number of the newest complete record (0: none yet): one load of the counter, no copy."""
        return int(self._hdr[_SEQ]) // 2

    def write(self, values: Mapping, *, epoch: int = 0) -> int:
        """Publish a record of every field (array-likes, as float64); returns its sequence number.

        Raises:
            ValueError: a field missing or unknown, a shape not the layout's (field and both shapes named),
                NaN/inf in a finite-only field (named), an epoch not in [0, 2**64); nothing is written then.
        """
        if set(values) != set(self.fields):
            missing, unknown = sorted(set(self.fields) - set(values)), sorted(set(values) - set(self.fields))
            raise ValueError(f"slot write: fields missing {missing}, unknown {unknown}")
        epoch = checks.integer("epoch", epoch, low=0, high=2**64 - 1)
        arrays = [np.asarray(values[name], dtype=np.float64) for name in self.fields]
        for (name, shape), value in zip(self.fields.items(), arrays, strict=True):
            if value.shape != shape:
                raise ValueError(f"slot field {name!r}: the layout's shape is {shape}, got {value.shape}")
        np.concatenate([value.ravel() for value in arrays], out=self._stage)
        if self.finite and not np.isfinite(self._stage).all():  # one check of the record, then per field
            for name in (name for name in self.fields if name in self.finite):
                if not np.isfinite(self._stage[self._slices[name]]).all():
                    raise ValueError(f"slot field {name!r} contains NaN or inf (the field is finite-only)")
        hdr, count = self._hdr, int(self._hdr[_SEQ])
        count += 1 if count % 2 == 0 else 2  # odd: a writer died mid-write; this one goes on from there
        seq, now = (count + 1) // 2, time.monotonic_ns()
        crc = self._crc(self._stage, seq, epoch, now) if self.checksum else 0
        hdr[_SEQ] = count  # odd: a write in progress
        hdr[_EPOCH], hdr[_TIME], hdr[_CRC] = epoch, now, crc
        np.copyto(self._data, self._stage)
        hdr[_SEQ] = count + 1
        return seq

    @staticmethod
    def _crc(data: np.ndarray, seq: int, epoch: int, time_ns: int) -> int:
        return zlib.crc32(data, zlib.crc32(struct.pack("<QQQ", seq, epoch, time_ns)))

    def _copy(self, words: np.ndarray, data: np.ndarray) -> None:
        """The copy between the two counter loads (a method so that a test can interleave a write)."""
        np.copyto(words, self._hdr[1:])
        np.copyto(data, self._data)

    def read(self) -> SlotRecord | None:
        """The newest complete record; ``None``: none yet, or no consistent copy in ``max_retries`` tries."""
        words, data, hdr = np.empty(3, np.uint64), np.empty_like(self._stage), self._hdr
        for _ in range(self.max_retries):
            if (before := int(hdr[_SEQ])) == 0:
                return None
            if before % 2 == 0:
                self._copy(words, data)
                epoch, stamp, crc = (int(w) for w in words)
                same = int(hdr[_SEQ]) == before
                if same and (not self.checksum or self._crc(data, before // 2, epoch, stamp) == crc):
                    values = {name: data[sl].reshape(self.fields[name]) for name, sl in self._slices.items()}
                    return SlotRecord(before // 2, epoch, stamp, values)
            self.torn_reads += 1
        self.failed_reads += 1
        return None

    def close(self) -> None:
        """Unmap the segment in this process (idempotent); the slot is unusable afterwards."""
        if self._data is not None:
            self._hdr = self._data = None  # the numpy views must go before the buffer is released
            self._shm.close()

    def unlink(self) -> None:
        """Remove the segment's name (once, by the creator; mappings stay valid until closed)."""
        self._shm.unlink()

    def __reduce__(self):
        return (type(self).attach, (self.description,))

    __del__ = close


@dataclass(frozen=True)
class PlanLayout:
    """The shapes of a plan record, fixed for a run: nodes ``N``, ``nq``, ``nv``, joints ``nj``, torque nodes
    ``n_tau``, force contacts ``n_c``, feet ``n_feet`` (rows of the contact flags).

    Raises:
        ValueError: a count that is not a positive int (the field named), ``N < 2`` or ``n_tau > N``.
    """

    N: int
    nq: int
    nv: int
    nj: int
    n_tau: int
    n_c: int
    n_feet: int = 4

    def __post_init__(self):
        for key, value in asdict(self).items():
            checks.integer(f"PlanLayout.{key}", value, low=2 if key == "N" else 1)
        checks.integer("PlanLayout.n_tau", self.n_tau, high=self.N)

    @classmethod
    def from_mpc(cls, mpc) -> PlanLayout:
        """The layout of a :class:`wbmpc.control.mpc.WholeBodyMPC`'s plans."""
        robot, n_tau = mpc.robot, mpc.ocp.settings.n_tau_nodes
        return cls(mpc.n_nodes, robot.nq, robot.nv, robot.nj, n_tau, len(robot.contact_frames), robot.n_feet)

    def fields(self) -> dict[str, tuple[int, ...]]:
        """The slot fields of a plan: its arrays, ``flags`` (success, fallback, hold) and scalars."""
        N, n = self.N, self.N - 1
        out = {"t": (), "dts": (n,), "q": (N, self.nq), "v": (N, self.nv), "a": (n, self.nv)}
        out |= {"forces": (n, self.n_c, 3), "tau": (self.n_tau, self.nj), "contact": (self.n_feet, n)}
        scalars = ("iterations", "solve_time", "status", "constraint_violation", "observation_seq")
        return out | {"flags": (3,)} | dict.fromkeys((*scalars, "observation_time"), ())


class PlanChannel(LatestSlot):
    """MPC plans from the worker to the controller, latest only: a :class:`LatestSlot` of a plan layout.

    Sent: the plan's arrays, flags, ``iterations``, ``solve_time``, ``status`` (a code of :data:`STATUSES`),
    ``constraint_violation`` (may be inf; all else must be finite); not ``reason``, ``findings``, ``timings``.

    ``PlanChannel.attach(name, layout=None)`` adopts the slot's layout or checks it (ValueError naming both).

    Attributes:
        layout: The :class:`PlanLayout` both ends agree on.
        rejected_stale: Plans refused as older than the caller's (``seq`` below ``after_seq``) or planned from
            an older observation than the last plan returned in the same epoch (out of order);
            rejected_epoch: plans of another epoch than the caller's (each plan counted once).
    """

    def __init__(self, shm: SharedMemory, spec: dict, owner: bool, layout: PlanLayout | None = None):
        super().__init__(shm, spec, owner)
        meta = spec["meta"]
        self.layout = PlanLayout(**meta) if set(meta) == set(PlanLayout.__dataclass_fields__) else None
        if self.layout is None or self.fields != self.layout.fields() or layout not in (None, self.layout):
            self.close()
            what = self.layout or "no PlanLayout (not a plan slot)"
            raise ValueError(f"plan slot {shm.name!r} holds {what}, this process expects {layout or 'one'}")
        self.rejected_stale = self.rejected_epoch = 0
        self._last: tuple | None = None  # (plan, meta) of the newest record copied
        self._counted = 0  # the last seq counted as rejected
        self._source = (-1, -1)  # (epoch, observation_seq) of the last plan returned

    @classmethod
    def create(cls, layout: PlanLayout, name: str | None = None, *, checksum: bool = True) -> PlanChannel:
        """Allocate a plan slot (``name``, ``checksum`` and what it raises: :meth:`LatestSlot.create`)."""
        finite = [key for key in layout.fields() if key != "constraint_violation"]
        return super().create(layout.fields(), name, finite=finite, checksum=checksum, meta=asdict(layout))

    def publish(self, plan: MPCSolution, *, epoch: int, observation_seq: int, observation_time: float) -> int:
        """Write a plan made from observation ``observation_seq`` (measured at ``observation_time`` [s]);
        returns the plan's sequence number.

        Raises:
            ValueError: a shape other than the layout's or a non-finite value (the field named), a bad epoch.
        """
        values = {key: getattr(plan, key) for key in ("t", "dts", "q", "v", "a", "forces", "tau", "contact")}
        values["status"] = STATUSES.index(plan.status) if plan.status in STATUSES else 0
        values.update(flags=[plan.success, plan.fallback, plan.hold], iterations=plan.iterations)
        values.update(solve_time=plan.solve_time, constraint_violation=plan.constraint_violation)
        values.update(observation_seq=observation_seq, observation_time=observation_time)
        return self.write(values, epoch=epoch)

    def latest(self, after_seq: int, epoch: int) -> tuple[MPCSolution, PlanMeta] | None:
        """The newest plan and its :class:`PlanMeta` if it is newer than ``after_seq`` and of ``epoch``;
        ``None`` otherwise and while no consistent copy can be made (try again next tick). The record is
        copied only when its sequence number changed: a poll of an unchanged slot is one counter load."""
        if (seq := self.seq) in (0, after_seq):
            return None
        if self._last is None or self._last[1].seq != seq:
            if (record := self.read()) is None:
                return None
            self._last = self._decode(record)
        plan, meta = self._last
        stale = meta.seq < after_seq or (meta.epoch, meta.observation_seq) < self._source
        if meta.seq != after_seq and not stale and meta.epoch == epoch:
            self._source = (meta.epoch, meta.observation_seq)
            return plan, meta
        if meta.seq != after_seq and self._counted != meta.seq:  # a plan counts once, however often polled
            self._counted = meta.seq
            self.rejected_epoch += meta.epoch != epoch
            self.rejected_stale += meta.epoch == epoch
        return None

    @staticmethod
    def _decode(record: SlotRecord) -> tuple[MPCSolution, PlanMeta]:
        from wbmpc.control.config import MPCSolution  # lazy: a reader alone loads no Pinocchio

        v = record.values
        kw = {key: v[key] for key in ("dts", "q", "v", "a", "forces", "tau")}
        kw.update(zip(("success", "fallback", "hold"), (bool(x > 0.5) for x in v["flags"]), strict=True))
        kw.update(t=float(v["t"]), contact=v["contact"] > 0.5, iterations=int(v["iterations"]))
        kw.update(solve_time=float(v["solve_time"]), constraint_violation=float(v["constraint_violation"]))
        plan = MPCSolution(status=STATUSES[int(v["status"])], **kw)
        source = int(v["observation_seq"]), float(v["observation_time"])
        return plan, PlanMeta(record.seq, record.epoch, *source, record.write_time_ns)


#: The commands sent with an observation and their shapes: base velocity [m/s], yaw rate [rad/s], end-effector
#: velocity [m/s] and force [N], a gait index both ends agree on.
COMMANDS = {"base_velocity": (3,), "yaw_rate": (), "ee_velocity": (3,), "ee_force": (3,), "gait_id": ()}
SharedObservation = namedtuple("SharedObservation", "seq epoch write_time_ns t q v".split() + [*COMMANDS])
SharedObservation.__doc__ = """An observation as the worker reads it: ``seq``, ``epoch``, ``write_time_ns``
[ns], the measurement's time ``t`` [s], ``q`` (nq,), ``v`` (nv,), and the :data:`COMMANDS`."""


class ObservationChannel(LatestSlot):
    """The measured state and the commands from the controller to the MPC worker, latest only. Every field is
    finite-only: a NaN observation raises ValueError in :meth:`publish` and is never sent."""

    @classmethod
    def create(cls, nq: int, nv: int, name: str | None = None) -> ObservationChannel:
        """Allocate an observation slot for ``nq`` positions and ``nv`` velocities (errors: LatestSlot's)."""
        return super().create({"t": (), "q": (nq,), "v": (nv,), **COMMANDS}, name, finite=True)

    def publish(self, t: float, q, v, *, epoch: int, **commands) -> int:
        """Write the state measured at ``t`` [s], ``q`` (nq,), ``v`` (nv,), and the commands (keywords of
        :data:`COMMANDS`, zero when left out); returns the observation's sequence number.

        Raises:
            ValueError: an unknown command, a shape not the layout's, NaN/inf (the field named), a bad epoch.
        """
        values = {key: np.zeros(shape) for key, shape in COMMANDS.items()} | commands
        return self.write({**values, "t": t, "q": q, "v": v}, epoch=epoch)

    def latest(self, after_seq: int = 0) -> SharedObservation | None:
        """The newest observation if its ``seq`` is above ``after_seq``, else ``None``."""
        if self.seq <= after_seq or (record := self.read()) is None or record.seq <= after_seq:
            return None
        v = dict(record.values)
        v.update(t=float(v["t"]), yaw_rate=float(v["yaw_rate"]), gait_id=int(v["gait_id"]))
        return SharedObservation(record.seq, record.epoch, record.write_time_ns, **v)
