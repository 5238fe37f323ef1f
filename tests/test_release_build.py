"""The release library built in the background and switched to between two solves (wbmpc.solver.release).

The "release" flags here are the base flags plus a macro: a distinct cache key whose library computes exactly
what the base one does, so a switch must leave the solutions bit-identical (only the library changes) and its
build costs a base build's time. The real release flags (-O3 -march=native) take minutes; the benchmark of
issue 22 times them.
"""

from __future__ import annotations

import numpy as np
import pytest

from wbmpc.control.mpc import MPCConfig, SolverSettings, WholeBodyMPC
from wbmpc.model.robot import load_b1_z1
from wbmpc.ocp import OCPSettings
from wbmpc.ocp.gait import make_gait
from wbmpc.solver import codegen
from wbmpc.solver.direct import build as direct_build
from wbmpc.solver.release import ReleaseUpgrade

SMALL = OCPSettings(n_nodes=3, n_tau_nodes=1)
BASE = ("-O1",)
RELEASE = ("-O1", "-DWBMPC_RELEASE_TEST")
BUILD_TIMEOUT_S = 600.0


@pytest.fixture
def full_mode(tmp_path, monkeypatch):
    """Full mode (quick mode leaves the release library out) with a cache of this test's own."""
    monkeypatch.delenv("WBMPC_QUICK", raising=False)
    monkeypatch.setenv("WBMPC_CACHE_DIR", str(tmp_path))
    return tmp_path


def _mpc(direct: bool, release=RELEASE, build: bool = True) -> WholeBodyMPC:
    robot = load_b1_z1()
    config = MPCConfig(gait=make_gait("stand"), dt_max=0.02)
    solver = SolverSettings(
        compiled=True, direct=direct, compile_flags=BASE, release_flags=release, release_build=build
    )
    mpc = WholeBodyMPC(robot, SMALL, config, solver)
    mpc.verbose = False
    return mpc


def _states(robot, n: int):
    """Standing states, each a little off the last (so that every solve iterates)."""
    rng = np.random.default_rng(3)
    q, v = robot.q_nominal.copy(), np.zeros(robot.nv)
    for _ in range(n):
        q = q.copy()
        q[2] += 0.004 * rng.standard_normal()
        v = 0.05 * rng.standard_normal(robot.nv)
        yield q, v


def _library(mpc) -> str:
    if mpc.solver_settings.direct:
        from wbmpc.solver.direct.adapter import _DRIVERS

        return str(_DRIVERS[mpc].library_path)
    return str(mpc.compiled_nlp.library)


@pytest.mark.parametrize("direct", [False, True], ids=["plugin", "direct"])
def test_switches_to_the_release_library_between_solves_and_keeps_the_solutions(full_mode, direct):
    mpc, reference = _mpc(direct), _mpc(direct, release=None)
    states = list(_states(mpc.robot, 4))
    first = mpc.solve(*states[0], t=0.0)
    assert first.success and mpc.library_flags() == BASE
    assert mpc.release.process is not None, "the release build did not start after the base build"
    base_library = _library(mpc)
    kind = direct_build if direct else codegen
    assert kind.cached(mpc.ocp, RELEASE) is None  # not there before the background build ends
    twin = _mpc(direct)  # a second MPC of the problem while the build runs: it waits for the same build
    assert twin.solve(*states[0], t=0.0).success
    assert twin.release.process is mpc.release.process
    mpc.release.process.wait(BUILD_TIMEOUT_S)
    assert mpc.release.process.returncode == 0
    assert kind.cached(mpc.ocp, RELEASE) is not None
    plans = [first] + [mpc.solve(*s, t=0.01 * (i + 1)) for i, s in enumerate(states[1:])]
    mpc.release._last_poll = 0.0  # noqa: SLF001 -- the poll period would otherwise hide the build's end
    assert mpc.stats["library_switches"] <= 1
    plans.append(mpc.solve(*states[-1], t=0.05))
    assert mpc.stats["library_switches"] == 1
    assert mpc.library_flags() == RELEASE and _library(mpc) != base_library
    assert any("library_switch" in p.timings for p in plans[1:])
    expected = [reference.solve(*s, t=0.01 * i) for i, s in enumerate(states)]
    expected.append(reference.solve(*states[-1], t=0.05))
    assert reference.stats["library_switches"] == 0 and reference.release.process is None
    for plan, ref in zip(plans, expected, strict=True):
        assert plan.success and ref.success
        assert plan.iterations == ref.iterations
        np.testing.assert_array_equal(plan.w, ref.w)  # the same arithmetic: the warm start carried over
    # A new MPC of the same problem finds the release library and builds nothing.
    again = _mpc(direct)
    assert again.library_flags() == RELEASE
    assert again.solve(*states[0], t=0.0).success
    assert again.release.process is None and again.stats["library_switches"] == 0
    assert _library(again) == _library(mpc)


def test_a_failed_release_build_warns_once_and_keeps_the_base_library(full_mode):
    mpc = _mpc(False, release=("-O1", "-fwbmpc-no-such-flag"))
    q, v = next(_states(mpc.robot, 1))
    assert mpc.solve(q, v).success
    mpc.release.process.wait(BUILD_TIMEOUT_S)
    mpc.release._last_poll = 0.0  # noqa: SLF001
    with pytest.warns(UserWarning, match="wbmpc-no-such-flag"):
        plan = mpc.solve(q, v, t=0.01)
    assert plan.success and mpc.library_flags() == BASE and mpc.stats["library_switches"] == 0
    assert "exit code" in mpc.release.failure
    mpc.release._last_poll = 0.0  # noqa: SLF001
    assert mpc.release.start() is False  # not retried in this MPC
    assert mpc.solve(q, v, t=0.02).success


def test_without_release_build_the_release_library_is_used_only_when_cached(full_mode):
    """``release_build=False`` (the runtime's worker): no compiler starts; a release library another MPC
    left in the cache is used from the first solve."""
    q, v = next(_states(load_b1_z1(), 1))
    waiting = _mpc(False, build=False)
    assert waiting.solve(q, v).success
    assert waiting.release.process is None and waiting.library_flags() == BASE
    builder = _mpc(False)
    assert builder.solve(q, v).success and builder.release.process is not None
    builder.release.process.wait(BUILD_TIMEOUT_S)
    later = _mpc(False, build=False)
    assert later.library_flags() == RELEASE and later.solve(q, v).success
    assert later.release.process is None


def test_quick_mode_leaves_the_release_library_out(tmp_path, monkeypatch):
    monkeypatch.setenv("WBMPC_QUICK", "1")
    monkeypatch.setenv("WBMPC_CACHE_DIR", str(tmp_path))
    mpc = _mpc(False)
    assert mpc.library_flags() == BASE and not mpc.release.enabled
    assert mpc.release.start() is False and mpc.release.process is None


def test_release_settings_are_checked():
    with pytest.raises(ValueError, match="release_flags"):
        SolverSettings(compiled=True, release_flags=("-O3", 3))
    assert SolverSettings(release_flags=["-O2"]).release_flags == ("-O2",)
    assert SolverSettings().release_flags == codegen.RELEASE_FLAGS
    with pytest.raises(ValueError, match="release_build"):
        SolverSettings(release_build="no")
    with pytest.raises(ValueError, match="kind"):
        ReleaseUpgrade(None, "plugin", BASE, RELEASE)
