"""Gaps in the tests of wbmpc/ocp/builder.py found by mutation testing (docs/mutation/builder_mpc.md).

Every constraint row and the cost of a small OCP, evaluated at a random point (random state, inputs and
parameters, swing and stance feet mixed), against the same quantities computed with numeric Pinocchio from
the physical definitions of the module docstring: Euler transitions, RNEA with the applied forces ``c F``,
the friction cone relaxed by ``1 - c``, the foot and end-effector velocities in world axes, the limits.
Standing solves leave most of these terms at zero (no swing foot, no tangential force, no arm velocity), so
a flipped sign or a dropped factor in them survives the solve tests.
"""

import warnings

import casadi as ca
import numpy as np
import pinocchio as pin
import pytest

from wbmpc.model.robot import load_b1_z1
from wbmpc.ocp import OCP, OCPSettings
from wbmpc.ocp.time_grid import geometric_time_steps

N, N_TAU, FRACTION = 4, 2, 0.8
LWA = pin.LOCAL_WORLD_ALIGNED


@pytest.fixture(scope="module")
def robot():
    return load_b1_z1()


def _random_point(robot, ocp, seed):
    """Physical quantities of every node, the parameter values and ``(w, p)`` for the NLP."""
    rng = np.random.default_rng(seed)
    model, nv, nj = robot.model, robot.nv, robot.nj
    n_c = len(robot.contact_frames)
    q_hat = pin.integrate(model, robot.q_nominal, 0.1 * rng.standard_normal(nv))
    v_hat = 0.3 * rng.standard_normal(nv)
    dq = 0.1 * rng.standard_normal((N, nv))
    v = 0.3 * rng.standard_normal((N, nv))
    dq[0], v[0] = 0.0, v_hat  # node 0 is the measurement
    a = rng.standard_normal((N - 1, nv))
    forces = 100.0 * rng.standard_normal((N - 1, n_c, 3))
    tau = 20.0 * rng.standard_normal((N_TAU, nj))
    contact = np.array([[1, 0, 1], [0, 1, 1], [1, 1, 0], [0, 0, 1]], float)  # feet x stages, both kinds
    values = {
        "q_hat": q_hat,
        "v_hat": v_hat,
        "dq_des": 0.1 * rng.standard_normal(nv),
        "v_des": 0.2 * rng.standard_normal(nv),
        "dt_min": 0.01,
        "dt_max": 0.05,
        "contact": contact,
        "swing_vz": rng.standard_normal((4, N - 1)),
        "force_des": 100.0 * rng.uniform(size=(4, N - 1)),
        "ee_velocity": rng.standard_normal((3, N - 1)),
        "ee_force": 10.0 * rng.standard_normal(3),
        "mu": 0.6,
        "Q": rng.uniform(0.5, 2.0, 2 * nv),
        "R": rng.uniform(0.5, 2.0, ocp.n_weights_input),
    }
    # The paper layout's arm force variable is not at its command here: the rows must use the variable.
    w = ocp.join(q_hat, dq, v, a, forces, tau)
    return dict(dq=dq, v=v, a=a, forces=forces, tau=tau, values=values, w=w, p=ocp.params.pack(values))


def _relative(g, lo, hi, x, lower, upper):
    """A limit row keeps the place of ``x`` between its limits: ``(g - lo) / (hi - lo)`` equals it."""
    np.testing.assert_allclose((g - lo) / (hi - lo), (x - lower) / (upper - lower), rtol=1e-9, atol=1e-9)


def _expected(robot, ocp, point):
    """Rows (by stage and name) and the cost from numeric Pinocchio."""
    model, data = robot.model, robot.model.createData()
    nv = robot.nv
    val = point["values"]
    dq, v, a, forces, tau = (point[k] for k in ("dq", "v", "a", "forces", "tau"))
    weight = robot.mass * robot.gravity
    dts = geometric_time_steps(N, val["dt_min"], val["dt_max"])
    feet = robot.foot_frames
    ee_input = ocp.settings.ee_force_input
    rows, cost = [], 0.0
    for k in range(N):
        q = pin.integrate(model, val["q_hat"], dq[k])
        pin.forwardKinematics(model, data, q, v[k])
        pin.updateFramePlacements(model, data)
        pin.computeJointJacobians(model, data, q)
        stage = {}
        x_err = np.concatenate([dq[k] - val["dq_des"], v[k] - val["v_des"]])
        cost += val["Q"] @ x_err**2
        if k < N - 1:
            c = val["contact"][:, k]
            F = forces[k]
            n_dec = len(robot.contact_frames) if ee_input else len(feet)
            f_des = np.zeros((n_dec, 3))
            f_des[: len(feet), 2] = val["force_des"][:, k]
            if ee_input:
                f_des[-1] = val["ee_force"]
            R = val["R"]
            cost += R[nv : nv + 3 * n_dec] @ ((F[:n_dec] - f_des).ravel() ** 2) + R[:nv] @ a[k] ** 2
            if k < N_TAU:
                start = nv + 3 * len(robot.contact_frames)
                cost += R[start:] @ tau[k] ** 2
            applied = [c[i] * F[i] for i in range(len(feet))] + [F[-1] if ee_input else val["ee_force"]]
            stage["transition"] = np.concatenate([dq[k + 1], v[k + 1]]) - np.concatenate(
                [dq[k] + v[k] * dts[k], v[k] + a[k] * dts[k]]
            )
            if k == 0 and ocp.settings.initial_state_variables:
                stage["initial_state"] = np.concatenate([dq[0], v[0] - val["v_hat"]])
            JtF = sum(
                pin.getFrameJacobian(model, data, robot.frame_id(f), LWA)[:3].T @ applied[i]
                for i, f in enumerate(robot.contact_frames)
            )
            rnea = pin.rnea(model, data, q, v[k], a[k]) - JtF
            stage["dynamics"] = np.concatenate([rnea[:6], rnea[6:] - tau[k]]) if k < N_TAU else rnea[:6]
            if k < N_TAU:
                stage["torque_limits"] = tau[k]
            stage["friction_cone"] = np.concatenate(
                [
                    [
                        F[i, 2] / weight + 1 - c[i],
                        (val["mu"] ** 2 * F[i, 2] ** 2 - F[i, 0] ** 2 - F[i, 1] ** 2),
                    ]
                    for i in range(len(feet))
                ]
            )
            stage["friction_cone"][1::2] = stage["friction_cone"][1::2] / weight**2 + (1 - c)
            if ee_input:
                stage["ee_force"] = F[-1] - val["ee_force"]
            if k >= 1:
                foot = []
                for i, f in enumerate(feet):
                    vel = pin.getFrameVelocity(model, data, robot.frame_id(f), LWA).linear
                    foot += [
                        c[i] * vel[:2] + (1 - c[i]) * F[i, :2] / weight,
                        [vel[2] - (1 - c[i]) * val["swing_vz"][i, k]],
                    ]
                stage["foot_velocity"] = np.concatenate(foot)
                ee_vel = pin.getFrameVelocity(model, data, robot.frame_id(robot.ee_frame), LWA).linear
                stage["ee_velocity"] = ee_vel - val["ee_velocity"][:, k]
        if k >= 1:
            stage["joint_position_limits"] = q[7:]
            stage["joint_velocity_limits"] = v[k][6:]
        rows.append(stage)
    return rows, cost


@pytest.mark.parametrize(
    "layout",
    [{}, {"ee_force_input": True, "initial_state_variables": True}],
    ids=["parameters", "paper_layout"],
)
def test_every_row_and_the_cost_match_numeric_pinocchio(robot, layout):
    ocp = OCP(robot, OCPSettings(n_nodes=N, n_tau_nodes=N_TAU, torque_limit_fraction=FRACTION, **layout))
    f = ca.Function("fg", [ocp.nlp["x"], ocp.nlp["p"]], [ocp.nlp["f"], ocp.nlp["g"]])
    point = _random_point(robot, ocp, seed=3)
    cost, g = (np.asarray(out).ravel() for out in f(point["w"], point["p"]))
    rows, expected_cost = _expected(robot, ocp, point)
    np.testing.assert_allclose(cost, expected_cost, rtol=1e-9)
    lo_q, hi_q = robot.joint_position_limits
    v_max, t_max = robot.joint_velocity_limits, FRACTION * robot.joint_torque_limits
    limits = {
        "torque_limits": (-t_max, t_max),
        "joint_position_limits": (lo_q, hi_q),
        "joint_velocity_limits": (-v_max, v_max),
    }
    n_rows = 0
    for info, stage in zip(ocp.stages, rows, strict=True):
        assert set(info.rows) == set(stage), f"node {info.k}"
        for name, expected in stage.items():
            sl = info.rows[name]
            n_rows += sl.stop - sl.start
            value, lo, hi = g[sl], ocp.lbg[sl], ocp.ubg[sl]
            if name in limits:
                _relative(value, lo, hi, expected, *limits[name])
                np.testing.assert_allclose(lo, -1.0)
                np.testing.assert_allclose(hi, 1.0)
                continue
            np.testing.assert_allclose(
                value, expected, rtol=1e-8, atol=1e-8, err_msg=f"{name}, node {info.k}"
            )
            if name == "friction_cone":
                assert np.all(lo == 0) and np.all(hi == np.inf)
            else:
                assert np.all(lo == 0) and np.all(hi == 0), name
                assert all(ocp.equality[sl]), name
    assert n_rows == ocp.n_constraints


@pytest.mark.parametrize("layout", [{}, {"ee_force_input": True}], ids=["parameters", "paper_layout"])
def test_plan_function_returns_the_physical_plan(robot, layout):
    """The plan of a primal vector: the increments, velocities, accelerations, the forces acting on the
    robot (``c F`` on the feet, the arm force) and the torques that went in."""
    ocp = OCP(robot, OCPSettings(n_nodes=N, n_tau_nodes=N_TAU, **layout))
    point = _random_point(robot, ocp, seed=5)
    plan = {k: np.array(v) for k, v in ocp.plan_function(w=point["w"], p=point["p"]).items()}
    val = point["values"]
    np.testing.assert_allclose(plan["dq"].T, point["dq"], atol=1e-12)
    np.testing.assert_allclose(plan["v"].T, point["v"], atol=1e-12)
    np.testing.assert_allclose(plan["a"].T, point["a"], atol=1e-12)
    np.testing.assert_allclose(plan["tau"].T, point["tau"], atol=1e-12)
    applied = point["forces"].copy()
    applied[:, :4] *= val["contact"].T[:, :, None]
    if not layout:
        applied[:, -1] = val["ee_force"]
    np.testing.assert_allclose(plan["forces"].T.reshape(N - 1, -1, 3), applied, atol=1e-12)
    split = ocp.split(point["w"], point["p"])
    np.testing.assert_allclose(split["dq"], point["dq"], atol=1e-12)
    np.testing.assert_allclose(split["v"], point["v"], atol=1e-12)
    np.testing.assert_allclose(split["a"], point["a"], atol=1e-12)
    np.testing.assert_allclose(split["tau"], point["tau"], atol=1e-12)
    np.testing.assert_allclose(
        np.array(ocp.dts_function(0.01, 0.05)).ravel(), geometric_time_steps(N, 0.01, 0.05)
    )


def test_a_terminal_node_without_velocity_costs_its_configuration_error(robot):
    """Centroidal velocity: the terminal node has no velocity, its cost is ``Q_dq (dq - dq_des)^2``."""
    ocp = OCP(robot, OCPSettings(n_nodes=3, n_tau_nodes=1, formulation="centroidal_velocity"))
    f = ca.Function("f", [ocp.nlp["x"], ocp.nlp["p"]], [ocp.nlp["f"]])
    rng = np.random.default_rng(1)
    values = {
        name: rng.uniform(0.5, 1.5, rows * cols) for name, (_, (rows, cols)) in ocp.params.blocks.items()
    }
    values["q_hat"] = robot.q_nominal
    p = ocp.params.pack(values)
    w = 0.1 * rng.standard_normal(ocp.n_variables)
    last = ocp.stages[-1]
    dq_offset = last.x_offset + 6  # terminal state [h / m, dq]
    base = float(f(w, p))
    for i in (0, 7, robot.nv - 1):
        step = np.zeros_like(w)
        step[dq_offset + i] = 0.3
        x = w[dq_offset + i] - values["dq_des"][i]
        assert float(f(w + step, p)) - base == pytest.approx(
            values["Q"][i] * ((x + 0.3) ** 2 - x**2), rel=1e-9
        )


def test_forward_dynamics_transition_uses_the_applied_forces(robot):
    """Forward dynamics: ``v' - v = dt M^-1 ([0; tau] + J^T (c F) - b)`` with the arm's commanded force."""
    ocp = OCP(robot, OCPSettings(n_nodes=3, n_tau_nodes=1, formulation="forward_dynamics"))
    g = ca.Function("g", [ocp.nlp["x"], ocp.nlp["p"]], [ocp.nlp["g"]])
    rng = np.random.default_rng(2)
    model, data, nv = robot.model, robot.model.createData(), robot.nv
    values = {
        name: rng.uniform(0.5, 1.5, rows * cols) for name, (_, (rows, cols)) in ocp.params.blocks.items()
    }
    contact = np.array([1.0, 0.0, 1.0, 1.0])
    values |= {"q_hat": robot.q_nominal, "dt_min": 0.01, "dt_max": 0.05}
    values["contact"] = np.tile(contact[:, None], (1, 2))  # 3 nodes: 2 stages
    p = ocp.params.pack(values)
    w = 0.1 * rng.standard_normal(ocp.n_variables)
    s1 = ocp.stages[1]  # stage 1: [dq, v] then [tau, F]
    w[s1.u_offset + robot.nj : s1.u_offset + s1.nu] = 50.0 * rng.standard_normal(s1.nu - robot.nj)
    dq, v = w[s1.x_offset : s1.x_offset + nv], w[s1.x_offset + nv : s1.x_offset + 2 * nv]
    tau, F = (
        w[s1.u_offset : s1.u_offset + robot.nj],
        w[s1.u_offset + robot.nj : s1.u_offset + s1.nu].reshape(4, 3),
    )
    x_next = w[ocp.stages[2].x_offset : ocp.stages[2].x_offset + 2 * nv]
    q = pin.integrate(model, robot.q_nominal, dq)
    applied = [contact[i] * F[i] for i in range(4)] + [values["ee_force"]]
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    JtF = sum(
        pin.getFrameJacobian(model, data, robot.frame_id(f), LWA)[:3].T @ applied[i]
        for i, f in enumerate(robot.contact_frames)
    )
    M = pin.crba(model, data, q)
    M = np.triu(M) + np.triu(M, 1).T
    b = pin.rnea(model, data, q, v, np.zeros(nv))
    a = np.linalg.solve(M, np.r_[np.zeros(6), tau] + JtF - b)
    dt = geometric_time_steps(3, 0.01, 0.05)[1]
    rows = np.asarray(g(w, p)).ravel()[s1.rows["transition"]]
    np.testing.assert_allclose(rows, x_next - np.r_[dq + v * dt, v + a * dt], rtol=1e-8, atol=1e-8)


# --- the helpers: limit rows, parameter packing, stage sizes, split, the plan at the velocity level -------


def test_unit_rows_keep_the_feasible_set_with_unit_bounds():
    """Finite ranges become ``-1 <= (x - mid) / half <= 1``; infinite, huge or empty ranges (an equality) are
    left as they are, without a warning from the infinite or largest-float bounds."""
    from wbmpc.ocp.builder import _unit_rows

    big = np.finfo(float).max  # Pinocchio's "no limit" (continuous joints): the range overflows to inf
    lower = np.array([-2.0, 0.5, -3.0, -np.inf, -1e7, 1.5, -np.inf, 2.0, -big])
    upper = np.array([3.0, 0.75, 2e5, 4.0, 1e7, 1.5, np.inf, np.inf, big])
    scaled = np.arange(9) < 3
    x = ca.SX.sym("x", 9)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        expr, lo, hi = _unit_rows(x, lower, upper)
    assert lo.dtype == hi.dtype == float
    np.testing.assert_array_equal(lo[scaled], -1.0)
    np.testing.assert_array_equal(hi[scaled], 1.0)
    np.testing.assert_array_equal(lo[~scaled], lower[~scaled])
    np.testing.assert_array_equal(hi[~scaled], upper[~scaled])
    f = ca.Function("f", [x], [expr])
    rng = np.random.default_rng(0)
    for x0 in rng.uniform(-5.0, 5.0, (5, 9)):
        rows = np.asarray(f(x0)).ravel()
        mid, half = (upper[scaled] + lower[scaled]) / 2, (upper[scaled] - lower[scaled]) / 2
        np.testing.assert_allclose(rows[scaled], (x0[scaled] - mid) / half, rtol=1e-14)
        np.testing.assert_array_equal(rows[~scaled], x0[~scaled])
        # the same feasible set, row by row
        np.testing.assert_array_equal((lo <= rows) & (rows <= hi), (lower <= x0) & (x0 <= upper))
    # integer bounds (e.g. a list) are read as floats
    expr, lo, hi = _unit_rows(x[:2], [0, -1], [1, 3])
    np.testing.assert_array_equal(lo, -1.0)
    np.testing.assert_allclose(
        np.asarray(ca.Function("g", [x], [expr])(np.full(9, 0.5))).ravel(), [0.0, -0.25]
    )


def test_parameter_layout_packs_column_major_and_unpacks():
    """The packed vector is what the symbols read (matrices column-major), ``unpack`` inverts ``pack``, and
    every malformed value is refused."""
    from wbmpc.ocp.builder import ParameterLayout

    P = ParameterLayout()
    syms = [P.add("a", 3), P.add("m", 2, 3), P.add("s", 1)]
    assert P.size == 10 and P.vector.shape == (10, 1)
    assert P.blocks == {"a": (0, (3, 1)), "m": (3, (2, 3)), "s": (9, (1, 1))}
    m = np.arange(6.0).reshape(2, 3) + 10.0
    values = {"a": [1.0, 2.0, 3.0], "m": m, "s": 7.0}
    p = P.pack(values)
    assert p.shape == (10,)
    np.testing.assert_array_equal(p, [1, 2, 3, 10, 13, 11, 14, 12, 15, 7])
    read = ca.Function("read", [P.vector], syms)(p)
    np.testing.assert_array_equal(np.asarray(read[0]).ravel(), values["a"])
    np.testing.assert_array_equal(np.asarray(read[1]), m)
    assert float(read[2]) == 7.0
    np.testing.assert_array_equal(P.pack(values | {"m": m.ravel()}), p)  # a flat value: the matrix's ravel
    np.testing.assert_array_equal(P.unpack(p, "m"), m)
    np.testing.assert_array_equal(P.unpack(p, "a"), values["a"])
    np.testing.assert_array_equal(P.unpack(p, "s"), [7.0])
    P.unpack(p, "a")[:] = 0.0  # a copy
    assert p[0] == 1.0
    two = ParameterLayout()  # two columns (the per-stage blocks of a 3-node OCP)
    two.add("c", 3, 2)
    c = np.arange(6.0).reshape(3, 2)
    np.testing.assert_array_equal(two.unpack(two.pack({"c": c}), "c"), c)
    with pytest.raises(ValueError, match=r"missing: \['s'\], unknown: \[\]"):
        P.pack({"a": values["a"], "m": m})
    with pytest.raises(ValueError, match=r"missing: \[\], unknown: \['t'\]"):
        P.pack(values | {"t": 1.0})
    with pytest.raises(ValueError, match=r"'m' must have shape \(2, 3\), got \(3, 2\)"):
        P.pack(values | {"m": m.T})
    with pytest.raises(ValueError, match=r"'a' must have shape \(3, 1\), got \(2,\)"):
        P.pack(values | {"a": [1.0, 2.0]})
    for bad in (np.nan, np.inf, -np.inf):
        with pytest.raises(ValueError, match="'s' contains NaN or inf"):
            P.pack(values | {"s": bad})
    with pytest.raises(ValueError):  # not a number: a ValueError too, as every bad input of the package
        P.pack(values | {"s": "fast"})


def test_parameter_blocks_of_the_ocp(robot):
    """The blocks the OCP's rows read, with one column per stage for the per-stage parameters."""
    ocp = OCP(robot, OCPSettings(n_nodes=3, n_tau_nodes=1))
    nv, n_stages = robot.nv, 2
    expected = {
        "q_hat": (robot.nq, 1),
        "v_hat": (nv, 1),
        "dq_des": (nv, 1),
        "v_des": (nv, 1),
        "dt_min": (1, 1),
        "dt_max": (1, 1),
        "contact": (4, n_stages),
        "swing_vz": (4, n_stages),
        "force_des": (4, n_stages),
        "ee_velocity": (3, n_stages),
        "ee_force": (3, 1),
        "mu": (1, 1),
        "Q": (2 * nv, 1),
        "R": (nv + 3 * len(robot.contact_frames) + robot.nj, 1),
    }
    assert {name: shape for name, (_, shape) in ocp.params.blocks.items()} == expected
    assert ocp.params.size == ocp.nlp["p"].numel() == sum(r * c for r, c in expected.values())
    assert ocp.stage_parameter_sizes() == {
        name: expected[name][0] for name in ocp.STAGE_PARAMETERS if name != "dt"
    } | {"dt": 1}


@pytest.mark.parametrize(
    "settings",
    [
        dict(n_nodes=4, n_tau_nodes=2),
        dict(n_nodes=4, n_tau_nodes=2, initial_state_variables=True, ee_force_input=True),
        dict(n_nodes=3, n_tau_nodes=1),
        dict(n_nodes=3, n_tau_nodes=1, formulation="centroidal_velocity"),
        dict(n_nodes=3, n_tau_nodes=1, formulation="forward_dynamics"),
    ],
    ids=["parameters", "paper_layout", "one_torque_node", "centroidal_velocity", "forward_dynamics"],
)
def test_stage_sizes_are_what_fatrop_detects(robot, settings):
    """``stage_sizes`` against Fatrop's own structure detection on the OCP, and the sizes add up to the
    NLP's variables and rows (the transition rows counted as dynamics)."""
    from wbmpc.solver.nlpsol import make_nlpsol, solver_options

    ocp = OCP(robot, OCPSettings(**settings))
    sizes = ocp.stage_sizes()
    assert sum(sizes["nx"]) + sum(sizes["nu"]) == ocp.n_variables
    assert sum(sizes["ng"]) + sum(sizes["nx"][1:]) == ocp.n_constraints
    options = solver_options("fatrop", tol=1e-3, max_iter=1, mu_init=0.1, warm=False, equality=ocp.equality)
    solver = make_nlpsol("s", "fatrop", ocp.nlp, options)
    values = {name: np.ones(rows * cols) for name, (_, (rows, cols)) in ocp.params.blocks.items()}
    values |= {"q_hat": robot.q_nominal, "dt_min": 0.01, "dt_max": 0.05}
    solver(x0=np.zeros(ocp.n_variables), p=ocp.params.pack(values), lbg=ocp.lbg, ubg=ocp.ubg)  # one iteration
    stats = solver.stats()
    assert {key: list(stats[key]) for key in ("nx", "nu", "ng")} == sizes


def test_split_needs_a_primal_vector_of_the_right_size_and_the_parameters(robot):
    ocp = OCP(robot, OCPSettings(n_nodes=3, n_tau_nodes=1))
    w = np.zeros(ocp.n_variables)
    with pytest.raises(
        ValueError, match=rf"w must have shape \({ocp.n_variables},\), got \({ocp.n_variables + 1},\)"
    ):
        ocp.split(np.zeros(ocp.n_variables + 1))
    with pytest.raises(ValueError, match=r"split\(w, p\) needs p"):
        ocp.split(w)
    values = {name: np.zeros(rows * cols) for name, (_, (rows, cols)) in ocp.params.blocks.items()}
    values |= {"q_hat": robot.q_nominal, "v_hat": np.arange(robot.nv, dtype=float)}
    blocks = ocp.split([0] * ocp.n_variables, ocp.params.pack(values))  # any array-like, read as floats
    assert all(block.dtype == float for block in blocks.values())
    np.testing.assert_array_equal(blocks["dq"][0], 0.0)
    np.testing.assert_array_equal(blocks["v"][0], values["v_hat"])  # node 0: the measurement
    assert blocks["dq"].shape == blocks["v"].shape == (3, robot.nv)
    assert blocks["a"].shape == (2, robot.nv) and blocks["F"].shape == (2, 3 * 4)
    assert blocks["tau"].shape == (1, robot.nj)


def _pin_plan_residuals(robot, q, v, a, applied):
    """RNEA minus the applied forces' generalised force (numeric Pinocchio)."""
    model, data = robot.model, robot.model.createData()
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    JtF = sum(
        pin.getFrameJacobian(model, data, robot.frame_id(f), LWA)[:3].T @ applied[i]
        for i, f in enumerate(robot.contact_frames)
    )
    return pin.rnea(model, data, q, v, a) - JtF


@pytest.mark.parametrize("formulation", ["centroidal_velocity", "centroidal_velocity_nobase"])
def test_velocity_level_plan_is_consistent_with_its_forces(robot, formulation):
    """At the velocity level the plan's joint accelerations are the finite differences of the velocities,
    the base acceleration the one the applied forces imply (RNEA base rows zero), the torques of the
    torque-limited nodes the RNEA joint rows, and the terminal velocity repeats the last one."""
    n_nodes, n_tau = 4, 2
    ocp = OCP(robot, OCPSettings(n_nodes=n_nodes, n_tau_nodes=n_tau, formulation=formulation))
    rng = np.random.default_rng(7)
    nv = robot.nv
    values = {
        name: rng.uniform(0.5, 1.5, rows * cols) for name, (_, (rows, cols)) in ocp.params.blocks.items()
    }
    contact = np.array([[1, 0, 1], [0, 1, 1], [1, 1, 0], [1, 1, 1]], float)
    q_hat = pin.integrate(robot.model, robot.q_nominal, 0.1 * rng.standard_normal(nv))
    values |= {"q_hat": q_hat, "dt_min": 0.01, "dt_max": 0.05, "contact": contact}
    p = ocp.params.pack(values)
    w = 0.2 * rng.standard_normal(ocp.n_variables)
    plan = {k: np.array(val) for k, val in ocp.plan_function(w=w, p=p).items()}
    dts = geometric_time_steps(n_nodes, 0.01, 0.05)
    assert plan["v"].shape == (nv, n_nodes) and plan["a"].shape == (nv, n_nodes - 1)
    assert plan["tau"].shape == (robot.nj, n_tau)
    np.testing.assert_array_equal(plan["v"][:, -1], plan["v"][:, -2])
    np.testing.assert_allclose(plan["dq"][:, 0], 0.0, atol=1e-14)
    for k in range(n_nodes - 1):
        q = pin.integrate(robot.model, q_hat, plan["dq"][:, k])
        v, a = plan["v"][:, k], plan["a"][:, k]
        np.testing.assert_allclose(a[6:], (plan["v"][6:, k + 1] - v[6:]) / dts[k], rtol=1e-10, atol=1e-10)
        applied = plan["forces"][:, k].reshape(-1, 3)
        np.testing.assert_allclose(applied[-1], values["ee_force"])  # the command acts on the robot
        residual = _pin_plan_residuals(robot, q, v, a, applied)
        np.testing.assert_allclose(residual[:6], 0.0, atol=1e-8 * max(1.0, np.abs(residual).max()))
        if k < n_tau:
            np.testing.assert_allclose(plan["tau"][:, k], residual[6:], rtol=1e-8, atol=1e-8)
    blocks = ocp.split(w, p)
    for k in range(n_nodes - 1):
        np.testing.assert_allclose(
            plan["forces"][:12, k].reshape(4, 3),
            contact[:, k, None] * blocks["F"][k].reshape(4, 3),
            atol=1e-14,
        )


def test_join_of_a_velocity_level_formulation_stores_the_momentum_of_each_node(robot):
    """``join`` at the velocity level: the state's ``h`` is the centroidal momentum / mass of the node's
    configuration ``q_hat (+) dq`` and velocity (numeric Pinocchio), the inputs the velocities and the foot
    forces (the arm force is a parameter); ``split`` reads them back."""
    n_nodes = 3
    ocp = OCP(robot, OCPSettings(n_nodes=n_nodes, n_tau_nodes=1, formulation="centroidal_velocity"))
    rng = np.random.default_rng(8)
    model, nv = robot.model, robot.nv
    q_hat = pin.integrate(model, robot.q_nominal, 0.1 * rng.standard_normal(nv))
    dq, v = 0.1 * rng.standard_normal((n_nodes, nv)), rng.standard_normal((n_nodes, nv))
    dq[0] = 0.0
    forces = 100.0 * rng.standard_normal((n_nodes - 1, 5, 3))
    w = ocp.join(q_hat, dq, v, np.zeros((n_nodes - 1, nv)), forces, np.zeros((0, robot.nj)))
    values = {name: np.zeros(rows * cols) for name, (_, (rows, cols)) in ocp.params.blocks.items()}
    values |= {"q_hat": q_hat, "v_hat": v[0]}
    blocks = ocp.split(w, ocp.params.pack(values))
    data = model.createData()
    mass = sum(inertia.mass for inertia in model.inertias)
    for k in range(n_nodes):
        h = pin.computeCentroidalMomentum(model, data, pin.integrate(model, q_hat, dq[k]), v[k])
        np.testing.assert_allclose(blocks["h"][k], np.r_[h.linear, h.angular] / mass, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(blocks["dq"][k], dq[k], atol=1e-15)
    np.testing.assert_allclose(blocks["v"], v[:-1], atol=1e-15)
    np.testing.assert_allclose(blocks["F"], forces[:, :4].reshape(n_nodes - 1, 12), atol=1e-15)


def test_join_fills_missing_torque_rows_with_zeros(robot):
    ocp = OCP(robot, OCPSettings(n_nodes=4, n_tau_nodes=2))
    nv, n = robot.nv, 4
    tau = np.full((1, robot.nj), 5.0)  # torques of stage 0 only
    w = ocp.join(
        robot.q_nominal,
        np.zeros((n, nv)),
        np.ones((n, nv)),
        np.ones((n - 1, nv)),
        np.ones((n - 1, 5, 3)),
        tau,
    )
    values = {name: np.zeros(rows * cols) for name, (_, (rows, cols)) in ocp.params.blocks.items()}
    values["q_hat"] = robot.q_nominal
    blocks = ocp.split(w, ocp.params.pack(values))
    np.testing.assert_array_equal(blocks["tau"], np.r_[tau, np.zeros((1, robot.nj))])


class _Scaled:
    """Initial-state rows that are not ``x_0 - c(p)``: the state cannot be substituted by a parameter."""

    @staticmethod
    def scaled(self, st, q_hat, v_hat):
        return 2 * ca.vertcat(st.dq, st.v - v_hat)

    @staticmethod
    def with_input(self, st, q_hat, v_hat):
        return ca.vertcat(st.dq, st.v - v_hat + (st.u[0] if st.u is not None else 0))

    @staticmethod
    def nonlinear(self, st, q_hat, v_hat):
        return ca.vertcat(st.dq + st.dq**2, st.v - v_hat)

    @staticmethod
    def parameter_gain(self, st, q_hat, v_hat):
        return ca.vertcat(st.dq, (1 + v_hat[0] ** 2) * st.v - v_hat)

    @staticmethod
    def short(self, st, q_hat, v_hat):
        return st.dq


@pytest.mark.parametrize("rows", ["scaled", "with_input", "nonlinear", "parameter_gain", "short"])
def test_initial_state_rows_that_are_not_x_minus_c_are_refused(robot, monkeypatch, rows):
    from wbmpc.ocp.formulations import InverseDynamics

    monkeypatch.setattr(InverseDynamics, "initial_state", getattr(_Scaled, rows))
    message = (
        r"'inverse_dynamics': initial_state\(\) must return x_0 - c\(p\) to enter node 0's state as a "
        r"parameter; use OCPSettings\(initial_state_variables=True\)$"
    )
    with pytest.raises(ValueError, match=message):
        OCP(robot, OCPSettings(n_nodes=3, n_tau_nodes=1))
    OCP(robot, OCPSettings(n_nodes=3, n_tau_nodes=1, initial_state_variables=True))  # pinned by rows: fine


def test_initial_state_value_is_the_measured_state(robot):
    """Node 0's state as a parameter: ``[0, v_hat]``, or ``[h(q_hat, v_hat) / m, 0]`` (velocity level)."""
    rng = np.random.default_rng(9)
    model, nv = robot.model, robot.nv
    q_hat = pin.integrate(model, robot.q_nominal, 0.1 * rng.standard_normal(nv))
    v_hat = rng.standard_normal(nv)
    mass = sum(inertia.mass for inertia in model.inertias)
    h = pin.computeCentroidalMomentum(model, model.createData(), q_hat, v_hat)
    for formulation, expected in (
        ("inverse_dynamics", np.r_[np.zeros(nv), v_hat]),
        ("centroidal_velocity", np.r_[h.linear / mass, h.angular / mass, np.zeros(nv)]),
    ):
        ocp = OCP(robot, OCPSettings(n_nodes=3, n_tau_nodes=1, formulation=formulation))
        values = {
            name: rng.uniform(size=rows * cols) for name, (_, (rows, cols)) in ocp.params.blocks.items()
        }
        values |= {"q_hat": q_hat, "v_hat": v_hat}
        x0 = np.asarray(ocp.initial_state_function(ocp.params.pack(values))).ravel()
        np.testing.assert_allclose(x0, expected, rtol=1e-10, atol=1e-12)
        # called by its input and output names, as the plan function is
        x0 = np.asarray(ocp.initial_state_function(p=ocp.params.pack(values))["x0"]).ravel()
        np.testing.assert_allclose(x0, expected, rtol=1e-10, atol=1e-12)
        # of a stage without inputs too (the OCP calls it on node 0, which has them)
        p = ocp.params.symbols
        st = ocp.formulation.stage("t", p["q_hat"], has_input=False, torque_limited=False)
        x0 = ca.Function("x0", [ocp.params.vector], [ocp.initial_state_value(st, p)])(ocp.params.pack(values))
        np.testing.assert_allclose(np.asarray(x0).ravel(), expected, rtol=1e-10, atol=1e-12)


def test_ocp_settings_accept_their_whole_range_and_refuse_the_rest_with_the_full_message():
    """``OCPSettings.__post_init__``: every bound on both sides, numpy integers, floats and booleans where
    they are meant, and each refusal's whole message (the bad-input catalogue matches only parts of them)."""
    from wbmpc.ocp.formulations import FORMULATIONS

    def refused(message, **kwargs):
        with pytest.raises(ValueError) as err:
            OCPSettings(**kwargs)
        assert str(err.value) == message

    # accepted: the ends of every range, numpy scalars
    for kwargs in (
        {"n_nodes": 3, "n_tau_nodes": 1},
        {"n_nodes": 3, "n_tau_nodes": 2},
        {"n_nodes": np.int64(4), "n_tau_nodes": np.int32(3)},
        {"n_nodes": 100, "n_tau_nodes": 99},
        {"torque_limit_fraction": 1},
        {"torque_limit_fraction": 1.0},
        {"torque_limit_fraction": 1e-9},
        {"torque_limit_fraction": np.float32(0.5)},
        {"ee_force_input": True, "initial_state_variables": True},
        {"ee_force_input": np.bool_(True), "initial_state_variables": np.bool_(False)},
        *({"formulation": name} for name in FORMULATIONS),
    ):
        settings = OCPSettings(**kwargs)
        assert all(getattr(settings, key) == value for key, value in kwargs.items())

    for n in (2, 0, -3):
        refused(f"n_nodes must be an integer >= 3, got {n!r}", n_nodes=n)
    for n in (15.0, "15", True, None):
        refused(f"n_nodes must be an integer >= 3, got {n!r}", n_nodes=n)
    refused(
        "n_nodes = 101 is above 100: the problem grows linearly (N = 1000 took 419 s and 11.4 GB for its "
        "first solve); the paper uses 15",
        n_nodes=101,
    )
    for n_nodes, n_tau in ((3, 0), (3, 3), (5, 5), (5, 7), (5, -1), (5, 2.0), (5, True), (5, "2")):
        refused(
            f"n_tau_nodes must be in [1, n_nodes - 1 = {n_nodes - 1}], got {n_tau}",
            n_nodes=n_nodes,
            n_tau_nodes=n_tau,
        )
    refused(f"unknown formulation 'magic'; available: {list(FORMULATIONS)}", formulation="magic")
    for fraction in (0, 0.0, -0.5, 1.0000001, 2, float("nan"), True, "0.5", None):
        refused(
            f"OCPSettings.torque_limit_fraction must be in (0, 1], got {fraction!r}",
            torque_limit_fraction=fraction,
        )
    for name in ("ee_force_input", "initial_state_variables"):
        for value in ("no", 0, 1, None):
            refused(f"OCPSettings.{name} must be True or False, got {value!r}", **{name: value})
