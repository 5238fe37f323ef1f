"""Gaps in the tests of wbmpc/ocp/builder.py found by mutation testing (docs/mutation/builder_mpc.md).

Every constraint row and the cost of a small OCP, evaluated at a random point (random state, inputs and
parameters, swing and stance feet mixed), against the same quantities computed with numeric Pinocchio from
the physical definitions of the module docstring: Euler transitions, RNEA with the applied forces ``c F``,
the friction cone relaxed by ``1 - c``, the foot and end-effector velocities in world axes, the limits.
Standing solves leave most of these terms at zero (no swing foot, no tangential force, no arm velocity), so
a flipped sign or a dropped factor in them survives the solve tests.
"""

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
