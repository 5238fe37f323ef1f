"""The whole-body inverse-dynamics MPC: structure, convergence, physics of the solution, robustness."""

import dataclasses

import casadi as ca
import numpy as np
import pinocchio as pin
import pytest
from conftest import forward_progress

from wbmpc.control.mpc import Commands, MPCConfig, SolverSettings, WholeBodyMPC
from wbmpc.model.quaternion import tilt
from wbmpc.model.robot import load_b1_z1
from wbmpc.ocp import OCP, OCPSettings
from wbmpc.ocp.gait import make_gait
from wbmpc.sim.closed_loop import ClosedLoopConfig, run_closed_loop
from wbmpc.sim.loop_config import CommandSchedule, PlantConfig

TOL = 1e-3  # the solver tolerance (paper)


@pytest.fixture(scope="module")
def robot():
    return load_b1_z1()


@pytest.fixture(scope="module")
def standing(robot):
    """The paper-size problem (15 nodes), standing, solved once from a cold start."""
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=15), MPCConfig(gait=make_gait("stand")))
    plan = mpc.solve(robot.q_nominal, np.zeros(robot.nv), t=0.0)
    return mpc, plan


def test_decision_variables_match_the_paper(standing, robot):
    mpc, _ = standing
    # Paper, Table I: 1226 decision variables for the inverse-dynamics MPC with 15 nodes and tau on 3 nodes,
    # counting the arm force pinned to its command on the 14 stages and node 0's state pinned to the
    # measurement; as parameters they drop 42 and 44 of them.
    paper = OCPSettings(n_nodes=15, ee_force_input=True, initial_state_variables=True)
    assert OCP(robot, paper).n_variables == 1226
    assert mpc.ocp.n_variables == 1226 - 3 * 14 - 44


def test_node0_state_as_parameter_gives_the_same_plan(robot):
    """Node 0's state pinned by equality rows (the paper) and substituted from the measurement: the same
    optimum with 44 variables and 44 equality rows fewer, on a trot with a moving base and a warm start."""
    plans, sizes = [], []
    v_hat = np.zeros(robot.nv)
    v_hat[[0, 1, 5, 8]] = [0.3, -0.1, 0.2, 0.5]
    for pinned in (True, False):
        settings = OCPSettings(n_nodes=8, initial_state_variables=pinned)
        mpc = WholeBodyMPC(robot, settings, MPCConfig(gait=make_gait("trot"), dt_max=0.06))
        mpc.solve(robot.q_nominal, v_hat, t=0.05)
        plans.append(mpc.solve(robot.q_nominal, v_hat, t=0.0625))
        sizes.append((mpc.ocp.n_variables, mpc.ocp.n_constraints))
    pinned, parameter = plans
    assert pinned.success and parameter.success
    assert sizes[0][0] - sizes[1][0] == 44 and sizes[0][1] - sizes[1][1] == 44
    np.testing.assert_allclose(parameter.v[0], v_hat, atol=1e-12)  # node 0 is the measurement itself
    np.testing.assert_allclose(parameter.q[0], robot.q_nominal, atol=1e-12)
    for name in ("q", "v", "a", "tau"):
        np.testing.assert_allclose(getattr(parameter, name), getattr(pinned, name), atol=1e-6, err_msg=name)
    np.testing.assert_allclose(parameter.forces, pinned.forces, atol=1e-5)


def test_the_arm_force_as_parameter_gives_the_same_plan(robot):
    """The paper's pinned arm-force input and the parameter give the same optimum (3 inputs fewer)."""
    commands = Commands(ee_force=np.array([5.0, 0.0, -20.0]), base_linear_velocity=np.array([0.2, 0.0, 0.0]))
    plans = []
    for ee_force_input in (True, False):
        settings = OCPSettings(n_nodes=8, ee_force_input=ee_force_input)
        mpc = WholeBodyMPC(robot, settings, MPCConfig(gait=make_gait("trot"), dt_max=0.06))
        plans.append(mpc.solve(robot.q_nominal, np.zeros(robot.nv), t=0.0, commands=commands))
    pinned, parameter = plans
    assert pinned.success and parameter.success
    np.testing.assert_allclose(parameter.tau, pinned.tau, atol=1e-6)
    np.testing.assert_allclose(parameter.forces, pinned.forces, atol=1e-6)
    np.testing.assert_allclose(parameter.forces[:, -1], np.tile(commands.ee_force, (7, 1)))


def test_fatrop_detects_the_stage_structure(robot):
    """The casadi plugin's structure detection finds the OCP's stages (the direct driver is given them)."""
    mpc = WholeBodyMPC(
        robot, OCPSettings(n_nodes=15), MPCConfig(gait=make_gait("stand")), SolverSettings(direct=False)
    )
    assert mpc.solve(robot.q_nominal, np.zeros(robot.nv), t=0.0).success
    stats = mpc._solver(cold=True).stats()
    expected = mpc.ocp.stage_sizes()
    # Node 0's state is a parameter: Fatrop's detection takes the first 44 of u_0's 50 entries as "x_0".
    assert list(stats["nx"]) == expected["nx"] == [44] * 15
    assert list(stats["nu"]) == expected["nu"] == [6] + [50] * 2 + [34] * 11 + [0]
    assert list(stats["ng"]) == expected["ng"]


def test_cold_start_converges_when_standing(standing):
    _, plan = standing
    assert plan.success, plan.status
    assert plan.iterations <= 30
    assert plan.constraint_violation < TOL


def test_solution_satisfies_rnea_friction_and_torque_limits(robot, standing):
    """Check the plan with numeric Pinocchio, independently of the symbolic model."""
    mpc, plan = standing
    model, data = robot.model, robot.model.createData()
    mu = mpc.config.mu
    for k in range(mpc.n_nodes - 1):
        q, v, a, forces = plan.q[k], plan.v[k], plan.a[k], plan.forces[k]
        pin.framesForwardKinematics(model, data, q)
        pin.computeJointJacobians(model, data, q)
        JtF = sum(
            pin.getFrameJacobian(model, data, robot.frame_id(f), pin.LOCAL_WORLD_ALIGNED)[:3].T @ forces[i]
            for i, f in enumerate(robot.contact_frames)
        )
        tau = pin.rnea(model, data, q, v, a) - JtF
        # The RNEA rows are equality constraints in N and N m: met to the solver tolerance.
        assert np.abs(tau[:6]).max() < TOL, f"node {k}: base wrench residual {tau[:6]}"
        if k < len(plan.tau):
            np.testing.assert_allclose(tau[6:], plan.tau[k], rtol=0, atol=TOL)
        fz = forces[:4, 2]
        assert np.all(fz >= -1e-6)
        assert np.all(mu**2 * fz**2 - forces[:4, 0] ** 2 - forces[:4, 1] ** 2 >= -1e-3)
    assert np.all(np.abs(plan.tau) <= robot.joint_torque_limits + 1e-6)
    # Standing still: the feet carry the weight.
    assert plan.forces[0, :4, 2].sum() == pytest.approx(robot.mass * robot.gravity, rel=0.02)


def test_trot_plan_has_zero_force_on_swing_feet(robot):
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=8), MPCConfig(gait=make_gait("trot"), dt_max=0.06))
    plan = mpc.solve(
        robot.q_nominal,
        np.zeros(robot.nv),
        t=0.1,
        commands=Commands(base_linear_velocity=np.array([0.2, 0.0, 0.0])),
    )
    assert plan.success, plan.status
    swing = ~plan.contact.T
    assert swing.any()
    assert np.all(plan.forces[:, :4][swing] == 0.0)
    stance_fz = plan.forces[:, :4, 2][~swing]
    assert stance_fz.mean() > 100.0  # two feet carry ~300 N each


def test_ipopt_agrees_with_fatrop(robot, standing):
    _, fatrop_plan = standing
    mpc = WholeBodyMPC(
        robot, OCPSettings(n_nodes=15), MPCConfig(gait=make_gait("stand")), SolverSettings(solver="ipopt")
    )
    plan = mpc.solve(robot.q_nominal, np.zeros(robot.nv), t=0.0)
    assert plan.success, plan.status
    np.testing.assert_allclose(plan.forces[0], fatrop_plan.forces[0], atol=2.0)
    np.testing.assert_allclose(plan.tau[0], fatrop_plan.tau[0], atol=1.0)


def test_injected_solver_failure_is_survived(robot, monkeypatch):
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=6), MPCConfig(gait=make_gait("stand"), dt_max=0.04))
    first = mpc.solve(robot.q_nominal, np.zeros(robot.nv), t=0.0)
    assert first.success

    def broken(cold, max_iter=None):
        def solve(**kwargs):
            raise RuntimeError("injected failure")

        return solve

    monkeypatch.setattr(mpc, "_solver", broken)
    second = mpc.solve(robot.q_nominal, np.zeros(robot.nv), t=0.0125)
    assert second.fallback and not second.success
    assert second.status == "solver_exception" and "injected failure" in second.reason
    # The warm solve and its cold retry both raised: one failure, two exceptions, no crash.
    assert mpc.stats["failures"] == 1 and mpc.stats["exceptions"] == 2 and mpc.stats["cold_retries"] == 1
    np.testing.assert_array_equal(second.tau, first.tau)  # the controller keeps the previous plan


def test_cold_retry_rescues_a_failed_warm_start(robot, monkeypatch):
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=6), MPCConfig(gait=make_gait("stand"), dt_max=0.04))
    assert mpc.solve(robot.q_nominal, np.zeros(robot.nv), t=0.0).success
    real = mpc._solver

    def warm_broken(cold, max_iter=None):
        if not cold:

            def solve(**kwargs):
                raise RuntimeError("injected warm failure")

            return solve
        return real(cold, max_iter)

    monkeypatch.setattr(mpc, "_solver", warm_broken)
    second = mpc.solve(robot.q_nominal, np.zeros(robot.nv), t=0.0125)
    assert second.success and not second.fallback
    assert second.status == "success" and second.reason == "" and second.timings["cold_retry"]
    assert mpc.stats["cold_retries"] == 1 and mpc.stats["failures"] == 0


class _UnconvergedSolver:
    """Stands in for the ``casadi.nlpsol`` of a solve that stops unconverged: it returns a finite iterate
    (``w``) and Fatrop's statistics for its iteration cap (``return_flag`` 1)."""

    def __init__(self, w, n_constraints):
        self.w, self.n_constraints, self.calls = w, n_constraints, []

    def __call__(self, **args):
        self.calls.append(args)
        return {
            "x": self.w.copy(),
            "g": np.zeros(self.n_constraints),
            "lam_g": np.ones(self.n_constraints),
            "f": 0.0,
        }

    def stats(self):
        return {
            "success": False,
            "return_status": 1,
            "iter_count": 30,
            "fatrop": {"return_flag": 1, "iterations_count": 30, "time_total": 1e-3},
        }


PLAN_ARRAYS = ("q", "v", "a", "forces", "tau", "w", "lam_g")


def _standing_mpc(robot, **config):
    fields = {f.name for f in dataclasses.fields(SolverSettings)}
    solver = SolverSettings(**{k: config.pop(k) for k in list(config) if k in fields})
    mpc = WholeBodyMPC(
        robot, OCPSettings(n_nodes=6), MPCConfig(gait=make_gait("stand"), dt_max=0.04, **config), solver
    )
    mpc.verbose = False
    return mpc


def test_an_unconverged_iterate_is_never_applied(robot, monkeypatch):
    """After a converged plan, a warm solve and its cold retry both stop unconverged (a finite iterate, not
    an exception): the previous plan comes back unchanged as the fallback, stays the warm start, and is
    what the low level applies; the iterate's torques, which differ, reach nothing."""
    mpc = _standing_mpc(robot)
    q, v = robot.q_nominal, np.zeros(robot.nv)
    first = mpc.solve(q, v, t=0.0)
    assert first.success
    kept = {name: getattr(first, name).copy() for name in PLAN_ARRAYS}
    rng = np.random.default_rng(0)
    fake = _UnconvergedSolver(first.w + 5.0 * rng.normal(size=first.w.size), mpc.ocp.n_constraints)
    monkeypatch.setattr(mpc, "_solver", lambda cold, max_iter=None: fake)
    second = mpc.solve(q, v, t=0.0125)
    # The warm start (with the previous duals) and the cold retry (without) both ran and both failed.
    assert len(fake.calls) == 2 and "lam_g0" in fake.calls[0] and "lam_g0" not in fake.calls[1]
    assert mpc.stats["failures"] == 1 and mpc.stats["cold_retries"] == 1 and mpc.stats["exceptions"] == 0
    assert not second.success and second.fallback and not second.hold
    assert second.status == "max_iter_exceeded" and "iteration cap" in second.reason
    for name in ("q", "v", "a", "forces", "tau"):
        np.testing.assert_array_equal(getattr(second, name), kept[name], err_msg=name)
    assert second.t == first.t  # the previous plan on its own time grid (the low level interpolates it)
    # The warm start of the next solve is still the converged plan, untouched.
    assert mpc.previous is first
    for name, value in kept.items():
        np.testing.assert_array_equal(getattr(mpc.previous, name), value, err_msg=name)
    # The unconverged iterate's torques differ by newton metres: applying them would show.
    iterate_tau = np.asarray(mpc.ocp.plan_function(w=fake.w, p=fake.calls[0]["p"])["tau"]).T
    assert np.abs(iterate_tau[0] - first.tau[0]).max() > 1.0
    # The low level applies the previous plan's torque (pure feed-forward: kp = kd = 0).
    from wbmpc.control.low_level import LowLevelController

    applied, previous = LowLevelController(), LowLevelController()
    applied.update(second)
    previous.update(first)
    for t in (0.0125, 0.014, 0.02):
        np.testing.assert_array_equal(applied.torque(t, q, v), previous.torque(t, q, v))


def test_a_closed_loop_keeps_applying_the_last_converged_plan(robot, monkeypatch):
    """Every solve after the first stops unconverged (injected): each logged plan is the first one, the
    applied torques are its interpolation, and the MPC ends with it as the warm start."""
    mpc = _standing_mpc(robot)
    real = mpc._solver
    fakes = []

    def unconverged_after_the_first(cold, max_iter=None):
        if mpc.previous is None:
            return real(cold, max_iter)
        w = mpc.previous.w + 0.2
        fakes.append(_UnconvergedSolver(w, mpc.ocp.n_constraints))
        return fakes[-1]

    monkeypatch.setattr(mpc, "_solver", unconverged_after_the_first)
    result = run_closed_loop(
        mpc, ClosedLoopConfig(duration=0.1, commands=CommandSchedule(arm_reference=None)), progress=False
    )
    log = result.log.arrays()
    assert len(fakes) == 2 * (len(log["solve_t"]) - 1) >= 10  # warm start and cold retry per tick
    assert log["success"][0] and not log["success"][1:].any() and log["fallback"][1:].all()
    first = mpc.previous
    assert first.t == 0.0 and first.success
    np.testing.assert_array_equal(log["plan_tau"], np.tile(first.tau[0], (len(log["solve_t"]), 1)))
    from wbmpc.control.low_level import LowLevelController

    reference = LowLevelController(torque_limits=robot.joint_torque_limits)
    reference.update(first)
    expected = [reference.torque(t, q, v) for t, q, v in zip(log["t"], log["q"], log["v"], strict=True)]
    np.testing.assert_allclose(log["tau"], expected, rtol=0, atol=1e-12)
    assert not result.fell


def test_a_real_iteration_cap_falls_back_to_the_previous_plan(robot):
    """Fatrop itself stopped at one iteration (warm start and cold retry) after a push: the previous plan."""
    mpc = _standing_mpc(robot, max_iter=1, retry_max_iter=1)
    q = robot.q_nominal
    first = mpc.solve(q, np.zeros(robot.nv), t=0.0)  # the cold start keeps its own cap (200)
    assert first.success
    kept = {name: getattr(first, name).copy() for name in PLAN_ARRAYS}
    pushed = np.zeros(robot.nv)
    pushed[[1, 5]] = 0.5  # sideways and yawing: one iteration cannot converge
    second = mpc.solve(q, pushed, t=0.0125)
    assert not second.success and second.fallback and not second.hold
    assert second.status == "max_iter_exceeded" and mpc.stats["cold_retries"] == 1
    for name in ("q", "v", "a", "forces", "tau"):
        np.testing.assert_array_equal(getattr(second, name), kept[name], err_msg=name)
    assert mpc.previous is first
    for name, value in kept.items():
        np.testing.assert_array_equal(getattr(first, name), value, err_msg=name)


def test_closed_loop_trot_stays_upright(robot):
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=15), MPCConfig(gait=make_gait("trot")))
    result = run_closed_loop(mpc, ClosedLoopConfig(duration=0.5), progress=False)
    s = result.summary
    assert not result.fell
    assert s["max_tilt_rad"] < 0.2
    assert s["converged_fraction"] >= 0.95
    assert s["torque_violations"] == 0
    assert s["ee_rms_m"] < 0.03
    # Limit rows with unit slacks: warm-started Fatrop needs 3 iterations, 4 near some contact switches
    # (4.2 on average with the rows in N m and rad/s, every solve at least 4).
    warm = np.asarray(result.log.iterations[1:])
    assert warm.max() <= 4 and warm.mean() <= 3.5, warm
    q = result.log.arrays()["q"]
    assert q[:, 2].min() > 0.4  # base height stays near nominal (0.53 m)
    assert max(tilt(qi) for qi in q) == pytest.approx(s["max_tilt_rad"])
    forward_progress(q, minimum=0.4 * 0.2 * 0.5)  # 0.2 m/s forward commanded (the default)


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda r: make_gait("gallop"), "gallop"),
        (lambda r: MPCConfig(dt_min=0.0), "dt_min"),
        (lambda r: MPCConfig(dt_min=0.05, dt_max=0.01), "dt_max"),
        (lambda r: SolverSettings(solver="snopt"), "snopt"),
        (lambda r: Commands(ee_velocity=np.zeros(2)).validated(), "ee_velocity"),
        (lambda r: Commands(ee_force=np.array([0.0, np.nan, 0.0])).validated(), "ee_force"),
        (lambda r: OCPSettings(n_nodes=2), "n_nodes"),
        (lambda r: OCPSettings(n_nodes=5, n_tau_nodes=5), "n_tau_nodes"),
    ],
)
def test_bad_configuration_is_named(robot, make, message):
    with pytest.raises(ValueError, match=message):
        make(robot)


def test_bad_state_is_named(robot, standing):
    mpc, _ = standing
    q = robot.q_nominal
    q[7] = np.nan
    with pytest.raises(ValueError, match="q_hat contains NaN"):
        mpc.solve(q, np.zeros(robot.nv))
    with pytest.raises(ValueError, match=r"v_hat must have shape \(22,\)"):
        mpc.solve(robot.q_nominal, np.zeros(21))


def test_closed_loop_trot_on_pybullet_stays_upright(robot):
    """The same MPC on a physics engine (contacts from collisions, not the schedule), pure feed-forward."""
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=15), MPCConfig(gait=make_gait("trot")))
    result = run_closed_loop(
        mpc, ClosedLoopConfig(duration=0.4, plant=PlantConfig(kind="pybullet")), progress=False
    )
    s = result.summary
    assert s["plant"] == "pybullet"
    assert not result.fell and s["max_tilt_rad"] < 0.2
    assert s["converged_fraction"] >= 0.95
    q = result.log.arrays()["q"]
    assert q[:, 2].min() > 0.4
    forward_progress(q, minimum=0.4 * 0.2 * 0.4)  # 0.2 m/s forward commanded (the default)


def test_unknown_plant_is_named(robot):
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=4), MPCConfig(gait=make_gait("stand"), dt_max=0.03))
    with pytest.raises(ValueError, match="unknown plant 'mujoco'"):
        run_closed_loop(mpc, ClosedLoopConfig(duration=0.1, plant=PlantConfig(kind="mujoco")), progress=False)


def test_limit_rows_have_unit_slacks_and_the_same_feasible_set(robot):
    """Torque, joint position and velocity limits are rows ``-1 <= (x - mid) / half <= 1``: unit slacks for
    the solver's bound multipliers (initialised at 1), the same feasible set."""
    ocp = OCP(robot, OCPSettings(n_nodes=4))
    for name in ("torque_limits", "joint_position_limits", "joint_velocity_limits"):
        rows = [s.rows[name] for s in ocp.stages if name in s.rows]
        assert rows, name
        for r in rows:
            assert np.all(ocp.lbg[r] == -1.0) and np.all(ocp.ubg[r] == 1.0), name
    rng = np.random.default_rng(0)
    w = 0.3 * rng.normal(size=ocp.n_variables)
    p = np.zeros(ocp.params.size)
    start, (n, _) = ocp.params.blocks["q_hat"]
    p[start : start + n] = robot.q_nominal
    g = np.asarray(ca.Function("g", [ocp.nlp["x"], ocp.nlp["p"]], [ocp.nlp["g"]])(w, p)).ravel()
    blocks, stage = ocp.split(w, p), ocp.stages[2]
    lo, hi = robot.joint_position_limits
    q_j = robot.q_nominal[7:] + blocks["dq"][2][6:]  # revolute joints: the increment adds
    np.testing.assert_allclose(
        g[stage.rows["joint_position_limits"]], (2 * q_j - hi - lo) / (hi - lo), atol=1e-12
    )
    v_max = robot.joint_velocity_limits
    np.testing.assert_allclose(g[stage.rows["joint_velocity_limits"]] * v_max, blocks["v"][2][6:], atol=1e-12)


def test_a_raising_cold_retry_after_an_unconverged_warm_solve_reports_the_warm_iterations(robot, monkeypatch):
    """Warm solve stops at its iteration cap, the cold retry raises: the report counts the warm solve's
    iterations, as the same warm solve without a retry reports them (they used to be added to the retry's
    -1, "no count", one too few)."""
    q, v = robot.q_nominal, np.zeros(robot.nv)
    v_kicked = v.copy()
    v_kicked[:3] = (0.5, -0.4, 0.3)  # one iteration cannot converge from here
    counts = []
    for retry in (False, True):
        mpc = _standing_mpc(robot, max_iter=1, cold_retry=retry)
        assert mpc.solve(q, v, 0.0).success
        if retry:
            real = mpc._solver

            def raising(**kwargs):
                raise RuntimeError("injected failure")

            monkeypatch.setattr(
                mpc, "_solver", lambda cold, max_iter=None, real=real: raising if cold else real(cold)
            )
        plan = mpc.solve(q, v_kicked, 0.0125)
        assert not plan.success and plan.fallback
        counts.append(plan.iterations)
    assert counts[0] >= 1 and counts[1] == counts[0], counts
