"""The six dynamics formulations: layout, Fatrop structure, convergence, physics of the plan, closed loop."""

import casadi as ca
import numpy as np
import pinocchio as pin
import pytest
from conftest import forward_progress

from wbmpc import cpin
from wbmpc.control.mpc import MPCConfig, SolverSettings, WholeBodyMPC
from wbmpc.model.robot import load_b1_z1
from wbmpc.model.statics import static_equilibrium
from wbmpc.ocp import OCP, OCPSettings
from wbmpc.ocp.formulations import FORMULATIONS, make_formulation
from wbmpc.ocp.gait import make_gait
from wbmpc.sim.closed_loop import ClosedLoopConfig, run_closed_loop
from wbmpc.sim.loop_config import CommandSchedule, LowLevelConfig
from wbmpc.solver import codegen

NAMES = list(FORMULATIONS)
TOL = 1e-3  # the solver tolerance (paper)
# Paper, Table I: decision variables with 15 nodes (14 with inputs) and joint torques on 3 nodes.
PAPER_DECISION_VARIABLES = {
    "inverse_dynamics": 1226,
    "forward_dynamics": 1094,
    "centroidal_velocity": 938,
    "centroidal_velocity_nobase": 854,
    "centroidal_acceleration": 1178,
    "centroidal_acceleration_nobase": 1094,
}


@pytest.fixture(scope="module")
def robot():
    return load_b1_z1()


@pytest.fixture(scope="module")
def smodel(robot):
    return cpin.SymbolicModel(robot.model)


@pytest.fixture(scope="module", params=NAMES)
def standing(request, robot):
    """Each formulation, 7 nodes, standing, solved once from a cold start and once warm."""
    mpc = WholeBodyMPC(
        robot, OCPSettings(n_nodes=7, formulation=request.param), MPCConfig(gait=make_gait("stand"))
    )
    q, v = robot.q_nominal, np.zeros(robot.nv)
    cold = mpc.solve(q, v, t=0.0)
    warm = mpc.solve(q, v, t=0.0125)
    return mpc, cold, warm


@pytest.mark.parametrize("name", NAMES)
def test_layout_matches_the_paper(smodel, robot, name):
    form = make_formulation(name, smodel, robot.contact_frames)
    n_nodes, n_tau = 15, 3
    size = n_nodes * form.nx + n_tau * form.nu(True) + (n_nodes - 1 - n_tau) * form.nu(False)
    assert size == PAPER_DECISION_VARIABLES[name]
    assert form.describe()["path_constraint"] == (
        name in ("inverse_dynamics", "centroidal_velocity", "centroidal_acceleration")
    )


@pytest.mark.parametrize("name", NAMES)
def test_node0_state_as_parameter_is_the_same_problem(robot, name):
    """Every formulation: node 0's state substituted from the measurement (default) gives the optimum of
    the paper's layout, where it is pinned by equality rows (``h_0 = h(q_hat, v_hat)`` or ``v_0 = v_hat``)."""
    v_hat = np.zeros(robot.nv)
    v_hat[[0, 2, 4, 7]] = [0.2, -0.05, 0.3, 0.4]
    plans = []
    for pinned in (True, False):
        settings = OCPSettings(n_nodes=5, formulation=name, initial_state_variables=pinned)
        mpc = WholeBodyMPC(robot, settings, MPCConfig(gait=make_gait("stand")))
        mpc.verbose = False
        plans.append(mpc.solve(robot.q_nominal, v_hat, t=0.0))
        assert (
            mpc.ocp.n_variables
            == (pinned * mpc.ocp.formulation.nx)
            + sum(s.nx + s.nu for s in mpc.ocp.stages[1:])
            + mpc.ocp.stages[0].nu
        )
    pinned, parameter = plans
    assert pinned.success and parameter.success, (pinned.status, parameter.status)
    for field in ("q", "v", "a", "forces", "tau"):
        np.testing.assert_allclose(
            getattr(parameter, field), getattr(pinned, field), atol=1e-5, err_msg=field
        )


def test_unknown_formulation_is_named():
    with pytest.raises(ValueError, match="unknown formulation 'rnea'.*inverse_dynamics"):
        OCPSettings(formulation="rnea")


def test_fatrop_detects_the_stages_and_converges_standing(robot, standing):
    """The casadi plugin's structure detection finds every formulation's stages; the default in-process
    solver (the direct driver) converges, and from the same cold start it is the plugin's algorithm."""
    mpc, cold, warm = standing
    assert mpc.solver_settings.direct_driver
    settings = OCPSettings(n_nodes=7, formulation=mpc.ocp.settings.formulation)
    plugin = WholeBodyMPC(robot, settings, MPCConfig(gait=make_gait("stand")), SolverSettings(direct=False))
    plugin.verbose = False
    reference = plugin.solve(robot.q_nominal, np.zeros(robot.nv), t=0.0)
    stats = plugin._solver(cold=True).stats()
    expected = plugin.ocp.stage_sizes()
    assert list(stats["nx"]) == expected["nx"]
    assert list(stats["nu"]) == expected["nu"]
    assert list(stats["ng"]) == expected["ng"]
    assert cold.success and warm.success, (cold.status, warm.status)
    assert cold.constraint_violation < TOL
    assert warm.iterations <= cold.iterations
    assert reference.success and cold.iterations == reference.iterations
    np.testing.assert_allclose(cold.w, reference.w, atol=1e-8, rtol=0)


def test_plan_is_a_static_equilibrium_with_consistent_torques(robot, standing):
    """Standing still, every formulation plans (nearly) zero motion, forces carrying the weight, and joint
    torques equal to the static ones g_j - J_c,j^T F (numeric Pinocchio, independent of the symbolic code)."""
    mpc, cold, _ = standing
    assert np.abs(cold.v).max() < 0.05
    weight = robot.mass * robot.gravity
    assert abs(cold.forces[0, :4, 2].sum() - weight) < 0.02 * weight
    eq = static_equilibrium(robot, cold.q[0], np.ones(4, bool), ee_force=np.zeros(3))
    # Same robot, same pose: torques within 3 % of the largest static torque.
    assert np.abs(cold.tau[0] - eq.tau).max() < 0.03 * np.abs(eq.tau).max()
    assert np.all(np.abs(cold.tau) <= robot.joint_torque_limits + 1e-6)


def test_the_numpy_plan_reader_equals_the_plan_function(standing):
    """Every formulation's plan read by NumPy (selections and contact-flag products of w and p, the rest
    through CasADi) equals the CasADi plan function, on the solution and on random vectors."""
    from wbmpc.ocp.plan_reader import PlanReader

    mpc, cold, _ = standing
    f = mpc.ocp.plan_function
    reader = PlanReader(f)
    assert set(reader.read) | set(reader.evaluated) == set(reader.names) == {"dq", "v", "a", "forces", "tau"}
    rng = np.random.default_rng(5)
    p = mpc.last_inputs["p"]  # of the warm solve: any parameter vector will do
    for w, pv in ((cold.w, p), (rng.normal(size=f.size1_in(0)), rng.normal(size=f.size1_in(1)))):
        got, expected = reader(w, pv), f(w=w, p=pv)
        for name in reader.names:
            np.testing.assert_array_equal(got[name], np.array(expected[name]).T, err_msg=name)
    np.testing.assert_array_equal(mpc.ocp.plan(cold.w, p)["v"], np.array(f(w=cold.w, p=p)["v"]).T)


def test_join_by_scatter_equals_join_by_stage(robot, standing):
    """Where the formulation's variables are the plan's entries, join() is a NumPy scatter: the same
    primal vector as the formulations' per-stage packing, with fewer torque rows than stages too; and
    the plan read back from it is what went in (the decision-variable part)."""
    mpc, cold, _ = standing
    ocp = mpc.ocp
    N, nv, rng = ocp.n_nodes, robot.nv, np.random.default_rng(9)
    dq, v = 0.01 * rng.normal(size=(N, nv)), rng.normal(size=(N, nv))
    a, forces = rng.normal(size=(N - 1, nv)), rng.normal(size=(N - 1, len(robot.contact_frames), 3))
    for tau in (rng.normal(size=(N - 1, robot.nj)), rng.normal(size=(1, robot.nj))):
        expected = ocp.join_by_stage(robot.q_nominal, dq, v, a, forces, tau)
        np.testing.assert_array_equal(ocp.join(robot.q_nominal, dq, v, a, forces, tau), expected)
    if mpc.ocp._reader().can_scatter:
        plan = ocp.plan(expected, mpc.last_inputs["p"])
        np.testing.assert_array_equal(plan["v"][1:], v[1:])


def test_plan_satisfies_the_equations_of_motion(robot, standing):
    """RNEA of the planned q, v, a and forces: base rows zero (no actuation of the floating base)."""
    mpc, cold, _ = standing
    model, data = robot.model, robot.model.createData()
    frames = [robot.frame_id(f) for f in robot.contact_frames]
    for k in range(len(cold.tau)):
        q, v, a = cold.q[k], cold.v[k], cold.a[k]
        pin.framesForwardKinematics(model, data, q)
        fext = pin.StdVec_Force()
        for _ in range(model.njoints):
            fext.append(pin.Force.Zero())
        for fid, force in zip(frames, cold.forces[k], strict=True):
            frame = model.frames[fid]
            R = data.oMi[frame.parentJoint].rotation
            local = R.T @ force
            fext[frame.parentJoint] += pin.Force(local, np.cross(frame.placement.translation, local))
        tau = pin.rnea(model, data, q, v, a, fext)
        # The inverse-dynamics rows (base = 0, joints = tau) are equality constraints in N and N m: a
        # converged solve meets them to the solver tolerance. The other formulations reconstruct the plan's
        # accelerations and torques so that the same rows hold (their own rows are met to it too).
        assert np.abs(tau[:6]).max() < TOL, tau[:6]
        assert np.abs(tau[6:] - cold.tau[k]).max() < TOL


@pytest.mark.parametrize("name", [n for n in NAMES if n.startswith("centroidal")])
def test_torque_estimate_has_the_static_sign(robot, smodel, name):
    """The centroidal torque limits bound g_j - J^T F: at a static equilibrium that is the true torque
    (the authors' code bounds g_j + J^T F, which differs by twice the contact term)."""
    form = make_formulation(name, smodel, robot.contact_frames)
    st = form.stage("t", ca.DM(robot.q_nominal), has_input=True, torque_limited=True)
    eq = static_equilibrium(robot, robot.q_nominal, np.ones(4, bool), ee_force=np.zeros(3))
    forces = np.vstack([eq.forces, np.zeros(3)])
    applied = {frame: st.forces[3 * i : 3 * i + 3] for i, frame in enumerate(robot.contact_frames)}
    expr = form.torque_expression(st, form.kinematics(st), applied)
    f = ca.Function("tau", [st.x, st.u], [expr])
    u = form.input_values(np.zeros(robot.nv), np.zeros(robot.nv), forces, None, True)
    x = form.state_values(robot.q_nominal, np.zeros(robot.nv), np.zeros(robot.nv))
    tau = np.array(f(x, u)).ravel()
    np.testing.assert_allclose(tau, eq.tau, atol=1e-6 * np.abs(eq.tau).max())


@pytest.mark.parametrize("name", [n for n in NAMES if n != "inverse_dynamics"])
def test_generated_functions_equal_casadi_derivatives(robot, name):
    """The per-stage generated NLP functions of every formulation equal CasADi's own derivatives."""
    ocp = OCP(robot, OCPSettings(n_nodes=4, n_tau_nodes=2, formulation=name))
    functions = {f.name(): f for f in codegen.nlp_functions(ocp)}
    x, p = ocp.nlp["x"], ocp.nlp["p"]
    lam_g = ca.SX.sym("lam_g", ocp.n_constraints)
    lagrangian = ocp.nlp["f"] + ca.dot(lam_g, ocp.nlp["g"])
    reference = ca.Function(
        "reference", [x, p, lam_g], [ocp.nlp["g"], ca.jacobian(ocp.nlp["g"], x), ca.hessian(lagrangian, x)[0]]
    )
    rng = np.random.default_rng(1)
    xv = 0.05 * rng.normal(size=ocp.n_variables)
    values = {name: rng.normal(size=shape) for name, (_, shape) in ocp.params.blocks.items()}
    values |= {"dt_min": 0.01, "dt_max": 0.1, "q_hat": robot.q_nominal}
    pv = ocp.params.pack(values)
    lg = rng.normal(size=ocp.n_constraints)
    g, jac_g, hess_l = (np.array(v) for v in reference(xv, pv, lg))
    np.testing.assert_allclose(np.array(functions["nlp_g"](xv, pv)).ravel(), g.ravel(), atol=1e-8)
    np.testing.assert_allclose(ca.densify(functions["nlp_jac_g"](xv, pv)[1]), jac_g, atol=1e-8)
    hx = ca.densify(functions["nlp_hess_l"](xv, pv, 1.0, lg)[1])
    np.testing.assert_allclose(hx, hess_l, atol=1e-8 * max(1.0, np.abs(hess_l).max()))


@pytest.mark.parametrize("name", NAMES)
def test_short_trot_in_closed_loop_stays_upright(robot, name):
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=9, formulation=name), MPCConfig())
    mpc.verbose = False
    config = ClosedLoopConfig(
        duration=0.5,
        commands=CommandSchedule(base_velocity=(0.1, 0.0, 0.0)),
        low_level=LowLevelConfig(kp=30.0, kd=2.0),
    )
    result = run_closed_loop(mpc, config, progress=False)
    assert not result.fell
    assert result.summary["max_tilt_rad"] < 0.1
    assert result.summary["converged_fraction"] >= 0.9
    forward_progress(result.log.arrays()["q"], minimum=0.4 * 0.1 * 0.5)  # 0.1 m/s forward commanded
