"""The runtime's plumbing between its processes: when a plan starts, how accounts come back, who runs where.

A plan made with delay compensation starts in the future (its measurement time plus the expected delay):
the controller keeps the plan in use until then, as the simulated loop does. Children report through
files written whole (a queue loses, or hangs on, a child killed mid-write)."""

import multiprocessing as mp
import os
import signal
from dataclasses import dataclass
from types import SimpleNamespace

import pytest

from wbmpc.runtime.accounts import read_account, write_account
from wbmpc.runtime.control_loop import ControlLoop
from wbmpc.runtime.run import CPU_LAYOUTS, RuntimeConfig, cpu_sets


class _Controller:
    def __init__(self):
        self.offered = []

    def offer(self, plan):
        self.offered.append(plan)


def _loop():
    loop = object.__new__(ControlLoop)  # only the hand-over's state: no processes, no robot
    loop.controller, loop.pending, loop.used_seq, loop.used_obs_t = _Controller(), [], 0, 0.0
    return loop


def test_a_plan_waits_for_its_start_time_and_the_newest_due_plan_wins():
    loop = _loop()
    early, later, latest = (SimpleNamespace(t=t) for t in (1.00, 1.02, 1.05))
    loop.pending = [(early, 7, 0.96), (later, 8, 0.98), (latest, 9, 1.01)]
    loop._start_due_plans(0.99)
    assert loop.controller.offered == [] and loop.used_seq == 0  # none has started: the old plan goes on
    loop._start_due_plans(1.00)
    assert loop.controller.offered == [early] and loop.used_seq == 7 and loop.used_obs_t == 0.96
    loop._start_due_plans(1.06)  # both later ones are due: the newest is used, the other dropped
    assert loop.controller.offered == [early, latest] and loop.used_seq == 9 and loop.used_obs_t == 1.01
    assert loop.pending == []


def test_a_plan_due_already_is_handed_over_at_once():
    loop = _loop()
    late = SimpleNamespace(t=0.5)  # arrived after its start (a slow solve): interpolated from its inside
    loop.pending = [(late, 3, 0.46)]
    loop._start_due_plans(0.52)
    assert loop.controller.offered == [late] and loop.used_seq == 3


@dataclass
class _Account:
    solves: int
    errors: list


def test_an_account_round_trips_and_a_missing_one_says_why(tmp_path):
    path = tmp_path / "worker.pickle"
    assert read_account(path) == {"errors": ["no account received (the process was killed?)"]}
    write_account(path, _Account(3, []))
    assert read_account(path) == {"solves": 3, "errors": []}
    assert [p.name for p in tmp_path.iterdir()] == ["worker.pickle"]  # no partial file left


def _write_big_account_forever(path):
    write_account(path, {"t": list(range(1_000_000))})  # a robot's per-step log: megabytes
    signal.pause()


def test_a_child_killed_after_its_account_is_read_without_hanging(tmp_path):
    """A queue would block the parent on a message half written by a killed child; a file is whole."""
    path = tmp_path / "robot.pickle"
    child = mp.get_context("spawn").Process(target=_write_big_account_forever, args=(str(path),))
    child.start()
    try:
        for _ in range(200):
            if path.exists():
                break
            child.join(0.05)
        child.kill()
        child.join(5)
        assert len(read_account(path)["t"]) == 1_000_000
    finally:
        if child.is_alive():
            child.kill()


def test_cpu_layouts_give_one_process_a_cpu_to_itself():
    assert cpu_sets("split", {0, 1}) == {"controller": {0}, "worker": {1}, "robot": {0}}
    assert cpu_sets("controller", {0, 1}) == {"controller": {1}, "worker": {0}, "robot": {0}}
    assert cpu_sets("robot", {0, 1, 2, 3}) == {"controller": {0, 1, 2}, "worker": {0, 1, 2}, "robot": {3}}
    assert cpu_sets("any", {0, 1}) == dict.fromkeys(("controller", "worker", "robot"))
    assert cpu_sets("split", {0}) == dict.fromkeys(("controller", "worker", "robot"))  # one CPU: nothing
    assert set(cpu_sets("split")["worker"]) <= os.sched_getaffinity(0)
    assert set(CPU_LAYOUTS) == {"split", "controller", "robot", "any"}


def test_a_bad_cpu_layout_is_refused_before_anything_starts():
    with pytest.raises(ValueError, match=r"cpu_layout must be one of .*'fast'"):
        RuntimeConfig(cpu_layout="fast")


def test_plan_latencies_are_the_first_use_minus_the_measurement_time():
    import numpy as np

    from wbmpc.runtime.report import plan_latencies

    log = {
        "t": np.array([0.0, 0.002, 0.004, 0.006, 0.008, 0.010]),
        "plan_seq": np.array([1, 1, 2, 2, 3, 3]),
        "plan_obs_t": np.array([0.0, 0.0, -0.030, -0.030, -0.025, -0.025]),
        "damping": np.array([False, False, False, False, True, True]),
    }
    uses, latency = plan_latencies(log)
    # plan 2 first used at 4 ms, made from the measurement at -30 ms; plan 3 only in damping: not used
    assert uses == pytest.approx([0.004]) and latency == pytest.approx([0.034])


def test_a_run_folder_without_its_files_is_named_with_the_command_that_writes_them(tmp_path):
    from wbmpc.runtime.report import load_run

    message = r"no summary.json and no runtime_log.npz.*python -m wbmpc.runtime"
    with pytest.raises(FileNotFoundError, match=message):
        load_run(tmp_path)


def test_the_worker_solves_with_the_direct_driver_by_default():
    # compiled or in process (its VM build); the plugin when told
    assert RuntimeConfig().direct is True and RuntimeConfig(compiled=False).direct is True
    assert RuntimeConfig(direct=False).direct is False


def test_the_worker_recipe_solves_with_the_driver_it_is_told_and_starts_no_release_build():
    from wbmpc.control.mpc import WholeBodyMPC
    from wbmpc.runtime.mpc_worker import MPCRecipe

    built = {}

    def record(self, robot, settings, config, solver):
        built["solver"] = solver
        raise RuntimeError("stop before the build")

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(WholeBodyMPC, "__init__", record)
        for direct in (False, True):
            with pytest.raises(RuntimeError, match="stop before the build"):
                MPCRecipe(direct=direct, max_iter=15).build()
            solver = built["solver"]
            assert (solver.direct, solver.compiled, solver.max_iter) == (direct, True, 15)
            assert solver.driver_threads == 1  # the loops have the other cores
            # the release library if cached, but no gcc taking a core from the loops mid-run
            assert solver.release_flags is not None and solver.release_build is False
