"""Tests for wbmpc.ocp.time_grid."""

import casadi as ca
import numpy as np
import pytest

from wbmpc.ocp.time_grid import (
    geometric_time_steps,
    horizon_for,
    interp_row,
    interp_rows,
    interp_weights,
    node_times,
    symbolic_geometric_time_steps,
    uniform_time_steps,
)


def test_paper_grid():
    dts = geometric_time_steps(15, 0.01, 0.1)
    assert dts.shape == (14,)
    assert dts[0] == 0.01 and dts[-1] == 0.1  # exact end points
    gamma = 10 ** (1 / 13)
    exact = 0.01 * (gamma**14 - 1) / (gamma - 1)  # geometric series
    assert 0.55 <= dts.sum() <= 0.57
    assert dts.sum() == pytest.approx(exact, rel=1e-12)
    assert dts.sum() == pytest.approx(0.5644522642, abs=1e-9)
    assert horizon_for(15, 0.01, 0.1) == pytest.approx(exact, rel=1e-12)


@pytest.mark.parametrize("n, dt_min, dt_max", [(3, 0.01, 0.05), (15, 0.01, 0.1), (30, 0.002, 0.2)])
def test_monotone_constant_ratio(n, dt_min, dt_max):
    dts = geometric_time_steps(n, dt_min, dt_max)
    assert np.all(np.diff(dts) > 0)
    ratios = dts[1:] / dts[:-1]
    np.testing.assert_allclose(ratios, (dt_max / dt_min) ** (1 / (n - 2)), rtol=1e-12)


def test_uniform_special_cases():
    np.testing.assert_allclose(geometric_time_steps(10, 0.02, 0.02), uniform_time_steps(10, 0.02), rtol=0)
    np.testing.assert_array_equal(geometric_time_steps(2, 0.01, 0.1), [0.01])
    assert uniform_time_steps(5, 0.05).shape == (4,)


def test_node_times():
    dts = geometric_time_steps(15, 0.01, 0.1)
    t = node_times(dts, t0=1.5)
    assert t.shape == (15,) and t[0] == 1.5
    np.testing.assert_allclose(np.diff(t), dts, rtol=1e-12)
    assert t[-1] == pytest.approx(1.5 + dts.sum())


@pytest.mark.parametrize("n", [2, 3, 15])
def test_symbolic_matches_numeric(n):
    lo, hi = ca.SX.sym("dt_min"), ca.SX.sym("dt_max")
    steps = symbolic_geometric_time_steps(n, lo, hi)
    assert len(steps) == n - 1
    f = ca.Function("dts", [lo, hi], [ca.vertcat(*steps)])
    for a, b in [(0.01, 0.1), (0.02, 0.02), (0.005, 0.03)]:
        np.testing.assert_allclose(f(a, b).full().ravel(), geometric_time_steps(n, a, b), rtol=1e-12)


def test_symbolic_mx():
    lo, hi = ca.MX.sym("dt_min"), ca.MX.sym("dt_max")
    f = ca.Function("dts", [lo, hi], [ca.vertcat(*symbolic_geometric_time_steps(15, lo, hi))])
    np.testing.assert_allclose(f(0.01, 0.1).full().ravel(), geometric_time_steps(15, 0.01, 0.1), rtol=1e-12)


@pytest.mark.parametrize(
    "args, name",
    [
        ((15, 0.0, 0.1), "dt_min"),
        ((15, -0.01, 0.1), "dt_min"),
        ((15, float("nan"), 0.1), "dt_min"),
        ((15, 0.01, float("nan")), "dt_max"),
        ((15, 0.01, float("inf")), "dt_max"),
        ((15, 0.1, 0.01), "dt_max"),
        ((1, 0.01, 0.1), "n_nodes"),
        ((15.0, 0.01, 0.1), "n_nodes"),
        ((True, 0.01, 0.1), "n_nodes"),
    ],
)
def test_errors(args, name):
    with pytest.raises(ValueError, match=name):
        geometric_time_steps(*args)


def test_other_errors():
    with pytest.raises(ValueError, match="dt"):
        uniform_time_steps(5, 0.0)
    with pytest.raises(ValueError, match="n_nodes"):
        symbolic_geometric_time_steps(1, 0.01, 0.1)
    for bad in ([0.01, -0.01], [0.01, 0.0], [0.01, float("nan")], [0.01, float("inf")], [np.inf, -np.inf]):
        with pytest.raises(ValueError, match="dts must be finite and > 0"):
            node_times(bad)
    with pytest.raises(ValueError, match="dts"):
        node_times([])
    with pytest.raises(ValueError, match="t0"):
        node_times([0.01], t0=float("nan"))


def test_interpolation_helpers_agree():
    """interp_row (one time) and interp_rows with precomputed weights give interp_rows' numbers exactly,
    inside the grid, on its nodes and held beyond both ends; linear in between."""
    rng = np.random.default_rng(3)
    t_old = node_times(geometric_time_steps(15, 0.01, 0.1), 0.3)
    rows = rng.normal(size=(15, 7))
    t_new = np.concatenate([rng.uniform(0.0, 1.2, 300), t_old, [t_old[0] - 1.0, t_old[-1] + 1.0]])
    expected = interp_rows(t_new, t_old, rows)
    np.testing.assert_array_equal(interp_rows(t_new, t_old, rows, interp_weights(t_new, t_old)), expected)
    for t, row in zip(t_new, expected, strict=True):
        np.testing.assert_array_equal(interp_row(t, t_old, rows), row)
    np.testing.assert_array_equal(expected[300:315], rows)  # on the nodes: the rows
    np.testing.assert_array_equal(expected[-2:], rows[[0, -1]])  # held at the ends
    middle = 0.5 * (t_old[3] + t_old[4])
    np.testing.assert_allclose(interp_row(middle, t_old, rows), 0.5 * (rows[3] + rows[4]), rtol=1e-12)
    np.testing.assert_array_equal(interp_row(0.7, t_old[:1], rows[:1]), rows[0])  # one node: held


def test_a_plans_node_times_follow_its_time_and_steps():
    """MPCSolution.node_times: the plan's t and cumulated dts, a fresh array that follows changes."""
    from wbmpc.control.config import MPCSolution

    dts = geometric_time_steps(5, 0.01, 0.1)
    plan = MPCSolution(
        t=0.2, dts=dts.copy(), q=np.zeros((5, 1)), v=np.zeros((5, 1)), a=np.zeros((4, 1)),
        forces=np.zeros((4, 1, 3)), tau=np.zeros((4, 1)), contact=np.ones((4, 4), bool), success=True,
        iterations=1, solve_time=0.0, status="success", constraint_violation=0.0,
    )  # fmt: skip
    np.testing.assert_array_equal(plan.node_times, node_times(dts, 0.2))
    plan.node_times[:] = -1.0  # a copy: the caller cannot change the plan's
    np.testing.assert_array_equal(plan.node_times, node_times(dts, 0.2))
    plan.t = 0.5
    np.testing.assert_array_equal(plan.node_times, node_times(dts, 0.5))
    plan.dts[0] = 0.02  # changed in place
    np.testing.assert_array_equal(plan.node_times, node_times(plan.dts, 0.5))
