"""Latest-only shared-memory slots (wbmpc.runtime.shared): plan round trip, a reader in another process that
never sees a torn record, stale and other-epoch plans rejected, the errors on bad writes and attaches."""

import multiprocessing as mp
import pickle
import time

import numpy as np
import pytest

from wbmpc.runtime.shared import (
    STATUSES,
    LatestSlot,
    ObservationChannel,
    PlanChannel,
    PlanLayout,
    SlotDescription,
)

LAYOUT = PlanLayout(N=15, nq=26, nv=24, nj=18, n_tau=3, n_c=5)


@pytest.fixture
def slots():
    """Create slots through ``slots(make, *args)``; all are closed and unlinked after the test."""
    made = []

    def make(factory, *args, **kwargs):
        slot = factory(*args, **kwargs)
        made.append(slot)
        return slot

    yield make
    for slot in made:
        slot.close()
        try:
            slot.unlink()
        except FileNotFoundError:
            pass


def random_plan(layout=LAYOUT, seed=0, **overrides):
    from wbmpc.control.config import MPCSolution  # lazy: the spawned reader imports this module

    rng = np.random.default_rng(seed)
    N = layout.N
    fields = dict(
        t=float(rng.uniform(0, 100)),
        dts=rng.uniform(0.01, 0.1, N - 1),
        q=rng.normal(size=(N, layout.nq)),
        v=rng.normal(size=(N, layout.nv)),
        a=rng.normal(size=(N - 1, layout.nv)),
        forces=rng.normal(size=(N - 1, layout.n_c, 3)),
        tau=rng.normal(size=(layout.n_tau, layout.nj)),
        contact=rng.random((layout.n_feet, N - 1)) > 0.5,
        success=True,
        iterations=int(rng.integers(1, 50)),
        solve_time=float(rng.uniform(0, 0.02)),
        status="success",
        constraint_violation=float(rng.uniform(0, 1e-6)),
    )
    return MPCSolution(**(fields | overrides))


def test_a_plan_survives_the_round_trip_exactly(slots):
    writer = slots(PlanChannel.create, LAYOUT)
    reader = PlanChannel.attach(writer.name, layout=LAYOUT)
    plan = random_plan(fallback=True, hold=True, success=False, status="max_iter_exceeded")
    seq = writer.publish(plan, epoch=3, observation_seq=41, observation_time=12.5)
    got, meta = reader.latest(after_seq=0, epoch=3)
    for key in ("dts", "q", "v", "a", "forces", "tau", "contact"):
        np.testing.assert_array_equal(getattr(got, key), getattr(plan, key), err_msg=key)
    assert got.contact.dtype == bool
    assert (got.t, got.iterations, got.solve_time, got.status) == (
        plan.t,
        plan.iterations,
        plan.solve_time,
        plan.status,
    )
    assert (got.success, got.fallback, got.hold, got.constraint_violation) == (
        False,
        True,
        True,
        plan.constraint_violation,
    )
    assert (meta.seq, meta.epoch, meta.observation_seq, meta.observation_time) == (seq, 3, 41, 12.5)
    assert abs(meta.write_time_ns - time.monotonic_ns()) < 60e9
    got.q[0, 0] += 1.0  # the plan is a private copy: the slot is untouched
    again = PlanChannel.attach(writer.name).latest(0, 3)[0]
    assert again.q[0, 0] == plan.q[0, 0]
    reader.close()


def test_an_unknown_status_travels_as_other_and_an_infinite_violation_is_allowed(slots):
    channel = slots(PlanChannel.create, LAYOUT)
    channel.publish(
        random_plan(status="made_up", constraint_violation=np.inf),
        epoch=0,
        observation_seq=1,
        observation_time=0.0,
    )
    plan, _ = channel.latest(0, 0)
    assert plan.status == "other" and plan.constraint_violation == np.inf


def test_the_status_table_covers_every_status_the_solver_and_mpc_report():
    from wbmpc.solver.statuses import FATROP_FLAGS, IPOPT_STATUSES

    names = {name for name, _ in (*FATROP_FLAGS.values(), *IPOPT_STATUSES.values())}
    names |= {
        "hold",
        "fatrop_failed",
        "non_finite_solution",
        "nan_in_evaluation",
        "evaluation_error",
        "solver_exception",
    }
    assert names <= set(STATUSES)
    assert STATUSES[0] == "other" and len(set(STATUSES)) == len(STATUSES)


def test_latest_only_and_each_rejection_counted_once(slots):
    writer = slots(PlanChannel.create, LAYOUT)
    reader = PlanChannel.attach(writer.name)
    assert reader.latest(0, 1) is None  # nothing written yet
    for k in range(3):
        writer.publish(random_plan(seed=k), epoch=1, observation_seq=10 + k, observation_time=float(k))
    plan, meta = reader.latest(0, 1)
    assert meta.seq == 3 and meta.observation_seq == 12  # the newest only; the first two were skipped
    assert reader.latest(meta.seq, 1) is None  # nothing newer
    # Planned from an older measurement than the plan in use (same epoch): out of order, refused.
    writer.publish(random_plan(), epoch=1, observation_seq=11, observation_time=1.0)
    assert reader.latest(meta.seq, 1) is None and reader.latest(meta.seq, 1) is None
    assert (reader.rejected_epoch, reader.rejected_stale) == (0, 1)
    # The controller reset (epoch 2): a plan of epoch 1 is refused, however often it is polled.
    writer.publish(random_plan(), epoch=1, observation_seq=13, observation_time=3.0)
    for _ in range(5):
        assert reader.latest(meta.seq, 2) is None
    assert (reader.rejected_epoch, reader.rejected_stale) == (1, 1)
    # The observation order is per epoch: the new epoch's first plan is accepted.
    writer.publish(random_plan(), epoch=2, observation_seq=2, observation_time=5.0)
    plan, meta = reader.latest(meta.seq, 2)
    assert (meta.seq, meta.epoch, meta.observation_seq) == (6, 2, 2)
    # Older than what the caller already holds (its after_seq from before a writer restart).
    assert reader.latest(100, 2) is None and reader.rejected_stale == 2
    assert (reader.rejected_epoch, reader.rejected_stale, reader.torn_reads) == (1, 2, 0)
    reader.close()


def test_a_poll_of_an_unchanged_slot_copies_nothing(slots, monkeypatch):
    channel = slots(PlanChannel.create, LAYOUT)
    channel.publish(random_plan(), epoch=0, observation_seq=1, observation_time=0.0)
    assert channel.latest(0, 0) is not None
    monkeypatch.setattr(channel, "read", lambda: pytest.fail("read() called for an unchanged record"))
    assert channel.latest(1, 0) is None
    assert channel.latest(0, 0) is not None  # the cached copy


def test_a_write_that_overlaps_the_copy_is_detected_and_retried(slots):
    for checksum in (False, True):
        writer = slots(LatestSlot.create, {"x": (1000,), "s": ()}, checksum=checksum)
        writer.write({"x": np.full(1000, 1.0), "s": 1.0}, epoch=1)
        reader = LatestSlot.attach(writer.name)
        copies = []

        def torn_copy(words, data, reader=reader, writer=writer, copies=copies):
            copies.append(1)
            np.copyto(words, reader._hdr[1:])
            data[:500] = reader._data[:500]
            if len(copies) == 1:  # the writer runs in the middle of the first copy
                writer.write({"x": np.full(1000, 2.0), "s": 2.0}, epoch=2)
            data[500:] = reader._data[500:]

        reader._copy = torn_copy
        record = reader.read()
        assert record.seq == 2 and record.epoch == 2 and np.all(record.values["x"] == 2.0)
        assert (len(copies), reader.torn_reads, reader.failed_reads) == (2, 1, 0)
        reader.close()


def test_a_write_in_progress_or_a_corrupt_record_is_never_returned(slots):
    writer = slots(LatestSlot.create, {"x": (8,)})
    writer.write({"x": np.arange(8.0)})
    reader = LatestSlot.attach(writer.name)
    reader.max_retries = 5
    writer._hdr[0] += 1  # odd: a write in progress (or a writer that died in one)
    assert reader.read() is None and (reader.torn_reads, reader.failed_reads) == (5, 1)
    assert writer.write({"x": np.ones(8)}) == 3  # goes on counting past the dead write
    writer._data[3] = 99.0  # data changed under an unchanged counter: what weak ordering could show
    assert reader.read() is None and reader.failed_reads == 2  # the CRC catches it
    unchecked = slots(LatestSlot.create, {"x": (8,)}, checksum=False)
    unchecked.write({"x": np.ones(8)})
    unchecked._data[3] = 99.0
    assert unchecked.read().values["x"][3] == 99.0  # without the CRC only the counter protects the copy
    reader.close()


def _reader(descriptions, ready, stop, results):
    """Spawned process: read both slots until ``stop``, checking every record's invariant."""
    slots = [LatestSlot.attach(d) for d in descriptions]
    ready.set()
    reads = bad = backwards = 0
    last = [0] * len(slots)
    while not stop.is_set():
        for i, slot in enumerate(slots):
            record = slot.read()
            if record is None:
                continue
            reads += 1
            ok = record.epoch == record.seq and all(np.all(v == record.seq) for v in record.values.values())
            bad += not ok
            backwards += record.seq < last[i]
            last[i] = record.seq
    final = [slot.read().seq for slot in slots]
    torn = [slot.torn_reads for slot in slots]
    results.put({"reads": reads, "bad": bad, "backwards": backwards, "final": final, "torn": torn})
    for slot in slots:
        slot.close()


def test_a_reader_in_another_process_never_sees_a_torn_record(slots):
    fields = {"a": (64, 64), "b": (1000,), "s": ()}  # 41 kB: a copy takes long enough to be overlapped
    writers = [slots(LatestSlot.create, fields, checksum=checksum) for checksum in (False, True)]
    ctx = mp.get_context("spawn")
    ready, stop, results = ctx.Event(), ctx.Event(), ctx.Queue()
    child = ctx.Process(target=_reader, args=([w.description for w in writers], ready, stop, results))
    child.start()
    try:
        assert ready.wait(30), "the reader process did not start"
        seq, end = 0, time.monotonic() + 0.5
        while time.monotonic() < end:
            seq += 1
            for writer in writers:
                assert (
                    writer.write({k: np.full(shape, float(seq)) for k, shape in fields.items()}, epoch=seq)
                    == seq
                )
        stop.set()
        report = results.get(timeout=30)
    finally:
        stop.set()
        child.join(30)
    assert child.exitcode == 0
    assert report["reads"] > 10 and report["bad"] == 0 and report["backwards"] == 0, report
    assert report["final"] == [seq, seq], report  # latest-only: the last record written


def test_bad_writes_name_the_field(slots):
    slot = slots(LatestSlot.create, {"q": (3,), "s": ()}, finite=["q"])
    with pytest.raises(ValueError, match=r"'q'.*\(3,\).*\(4,\)"):
        slot.write({"q": np.zeros(4), "s": 0.0})
    with pytest.raises(ValueError, match="'q' contains NaN"):
        slot.write({"q": [0.0, np.nan, 0.0], "s": 0.0})
    slot.write({"q": np.zeros(3), "s": np.inf})  # s is not finite-only
    with pytest.raises(ValueError, match=r"missing \['s'\], unknown \['r'\]"):
        slot.write({"q": np.zeros(3), "r": 0.0})
    with pytest.raises(ValueError, match="epoch"):
        slot.write({"q": np.zeros(3), "s": 0.0}, epoch=-1)
    assert slot.seq == 1  # the failed writes wrote nothing
    plans = slots(PlanChannel.create, LAYOUT)
    with pytest.raises(ValueError, match=r"'tau'.*\(3, 18\).*\(2, 18\)"):
        plans.publish(random_plan(tau=np.zeros((2, 18))), epoch=0, observation_seq=0, observation_time=0.0)
    with pytest.raises(ValueError, match="'q' contains NaN"):
        plans.publish(
            random_plan(q=np.full((15, 26), np.nan)), epoch=0, observation_seq=0, observation_time=0.0
        )
    with pytest.raises(ValueError, match="shape"):
        LatestSlot.create({"q": (3, -1)})
    with pytest.raises(ValueError, match="unknown fields"):
        LatestSlot.create({"q": (3,)}, finite=["v"])


def test_attaching_with_another_layout_names_both(slots):
    plans = slots(PlanChannel.create, LAYOUT)
    other = PlanLayout(N=12, nq=19, nv=18, nj=12, n_tau=3, n_c=4)
    with pytest.raises(ValueError, match=r"holds PlanLayout\(N=15.*expects PlanLayout\(N=12"):
        PlanChannel.attach(plans.name, layout=other)
    observations = slots(ObservationChannel.create, 26, 24)
    with pytest.raises(ValueError, match="not a plan slot"):
        PlanChannel.attach(observations.name)
    stale = SlotDescription(plans.name, observations.description.layout)
    with pytest.raises(ValueError, match="this process expects"):
        LatestSlot.attach(stale)
    with pytest.raises(FileNotFoundError):
        LatestSlot.attach("wbmpc_no_such_slot")


def test_channels_pickle_as_attachments(slots):
    plans = slots(PlanChannel.create, LAYOUT)
    plans.publish(random_plan(), epoch=4, observation_seq=2, observation_time=1.0)
    copy = pickle.loads(pickle.dumps(plans))
    assert isinstance(copy, PlanChannel) and copy.layout == LAYOUT and copy.name == plans.name
    assert copy.latest(0, 4)[1].seq == 1 and not copy.owner
    copy.close()


def test_observations_with_commands(slots):
    channel = slots(ObservationChannel.create, 26, 24)
    reader = ObservationChannel.attach(channel.description)
    assert reader.latest() is None and (reader.fields["q"], reader.fields["v"]) == ((26,), (24,))
    q, v = np.arange(26.0), -np.arange(24.0)
    seq = channel.publish(0.25, q, v, epoch=7, base_velocity=[0.5, 0, 0], yaw_rate=0.2, gait_id=3)
    obs = reader.latest(0)
    assert (obs.seq, obs.epoch, obs.t, obs.yaw_rate, obs.gait_id) == (seq, 7, 0.25, 0.2, 3)
    np.testing.assert_array_equal(obs.q, q)
    np.testing.assert_array_equal(obs.v, v)
    np.testing.assert_array_equal(obs.base_velocity, [0.5, 0, 0])
    np.testing.assert_array_equal(obs.ee_force, np.zeros(3))
    assert reader.latest(seq) is None
    with pytest.raises(ValueError, match="'v' contains NaN"):
        channel.publish(0.3, q, np.full(24, np.nan), epoch=7)
    with pytest.raises(ValueError, match="unknown"):
        channel.publish(0.3, q, v, epoch=7, yaw=1.0)
    assert reader.latest(0).seq == seq  # the refused observations were never sent
    reader.close()


def test_plan_layout_from_an_mpc_and_its_checks():
    from types import SimpleNamespace

    robot = SimpleNamespace(nq=26, nv=24, nj=18, contact_frames=("a", "b", "c", "d", "e"), n_feet=4)
    mpc = SimpleNamespace(
        robot=robot, n_nodes=15, ocp=SimpleNamespace(settings=SimpleNamespace(n_tau_nodes=3))
    )
    assert PlanLayout.from_mpc(mpc) == LAYOUT
    with pytest.raises(ValueError, match="PlanLayout.N"):
        PlanLayout(N=1, nq=26, nv=24, nj=18, n_tau=1, n_c=5)
    with pytest.raises(ValueError, match="PlanLayout.n_tau"):
        PlanLayout(N=15, nq=26, nv=24, nj=18, n_tau=16, n_c=5)
    with pytest.raises(ValueError, match="PlanLayout.nj"):
        PlanLayout(N=15, nq=26, nv=24, nj=1.5, n_tau=3, n_c=5)
