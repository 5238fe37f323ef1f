"""Streamed run logs (issue 12): chunks on disk equal the in-memory log, memory holds one chunk at most,
an interrupted run or a killed process leaves a readable partial log, and load_log names what is wrong."""

import json
import os
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from wbmpc.control.mpc import MPCConfig, WholeBodyMPC
from wbmpc.io.logs import LogWriter, RunLog, consolidate, load_log, parts_folder, save_log
from wbmpc.model.robot import load_b1_z1
from wbmpc.ocp import OCPSettings
from wbmpc.ocp.gait import make_gait
from wbmpc.sim import closed_loop
from wbmpc.sim.closed_loop import ClosedLoopConfig, ClosedLoopLog, run_closed_loop
from wbmpc.sim.loop_config import CommandSchedule

REPO_ROOT = Path(__file__).resolve().parents[1]
CHUNK = 0.2  # [s] of simulated time per chunk in these tests: 100 signal rows, 16 solves


@pytest.fixture(scope="module")
def mpc():
    mpc = WholeBodyMPC(load_b1_z1(), OCPSettings(n_nodes=6), MPCConfig(gait=make_gait("stand")))
    mpc.verbose = False
    return mpc


def _config(duration=0.5, overrides=None):
    commands = CommandSchedule(base_velocity=(0.0, 0.0, 0.0), overrides=overrides)
    return ClosedLoopConfig(duration=duration, commands=commands)


def _raise_after(t_stop, exception=RuntimeError):
    def schedule(t):
        if t > t_stop:
            raise exception(f"stop at t = {t}")
        return {}

    return schedule


def _assert_same(a: np.ndarray, b: np.ndarray, name: str):
    assert a.shape == b.shape and a.dtype == b.dtype, name
    if a.dtype.kind == "f":
        np.testing.assert_array_equal(a, b, err_msg=name)  # NaN == NaN here
    else:
        assert np.array_equal(a, b), name


def test_streamed_log_equals_the_in_memory_log_column_by_column(mpc, tmp_path):
    memory = run_closed_loop(mpc, _config(), progress=False)
    streamed = run_closed_loop(mpc, _config(), progress=False, log_path=tmp_path / "run.npz", log_chunk=CHUNK)
    a, b = memory.run_log(), load_log(tmp_path / "run.npz")
    assert not parts_folder(tmp_path / "run.npz").exists()
    assert set(a.signals) == set(b.signals) and set(a.solves) == set(b.solves)
    for name in a.signals:
        _assert_same(a.signals[name], b.signals[name], name)
    for name in a.solves:
        if name != "solve_time":  # wall time: differs between two runs of the same physics
            _assert_same(a.solves[name], b.solves[name], name)
    assert len(b["solve_time"]) == len(a["solve_time"])
    assert b.meta["partial"] is False and not b.partial
    assert b.meta["t_reached"] == pytest.approx(a["t"][-1]) and b.meta["chunks"] == 3
    skip = {"solve_ms", "machine"}
    assert {k: v for k, v in streamed.summary.items() if k not in skip} == {
        k: v for k, v in memory.summary.items() if k not in skip
    }
    assert b.meta["summary"]["mpc_solves"] == streamed.summary["mpc_solves"] == len(a["solve_t"])
    # users of result.log keep working: arrays() and run_log() read the file, save() copies it
    arrays = streamed.log.arrays()
    _assert_same(arrays["q"], memory.log.arrays()["q"], "q")
    assert streamed.run_log().meta["summary"] == streamed.summary
    copy = load_log(streamed.save(tmp_path / "copy"))
    _assert_same(copy["tau"], a["tau"], "tau")


def test_the_in_memory_lists_never_hold_more_than_a_chunk(mpc, tmp_path, monkeypatch):
    seen = []
    flush = ClosedLoopLog.flush

    def recording_flush(log):
        seen.append({name: len(getattr(log, name)) for name in ("t", "q", "solve_t", "timings", "plan_q")})
        flush(log)
        assert all(len(getattr(log, name)) == 0 for name in (*log.columns(), "timings", "plans"))

    monkeypatch.setattr(ClosedLoopLog, "flush", recording_flush)
    result = run_closed_loop(mpc, _config(0.7), progress=False, log_path=tmp_path / "run", log_chunk=CHUNK)
    rows, solves = round(CHUNK * 500), round(CHUNK * 80)
    assert len(seen) == 4  # 3 full chunks and the rest at the end
    assert all(s["t"] == s["q"] == rows for s in seen[:3]) and seen[3]["t"] == 50
    assert all(s["solve_t"] == s["timings"] == s["plan_q"] == solves for s in seen[:3])
    assert max(s["t"] for s in seen) <= rows and max(s["solve_t"] for s in seen) <= solves
    assert len(result.log.t) == 0 and len(result.log.timings) == 0 and result.log.path.exists()
    assert len(load_log(result.log.path)["t"]) == 350


def test_an_exception_inside_the_loop_leaves_a_partial_log_and_goes_on(mpc, tmp_path):
    config = _config(1.0, overrides=_raise_after(0.34))
    with pytest.raises(RuntimeError, match="stop at t = 0.35"):
        run_closed_loop(mpc, config, progress=False, log_path=tmp_path / "run.npz", log_chunk=CHUNK)
    log = load_log(tmp_path / "run.npz")
    assert log.partial and log.meta["t_reached"] == pytest.approx(0.348)  # the MPC tick at 0.35 s raised
    assert log.meta["interrupted"].startswith("RuntimeError: stop at t = 0.35")
    assert log["t"][-1] == pytest.approx(0.348) and len(log["t"]) == 175
    assert log["solve_t"][-1] == pytest.approx(0.3375) and len(log["solve_t"]) == 28
    assert log.meta["summary"]["duration_s"] == pytest.approx(0.348)
    assert not parts_folder(tmp_path / "run.npz").exists()


def test_ctrl_c_in_the_plant_step_leaves_a_partial_log(mpc, tmp_path, monkeypatch):
    from wbmpc.sim.plant import ContactPlant

    step, calls = ContactPlant.step, []

    def interrupted_step(plant, *args, **kwargs):
        calls.append(None)
        if len(calls) > 500:  # plant step 500: t = 0.25 s
            raise KeyboardInterrupt
        return step(plant, *args, **kwargs)

    monkeypatch.setattr(ContactPlant, "step", interrupted_step)
    with pytest.raises(KeyboardInterrupt):
        run_closed_loop(mpc, _config(1.0), progress=False, log_path=tmp_path / "run.npz", log_chunk=CHUNK)
    log = load_log(tmp_path / "run.npz")
    assert log.partial and log.meta["interrupted"].startswith("KeyboardInterrupt")
    assert log.meta["t_reached"] == pytest.approx(0.25) and len(log["t"]) == 126
    log.validate()


def test_a_killed_process_leaves_chunks_that_load_as_partial(mpc, tmp_path, monkeypatch):
    # a process killed mid-run never consolidates: no abort handling, the chunks and meta.json stay
    monkeypatch.setattr(ClosedLoopLog, "abort", lambda log, exc: None)
    config = _config(1.0, overrides=_raise_after(0.45))
    with pytest.raises(RuntimeError):
        run_closed_loop(mpc, config, progress=False, log_path=tmp_path / "run.npz", log_chunk=CHUNK)
    parts = tmp_path / "run.npz.parts"
    assert sorted(p.name for p in parts.iterdir()) == ["chunk_000000.npz", "chunk_000001.npz", "meta.json"]
    assert not (tmp_path / "run.npz").exists()
    for path in (tmp_path / "run.npz", parts):
        log = load_log(path)
        assert log.partial and "consolidated" in log.meta["interrupted"]
        assert log.meta["t_reached"] == pytest.approx(0.398) and len(log["t"]) == 200
        assert log.meta["requested_duration_s"] == 1.0
    kept = load_log(consolidate(parts))
    assert kept.partial and not parts.exists()
    _assert_same(kept["q"], log["q"], "q")


def test_the_log_writer_plans_columns_across_chunks(tmp_path):
    """String widths grow across chunks; a column that gets rows in no chunk drops (as in memory)."""
    writer = LogWriter(tmp_path / "log", meta={"robot": "test"})
    no_solves = {"solve_t": np.zeros(0), "status": np.zeros(0), "extra": np.zeros(0)}
    for k, solves in enumerate((no_solves, {"solve_t": [1.0], "status": ["ok"]})):
        signals = {"t": k + np.arange(3) * 0.1, "q": np.full((3, 2), k)}
        writer.write_chunk(RunLog(signals=signals, solves=solves))
    signals = {"t": 2 + np.arange(3) * 0.1, "q": np.full((3, 2), 2)}
    writer.write_chunk(RunLog(signals, {"solve_t": [2.0, 2.1], "status": ["max iterations", "ok"]}))
    assert writer.write_chunk(RunLog(signals={"t": np.zeros(0)})) is None
    meta = writer.close(lambda columns: {"n": len(columns["t"]), "q_sum": float(columns["q"].sum())})
    log = load_log(tmp_path / "log.npz")
    assert list(log["status"]) == ["ok", "max iterations", "ok"] and log["q"].shape == (9, 2)
    assert "extra" not in log.solves and log.meta["robot"] == "test"
    assert meta["summary"] == log.meta["summary"] == {"n": 9, "q_sum": 18.0}
    assert log.meta["t_reached"] == pytest.approx(2.2) and not log.partial and log.meta["chunks"] == 3


def test_load_log_names_a_truncated_file_a_bad_meta_and_a_missing_file(tmp_path):
    log = RunLog(signals={"t": np.arange(2000) * 0.002, "q": np.random.default_rng(0).normal(size=(2000, 5))})
    path = save_log(log, tmp_path / "run.npz")
    data = path.read_bytes()
    for name, cut in (("head", len(data) // 2), ("tail", len(data) - 30)):
        truncated = tmp_path / f"truncated_{name}.npz"
        truncated.write_bytes(data[:cut])
        with pytest.raises(ValueError, match=f"truncated_{name}.npz is truncated or corrupt"):
            load_log(truncated)
    bad_meta = tmp_path / "bad_meta.npz"
    np.savez(bad_meta, **{"signals/t": np.zeros(3), "meta": np.array("{'robot': not json")})
    with pytest.raises(ValueError, match=r"bad_meta.npz \(entry 'meta'\): the meta entry is not valid JSON"):
        load_log(bad_meta)
    with pytest.raises(FileNotFoundError, match="no log file at .*missing.npz"):
        load_log(tmp_path / "missing.npz")
    parts = tmp_path / "left.npz.parts"
    parts.mkdir()
    (parts / "meta.json").write_text("{oops")
    with pytest.raises(ValueError, match="meta.json: the meta entry is not valid JSON"):
        load_log(tmp_path / "left.npz")
    with zipfile.ZipFile(tmp_path / "zip_not_log.npz", "w") as archive:
        archive.writestr("readme.txt", "hello")
    with pytest.raises(ValueError, match="not a wbmpc log"):
        load_log(tmp_path / "zip_not_log.npz")


def test_streaming_arguments_are_checked(mpc, tmp_path):
    with pytest.raises(ValueError, match="keep_plans needs the in-memory log"):
        run_closed_loop(mpc, _config(), keep_plans=True, log_path=tmp_path / "x")
    with pytest.raises(ValueError, match="log_chunk must be"):
        run_closed_loop(mpc, _config(), log_path=tmp_path / "x", log_chunk=0.0)
    assert closed_loop.ClosedLoopLog().path is None  # in memory by default


def test_sigint_to_the_demo_leaves_a_readable_partial_log(tmp_path):
    out = tmp_path / "demo"
    # 8 nodes: the 6-node demo falls at t = 3.41 s, which a loaded machine reached before the first chunk.
    command = [sys.executable, "-m", "wbmpc.studies.demo", "--duration", "5", "--nodes", "8"]
    command += ["--no-replay", "--quiet", "--output", str(out)]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    # As from a terminal: SIGINT at its default. A parent that ignores it (a pytest-xdist worker does) would
    # pass SIG_IGN on, and Python then installs no KeyboardInterrupt handler at all.
    process = subprocess.Popen(
        command,
        cwd=REPO_ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        first_chunk = out / "log.npz.parts" / "chunk_000000.npz"
        deadline = time.monotonic() + 600
        while not first_chunk.exists():
            assert process.poll() is None, process.communicate()[1].decode()[-2000:]
            assert time.monotonic() < deadline, "the demo wrote no log chunk in 10 minutes"
            time.sleep(0.2)
        process.send_signal(signal.SIGINT)
        _, stderr = process.communicate(timeout=300)
    finally:
        if process.poll() is None:
            process.kill()
    lines = stderr.decode().strip().splitlines()
    assert process.returncode == 130, stderr.decode()[-2000:]
    assert lines[-1].startswith("demo interrupted at t = ") and lines[-1].endswith(
        f"partial log in {out}/log.npz"
    )
    log = load_log(out / "log.npz")
    assert log.partial and log.meta["interrupted"].startswith("KeyboardInterrupt")
    assert 1.0 - 0.002 <= log.meta["t_reached"] < 5.0 and log["t"][-1] == pytest.approx(log.meta["t_reached"])
    assert log.meta["summary"]["duration_s"] == pytest.approx(log.meta["t_reached"])
    assert not (out / "log.npz.parts").exists() and not (out / "summary.json").exists()
    json.dumps(log.meta)
