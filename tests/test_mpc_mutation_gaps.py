"""Gaps in the tests of wbmpc/control/mpc.py found by mutation testing (docs/mutation/builder_mpc.md).

The failed-solve rule with injected solver outcomes (a failed solve is never applied: the previous
converged plan comes back and stays the warm start; the cold retry's report), and physical properties of
the starts and parameters: the cold guess is a feasible standing point of the OCP, the shifted guess keeps
the previous plan's configurations at their times, the force targets carry the weight, the velocity
command is the commanded world velocity in the base frame.
"""

import casadi as ca
import numpy as np
import pinocchio as pin
import pytest

from wbmpc.control.mpc import Commands, MPCConfig, WholeBodyMPC
from wbmpc.model.robot import load_b1_z1
from wbmpc.ocp import OCPSettings
from wbmpc.ocp.gait import make_gait

PLAN = ("q", "v", "a", "forces", "tau")


@pytest.fixture(scope="module")
def robot():
    return load_b1_z1()


def _mpc(robot, gait="stand", n_nodes=4, **config):
    mpc = WholeBodyMPC(
        robot, OCPSettings(n_nodes=n_nodes), MPCConfig(gait=make_gait(gait), dt_max=0.03, **config)
    )
    mpc.verbose = False
    return mpc


class _Fake:
    """A ``casadi.nlpsol`` stand-in: raises, or returns a finite unconverged iterate (an iteration cap)."""

    def __init__(self, n_constraints, w=None, iterations=7):
        self.w, self.n, self.iterations, self.calls = w, n_constraints, iterations, []

    def __call__(self, **args):
        self.calls.append(args)
        if self.w is None:
            raise RuntimeError("injected failure")
        return {"x": self.w.copy(), "g": np.zeros(self.n), "lam_g": np.ones(self.n), "f": 0.0}

    def stats(self):
        return {
            "success": False,
            "return_status": 1,
            "iter_count": self.iterations,
            "fatrop": {"return_flag": 1, "iterations_count": self.iterations, "time_total": 1e-3},
        }


def _violation(mpc, w, p):
    g = np.asarray(ca.Function("g", [mpc.ocp.nlp["x"], mpc.ocp.nlp["p"]], [mpc.ocp.nlp["g"]])(w, p)).ravel()
    return np.max(np.maximum(0.0, np.maximum(mpc.ocp.lbg - g, g - mpc.ocp.ubg)))


def test_the_cold_guess_is_a_feasible_standing_point(robot):
    """Standing at rest with an arm load: the cold guess (static forces and torques on every node) meets
    every row of the OCP (transitions, RNEA, cone, foot and arm velocities, limits)."""
    mpc = _mpc(robot)
    q, v = robot.q_nominal, np.zeros(robot.nv)
    commands = Commands(ee_force=np.array([5.0, -3.0, -20.0]))
    params = mpc.parameters(q, v, 0.0, commands)
    x0 = mpc.cold_guess(q, v, params)
    assert _violation(mpc, x0, mpc.ocp.params.pack(params)) < 1e-8
    split = mpc.ocp.split(x0, mpc.ocp.params.pack(params))
    # The feet carry the weight and the arm's load.
    assert split["F"][:, 2:12:3].sum(axis=1) == pytest.approx(np.full(3, robot.mass * robot.gravity + 20.0))


def test_the_force_targets_carry_the_weight_and_the_arm_load_on_the_stance_feet(robot):
    mpc = _mpc(robot, gait="trot", n_nodes=8)
    q = robot.q_nominal
    load = np.array([0.0, 0.0, -30.0])  # pushing down on the robot
    params = mpc.parameters(q, np.zeros(robot.nv), 0.1, Commands(ee_force=load))
    contact = params["contact"]
    assert (contact == 0).any() and (contact == 1).any()
    np.testing.assert_allclose(params["force_des"].sum(axis=0), robot.mass * robot.gravity - load[2])
    assert np.all(params["force_des"][contact == 0] == 0)
    assert np.all(params["swing_vz"][contact == 1] == 0) and np.any(params["swing_vz"][contact == 0] != 0)
    np.testing.assert_array_equal(params["q_hat"], q)


def test_the_velocity_command_is_the_world_velocity_in_the_base_frame(robot):
    """Commands are in the heading frame: ``R_base v_des`` is the command turned by the heading only."""
    mpc = _mpc(robot)
    q = robot.q_nominal.copy()
    yaw, rpy = 0.7, np.array([0.1, -0.15, 0.7])
    q[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(*rpy)).coeffs()
    lin, ang = np.array([0.3, -0.2, 0.05]), np.array([0.02, 0.01, 0.4])
    params = mpc.parameters(
        q, np.zeros(robot.nv), 0.0, Commands(base_linear_velocity=lin, base_angular_velocity=ang)
    )
    R_base, R_heading = pin.rpy.rpyToMatrix(*rpy), pin.rpy.rpyToMatrix(0, 0, yaw)
    np.testing.assert_allclose(R_base @ params["v_des"][:3], R_heading @ lin, atol=1e-12)
    np.testing.assert_allclose(R_base @ params["v_des"][3:6], R_heading @ ang, atol=1e-12)
    assert np.all(params["v_des"][6:] == 0)
    # The desired pose: at the measured x, y and heading, level, at the nominal height.
    q_des = pin.integrate(robot.model, q, params["dq_des"])
    np.testing.assert_allclose(q_des[:2], q[:2], atol=1e-12)
    np.testing.assert_allclose(q_des[2], robot.q_nominal[2], atol=1e-12)
    np.testing.assert_allclose(pin.Quaternion(q_des[3:7]).toRotationMatrix(), R_heading, atol=1e-12)


def test_the_shifted_guess_keeps_the_previous_configurations_at_their_times(robot):
    """Warm start on the same node times from another measured pose: every node after the first keeps the
    previous plan's configuration, velocity and acceleration; node 0 is the measurement."""
    mpc = _mpc(robot, gait="trot", n_nodes=4)  # torques on every stage (n_tau_nodes = N - 1)
    q, v = robot.q_nominal, np.zeros(robot.nv)
    t = 0.2  # not 0: the node times of both plans start at t
    first = mpc.solve(q, v, t=t, commands=Commands(base_linear_velocity=np.array([0.3, 0.0, 0.0])))
    assert first.success
    q_hat = pin.integrate(robot.model, first.q[0], 0.01 * np.arange(robot.nv) / robot.nv)
    v_hat = first.v[0] + 0.1
    params = mpc.parameters(q_hat, v_hat, first.t, Commands(ee_force=np.array([3.0, 2.0, -10.0])))
    p = mpc.ocp.params.pack(params)
    split = mpc.ocp.split(mpc.shifted_guess(first, q_hat, first.t, params), p)
    q_guess = np.array([pin.integrate(robot.model, q_hat, d) for d in split["dq"]])
    np.testing.assert_allclose(q_guess[0], q_hat, atol=1e-12)
    np.testing.assert_allclose(q_guess[1:], first.q[1:], atol=1e-9)
    np.testing.assert_allclose(split["v"][0], v_hat, atol=1e-12)
    np.testing.assert_allclose(split["v"][1:], first.v[1:], atol=1e-9)
    np.testing.assert_allclose(split["a"], first.a, atol=1e-9)
    assert len(split["tau"]) == len(first.tau) == mpc.n_nodes - 1
    np.testing.assert_allclose(split["tau"], first.tau, atol=1e-9)
    # Forces re-initialised to the targets: the weight on the stance feet, the arm command.
    np.testing.assert_allclose(split["F"][:, 2:12:3], params["force_des"].T, atol=1e-12)
    np.testing.assert_allclose(split["F"][:, [0, 1, 3, 4, 6, 7, 9, 10]], 0.0, atol=1e-12)


def test_a_warm_failure_then_a_cold_raise_returns_the_previous_plan_with_both_reports(robot, monkeypatch):
    mpc = _mpc(robot)
    q, v = robot.q_nominal, np.zeros(robot.nv)
    first = mpc.solve(q, v, t=0.0)
    assert first.success
    kept = {name: getattr(first, name).copy() for name in PLAN}
    warm = _Fake(mpc.ocp.n_constraints, w=first.w + 1.0, iterations=7)
    cold = _Fake(mpc.ocp.n_constraints)  # raises
    monkeypatch.setattr(mpc, "_solver", lambda c, max_iter=None: cold if c else warm)
    second = mpc.solve(q, v, t=0.01)
    assert len(warm.calls) == 1 and len(cold.calls) == 1
    assert not second.success and second.fallback and not second.hold
    assert second.status == "max_iter_exceeded"  # the warm solve's (it returned an iterate)
    assert (
        second.reason.startswith("warm start: max_iter_exceeded; cold retry: ")
        and "injected" in second.reason
    )
    assert second.timings["total"] >= second.solve_time > 0
    for name in PLAN:
        np.testing.assert_array_equal(getattr(second, name), kept[name], err_msg=name)
    assert mpc.previous is first
    assert mpc.stats == {
        **mpc.stats,
        "solves": 2,
        "failures": 1,
        "exceptions": 1,
        "cold_retries": 1,
        "holds": 0,
    }


def test_a_raising_warm_solve_then_an_unconverged_retry_reports_the_retry(robot, monkeypatch):
    mpc = _mpc(robot)
    q, v = robot.q_nominal, np.zeros(robot.nv)
    first = mpc.solve(q, v, t=0.0)
    warm = _Fake(mpc.ocp.n_constraints)  # raises
    cold = _Fake(mpc.ocp.n_constraints, w=first.w + 1.0, iterations=9)
    monkeypatch.setattr(mpc, "_solver", lambda c, max_iter=None: cold if c else warm)
    second = mpc.solve(q, v, t=0.01)
    assert second.status == "max_iter_exceeded" and second.iterations == 9
    assert second.reason.startswith("warm start: solver_exception; cold retry: ")
    assert second.timings["cold_retry"] == 1.0
    for name in PLAN:
        np.testing.assert_array_equal(getattr(second, name), getattr(first, name), err_msg=name)
    # The retry starts from the cold guess without the previous duals.
    params = mpc.parameters(q, v, 0.01, Commands())
    np.testing.assert_allclose(cold.calls[0]["x0"], mpc.cold_guess(q, v, params))
    assert "lam_g0" not in cold.calls[0] and "lam_g0" in warm.calls[0]
    np.testing.assert_array_equal(warm.calls[0]["lam_g0"], first.lam_g)


def test_both_unconverged_add_their_iterations_and_times(robot, monkeypatch):
    mpc = _mpc(robot)
    q, v = robot.q_nominal, np.zeros(robot.nv)
    mpc.solve(q, v, t=0.0)
    warm = _Fake(mpc.ocp.n_constraints, w=mpc.previous.w + 1.0, iterations=7)
    cold = _Fake(mpc.ocp.n_constraints, w=mpc.previous.w - 1.0, iterations=9)
    monkeypatch.setattr(mpc, "_solver", lambda c, max_iter=None: cold if c else warm)
    second = mpc.solve(q, v, t=0.01)
    assert second.iterations == 16 and second.status == "max_iter_exceeded"
    assert second.reason.startswith("warm start: max_iter_exceeded; cold retry: ")
    assert np.isfinite(second.constraint_violation)


def test_a_failure_without_a_converged_plan_holds_and_counts(robot, monkeypatch):
    mpc = _mpc(robot)
    fake = _Fake(mpc.ocp.n_constraints)
    monkeypatch.setattr(mpc, "_solver", lambda c, max_iter=None: fake)
    plan = mpc.solve(robot.q_nominal, np.zeros(robot.nv), t=0.0)
    assert plan.hold and plan.fallback and not plan.success and mpc.previous is None
    assert len(fake.calls) == 1  # a cold start has no cold retry
    assert mpc.stats["holds"] == 1 and mpc.stats["failures"] == 1 and mpc.stats["cold_retries"] == 0
    assert plan.status == "solver_exception" and "injected" in plan.reason


@pytest.mark.parametrize("option", ["warm_start_false", "no_cold_retry", "no_dual_warm_start"])
def test_the_start_options(robot, monkeypatch, option):
    config = {"cold_retry": False} if option == "no_cold_retry" else {}
    if option == "no_dual_warm_start":
        config = {"dual_warm_start": False}
    mpc = _mpc(robot, **config)
    q, v = robot.q_nominal, np.zeros(robot.nv)
    first = mpc.solve(q, v, t=0.0)
    calls = []
    fake = _Fake(mpc.ocp.n_constraints)

    def record(cold, max_iter=None):
        calls.append((cold, max_iter))
        return fake

    monkeypatch.setattr(mpc, "_solver", record)
    second = mpc.solve(q, v, t=0.01, warm_start=option != "warm_start_false")
    assert second.fallback and mpc.previous is first
    params = mpc.parameters(q, v, 0.01, Commands())
    if option == "warm_start_false":  # a cold start: the cold guess, no duals, no retry
        assert calls == [(True, None)]
        np.testing.assert_allclose(fake.calls[0]["x0"], mpc.cold_guess(q, v, params))
        assert "lam_g0" not in fake.calls[0]
    elif option == "no_cold_retry":
        assert calls == [(False, None)] and mpc.stats["cold_retries"] == 0
        np.testing.assert_allclose(fake.calls[0]["x0"], mpc.shifted_guess(first, q, 0.01, params))
    else:
        assert calls == [(False, None), (True, mpc.config.retry_max_iter)]
        assert "lam_g0" not in fake.calls[0]


def test_a_non_unit_quaternion_is_normalised(robot):
    mpc = _mpc(robot)
    q = robot.q_nominal.copy()
    q[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(0.05, -0.04, 0.3)).coeffs()  # every component non-zero
    q[7] = 0.1  # the joint after the quaternion is not zero either
    scaled = q.copy()
    scaled[3:7] *= 3.0
    a = mpc.solve(q, np.zeros(robot.nv), t=0.0)
    mpc.reset()
    b = mpc.solve(scaled, np.zeros(robot.nv), t=0.0)
    # The OCP gets a unit quaternion (its symbolic integrate assumes one).
    q_ocp = mpc.ocp.params.unpack(mpc.last_inputs["p"], "q_hat")
    assert np.linalg.norm(q_ocp[3:7]) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(q_ocp[3:7], q[3:7], atol=1e-12)
    assert a.success and b.success
    np.testing.assert_allclose(b.q, a.q, atol=1e-9)
    np.testing.assert_allclose(b.tau, a.tau, atol=1e-6)


def test_prepare_builds_every_solver_a_loop_calls(robot, monkeypatch):
    """After ``prepare`` a cold start, a warm start and a failed warm start's cold retry build nothing."""
    mpc = _mpc(robot, max_iter=1, retry_max_iter=1)
    mpc.prepare()
    built = []
    real = mpc.make_solver
    monkeypatch.setattr(mpc, "make_solver", lambda *args: built.append(args) or real(*args))
    q = robot.q_nominal
    assert mpc.solve(q, np.zeros(robot.nv), t=0.0).success  # cold
    pushed = np.zeros(robot.nv)
    pushed[[1, 5]] = 0.5  # one warm iteration cannot converge: the cold retry runs
    second = mpc.solve(q, pushed, t=0.01)
    assert mpc.stats["cold_retries"] == 1 and not second.success
    assert built == []
    mpc.prepare()  # again: nothing new
    assert built == []


def test_the_hold_balances_the_commanded_arm_force(robot, monkeypatch):
    """A failed first solve under an arm load: the hold's torques and foot forces balance gravity and the
    commanded end-effector force (numeric Pinocchio)."""
    mpc = _mpc(robot)
    monkeypatch.setattr(mpc, "_solver", lambda c, max_iter=None: _Fake(mpc.ocp.n_constraints))
    load = np.array([8.0, -5.0, -25.0])
    plan = mpc.solve(robot.q_nominal, np.zeros(robot.nv), commands=Commands(ee_force=load))
    assert plan.hold and plan.t == 0.0  # t defaults to 0
    model, data = robot.model, robot.model.createData()
    q = robot.q_nominal
    g = pin.computeGeneralizedGravity(model, data, q).copy()
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    for k in range(len(plan.tau)):
        np.testing.assert_allclose(plan.forces[k, -1], load)
        JtF = sum(
            pin.getFrameJacobian(model, data, robot.frame_id(f), pin.LOCAL_WORLD_ALIGNED)[:3].T
            @ plan.forces[k, i]
            for i, f in enumerate(robot.contact_frames)
        )
        np.testing.assert_allclose(g - np.r_[np.zeros(6), plan.tau[k]] - JtF, 0.0, atol=1e-8)


def test_the_paper_layout_warm_starts_too(robot, monkeypatch):
    """The paper's layout (node 0's state and the arm force as pinned decision variables): the shifted guess
    is a finite point and the second solve is warm started from it (a NaN in it would silently make every
    solve a cold start)."""
    mpc = WholeBodyMPC(
        robot,
        OCPSettings(n_nodes=4, initial_state_variables=True, ee_force_input=True),
        MPCConfig(gait=make_gait("stand"), dt_max=0.03),
    )
    mpc.verbose = False
    q, v = robot.q_nominal, np.zeros(robot.nv)
    first = mpc.solve(q, v, t=0.0)
    assert first.success
    real, starts = mpc._solver, []
    monkeypatch.setattr(
        mpc, "_solver", lambda cold, max_iter=None: starts.append(cold) or real(cold, max_iter)
    )
    second = mpc.solve(q, v, t=0.01)
    assert second.success and starts == [False]
    guess = mpc.last_inputs["x0"]
    params = mpc.parameters(q, v, 0.01, Commands())
    np.testing.assert_allclose(guess, mpc.shifted_guess(first, q, 0.01, params))
    assert np.all(np.isfinite(guess))
    # Its node 0 is the measurement (what the initial-state rows pin), and its arm force the command.
    v_hat = np.full(robot.nv, 0.05)
    load = np.array([3.0, -2.0, -10.0])
    params = mpc.parameters(q, v_hat, 0.01, Commands(ee_force=load))
    split = mpc.ocp.split(mpc.shifted_guess(first, q, 0.01, params))
    np.testing.assert_array_equal(split["dq"][0], 0.0)
    np.testing.assert_array_equal(split["v"][0], v_hat)
    np.testing.assert_array_equal(split["F"][:, 12:], np.tile(load, (mpc.n_nodes - 1, 1)))


def test_a_velocity_level_formulation_warm_starts(robot, monkeypatch):
    """Centroidal velocity (configurations in the state): the second solve starts from the shifted plan."""
    mpc = WholeBodyMPC(
        robot,
        OCPSettings(n_nodes=4, formulation="centroidal_velocity"),
        MPCConfig(gait=make_gait("stand"), dt_max=0.03),
    )
    mpc.verbose = False
    q, v = robot.q_nominal, np.zeros(robot.nv)
    assert mpc.solve(q, v, t=0.0).success
    real, starts = mpc._solver, []
    monkeypatch.setattr(
        mpc, "_solver", lambda cold, max_iter=None: starts.append(cold) or real(cold, max_iter)
    )
    assert mpc.solve(q, v, t=0.01).success and starts == [False]


def test_a_robot_without_an_arm_holds_too(monkeypatch):
    """A failed first solve of the B1 without an arm: the static hold on its feet (no arm force anywhere)."""
    from wbmpc.model.robot import load_b1

    b1 = load_b1()
    mpc = WholeBodyMPC(b1, OCPSettings(n_nodes=4), MPCConfig(gait=make_gait("stand"), dt_max=0.03))
    mpc.verbose = False
    monkeypatch.setattr(mpc, "_solver", lambda c, max_iter=None: _Fake(mpc.ocp.n_constraints))
    plan = mpc.solve(b1.q_nominal, np.zeros(b1.nv), t=0.0)
    assert plan.hold and plan.forces.shape[1] == 4
    assert plan.forces[0, :, 2].sum() == pytest.approx(b1.mass * b1.gravity)
