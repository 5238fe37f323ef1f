"""The direct Fatrop driver (wbmpc.solver.direct) against the casadi-plugin compiled path.

On the default robot (B1 + Z1, N = 15, default settings): from the same start the direct driver is the same
algorithm (same solution to rounding, same status, same iterations) on standing and trotting ticks with
contact switches; from its primal-dual warm start it converges to the plugin's solution within the
tolerance's scale, satisfying the constraints, in no more iterations. The build (cached) takes about 110 s
on a 2-vCPU EPYC the first time; the tests after it take about 20 s.
"""

from __future__ import annotations

import numpy as np
import pytest

from wbmpc.control.mpc import MPCConfig, SolverSettings, WholeBodyMPC
from wbmpc.model.robot import load_b1_z1
from wbmpc.ocp import OCPSettings
from wbmpc.ocp.gait import make_gait
from wbmpc.solver.direct import DirectFatrop
from wbmpc.studies.direct_fatrop import record_ticks

# Primal agreement from one start: the same algorithm, only rounding differs (the plugin's MX assembly).
SAME_START_ATOL = 1e-8


@pytest.fixture(scope="module")
def setup():
    robot = load_b1_z1()
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=15), MPCConfig(), SolverSettings(compiled=True))
    mpc.verbose = False
    mpc.prepare()
    direct = DirectFatrop(mpc.ocp, tol=mpc.solver_settings.tol, max_iter=mpc.solver_settings.max_iter)
    trot = record_ticks(mpc, duration=1.0)
    contact = mpc.ocp.params.blocks["contact"]

    def contact_now(tick):
        start, (rows, _) = contact
        return tuple(tick.p[start : start + rows] > 0.5)

    # Ticks where the stance of node 0 changed since the previous tick (lift-off / touchdown), plus others.
    switches = [
        b for a, b in zip(trot, trot[1:], strict=False) if contact_now(a) != contact_now(b) and not b.cold
    ]
    others = [t for t in trot[5::8] if not t.cold]
    mpc_stand = WholeBodyMPC(
        robot, OCPSettings(n_nodes=15), MPCConfig(gait=make_gait("stand")), SolverSettings(compiled=True)
    )
    mpc_stand.verbose = False
    q, v = robot.q_nominal, np.zeros(robot.nv)
    stand = []
    for t in (0.0, 0.0125):
        mpc_stand.solve(q, v, t)
        stand.append(dict(mpc_stand.last_inputs))
    return {
        "mpc": mpc,
        "mpc_stand": mpc_stand,
        "direct": direct,
        "trot": trot,
        "switches": switches[:4],
        "others": others[:4],
        "stand": stand,
    }


def _plugin(mpc, p, x0, cold):
    solver = mpc._solver(cold=cold)
    out = solver(x0=x0, p=p, lbg=mpc.ocp.lbg, ubg=mpc.ocp.ubg)
    stats = solver.stats()
    return (
        np.array(out["x"]).ravel(),
        np.array(out["lam_g"]).ravel(),
        int(stats["iter_count"]),
        bool(stats["success"]),
    )


def _violation(mpc, g):
    return float(np.max(np.maximum(0.0, np.maximum(mpc.ocp.lbg - g, g - mpc.ocp.ubg))))


def test_trot_has_contact_switches(setup):
    assert len(setup["switches"]) >= 2, "the recorded trot should switch node 0's stance twice within 1 s"


@pytest.mark.parametrize("which", ["stand", "switches", "others"])
def test_same_start_same_solution_and_iterations(setup, which):
    mpc, direct = (setup["mpc_stand"] if which == "stand" else setup["mpc"]), setup["direct"]
    cfg = mpc.solver_settings
    cases = (
        [(a["p"], a["x0"], i == 0) for i, a in enumerate(setup["stand"])]
        if which == "stand"
        else [(t.p, t.x0, False) for t in setup[which]]
    )
    assert cases
    for p, x0, cold in cases:
        w_ref, lam_ref, iters_ref, ok_ref = _plugin(mpc, p, x0, cold)
        # The plugin's options of that start (cold: Fatrop's default bound push).
        direct.set_option("bound_push", 1e-2 if cold else 1e-7)
        r = direct.solve(p, x0, mu_init=cfg.mu_init_cold if cold else cfg.mu_init_warm)
        direct.set_option("bound_push", 1e-7)
        assert ok_ref and r.success and r.status == "success"
        assert r.iterations == iters_ref
        np.testing.assert_allclose(r.w, w_ref, atol=SAME_START_ATOL, rtol=0)
        np.testing.assert_allclose(r.lam_g, lam_ref, atol=1e-6, rtol=1e-6)
        assert _violation(mpc, r.g) <= cfg.tol


def test_primal_dual_warm_start_matches_plugin_with_no_more_iterations(setup):
    mpc, direct = setup["mpc"], setup["direct"]
    cfg = mpc.solver_settings
    ticks = [t for t in setup["trot"] if not t.cold][:24]
    previous, total_plugin, total_direct = None, 0, 0
    for tick in ticks:
        w_ref, _, iters_ref, ok_ref = _plugin(mpc, tick.p, tick.x0, False)
        if previous is None:
            r = direct.solve(tick.p, tick.x0, mu_init=cfg.mu_init_warm)
        else:
            r = direct.solve(tick.p, tick.x0, mu_init=max(previous.mu, 1e-9), duals=previous)
            total_plugin += iters_ref
            total_direct += r.iterations
        assert ok_ref and r.success, r.reason
        # Two solutions that each meet the tolerance from different starts: close on the tolerance's scale.
        assert np.max(np.abs(r.w - w_ref)) <= 10 * cfg.tol
        assert _violation(mpc, r.g) <= cfg.tol
        previous = r
    assert total_direct <= total_plugin


def test_dual_warm_start_uses_the_duals(setup):
    """Warm duals change the start: from exact duals of the same tick the solve needs fewer iterations."""
    mpc, direct = setup["mpc"], setup["direct"]
    tick = setup["others"][0]
    cold_duals = direct.solve(tick.p, tick.x0, mu_init=mpc.solver_settings.mu_init_warm)
    again = direct.solve(tick.p, cold_duals.w, mu_init=max(cold_duals.mu, 1e-9), duals=cold_duals)
    assert again.success and again.iterations < cold_duals.iterations
    np.testing.assert_allclose(again.w, cold_duals.w, atol=10 * mpc.solver_settings.tol)


def test_bad_inputs_raise_before_solving(setup):
    direct, mpc = setup["direct"], setup["mpc"]
    tick = setup["others"][0]
    with pytest.raises(ValueError, match="p must have"):
        direct.solve(tick.p[:-1], tick.x0)
    with pytest.raises(ValueError, match="NaN"):
        direct.solve(tick.p, np.full_like(tick.x0, np.nan))
    with pytest.raises(ValueError, match="together"):
        direct.solve(tick.p, tick.x0, lam_g0=np.zeros(mpc.ocp.n_constraints))
    with pytest.raises(ValueError, match="Fatrop option"):
        direct.set_option("no_such_option", 1.0)
    with pytest.raises(ValueError, match="must be a wbmpc.ocp.OCP"):
        DirectFatrop("not an OCP")
    with pytest.raises(ValueError, match="flags must be a list"):
        DirectFatrop(mpc.ocp, flags="-O1")


def test_iteration_cap_is_a_named_failure(setup):
    mpc, direct = setup["mpc_stand"], setup["direct"]
    a = setup["stand"][0]
    direct.set_option("max_iter", 1)
    try:
        r = direct.solve(a["p"], a["x0"], mu_init=mpc.solver_settings.mu_init_cold)
    finally:
        direct.set_option("max_iter", mpc.solver_settings.max_iter)
    assert not r.success and r.status == "max_iter_exceeded" and r.reason


def test_behind_the_mpc_same_statuses_and_plans(setup):
    """SolverSettings(direct=True): the MPC's own solve() on the recorded observations of the trot."""
    robot, plugin_ticks = setup["mpc"].robot, [t for t in setup["trot"] if t.w is not None]
    mpc = WholeBodyMPC(
        robot, OCPSettings(n_nodes=15), MPCConfig(), SolverSettings(compiled=True, direct=True)
    )
    mpc.verbose = False
    direct_iterations = plugin_iterations = 0
    for i, tick in enumerate(plugin_ticks[:30]):
        plan = mpc.solve(tick.q_hat, tick.v_hat, tick.t, tick.commands)
        assert plan.success and plan.status == tick.status == "success" and not plan.fallback
        assert np.max(np.abs(plan.w - tick.w)) <= 10 * mpc.solver_settings.tol
        if i > 0:  # after the first (cold) tick both are warm started
            direct_iterations += plan.iterations
            plugin_iterations += tick.iterations
    assert direct_iterations <= plugin_iterations
    assert mpc.stats["failures"] == 0 and mpc.stats["exceptions"] == 0
    assert mpc._solver(cold=False).stats()["fatrop"]["warm_duals"]


def test_direct_settings_are_checked():
    with pytest.raises(ValueError, match="direct needs solver='fatrop'"):
        SolverSettings(solver="ipopt", direct=True)
    with pytest.raises(ValueError, match="True, False or None"):
        SolverSettings(direct="yes")


def test_unavailable_driver_falls_back_to_the_plugin(setup, monkeypatch):
    from wbmpc.solver.direct import adapter

    def unavailable(*args, **kwargs):
        raise OSError("g++ not found")

    monkeypatch.setattr(adapter, "DirectFatrop", unavailable)
    mpc = WholeBodyMPC(
        setup["mpc"].robot, OCPSettings(n_nodes=15), MPCConfig(), SolverSettings(compiled=True, direct=True)
    )
    mpc.verbose = False
    with pytest.warns(UserWarning, match="unavailable"):
        solver = mpc.make_solver("fallback", cold=True)
        plan = mpc.solve(mpc.robot.q_nominal, np.zeros(mpc.robot.nv), 0.0)
    assert not isinstance(solver, adapter.DirectNlpsol)
    assert plan.success and plan.status == "success"
