"""The direct Fatrop driver in process: its stage functions run in CasADi's virtual machine inside the driver.

On the default robot (B1 + Z1, N = 15): from the same start the VM driver is the plugin's algorithm (same
iterations, same solution to rounding) on recorded trotting ticks; spreading the stage evaluations over two
threads changes no bit of a warm-started chain; the default in-process MPC solves with it and falls back to
the in-process plugin when it cannot be built. Nothing here compiles a problem: the driver library builds
in about 4 s once per machine (cached).
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
import threading
import warnings

import casadi as ca
import numpy as np
import pytest

from wbmpc.control.mpc import MPCConfig, SolverSettings, WholeBodyMPC
from wbmpc.model.robot import load_b1_z1
from wbmpc.ocp import OCPSettings
from wbmpc.solver.direct import DirectFatrop
from wbmpc.solver.direct.adapter import DirectNlpsol
from wbmpc.studies.direct_fatrop import record_ticks

# The same algorithm from one start: only rounding differs (the plugin assembles the NLP in MX).
SAME_START_ATOL = 1e-8


@pytest.fixture(scope="module")
def setup():
    robot = load_b1_z1()
    plugin = WholeBodyMPC(robot, OCPSettings(n_nodes=15), MPCConfig(), SolverSettings(direct=False))
    plugin.verbose = False
    ticks = [t for t in record_ticks(plugin, duration=0.25) if not t.cold]
    cfg = plugin.solver_settings
    options = {"tol": cfg.tol, "max_iter": cfg.max_iter, "compiled": False, "progress": False}
    drivers = {n: DirectFatrop(plugin.ocp, threads=n, **options) for n in (1, 2)}
    return {"robot": robot, "plugin": plugin, "ticks": ticks, "drivers": drivers}


def test_vm_driver_is_the_plugins_algorithm_from_the_same_start(setup):
    plugin, ticks = setup["plugin"], setup["ticks"]
    cfg = plugin.solver_settings
    solver = plugin._solver(cold=False)
    assert len(ticks) >= 6
    for tick in ticks[::3]:
        out = solver(x0=tick.x0, p=tick.p, lbg=plugin.ocp.lbg, ubg=plugin.ocp.ubg)
        stats = solver.stats()
        for driver in setup["drivers"].values():
            r = driver.solve(tick.p, tick.x0, mu_init=cfg.mu_init_warm)
            assert stats["success"] and r.success, r.reason
            assert r.iterations == stats["iter_count"]
            np.testing.assert_allclose(r.w, np.array(out["x"]).ravel(), atol=SAME_START_ATOL, rtol=0)
            np.testing.assert_allclose(r.lam_g, np.array(out["lam_g"]).ravel(), atol=1e-6, rtol=1e-6)


def test_two_threads_give_the_same_bits_as_one(setup):
    """A primal-dual warm-started chain over the recorded ticks, on one and on two evaluation threads."""
    cfg = setup["plugin"].solver_settings
    chains = {}
    for n, driver in setup["drivers"].items():
        previous, chain = None, []
        for tick in setup["ticks"]:
            if previous is None:
                r = driver.solve(tick.p, tick.x0, mu_init=cfg.mu_init_warm)
            else:
                r = driver.solve(tick.p, tick.x0, mu_init=max(previous.mu, 1e-9), duals=previous)
            assert r.success, r.reason
            chain.append(r)
            previous = r
        chains[n] = chain
    assert driver.threads == 2
    for one, two in zip(chains[1], chains[2], strict=True):
        assert one.iterations == two.iterations
        for name in ("w", "lam_g", "z_l", "z_u", "g"):
            assert np.array_equal(getattr(one, name), getattr(two, name)), name


def test_threads_are_checked(setup):
    with pytest.raises(ValueError, match="threads must be an integer >= 1 and <= 8"):
        setup["drivers"][1].set_threads(9)
    assert setup["drivers"][1].threads == 1


def test_default_in_process_mpc_uses_the_vm_driver(setup):
    settings = SolverSettings()
    assert settings.direct_driver and not settings.compiled
    # The default is resolved when read, so a copy with compiled=True means the compiled plugin path.
    compiled = dataclasses.replace(settings, compiled=True)
    assert not compiled.direct_driver and compiled.driver_threads == 1
    assert SolverSettings(compiled=True, direct=True).driver_threads == 1
    assert not SolverSettings(solver="ipopt").direct_driver
    mpc = WholeBodyMPC(setup["robot"], OCPSettings(n_nodes=15), MPCConfig(), settings)
    mpc.verbose = False
    solver = mpc._solver(cold=False)
    assert isinstance(solver, DirectNlpsol) and not solver.driver.compiled
    q, v = setup["robot"].q_nominal, np.zeros(setup["robot"].nv)
    for t in (0.0, 0.0125, 0.025):
        plan = mpc.solve(q, v, t)
        assert plan.success, plan.reason
    assert mpc.stats["solves"] == 3 and mpc.stats["failures"] == 0 and mpc.stats["exceptions"] == 0
    assert solver.stats()["solver"] == "direct"


def test_unbuildable_vm_driver_falls_back_to_the_in_process_plugin(setup, monkeypatch):
    from wbmpc.solver.direct import build

    def no_compiler(**_):
        raise FileNotFoundError("the direct Fatrop driver needs gcc and g++ on PATH")

    monkeypatch.setattr(build, "build_vm", no_compiler)
    mpc = WholeBodyMPC(setup["robot"], OCPSettings(n_nodes=15), MPCConfig(), SolverSettings())
    mpc.verbose = False
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        solver = mpc._solver(cold=False)
    assert any("direct Fatrop driver is unavailable" in str(w.message) for w in caught)
    assert isinstance(solver, ca.Function) and mpc.compiled_nlp is None  # in process: nothing compiled
    plan = mpc.solve(setup["robot"].q_nominal, np.zeros(setup["robot"].nv), 0.0)
    assert plan.success, plan.reason


def test_a_new_team_takes_the_first_solve(setup):
    """Helpers created right before a solve still take its first evaluation (a helper that looked at the
    team's task counter only after the solve had posted its task would wait forever). Two busy processes
    keep the cores taken so that new helpers start late; a hung solve fails here after 60 s."""
    cfg = setup["plugin"].solver_settings
    tick = setup["ticks"][0]
    driver = setup["drivers"][2]
    reference = setup["drivers"][1].solve(tick.p, tick.x0, mu_init=cfg.mu_init_warm)
    results = []

    def solves():
        for _ in range(40):
            driver.set_threads(1)
            driver.set_threads(2)
            results.append(driver.solve(tick.p, tick.x0, mu_init=cfg.mu_init_warm))

    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    try:
        worker = threading.Thread(target=solves, daemon=True)
        worker.start()
        worker.join(timeout=60.0)
    finally:
        for process in busy:
            process.kill()
            process.wait()
    assert not worker.is_alive(), f"a solve on a new team hung (after {len(results)} solves)"
    assert len(results) == 40
    for r in results:
        assert np.array_equal(r.w, reference.w) and r.iterations == reference.iterations
