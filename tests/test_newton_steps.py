"""Fixed Fatrop iterations per tick (wbmpc.solver.direct.fixed_steps, wbmpc.studies.newton_steps).

On the default robot (B1 + Z1, N = 15) with the compiled direct driver (default -O1 flags, cached): exactly
k iterations are taken, one iteration from a tick's converged solution changes nothing beyond the
tolerance, two iterations are closer to the converged solution than one on recorded trot ticks, the
driver's options are Fatrop's defaults again afterwards, the fixed-step MPC applies finite plans only (a
NaN iterate is a failure with the MPC's fallback), and sqpmethod's solution equals Fatrop's if it converges.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from wbmpc.control.fixed_steps import FixedStepMPC
from wbmpc.control.mpc import MPCConfig, SolverSettings, WholeBodyMPC
from wbmpc.model.robot import load_b1_z1
from wbmpc.ocp import OCPSettings
from wbmpc.solver.direct import DirectFatrop
from wbmpc.solver.direct.fixed_steps import (
    FATROP_ACCEPTABLE_DEFAULTS,
    FIXED_STEPS_STATUS,
    fixed_step_solve,
    usable_iterate,
)
from wbmpc.studies.direct_fatrop import record_ticks
from wbmpc.studies.newton_steps import NodeZero, recorded_ticks, sqp_solver

SOLVER = SolverSettings(compiled=True, direct=True)


@pytest.fixture(scope="module")
def setup():
    robot = load_b1_z1()
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=15), MPCConfig(), SOLVER)
    mpc.verbose = False
    mpc.prepare()
    cfg = mpc.solver_settings
    direct = DirectFatrop(mpc.ocp, tol=cfg.tol, max_iter=cfg.max_iter, progress=False)
    ticks = record_ticks(mpc, duration=0.3)
    return {"robot": robot, "mpc": mpc, "direct": direct, "ticks": [t for t in ticks if not t.cold]}


def _chain(direct, ticks, n):
    """Converged solutions along ``n + 1`` ticks: (tick, previous tick's solution, this tick's)."""
    previous = direct.solve(ticks[0].p, ticks[0].x0)
    out = []
    for tick in ticks[1 : n + 1]:
        solution = direct.solve(tick.p, tick.x0, duals=previous)
        assert solution.success
        out.append((tick, previous, solution))
        previous = solution
    return out


def test_exactly_k_iterations_and_options_restored(setup):
    direct = setup["direct"]
    (tick, previous, converged), *_ = _chain(direct, setup["ticks"], 1)
    for k in (1, 2):
        r = fixed_step_solve(direct, tick.p, tick.x0, k, duals=previous)
        assert r.iterations == k
        assert usable_iterate(r) and not r.success  # an acceptable point, not converged
    for name, value in FATROP_ACCEPTABLE_DEFAULTS.items():
        assert direct.options[name] == value
    again = direct.solve(tick.p, tick.x0, duals=previous)  # the converged solve is unchanged afterwards
    assert again.success and again.iterations == converged.iterations
    np.testing.assert_allclose(again.w, converged.w, atol=1e-12)
    with pytest.raises(ValueError):
        fixed_step_solve(direct, tick.p, tick.x0, 0)


def test_one_step_from_the_converged_solution_changes_nothing(setup):
    direct = setup["direct"]
    for tick, _, converged in _chain(direct, setup["ticks"], 3):
        r = fixed_step_solve(direct, tick.p, converged.w, 1, duals=converged, mu_init=converged.mu)
        assert usable_iterate(r)
        assert np.max(np.abs(r.w - converged.w)) <= direct.tol


def test_two_steps_closer_than_one_on_recorded_ticks(setup):
    direct = setup["direct"]
    result = recorded_ticks(direct, setup["ticks"][:8])
    per = result["per_variant"]
    assert per["converged"]["flags"] == {"success": 7}
    for key in ("primal_diff", "tau0_diff_Nm", "force0_diff_N"):
        assert per["steps_2"][key]["max"] < per["steps_1"][key]["max"]
    assert per["steps_2"]["residuals"]["dynamics"]["max"] < per["steps_1"]["residuals"]["dynamics"]["max"]
    assert per["steps_1"]["iterations_mean"] == 1 and per["steps_2"]["iterations_mean"] == 2
    assert result["from_converged_max_primal_change"] <= direct.tol


def test_node_zero_of_the_converged_solution(setup):
    node0 = NodeZero(setup["mpc"].ocp)
    tick, _, converged = _chain(setup["direct"], setup["ticks"], 1)[0]
    tau, force = node0.torques_forces(converged.w, tick.p)
    assert tau.shape == (setup["robot"].nj,) and np.all(np.isfinite(force))
    residuals = node0.residuals(converged.g)
    assert max(residuals.values()) < setup["direct"].tol


def test_fixed_step_mpc_applies_finite_plans_and_fails_on_nan(setup):
    robot, ticks = setup["robot"], setup["ticks"]
    with pytest.raises(ValueError):
        FixedStepMPC(robot, OCPSettings(n_nodes=15), MPCConfig(), SolverSettings(compiled=True), steps=1)
    mpc = FixedStepMPC(robot, OCPSettings(n_nodes=15), MPCConfig(), SOLVER, steps=1)
    mpc.verbose = False
    plans = [mpc.solve(t.q_hat, t.v_hat, t.t, t.commands) for t in ticks[:6]]
    assert plans[0].status == "success"  # the cold start converges
    for plan in plans[1:]:
        assert plan.success and plan.status == FIXED_STEPS_STATUS and plan.iterations == 1
        assert all(np.all(np.isfinite(x)) for x in (plan.tau, plan.forces, plan.q, plan.v))
    # A NaN iterate is not applied: the warm solve fails (non_finite_solution) and the cold retry solves.
    solver = mpc._solver(cold=False)
    driver = solver.driver._driver
    real_solve = driver.solve

    def nan_solve(*args, **kwargs):
        result = real_solve(*args, **kwargs)
        return dataclasses.replace(result, w=np.full_like(result.w, np.nan))

    driver.solve = nan_solve
    try:
        warm = solver(x0=mpc.last_inputs["x0"], p=mpc.last_inputs["p"])
        assert not solver.stats()["success"] and np.isnan(warm["x"]).all()
    finally:
        del driver.solve
    before = mpc.stats["failures"]
    driver.solve = nan_solve
    try:
        tick = ticks[6]
        mpc.config = dataclasses.replace(mpc.config, cold_retry=False)
        plan = mpc.solve(tick.q_hat, tick.v_hat, tick.t, tick.commands)
    finally:
        del driver.solve
    assert not plan.success and plan.fallback and plan.status == "non_finite_solution"
    assert mpc.stats["failures"] == before + 1
    assert all(np.all(np.isfinite(x)) for x in (plan.tau, plan.forces))  # the previous plan, shifted


def test_sqpmethod_hpipm_equals_fatrop_if_it_converges(setup):
    ocp, direct = setup["mpc"].ocp, setup["direct"]
    tick, previous, converged = _chain(direct, setup["ticks"], 1)[0]
    solver = sqp_solver(ocp, "hpipm")  # the OCP structure from ocp.stage_sizes() is accepted
    sol = solver(x0=tick.x0, p=tick.p, lbg=ocp.lbg, ubg=ocp.ubg, lam_g0=previous.lam_g)
    stats = solver.stats()
    if stats["success"]:
        assert np.max(np.abs(np.array(sol["x"]).ravel() - converged.w)) < 10 * direct.tol
    else:  # measured: it does not converge here (docs/newton_steps.md)
        assert stats["return_status"] in ("Maximum_Iterations_Exceeded", "Search_Direction_Becomes_Too_Small")
