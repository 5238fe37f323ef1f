"""Gaps in the tests of wbmpc/control/mpc.py found by mutation testing (docs/mutation/builder_mpc.md).

The failed-solve rule with injected solver outcomes (a failed solve is never applied: the previous
converged plan comes back and stays the warm start; the cold retry's report), and physical properties of
the starts and parameters: the cold guess is a feasible standing point of the OCP, the shifted guess keeps
the previous plan's configurations at their times, the force targets carry the weight, the velocity
command is the commanded world velocity in the base frame.
"""

import dataclasses

import casadi as ca
import numpy as np
import pinocchio as pin
import pytest

from wbmpc.control.mpc import Commands, MPCConfig, SolverSettings, WholeBodyMPC
from wbmpc.model.robot import load_b1_z1
from wbmpc.ocp import OCPSettings
from wbmpc.ocp.gait import make_gait

PLAN = ("q", "v", "a", "forces", "tau")


@pytest.fixture(scope="module")
def robot():
    return load_b1_z1()


def _mpc(robot, gait="stand", n_nodes=4, **config):
    """A small MPC; ``config``: MPCConfig fields and SolverSettings fields (told apart by name)."""
    fields = {f.name for f in dataclasses.fields(SolverSettings)}
    solver = SolverSettings(**{k: config.pop(k) for k in list(config) if k in fields})
    mpc = WholeBodyMPC(
        robot, OCPSettings(n_nodes=n_nodes), MPCConfig(gait=make_gait(gait), dt_max=0.03, **config), solver
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
    # The converged plan: at t on the configured steps, from the measurement, the trot's stance flags at its
    # stage times, the forces per contact frame, the primal and dual solution.
    dts = mpc.time_steps()
    assert first.t == t and np.array_equal(first.dts, dts)
    np.testing.assert_allclose(first.q[0], q, atol=1e-9)
    stage_times = t + np.concatenate([[0.0], np.cumsum(dts)])[:-1]
    np.testing.assert_array_equal(first.contact, mpc.config.gait.sample(stage_times).contact)
    assert first.contact.dtype == bool and first.forces.shape == (mpc.n_nodes - 1, 5, 3)
    assert first.w.shape == (mpc.ocp.n_variables,) and first.lam_g.shape == (mpc.ocp.n_constraints,)
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
        "library_switches": 0,
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
        assert calls == [(False, None), (True, mpc.solver_settings.retry_max_iter)]
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


# --- the failed-solve rule: the retry's report, the counts, the flags (mutants of solve 53 to 297) ---------
def _scripted(mpc, monkeypatch, outcomes):
    """Replace every solver call by a scripted outcome ``(w or None, success, iterations, solve_time)``:
    ``None`` is a solver that raised (no iterate, no count); exact binary times make the sums exact."""
    calls = []

    def run(solver, args):
        w, success, iterations, solve_time = outcomes[len(calls)]
        calls.append(args)
        status = "success" if success else ("solver_exception" if w is None else "max_iter_exceeded")
        report = {
            "success": success,
            "status": status,
            "reason": "" if success else f"scripted {status}",
            "iterations": iterations,
            "solve_time": solve_time,
            "constraint_violation": np.inf if w is None else 0.0,
            "timings": {"wall": solve_time},
        }
        return w, None if w is None else np.zeros(mpc.ocp.n_constraints), report

    monkeypatch.setattr(mpc, "_solver", lambda cold, max_iter=None: None)
    monkeypatch.setattr(mpc, "_run_solver", run)
    return calls


@pytest.mark.parametrize(
    "warm, retry, iterations",
    [
        ("iterate", "iterate", 7 + 9),  # both stop at their caps: the iterations add up
        ("iterate", "raise", 7),  # the retry raised: the warm solve's count alone
        ("raise", "iterate", 0),  # the retry stopped at once: 0 iterations ran (not "no count")
        ("raise", "raise", -1),  # neither counted
    ],
)
def test_a_failed_retry_reports_both_times_and_the_iterations_that_ran(
    robot, monkeypatch, warm, retry, iterations
):
    mpc = _mpc(robot)
    q, v = robot.q_nominal, np.zeros(robot.nv)
    first = mpc.solve(q, v, t=0.0)
    assert first.success
    iterate = first.w + 1.0
    outcome = {
        ("warm", "iterate"): (iterate, False, 7, 0.25),
        ("warm", "raise"): (None, False, -1, 0.25),
        ("retry", "iterate"): (iterate - 2.0, False, 0 if warm == "raise" else 9, 0.5),
        ("retry", "raise"): (None, False, -1, 0.5),
    }
    calls = _scripted(mpc, monkeypatch, [outcome["warm", warm], outcome["retry", retry]])
    second = mpc.solve(q, v, t=0.01)
    assert len(calls) == 2
    assert second.success is False and second.fallback is True and second.hold is False
    assert second.solve_time == 0.75  # the warm solve's time and the retry's
    assert second.timings["wall"] == 0.75 and second.timings["cold_retry"] == 1.0  # both, on every path
    assert second.iterations == iterations
    assert second.reason.startswith("warm start: ") and "; cold retry: scripted " in second.reason
    for name in PLAN:
        np.testing.assert_array_equal(getattr(second, name), getattr(first, name), err_msg=name)
    assert mpc.previous is first


def test_a_converged_retry_is_the_new_plan_with_both_times(robot, monkeypatch):
    """The warm solve stops at its cap, the cold retry converges: the retry's plan is applied (not the warm
    iterate), becomes the warm start, and reports both solves' time and iterations."""
    mpc = _mpc(robot)
    q, v = robot.q_nominal, np.zeros(robot.nv)
    first = mpc.solve(q, v, t=0.0)
    _scripted(mpc, monkeypatch, [(first.w + 1.0, False, 7, 0.25), (first.w, True, 5, 0.5)])
    second = mpc.solve(q, v, t=0.01)
    assert second.success and not second.fallback and second.reason == ""
    assert second.solve_time == 0.75 and second.iterations == 12 and second.timings["cold_retry"] == 1.0
    assert second.timings["wall"] == 0.75
    np.testing.assert_array_equal(second.w, first.w)
    assert mpc.previous is second and mpc.stats["failures"] == 0 and mpc.stats["cold_retries"] == 1


def test_every_failure_and_every_hold_is_counted(robot, monkeypatch):
    """Two failed first solves are two holds and two failures; after a converged plan, two failed solves
    are two fallbacks to it (and no hold)."""
    mpc = _mpc(robot)
    q, v = robot.q_nominal, np.zeros(robot.nv)
    with monkeypatch.context() as patch:
        patch.setattr(mpc, "_solver", lambda c, max_iter=None: _Fake(mpc.ocp.n_constraints))
        for t in (0.0, 0.01):
            plan = mpc.solve(q, v, t=t)
            assert plan.hold and plan.t == t
    assert mpc.stats["holds"] == 2 and mpc.stats["failures"] == 2 and mpc.stats["solves"] == 2
    first = mpc.solve(q, v, t=0.02)
    assert first.success and first.hold is False
    monkeypatch.setattr(mpc, "_solver", lambda c, max_iter=None: _Fake(mpc.ocp.n_constraints))
    for t in (0.03, 0.04):
        plan = mpc.solve(q, v, t=t)
        assert plan.fallback is True and plan.hold is False and plan.t == first.t
    assert mpc.stats["holds"] == 2 and mpc.stats["failures"] == 4 and mpc.stats["solves"] == 5
    assert mpc.stats["cold_retries"] == 2 and mpc.stats["exceptions"] == 2 + 2 + 2


def test_the_total_time_is_the_time_of_the_call(robot):
    """``timings["total"]`` is the whole call: at least the solver's share, at most the caller's clock."""
    import time

    mpc = _mpc(robot)
    q, v = robot.q_nominal, np.zeros(robot.nv)
    for t in (0.0, 0.01):  # a cold start, a warm start
        start = time.perf_counter()
        plan = mpc.solve(q, v, t=t)
        elapsed = time.perf_counter() - start
        assert plan.success and 0.0 < plan.solve_time <= plan.timings["total"] <= elapsed


def test_the_findings_are_those_of_the_gait_in_force(robot, monkeypatch):
    """A speed command while a schedule stands, then trots: the plan carries the stand's
    ``speed_without_stepping`` warning, and no speed finding once the trot is in force (its stride reaches
    0.3 m/s); the hand held still in the world while the base walks is flagged in both."""
    from wbmpc.ocp.gait import GaitSchedule

    schedule = GaitSchedule([(make_gait("stand"), 0.4), (make_gait("trot"), 1.6)])
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=4), MPCConfig(gait=schedule, dt_max=0.03))
    mpc.verbose = False
    q, v = robot.q_nominal, np.zeros(robot.nv)
    walk = Commands(base_linear_velocity=np.array([0.3, 0.0, 0.0]))
    both = {"speed_without_stepping", "ee_world_hold_with_walking_base"}
    standing = mpc.solve(q, v, t=0.1, commands=walk)
    assert {f.code for f in standing.findings} == both
    assert any("'stand'" in f.message for f in standing.findings)
    assert mpc.solve(q, v, t=0.1).findings == ()  # nothing commanded
    monkeypatch.setattr(mpc, "_solver", lambda c, max_iter=None: _Fake(mpc.ocp.n_constraints))
    failed = mpc.solve(q, v, t=0.12, commands=walk)  # a fallback carries this solve's findings
    assert failed.fallback and not failed.hold and {f.code for f in failed.findings} == both
    mpc.reset()
    trotting = mpc.solve(q, v, t=0.9, commands=walk)  # a hold carries them too
    assert trotting.hold and {f.code for f in trotting.findings} == {"ee_world_hold_with_walking_base"}


def test_a_push_during_a_swing_aborts_it_in_the_solve(robot, monkeypatch):
    """A trot, a lateral push just after lift-off (measured base velocity 0.6 m/s off the plan's): the swing
    is aborted and the OCP plans that foot in stance (it is on the ground) until its nominal touchdown."""
    mpc = _mpc(robot, gait="trot", n_nodes=6)
    q, v = robot.q_nominal, np.zeros(robot.nv)
    assert mpc.solve(q, v, t=0.0).success
    t = 0.02
    swinging = ~mpc.config.gait.sample(np.array([t])).contact[:, 0]
    assert swinging.sum() == 2
    monkeypatch.setattr(mpc, "_solver", lambda c, max_iter=None: _Fake(mpc.ocp.n_constraints))
    pushed = v.copy()
    pushed[1] = 0.6
    assert mpc.stats["swing_aborts"] == 0
    mpc.solve(q, pushed, t=t)
    assert sorted(mpc.aborted_swings) == list(np.flatnonzero(swinging))
    assert mpc.stats["swing_aborts"] == 2  # each aborted swing counted once
    contact = mpc.ocp.params.unpack(mpc.last_inputs["p"], "contact")
    assert np.all(contact[swinging] == 1.0)
    mpc.solve(q, pushed, t=t + 0.005)  # still pushed: the same swings, already aborted, are not counted again
    assert mpc.stats["swing_aborts"] == 2
    # Unpushed, the same solve plans them in swing.
    mpc.reset()
    mpc.solve(q, v, t=t)
    assert np.all(mpc.ocp.params.unpack(mpc.last_inputs["p"], "contact")[swinging, 0] == 0.0)


# --- the static hold, the cold guess, a commanded base height (mutants of hold_plan, cold_guess,
# pose_at_height, desired_configuration) -----------------------------------------------------------------
def _assert_balanced(robot, q, forces, tau):
    """Rest at ``q``: gravity = the joint torques and the contact forces (feet, and the hand if any)."""
    model, data = robot.model, robot.model.createData()
    g = pin.computeGeneralizedGravity(model, data, q).copy()
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    JtF = sum(
        pin.getFrameJacobian(model, data, robot.frame_id(f), pin.LOCAL_WORLD_ALIGNED)[:3].T @ forces[i]
        for i, f in enumerate(robot.contact_frames)
    )
    np.testing.assert_allclose(g - np.r_[np.zeros(6), tau] - JtF, 0.0, atol=1e-7)


def _flight_gait():
    """A bound whose swings overlap: all four feet in the air from 0.4 s to 0.48 s of each 0.8 s cycle."""
    from wbmpc.ocp.gait import Gait

    return Gait("flight", 0.8, 0.6, (0.0, 0.0, 0.5, 0.5), make_gait("trot").tick)


def test_a_hold_without_a_report_is_the_documented_rest_plan(robot):
    """``hold_plan`` called directly (no solver report): the measured pose on every node at rest, the
    static torques on every torque node, the stage contact flags, and the report fields' defaults."""
    mpc = _mpc(robot, gait="walk")
    q = pin.integrate(robot.model, robot.q_nominal, 0.02 * np.sin(np.arange(robot.nv)))
    params = mpc.parameters(q, np.zeros(robot.nv), 0.25, Commands(ee_force=np.array([0.0, 0.0, -20.0])))
    plan = mpc.hold_plan(q, 0.25, params)
    N = mpc.n_nodes
    assert plan.t == 0.25 and plan.dts.shape == (N - 1,) and np.all(plan.dts == mpc.time_steps())
    np.testing.assert_array_equal(plan.q, np.tile(q, (N, 1)))
    np.testing.assert_array_equal(plan.v, np.zeros((N, robot.nv)))
    np.testing.assert_array_equal(plan.a, np.zeros((N - 1, robot.nv)))
    assert plan.forces.shape == (N - 1, len(robot.contact_frames), 3)
    assert plan.tau.shape == (mpc.ocp.settings.n_tau_nodes, robot.nj)
    for k in range(N - 1):
        np.testing.assert_array_equal(plan.forces[k], plan.forces[0])
    for k in range(len(plan.tau)):
        np.testing.assert_array_equal(plan.tau[k], plan.tau[0])
    np.testing.assert_array_equal(plan.contact, params["contact"] > 0.5)
    assert plan.contact.dtype == bool and plan.contact.any() and not plan.contact.all()
    assert plan.success is False and plan.fallback is True and plan.hold is True
    assert plan.iterations == -1 and plan.solve_time == 0.0 and plan.status == "hold" and plan.reason == ""
    assert plan.findings == () and plan.constraint_violation == np.inf and plan.timings == {}


def test_a_hold_carries_the_whole_failed_report(robot, monkeypatch):
    """A first solve that stops unconverged: the hold reports its iterations, time, status, reason,
    violation, timings and this solve's findings (not the defaults)."""
    mpc = _mpc(robot)
    _scripted(mpc, monkeypatch, [(np.zeros(mpc.ocp.n_variables), False, 7, 0.25)])
    walk = Commands(base_linear_velocity=np.array([0.3, 0.0, 0.0]))  # standing: a speed finding
    plan = mpc.solve(robot.q_nominal, np.zeros(robot.nv), t=0.0, commands=walk)
    assert plan.hold and plan.success is False
    assert plan.iterations == 7 and plan.solve_time == 0.25 and plan.status == "max_iter_exceeded"
    assert plan.reason == "scripted max_iter_exceeded" and plan.constraint_violation == 0.0
    assert plan.timings["wall"] == 0.25 and "total" in plan.timings
    assert "speed_without_stepping" in {f.code for f in plan.findings}


@pytest.mark.parametrize(
    "t, carrying",
    [
        (0.25, [True, True, True, False]),  # rear-right in swing: the other three hold the pose alone
        (0.05, [True] * 4),  # front-left in swing: rear-right would have to pull, all four hold it
        (0.19, [True] * 4),  # as at 0.05 on stage 0; the next stage's three would hold: not used
        (0.42, [True] * 4),  # a flight phase: no stance foot, all four hold it
    ],
)
def test_the_hold_is_the_stance_of_the_first_stage_when_it_can_hold(robot, t, carrying):
    """A walk (one foot in swing at a time) and a gait with a flight phase: the hold stands on the scheduled
    stance of stage 0 when it balances the pose with pushing feet, otherwise on all four; it always
    balances gravity and the commanded arm force, and no foot pulls."""
    gait = _flight_gait() if t == 0.42 else make_gait("walk")
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=4), MPCConfig(gait=gait, dt_max=0.03))
    q = robot.q_nominal
    load = np.array([0.0, 0.0, -20.0])
    params = mpc.parameters(q, np.zeros(robot.nv), t, Commands(ee_force=load))
    plan = mpc.hold_plan(q, t, params)
    if t == 0.19:
        assert list(plan.contact[:, 1]) == [True, True, True, False]  # the next stage's stance differs
    np.testing.assert_array_equal(np.abs(plan.forces[0, :4, 2]) > 1.0, carrying)
    assert np.all(plan.forces[0, :4, 2] >= 0.0)
    np.testing.assert_array_equal(plan.forces[0, 4], load)
    _assert_balanced(robot, q, plan.forces[0], plan.tau[0])


def test_the_cold_guess_of_a_robot_without_an_arm_is_feasible():
    """The B1 alone: static forces and torques on its four feet (no arm force anywhere), every row met."""
    from wbmpc.model.robot import load_b1

    b1 = load_b1()
    mpc = WholeBodyMPC(b1, OCPSettings(n_nodes=4), MPCConfig(gait=make_gait("stand"), dt_max=0.03))
    q, v = b1.q_nominal, np.zeros(b1.nv)
    params = mpc.parameters(q, v, 0.0, Commands())
    x0 = mpc.cold_guess(q, v, params)
    p = mpc.ocp.params.pack(params)
    assert _violation(mpc, x0, p) < 1e-8
    split = mpc.ocp.split(x0, p)
    assert split["F"].shape[1] == 12
    np.testing.assert_allclose(split["F"][:, 2::3].sum(axis=1), b1.mass * b1.gravity)


def test_the_cold_guess_of_a_flight_phase_has_no_foot_force(robot):
    """Nodes with no stance foot get zero foot forces and zero torques (no static solution); the other nodes
    are static (the static-equilibrium forces of their stance with the arm's load)."""
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=4), MPCConfig(gait=_flight_gait(), dt_max=0.03))
    q, v = robot.q_nominal, np.zeros(robot.nv)
    load = np.array([2.0, 0.0, -10.0])
    params = mpc.parameters(q, v, 0.39, Commands(ee_force=load))
    flight = ~params["contact"].astype(bool).any(axis=0)
    assert flight.any() and not flight.all()
    split = mpc.ocp.split(mpc.cold_guess(q, v, params), mpc.ocp.params.pack(params))
    F = split["F"].reshape(mpc.n_nodes - 1, -1, 3)
    np.testing.assert_array_equal(F[flight, :4], 0.0)
    from wbmpc.model.statics import static_equilibrium

    for k in np.flatnonzero(~flight):
        stance = params["contact"][:, k] > 0.5
        np.testing.assert_allclose(
            F[k], static_equilibrium(robot, q, stance, ee_force=load).forces, atol=1e-9
        )
    tau = split["tau"]
    np.testing.assert_array_equal(tau[flight[: len(tau)]], 0.0)


def _feet(robot, q):
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, q)
    return np.array([data.oMf[robot.frame_id(f)].translation for f in robot.foot_frames])


def test_a_commanded_base_height_keeps_the_feet_where_the_nominal_pose_has_them(robot):
    """``pose_at_height``: the base at the height (same x, y, orientation), the leg joints that keep every
    foot at its nominal position, the arm's joints unchanged, within the joint limits; one pose per 0.1 mm."""
    mpc = _mpc(robot)
    nominal = robot.q_nominal
    arm = [robot.joint_index_v(n) + 1 for n in robot.arm_joint_names]  # q index of a revolute joint
    legs = np.setdiff1d(np.arange(7, robot.nq), arm)
    lower, upper = robot.model.lowerPositionLimit, robot.model.upperPositionLimit
    for height in (round(nominal[2] - 0.08, 4), round(nominal[2] + 0.05, 4)):  # on the 0.1 mm grid
        q = mpc.pose_at_height(height)
        assert q[2] == height
        np.testing.assert_array_equal(q[[0, 1]], nominal[[0, 1]])
        np.testing.assert_allclose(q[3:7], nominal[3:7], atol=1e-12)
        np.testing.assert_array_equal(q[arm], nominal[arm])
        np.testing.assert_allclose(_feet(robot, q), _feet(robot, nominal), atol=1e-8)
        assert np.abs(q[legs] - nominal[legs]).max() > 1e-3
        # The same legs within the same 0.1 mm (the feet within 0.05 mm), the base where asked; a copy.
        near = mpc.pose_at_height(height + 3e-5)
        np.testing.assert_array_equal(near[legs], q[legs])
        assert near[2] == height + 3e-5
        np.testing.assert_allclose(_feet(robot, near)[:, 2], _feet(robot, nominal)[:, 2] + 3e-5, atol=1e-8)
        q[:] = 0.0
        assert mpc.pose_at_height(height)[2] == height
    # Beyond the legs' range the knees stop at their limits (low: lower, high: upper).
    for height in (0.2, 0.75):
        q = mpc.pose_at_height(height)
        assert np.all(q[7:] >= lower[7:]) and np.all(q[7:] <= upper[7:])


def test_the_desired_pose_of_a_height_command(robot):
    """A base height command: the desired configuration is the height's pose at the measured x, y and
    heading (level), and the posture cost's target ``dq_des`` leads there."""
    mpc = _mpc(robot)
    q = robot.q_nominal.copy()
    q[:2] = (1.2, -0.7)
    q[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(0.1, -0.05, 0.6)).coeffs()
    height = robot.q_nominal[2] - 0.06
    params = mpc.parameters(q, np.zeros(robot.nv), 0.0, Commands(base_height=height))
    q_des = pin.integrate(robot.model, q, params["dq_des"])
    expected = mpc.pose_at_height(height)
    np.testing.assert_allclose(q_des[:3], [1.2, -0.7, height], atol=1e-12)
    R = pin.Quaternion(q_des[3:7]).normalized().toRotationMatrix()
    np.testing.assert_allclose(R, pin.rpy.rpyToMatrix(0.0, 0.0, 0.6), atol=1e-12)
    np.testing.assert_allclose(q_des[7:], expected[7:], atol=1e-12)
    assert np.abs(expected[7:] - robot.q_nominal[7:]).max() > 1e-3


# --- one solver call's report (mutants of _run_solver) ------------------------------------------------------
class _Returns:
    """A solver stand-in that returns ``w`` and ``g`` with the given statistics."""

    def __init__(self, w, g, stats):
        self.w, self.g, self._stats = w, g, stats

    def __call__(self, **args):
        return {"x": self.w.copy(), "g": self.g.copy(), "lam_g": np.zeros(self.g.size), "f": 0.0}

    def stats(self):
        return dict(self._stats)


CONVERGED = {
    "success": True,
    "return_status": 0,
    "iter_count": 4,
    "fatrop": {"return_flag": 0, "iterations_count": 4, "time_total": 1e-3},
}


def test_the_reported_violation_is_that_of_the_returned_point(robot, monkeypatch):
    """A converged plan reports the bound violation of its own constraint values; a returned point half a
    unit under a lower bound or a quarter over an upper one reports that."""
    mpc = _mpc(robot)
    q, v = robot.q_nominal, np.zeros(robot.nv)
    plan = mpc.solve(q, v, t=0.0)
    assert plan.success and plan.status == "success" and plan.reason == ""  # no reason on a success
    assert 0.0 <= plan.constraint_violation < 1e-3
    assert plan.constraint_violation == pytest.approx(
        _violation(mpc, plan.w, mpc.last_inputs["p"]), abs=1e-12
    )
    lbg, ubg = mpc.ocp.lbg, mpc.ocp.ubg
    inequality = np.flatnonzero(np.isfinite(lbg) & np.isfinite(ubg) & (lbg < ubg))
    lower_only = np.flatnonzero(np.isfinite(lbg) & ~np.isfinite(ubg))
    assert inequality.size and lower_only.size
    for row, g_row, expected in (
        (lower_only[0], lbg[lower_only[0]] - 0.5, 0.5),
        (inequality[0], ubg[inequality[0]] + 0.25, 0.25),
        (inequality[0], lbg[inequality[0]] - 0.125, 0.125),
    ):
        g = np.clip(np.zeros(lbg.size), lbg, ubg)
        g[row] = g_row
        fake = _Returns(plan.w, g, {**CONVERGED, "success": False, "fatrop": {"return_flag": 1}})
        monkeypatch.setattr(mpc, "_solver", lambda c, max_iter=None, fake=fake: fake)
        w, lam_g, report = mpc._run_solver(fake, mpc.last_inputs)
        assert report["constraint_violation"] == pytest.approx(expected, abs=1e-12)
        assert report["success"] is False and report["status"] == "max_iter_exceeded"


def test_a_non_finite_iterate_is_never_a_success(robot, monkeypatch):
    """The solver says it converged but returns a NaN: not a success, said so; the previous plan is kept."""
    mpc = _mpc(robot)
    q, v = robot.q_nominal, np.zeros(robot.nv)
    first = mpc.solve(q, v, t=0.0)
    w = first.w.copy()
    w[3] = np.nan
    fake = _Returns(w, np.zeros(mpc.ocp.n_constraints), CONVERGED)
    monkeypatch.setattr(mpc, "_solver", lambda c, max_iter=None: fake)
    second = mpc.solve(q, v, t=0.01)
    assert second.success is False and second.fallback and mpc.previous is first
    assert second.status == "non_finite_solution" and second.reason.endswith(
        "cold retry: the solver returned NaN or inf"
    )
    _, _, report = mpc._run_solver(fake, mpc.last_inputs)
    assert report["status"] == "non_finite_solution" and report["reason"] == "the solver returned NaN or inf"
    assert report["iterations"] == 4 and report["success"] is False


def test_statistics_without_success_or_count_are_a_failure_without_count(robot, monkeypatch):
    """A solver whose statistics say neither success nor an iteration count: a failure (the hold), -1."""
    mpc = _mpc(robot)
    fake = _Returns(np.zeros(mpc.ocp.n_variables), np.zeros(mpc.ocp.n_constraints), {})
    monkeypatch.setattr(mpc, "_solver", lambda c, max_iter=None: fake)
    plan = mpc.solve(robot.q_nominal, np.zeros(robot.nv), t=0.0)
    assert plan.hold and plan.success is False and plan.iterations == -1 and plan.reason != ""


def test_a_raising_solver_reports_no_count_no_point_and_its_time(robot, monkeypatch):
    """A raising solver: no iteration count (-1), no point (infinite violation), its wall time within the
    call's; each raise is counted."""
    import time

    mpc = _mpc(robot)
    monkeypatch.setattr(mpc, "_solver", lambda c, max_iter=None: _Fake(mpc.ocp.n_constraints))
    for n in (1, 2):
        start = time.perf_counter()
        plan = mpc.solve(robot.q_nominal, np.zeros(robot.nv), t=0.0)
        elapsed = time.perf_counter() - start
        assert plan.hold and plan.iterations == -1 and plan.constraint_violation == np.inf
        assert plan.status == "solver_exception" and mpc.stats["exceptions"] == n
        assert 0.0 < plan.solve_time == plan.timings["wall"] <= plan.timings["total"] <= elapsed


def test_solver_timings_split_the_wall_time():
    """Where a solve's time went: the derivative evaluations (every ``t_wall_nlp_*``), the solver's own
    work (its total minus them), the Python overhead (the wall time minus its total); Fatrop's total and
    split when it reports them, else CasADi's total, else the wall time."""
    from wbmpc.control.mpc import solver_timings

    evaluations = {
        "t_wall_nlp_f": 0.0625,
        "t_wall_nlp_hess_l": 0.125,
        "t_wall_nlp_jac_g": 0.25,
        "t_proc_x": 8.0,
    }
    fatrop = {"time_total": 1.0, "compute_sd_time": 0.375, "initialization_time": 0.03125}
    cases = [
        (
            {**evaluations, "t_wall_total": 4.0, "fatrop": fatrop},
            1.0,
            {"search_direction": 0.375, "initialization": 0.03125},
        ),
        (
            {**evaluations, "t_wall_total": 4.0, "fatrop": {"time_total": 1.0}},
            1.0,
            {"search_direction": 0.0, "initialization": 0.0},
        ),
        ({**evaluations, "t_wall_total": 4.0}, 4.0, {}),  # IPOPT: CasADi's total
        ({**evaluations, "t_wall_total": 4.0, "fatrop": "n/a"}, 4.0, {}),
        (dict(evaluations), 2.0, {}),  # no total at all: the wall time
        ({}, 2.0, {"evaluations": 0.0, "hessian": 0.0, "jacobian": 0.0}),
    ]
    for stats, total, extra in cases:
        expected = {
            "wall": 2.0,
            "evaluations": 0.4375,
            "hessian": 0.125,
            "jacobian": 0.25,
            "solver": total - 0.4375,
            "overhead": 2.0 - total,
        }
        expected.update(extra)
        if not stats:
            expected["solver"] = total
        assert solver_timings(stats, 2.0) == expected, stats


# --- parameters, weights, the solvers' construction, the MPC's arguments (mutants of parameters, weights,
# recovery_parameters, solver_options, _solver, make_solver, __init__, gait, contact_plan; mpc_rest.md) ------
def _stage_times(mpc, t):
    """The times of the stages' first nodes: ``t`` then the configured steps added up."""
    return t + np.concatenate([[0.0], np.cumsum(mpc.time_steps())])[:-1]


def test_a_gait_schedule_carried_by_the_commands_is_the_gait_of_the_solve(robot):
    """A command schedule's gait (a 0.5 s trot then a 0.8 s trot, both swings in the horizon) replaces the
    configured stand: its stance flags at the stage times, and each swinging foot's vertical velocity target
    that of its own gait's swing (0.25 s or 0.4 s) at its phase; no gait commanded: the configured one."""
    from wbmpc.ocp.gait import GaitSchedule, swing_vertical_velocity

    mpc = _mpc(robot, gait="stand", n_nodes=8)
    schedule = GaitSchedule([(make_gait("trot", 0.5), 0.5), (make_gait("trot", 0.8), 10.0)])
    q, v, t = robot.q_nominal, np.zeros(robot.nv), 0.42
    assert mpc.gait() is mpc.config.gait and mpc.gait(Commands()) is mpc.config.gait
    assert mpc.gait(Commands(gait=schedule)) is schedule
    params = mpc.parameters(q, v, t, Commands(gait=schedule))
    sample = schedule.sample(_stage_times(mpc, t))
    np.testing.assert_array_equal(params["contact"], sample.contact)
    swinging = ~sample.contact
    assert set(np.unique(sample.swing_duration[swinging])) == {0.25, 0.4}
    swing = mpc.config.swing
    expected = np.zeros_like(params["swing_vz"])
    for foot, k in zip(*np.nonzero(swinging), strict=True):
        expected[foot, k] = swing_vertical_velocity(
            sample.swing_phase[foot, k],
            sample.swing_duration[foot, k],
            swing.height,
            swing.v_liftoff,
            swing.v_touchdown,
        )
    np.testing.assert_allclose(params["swing_vz"], expected, rtol=1e-12, atol=1e-12)
    assert np.any(expected != 0.0)
    standing = mpc.parameters(q, v, t, Commands())
    assert np.all(standing["contact"] == 1.0) and np.all(standing["swing_vz"] == 0.0)


def test_the_force_targets_split_the_weight_by_the_front_force_ratio(robot):
    """Standing: the front feet carry ``front_force_ratio`` of the weight, the rear ones the rest, each pair
    equally; the config's ratio, else the robot's (0.4 here, not the 0.5 of an even split)."""
    light_front = dataclasses.replace(robot, front_force_ratio=0.4)
    weight = robot.mass * robot.gravity
    q, v = robot.q_nominal, np.zeros(robot.nv)
    for ratio, front in ((None, 0.4), (0.7, 0.7)):
        mpc = _mpc(light_front, front_force_ratio=ratio)
        force = mpc.parameters(q, v, 0.0, Commands())["force_des"]
        np.testing.assert_allclose(force[:2], front * weight / 2, rtol=1e-12)  # FL, FR
        np.testing.assert_allclose(force[2:], (1.0 - front) * weight / 2, rtol=1e-12)  # RL, RR


def test_the_end_effector_velocity_command_holds_on_every_stage(robot):
    """A (3,) arm velocity command is the target of every stage (each column of the (3, N-1) block); a
    (3, N-1) one gives each stage its own column."""
    mpc = _mpc(robot, n_nodes=4)
    q, v = robot.q_nominal, np.zeros(robot.nv)
    held = np.array([0.1, -0.2, 0.3])
    layout = mpc.ocp.params
    params = mpc.parameters(q, v, 0.0, Commands(ee_velocity=held))
    np.testing.assert_array_equal(
        layout.unpack(layout.pack(params), "ee_velocity"), np.tile(held[:, None], 3)
    )
    per_stage = np.array([[0.1, 0.2, 0.3], [-0.1, 0.0, 0.1], [0.05, 0.0, -0.05]])
    params = mpc.parameters(q, v, 0.0, Commands(ee_velocity=per_stage))
    np.testing.assert_array_equal(layout.unpack(layout.pack(params), "ee_velocity"), per_stage)


def test_the_weights_of_the_config_are_used_and_bad_ones_refused_with_the_whole_message(robot):
    """Weights of the config (zeros and weights below 1 are weights too, a list of numbers an array) are the
    cost's; ``None`` is the default. A config changed after its checks (a NaN, an inf, a negative weight, a
    wrong size or shape) is refused by the MPC with the whole message."""
    from wbmpc.control.mpc import default_weights

    mpc = _mpc(robot)
    q, v = robot.q_nominal, np.zeros(robot.nv)
    Q0, R0 = default_weights(robot)
    Q, R = np.resize([0.0, 0.5, 2.0], Q0.size), np.resize([0.25, 0.0], R0.size)
    mpc.config.Q = list(Q)
    Qw, Rw = mpc.weights()
    np.testing.assert_array_equal(Qw, Q)
    np.testing.assert_array_equal(Rw, R0)
    mpc.config.R = R
    layout = mpc.ocp.params
    p = layout.pack(mpc.parameters(q, v, 0.0, Commands()))
    np.testing.assert_array_equal(layout.unpack(p, "Q"), Q)
    np.testing.assert_array_equal(layout.unpack(p, "R"), R)
    n = Q0.size
    prefix = f"MPCConfig.Q must hold {n} finite weights >= 0 for this robot and formulation, got shape "
    for value, tail in (
        (np.full(n, np.nan), f"({n},), min nan"),
        (np.where(np.arange(n) == 3, np.inf, 1.0), f"({n},), min 1.0"),
        (Q - 1.0, f"({n},), min -1.0"),
        (np.ones(3), "(3,), min 1.0"),
        (np.ones((n, 1)), f"({n}, 1), min 1.0"),
        (np.zeros(0), "(0,)"),
    ):
        mpc.config.Q = value
        with pytest.raises(ValueError) as refused:
            mpc.weights()
        assert str(refused.value) == prefix + tail


def test_the_solver_options_of_each_start(robot):
    """Cold starts: the cold iteration cap and barrier parameter; warm starts: the warm ones and Fatrop's
    warm-start bound push; a given cap replaces the settings' (the cold retry); the tolerance and the
    constraints' equality flags (Fatrop's structure detection) in all."""
    mpc = _mpc(robot, tol=2e-3, max_iter=11, cold_max_iter=22, mu_init_warm=1e-3, mu_init_cold=0.2)
    base = {"print_level": 0, "tol": 2e-3}
    for (cold, max_iter), inner in (
        ((True, None), {**base, "max_iter": 22, "mu_init": 0.2}),
        ((False, None), {**base, "max_iter": 11, "mu_init": 1e-3, "bound_push": 1e-7}),
        ((True, 5), {**base, "max_iter": 5, "mu_init": 0.2}),
        ((False, 5), {**base, "max_iter": 5, "mu_init": 1e-3, "bound_push": 1e-7}),
    ):
        options = mpc.solver_options(cold, max_iter)
        assert options["fatrop"] == inner, (cold, max_iter)
        assert options["structure_detection"] == "auto"
        np.testing.assert_array_equal(options["equality"], mpc.ocp.equality)


def test_each_start_has_its_own_solver_built_once(robot, monkeypatch):
    """The cold start, the warm start and a capped cold start (the retry) each get a solver built with their
    own options, on first use, and the same one afterwards."""
    mpc = _mpc(robot)
    built = []
    monkeypatch.setattr(
        mpc, "make_solver", lambda name, cold, max_iter=None: built.append((cold, max_iter)) or object()
    )
    cold, warm, retry = mpc._solver(True), mpc._solver(False), mpc._solver(True, 7)
    assert len({id(cold), id(warm), id(retry)}) == 3
    assert mpc._solver(True) is cold and mpc._solver(False) is warm and mpc._solver(True, 7) is retry
    assert built == [(True, None), (False, None), (True, 7)]


def test_a_compiled_mpc_builds_its_library_once_and_solves_with_it(robot, monkeypatch):
    """``SolverSettings(compiled=True)``: the first solver builds the library (the MPC's OCP, the settings'
    flags, progress shown by a new MPC), every solver is made from it with its own options and the horizon
    (the library's check); nothing is built before (no compile for an MPC that never solves)."""
    from pathlib import Path
    from types import SimpleNamespace

    import wbmpc.control.mpc as mpc_module

    mpc = WholeBodyMPC(
        robot,
        OCPSettings(n_nodes=4),
        MPCConfig(gait=make_gait("stand"), dt_max=0.03),
        SolverSettings(compiled=True, compile_flags=("-O0",)),
    )
    assert mpc.compiled_nlp is None and mpc.last_inputs is None  # nothing built or solved yet
    library = Path("/nonexistent/wbmpc_nlp.so")
    builds, made = [], []

    def build(ocp, flags, progress):
        builds.append((ocp, flags, progress))
        return SimpleNamespace(library=library)

    monkeypatch.setattr(mpc_module.codegen, "build", build)
    monkeypatch.setattr(
        mpc_module, "make_nlpsol", lambda *args, **kwargs: made.append((args, kwargs)) or object()
    )
    mpc.make_solver("cold", True)
    mpc.make_solver("retry", True, 7)
    mpc.make_solver("warm", False)
    assert len(builds) == 1 and builds[0][0] is mpc.ocp and builds[0][1:] == (("-O0",), True)
    assert mpc.compiled_nlp.library == library
    assert len(made) == 3
    for (args, kwargs), (name, cold, max_iter) in zip(
        made, [("cold", True, None), ("retry", True, 7), ("warm", False, None)], strict=True
    ):
        assert args[:2] == (name, "fatrop") and args[2] is mpc.ocp.nlp and args[4] == library
        expected = mpc.solver_options(cold, max_iter)
        assert args[3]["fatrop"] == expected["fatrop"] and args[3].keys() == expected.keys()
        assert kwargs == {"n_nodes": 4}


def test_the_mpc_refuses_wrong_arguments_with_the_whole_message(robot):
    three_feet = dataclasses.replace(robot, foot_frames=robot.foot_frames[:3])
    cases = [
        (
            lambda: WholeBodyMPC("b1_z1"),
            "robot must be a wbmpc.model.robot.Robot (see load_robot), got 'b1_z1'",
        ),
        (
            lambda: WholeBodyMPC(three_feet),
            f"robot {robot.name!r} has 3 foot frames {list(robot.foot_frames[:3])}; the MPC's gaits "
            "schedule 4 feet in the order ('FL', 'FR', 'RL', 'RR') (front-left, front-right, rear-left, "
            "rear-right): give load_robot four foot_frames",
        ),
        (lambda: WholeBodyMPC(robot, {"n_nodes": 5}), "settings must be an OCPSettings, got {'n_nodes': 5}"),
        (lambda: WholeBodyMPC(robot, None, {"mu": 0.5}), "config must be an MPCConfig, got {'mu': 0.5}"),
        (
            lambda: WholeBodyMPC(robot, None, None, {"max_iter": 7}),
            "solver must be a SolverSettings (wbmpc.control.mpc), got {'max_iter': 7}",
        ),
    ]
    for make, message in cases:
        with pytest.raises(ValueError) as refused:
            make()
        assert str(refused.value) == message


def test_the_contact_plan_is_the_configured_gait_or_the_one_given(robot):
    """Without an aborted swing: the configured gait's stance flags at the given times, or those of the
    gait given."""
    mpc = _mpc(robot, gait="trot")
    times = np.linspace(0.0, 0.8, 17)
    walk = make_gait("walk")
    trot_flags, walk_flags = mpc.config.gait.sample(times).contact, walk.sample(times).contact
    assert not np.array_equal(trot_flags, walk_flags)
    np.testing.assert_array_equal(mpc.contact_plan(times), trot_flags)
    np.testing.assert_array_equal(mpc.contact_plan(times, walk), walk_flags)


def test_a_push_aborts_the_swings_of_the_commanded_gait(robot):
    """The configured gait stands, the commands trot: a push just after lift-off aborts the swings of the
    trot (the gait walked), not those of the configured stand (it has none)."""
    mpc = _mpc(robot, gait="stand", n_nodes=6)
    q, t = robot.q_nominal, 0.02
    walk = Commands(gait=make_gait("trot"))
    swinging = ~walk.gait.sample(np.array([t])).contact[:, 0]
    assert swinging.sum() == 2
    pushed = np.zeros(robot.nv)
    pushed[1] = 0.6
    params = mpc.parameters(q, pushed, t, walk)
    mpc.previous = mpc.hold_plan(q, 0.0, params)  # a plan at rest: the measured 0.6 m/s is a push
    out = mpc.recovery_parameters(params, q, pushed, t, walk)
    assert sorted(mpc.aborted_swings) == list(np.flatnonzero(swinging))
    assert mpc.stats["swing_aborts"] == 2
    assert np.all(out["contact"][swinging, 0] == 1.0) and np.all(params["contact"][swinging, 0] == 0.0)
