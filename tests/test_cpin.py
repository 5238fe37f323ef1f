"""The CasADi mirror of Pinocchio (wbmpc.cpin) against numeric Pinocchio at random states."""

import functools

import casadi as ca
import numpy as np
import pinocchio as pin
import pytest

from wbmpc import cpin
from wbmpc.model.robot import load_b1, load_b1_z1

TOL = 1e-9
N_STATES = 25


@functools.cache
def load(name):
    return load_b1_z1() if name == "b1_z1" else load_b1()


@pytest.fixture(params=["b1_z1", "b1"])
def setup(request):
    # The symbolic model is built in each test (not once per module): mutation testing runs only the tests
    # that call a mutated function, and would otherwise run only the first test for a mutant of it.
    robot = load(request.param)
    return robot, cpin.SymbolicModel(robot.model)


def random_state(model, rng, base_range=2.0):
    q = pin.randomConfiguration(model)  # random unit quaternion, joints within limits
    q[:3] = rng.uniform(-base_range, base_range, 3)
    return q, rng.normal(size=model.nv), rng.normal(size=model.nv)


def symbols(smodel):
    return ca.SX.sym("q", smodel.nq), ca.SX.sym("v", smodel.nv), ca.SX.sym("a", smodel.nv)


def pin_fext(model, data, q, frames, F):
    """Pinocchio fext for world-frame point forces at frame origins (expressed in the parent joint frames)."""
    pin.framesForwardKinematics(model, data, q)
    fext = pin.StdVec_Force()
    for _ in range(model.njoints):
        fext.append(pin.Force.Zero())
    for i, name in enumerate(frames):
        frame = model.frames[model.getFrameId(name)]
        local = data.oMi[frame.parentJoint].rotation.T @ F[3 * i : 3 * i + 3]
        fext[frame.parentJoint] += pin.Force(local, np.cross(frame.placement.translation, local))
    return fext


def test_rnea_with_contact_forces_matches_pinocchio(setup):
    robot, smodel = setup
    f = cpin.rnea_function(smodel, robot.contact_frames)
    model, data = robot.model, robot.model.createData()
    rng = np.random.default_rng(0)
    for _ in range(N_STATES):
        q, v, a = random_state(model, rng)
        F = rng.normal(scale=100.0, size=3 * len(robot.contact_frames))
        expected = pin.rnea(model, data, q, v, a, pin_fext(model, data, q, robot.contact_frames, F))
        np.testing.assert_allclose(np.array(f(q, v, a, F)).ravel(), expected, atol=TOL, rtol=0)


def test_rnea_equals_mass_matrix_form(setup):
    """tau = M a + b - J_c^T F with J_c the LOCAL_WORLD_ALIGNED linear Jacobians (the paper's Eq. 2)."""
    robot, smodel = setup
    f = cpin.rnea_function(smodel, robot.contact_frames)
    model, data = robot.model, robot.model.createData()
    rng = np.random.default_rng(1)
    q, v, a = random_state(model, rng)
    F = rng.normal(scale=100.0, size=3 * len(robot.contact_frames))
    M = pin.crba(model, data, q)
    M = np.triu(M) + np.triu(M, 1).T
    b = pin.nonLinearEffects(model, data, q, v)
    pin.computeJointJacobians(model, data, q)
    pin.framesForwardKinematics(model, data, q)
    JtF = sum(
        pin.getFrameJacobian(model, data, model.getFrameId(name), pin.LOCAL_WORLD_ALIGNED)[:3].T
        @ F[3 * i : 3 * i + 3]
        for i, name in enumerate(robot.contact_frames)
    )
    np.testing.assert_allclose(np.array(f(q, v, a, F)).ravel(), M @ a + b - JtF, atol=1e-8)


def test_rnea_jacobian_matches_finite_differences():
    robot = load_b1_z1()
    smodel = cpin.SymbolicModel(robot.model)
    q, v, a = symbols(smodel)
    dq = ca.SX.sym("dq", smodel.nv)
    F = ca.SX.sym("F", 3 * len(robot.contact_frames))
    forces = {name: F[3 * i : 3 * i + 3] for i, name in enumerate(robot.contact_frames)}
    # Differentiate in the tangent space of q (as the MPC does) and w.r.t. v, a, F.
    tau = cpin.rnea(smodel, cpin.integrate(smodel, q, dq), v, a, forces)
    z = ca.vertcat(dq, v, a, F)
    f = ca.Function("f", [q, z], [tau])
    jac = ca.Function("j", [q, z], [ca.jacobian(tau, z)])
    rng = np.random.default_rng(2)
    for _ in range(3):
        q0, v0, a0 = random_state(robot.model, rng)
        z0 = np.concatenate([np.zeros(smodel.nv), v0, a0, rng.normal(scale=100.0, size=F.numel())])
        J = np.array(jac(q0, z0))
        h = 1e-6
        J_fd = np.column_stack(
            [
                (np.array(f(q0, z0 + h * e)) - np.array(f(q0, z0 - h * e))).ravel() / (2 * h)
                for e in np.eye(z0.size)
            ]
        )
        np.testing.assert_allclose(J, J_fd, atol=1e-5 * max(1.0, np.abs(J).max()))


def test_integrate_and_difference_match_pinocchio(setup):
    robot, smodel = setup
    model = robot.model
    q, dq, q1 = ca.SX.sym("q", smodel.nq), ca.SX.sym("dq", smodel.nv), ca.SX.sym("q1", smodel.nq)
    integrate = ca.Function("integrate", [q, dq], [cpin.integrate(smodel, q, dq)])
    difference = ca.Function("difference", [q, q1], [cpin.difference(smodel, q, q1)])
    rng = np.random.default_rng(3)
    for scale in (1e-7, 1e-3, 0.5, 1.5):  # both sides of the small-angle switch
        for _ in range(N_STATES):
            q0, _, _ = random_state(model, rng)
            step = rng.normal(scale=scale, size=model.nv)
            expected = pin.integrate(model, q0, step)
            got = np.array(integrate(q0, step)).ravel()
            np.testing.assert_allclose(got, expected, atol=TOL)
            if np.linalg.norm(step[3:6]) > np.pi - 0.1:
                continue  # the logarithm returns another (equivalent) rotation vector beyond pi
            np.testing.assert_allclose(np.array(difference(q0, expected)).ravel(), step, atol=TOL)
            np.testing.assert_allclose(
                np.array(difference(q0, expected)).ravel(), pin.difference(model, q0, expected), atol=TOL
            )


def test_integrate_derivatives_are_finite_at_zero():
    """q_k = q_hat (+) dq_k is differentiated at dq = 0 in every MPC solve: no NaN from the small angle."""
    smodel = cpin.SymbolicModel(load_b1_z1().model)
    q, dq = ca.SX.sym("q", smodel.nq), ca.SX.sym("dq", smodel.nv)
    lam = ca.SX.sym("lam", smodel.nq)
    out = cpin.integrate(smodel, q, dq)
    hess = ca.Function("h", [q, dq, lam], [ca.hessian(ca.dot(lam, out), dq)[0]])
    q0 = load_b1_z1().q_nominal
    H = np.array(hess(q0, np.zeros(smodel.nv), np.ones(smodel.nq)))
    assert np.all(np.isfinite(H))
    assert np.abs(H).max() > 0.1  # the rotation is curved: second derivatives are not all zero


@pytest.mark.parametrize("reference", [cpin.LOCAL_WORLD_ALIGNED, cpin.LOCAL, cpin.WORLD])
def test_frame_kinematics_match_pinocchio(setup, reference):
    robot, smodel = setup
    model, data = robot.model, robot.model.createData()
    q, v, _ = symbols(smodel)
    kin = cpin.forward_kinematics(smodel, q, v)
    outputs = []
    for name in robot.contact_frames + ("base",):
        R, p = cpin.frame_placement(kin, name)
        vel = cpin.frame_velocity(kin, name, reference)
        outputs += [ca.vec(R), p, vel.vector()]
    outputs.append(cpin.center_of_mass(kin))
    f = ca.Function("kin", [q, v], [ca.vertcat(*outputs)])
    pin_ref = {"LOCAL": pin.LOCAL, "WORLD": pin.WORLD, "LOCAL_WORLD_ALIGNED": pin.LOCAL_WORLD_ALIGNED}[
        reference
    ]
    rng = np.random.default_rng(4)
    for _ in range(N_STATES):
        q0, v0, _ = random_state(model, rng)
        pin.forwardKinematics(model, data, q0, v0)
        pin.updateFramePlacements(model, data)
        expected = []
        for name in robot.contact_frames + ("base",):
            fid = model.getFrameId(name)
            M = data.oMf[fid]
            expected += [
                M.rotation.ravel(order="F"),
                M.translation,
                pin.getFrameVelocity(model, data, fid, pin_ref).vector,
            ]
        expected.append(pin.centerOfMass(model, data, q0))
        np.testing.assert_allclose(np.array(f(q0, v0)).ravel(), np.concatenate(expected), atol=TOL)


def test_unknown_frame_is_named():
    smodel = cpin.SymbolicModel(load_b1().model)
    q, v, a = symbols(smodel)
    with pytest.raises(ValueError, match="no_such_foot"):
        cpin.rnea(smodel, q, v, a, {"no_such_foot": ca.SX.zeros(3)})


def test_rnea_instruction_budget():
    """The paper's RNEA constraint has 3,818 instructions; ours with 5 contact frames must not exceed it."""
    robot = load_b1_z1()
    f = cpin.rnea_function(cpin.SymbolicModel(robot.model), robot.contact_frames)
    assert len(robot.contact_frames) == 5 and robot.nv == 22
    assert f.n_instructions() <= 3818
