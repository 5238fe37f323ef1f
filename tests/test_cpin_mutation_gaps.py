"""Properties of wbmpc.cpin that mutation testing found unchecked (docs/mutation/cpin.md).

Each test compares with numeric Pinocchio or checks an invariant; none restates the implementation.
"""

import casadi as ca
import numpy as np
import pinocchio as pin
import pytest
from test_cpin import pin_fext, random_state
from test_cpin_dynamics import assert_close, synthetic_robot

from wbmpc import cpin
from wbmpc.cpin import spatial
from wbmpc.model.robot import load_b1


def _with_armature(robot, seed):
    """The robot with a random armature on most degrees of freedom (base ones too) and zero on a few:
    both branches of every ``armature != 0`` test (the calibrated models have a joint armature)."""
    rng = np.random.default_rng(seed)
    armature = rng.uniform(0.05, 0.5, robot.model.nv)
    armature[rng.choice(robot.model.nv, size=robot.model.nv // 3, replace=False)] = 0.0
    robot.model.armature = armature
    return robot


@pytest.mark.parametrize("name", ["synthetic", "b1"])
def test_armature_in_rnea_crba_and_aba_matches_pinocchio(name):
    robot = _with_armature(synthetic_robot(3) if name == "synthetic" else load_b1(), seed=4)
    model, data = robot.model, robot.model.createData()
    smodel = cpin.SymbolicModel(model)
    q = ca.SX.sym("q", smodel.nq)
    rnea = cpin.rnea_function(smodel, robot.contact_frames)
    crba = ca.Function("crba", [q], [cpin.crba(smodel, q)])
    aba = {m: cpin.aba_function(smodel, robot.contact_frames, m) for m in ("articulated", "crba")}
    rng = np.random.default_rng(5)
    for _ in range(5):
        q0, v0, a0 = random_state(model, rng)
        F = rng.normal(scale=100.0, size=3 * len(robot.contact_frames))
        fext = pin_fext(model, data, q0, robot.contact_frames, F)
        tau = pin.rnea(model, data, q0, v0, a0, fext)
        assert_close(np.array(rnea(q0, v0, a0, F)).ravel(), tau)
        M = pin.crba(model, data, q0)
        assert_close(np.array(crba(q0)), np.triu(M) + np.triu(M, 1).T)
        for method, f in aba.items():
            assert_close(np.array(f(q0, v0, tau, F)).ravel(), a0, rtol=1e-9 * np.abs(tau).max()), method


def _unit_vectors(rng, n):
    x = rng.normal(size=(n, 3))
    return x / np.linalg.norm(x, axis=1, keepdims=True)


# Rotation angles on both sides of the small-angle switch (theta^2 < 1e-8: Taylor expansions).
TAYLOR_ANGLES = (2e-5, 5e-5, 9.9e-5)
EXACT_ANGLES = (0.3, 1.0, 2.5)


@pytest.mark.parametrize("theta", TAYLOR_ANGLES + EXACT_ANGLES)
def test_exponential_and_logarithm_match_pinocchio_on_both_sides_of_the_switch(theta):
    """exp3, its quaternion, V(omega) of exp6, log3 and V^-1 of log6 against Pinocchio. With a 1 km
    translation the theta^2 corrections of V (theta^3 |nu| ~ 1e-10 m) are far above rounding."""
    w, R = ca.SX.sym("w", 3), ca.SX.sym("R", 3, 3)
    exp3 = ca.Function("exp3", [w], [spatial.exp3(w)])
    quat = ca.Function("quat", [w], [spatial.exp3_quaternion(w)])
    V = ca.Function("V", [w], [spatial.se3_left_jacobian(w)])
    V_inv = ca.Function("V_inv", [w], [spatial.se3_left_jacobian_inverse(w)])
    log3 = ca.Function("log3", [R], [spatial.log3(R)])
    rng = np.random.default_rng(int(theta * 1e6))
    for axis in _unit_vectors(rng, 10):
        omega = theta * axis
        nu = 1e3 * rng.normal(size=3)
        R0 = pin.exp3(omega)
        np.testing.assert_allclose(np.array(exp3(omega)), R0, rtol=0, atol=1e-15)
        expected = pin.Quaternion(R0).coeffs()  # q or -q: w = cos(theta / 2) > 0 below pi
        np.testing.assert_allclose(
            np.array(quat(omega)).ravel(), np.sign(expected[3]) * expected, rtol=0, atol=1e-15
        )
        np.testing.assert_allclose(np.array(log3(R0)).ravel(), omega, rtol=0, atol=1e-15 * theta)
        M = pin.exp6(pin.Motion(nu, omega))
        np.testing.assert_allclose(np.array(V(omega)) @ nu, M.translation, rtol=0, atol=1e-12)
        np.testing.assert_allclose(np.array(V_inv(omega)) @ M.translation, nu, rtol=0, atol=1e-11)


def test_rnea_refuses_kinematics_without_acceleration():
    smodel = cpin.SymbolicModel(load_b1().model)
    q, v = ca.SX.sym("q", smodel.nq), ca.SX.sym("v", smodel.nv)
    data = cpin.forward_kinematics(smodel, q, v)
    message = "rnea needs forward kinematics computed with velocity and acceleration"
    with pytest.raises(ValueError, match=message):
        cpin.rnea(smodel, q, v, v, data=data)


def test_centroidal_momentum_refuses_kinematics_without_velocity():
    smodel = cpin.SymbolicModel(load_b1().model)
    q, v = ca.SX.sym("q", smodel.nq), ca.SX.sym("v", smodel.nv)
    with pytest.raises(ValueError, match=r"centroidal_momentum needs forward_kinematics\(model, q, v\)"):
        cpin.centroidal_momentum(smodel, q, v, data=cpin.forward_kinematics(smodel, q))


def test_functions_take_and_return_the_documented_names():
    """``rnea_function``: ``(q, v, a, F) -> tau`` and ``aba_function``: ``(q, v, tau, F) -> a``, callable
    by keyword (as a generated library is): the same values as Pinocchio."""
    robot = load_b1()
    model, data = robot.model, robot.model.createData()
    smodel = cpin.SymbolicModel(model)
    rng = np.random.default_rng(6)
    q, v, a = random_state(model, rng)
    F = rng.normal(scale=100.0, size=3 * len(robot.contact_frames))
    tau = pin.rnea(model, data, q, v, a, pin_fext(model, data, q, robot.contact_frames, F))
    out = cpin.rnea_function(smodel, robot.contact_frames, name="inverse")(q=q, v=v, a=a, F=F)
    assert list(out) == ["tau"]
    assert_close(np.array(out["tau"]).ravel(), tau)
    for method in ("articulated", "crba"):
        f = cpin.aba_function(smodel, robot.contact_frames, method, name="forward")
        out = f(q=q, v=v, tau=tau, F=F)
        assert list(out) == ["a"] and f.name() == "forward"
        assert_close(np.array(out["a"]).ravel(), a, rtol=1e-9 * np.abs(tau).max())


@pytest.mark.parametrize("reference", [cpin.LOCAL_WORLD_ALIGNED, cpin.LOCAL, cpin.WORLD])
def test_frame_kinematics_of_prismatic_unaligned_and_base_frames_match_pinocchio(reference):
    """Frame placements, velocities and the centre of mass on the synthetic tree (prismatic and unaligned
    joints, rotated joint placements, a frame on the base joint), which the B1 models do not have."""
    robot = synthetic_robot(7)
    model, data = robot.model, robot.model.createData()
    # A massless body (a sensor link) before the others and a body of exactly 1 kg, both in the CoM.
    model.inertias[2] = pin.Inertia.Zero()
    model.inertias[4] = pin.Inertia(1.0, np.array([0.1, -0.2, 0.05]), np.diag([0.01, 0.02, 0.03]))
    smodel = cpin.SymbolicModel(model)
    q, v = ca.SX.sym("q", smodel.nq), ca.SX.sym("v", smodel.nv)
    kin = cpin.forward_kinematics(smodel, q, v)
    outputs = []
    for name in robot.contact_frames:
        R, p = cpin.frame_placement(kin, name)
        outputs += [ca.vec(R), p, cpin.frame_velocity(kin, name, reference).vector()]
    f = ca.Function("kin", [q, v], [ca.vertcat(*outputs, cpin.center_of_mass(kin))])
    pin_reference = getattr(pin, reference)
    rng = np.random.default_rng(8)
    for _ in range(10):
        q0, v0, _ = random_state(model, rng)
        pin.forwardKinematics(model, data, q0, v0)
        pin.updateFramePlacements(model, data)
        expected = []
        for name in robot.contact_frames:
            fid = model.getFrameId(name)
            M = data.oMf[fid]
            velocity = pin.getFrameVelocity(model, data, fid, pin_reference).vector
            expected += [M.rotation.ravel(order="F"), M.translation, velocity]
        expected.append(pin.centerOfMass(model, data, q0))
        assert_close(np.array(f(q0, v0)).ravel(), np.concatenate(expected))


def _model(*joints, placement=None):
    """A chain of the given Pinocchio joints, each with a random body."""
    model = pin.Model()
    parent = 0
    for k, joint in enumerate(joints):
        parent = model.addJoint(parent, joint, placement or pin.SE3.Identity(), f"j{k}")
        model.appendBodyToJoint(parent, pin.Inertia.Random(), pin.SE3.Identity())
    return model


@pytest.mark.parametrize(
    ("model", "message"),
    [
        (_model(pin.JointModelRX()), "needs a free-flyer root joint"),
        (_model(pin.JointModelRX(), pin.JointModelFreeFlyer()), "free-flyer joint 'j1' must be the root"),
        (_model(pin.JointModelFreeFlyer(), placement=pin.SE3.Random()), "'j0' must have an identity joint"),
        (
            _model(
                pin.JointModelFreeFlyer(), placement=pin.SE3(pin.utils.rotate("z", np.pi / 2), np.zeros(3))
            ),
            "'j0' must have an identity joint",
        ),
        (
            _model(pin.JointModelFreeFlyer(), pin.JointModelSpherical()),
            r"'j1' has type JointModelSpherical, which .* \(free flyer, revolute and prismatic joints only\)",
        ),
        (pin.Model(), "needs a free-flyer root joint"),
    ],
)
def test_unsupported_models_are_refused_by_name(model, message):
    with pytest.raises(ValueError, match=message):
        cpin.SymbolicModel(model)


def test_kinematics_errors_are_named():
    smodel = cpin.SymbolicModel(load_b1().model)
    q, v = ca.SX.sym("q", smodel.nq), ca.SX.sym("v", smodel.nv)
    with pytest.raises(ValueError, match="forward_kinematics: an acceleration needs a velocity"):
        cpin.forward_kinematics(smodel, q, None, v)
    with pytest.raises(ValueError, match=r"frame_velocity needs forward_kinematics\(model, q, v\)"):
        cpin.frame_velocity(cpin.forward_kinematics(smodel, q), "FL_foot")
    with pytest.raises(ValueError, match="unknown reference frame 'BODY'; use LOCAL, WORLD or LOCAL_WORLD"):
        cpin.frame_velocity(cpin.forward_kinematics(smodel, q, v), "FL_foot", "BODY")
    with pytest.raises(ValueError, match="unknown frame 'no_such_frame' in model"):
        smodel.frame("no_such_frame")


def test_momentum_rate_under_another_gravity():
    """Gravity acts at the centre of mass: changing it (numpy or SX, e.g. a tilted or lunar one) changes
    the linear rate by m (g' - g) and the moment about the centre of mass not at all."""
    robot = load_b1()
    smodel = cpin.SymbolicModel(robot.model)
    q, F = ca.SX.sym("q", smodel.nq), ca.SX.sym("F", 3 * len(robot.contact_frames))
    forces = {name: F[3 * i : 3 * i + 3] for i, name in enumerate(robot.contact_frames)}
    g_other = np.array([0.3, -0.2, -1.62])
    rate = ca.Function("rate", [q, F], [cpin.centroidal_momentum_rate(smodel, q, forces)])
    g_sym = ca.SX.sym("g", 3)
    other = ca.Function("other", [q, F, g_sym], [cpin.centroidal_momentum_rate(smodel, q, forces, g_sym)])
    other_np = ca.Function("other_np", [q, F], [cpin.centroidal_momentum_rate(smodel, q, forces, g_other)])
    mass = pin.computeTotalMass(robot.model)
    rng = np.random.default_rng(9)
    for _ in range(5):
        q0, _, _ = random_state(robot.model, rng)
        F0 = rng.normal(scale=100.0, size=F.numel())
        shift = np.concatenate([mass * (g_other - robot.model.gravity.linear), np.zeros(3)])
        expected = np.array(rate(q0, F0)).ravel() + shift
        assert_close(np.array(other(q0, F0, g_other)).ravel(), expected)
        assert_close(np.array(other_np(q0, F0)).ravel(), expected)


def test_clean_constant_snaps_rounding_noise_to_exact_zeros_and_ones():
    """Rounding noise of a placement (cos(pi/2) = 6e-17, 1 - 1e-16) becomes exact 0 and +-1, so that CasADi
    drops the operations; other values, and 0/+-1 more than the tolerance away, are kept."""
    noisy = np.array([[6e-17, 1 - 1e-16, -1 + 1e-13], [-3e-13, 1 + 2e-13, -1 - 5e-13], [0.5, 2.0, -2.0]])
    cleaned = np.array(ca.DM(spatial.clean_constant(noisy)))
    np.testing.assert_array_equal(cleaned, [[0.0, 1.0, -1.0], [0.0, 1.0, -1.0], [0.5, 2.0, -2.0]])
    kept = np.array([1e-11, 1 - 1e-11, -1 + 1e-11, 2 + 1e-13])
    np.testing.assert_array_equal(np.array(ca.DM(spatial.clean_constant(kept))).ravel(), kept)
    # Exact zeros and ones are no operations: R x with a cleaned rotation has fewer instructions.
    c, s = np.cos(np.pi / 2), np.sin(np.pi / 2)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    x = ca.SX.sym("x", 3)
    count = {
        k: ca.Function("Rx", [x], [ca.mtimes(M, x)]).n_instructions()
        for k, M in [("raw", ca.SX(ca.DM(R))), ("clean", spatial.clean_constant(R))]
    }
    assert count["clean"] < count["raw"]


def _every_joint_type_robot(seed):
    """A free flyer and two branches with every supported joint type (the six axis-aligned ones, revolute
    and prismatic unaligned), rotated joint placements and a contact frame at the end of each branch."""
    pin.seed(seed)
    rng = np.random.default_rng(seed)
    model = pin.Model()
    axis = rng.normal(size=(2, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    branches = (
        [
            pin.JointModelRX(),
            pin.JointModelPY(),
            pin.JointModelRZ(),
            pin.JointModelPrismaticUnaligned(axis[0]),
        ],
        [
            pin.JointModelPX(),
            pin.JointModelRY(),
            pin.JointModelPZ(),
            pin.JointModelRevoluteUnaligned(axis[1]),
        ],
    )
    root = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "root")
    model.appendBodyToJoint(root, pin.Inertia.Random(), pin.SE3.Identity())
    frames = []
    for b, joints in enumerate(branches):
        parent = root
        for k, joint in enumerate(joints):
            parent = model.addJoint(parent, joint, pin.SE3.Random(), f"b{b}_{k}")
            model.appendBodyToJoint(parent, pin.Inertia.Random(), pin.SE3.Identity())
        frames.append(f"tip{b}")
        model.addFrame(pin.Frame(frames[-1], parent, 0, pin.SE3.Random(), pin.FrameType.OP_FRAME))
    model.lowerPositionLimit = -np.ones(model.nq)
    model.upperPositionLimit = np.ones(model.nq)
    model.gravity.linear = np.array([0.4, -0.3, -9.5])  # a tilted gravity: every axis of the base sees it
    # Armature: none, exactly 1 (a value a "!= 0" test could be confused with) and random ones.
    model.armature = np.resize([0.0, 1.0, 0.37, 1.0, 0.0, 0.12], model.nv)  # base DoFs, then the joints
    return model, frames


def test_every_joint_type_matches_pinocchio():
    """Kinematics, RNEA, CRBA, both forward dynamics, the centroidal momentum and the mass of a tree with
    every supported joint type (the B1 models and the synthetic tree have no PY joint) and an armature of
    exactly 1 on some DoFs (the other armature tests draw it from (0.05, 0.5))."""
    model, frames = _every_joint_type_robot(11)
    data = model.createData()
    smodel = cpin.SymbolicModel(model)
    assert [info.kind for info in smodel.joints[1:]] == ["freeflyer"] + 2 * ["revolute", "prismatic"] + 2 * [
        "prismatic",
        "revolute",
    ]
    assert [info.axis for info in smodel.joints[2:]] == [0, 1, 2, None, 0, 1, 2, None]
    assert smodel.total_mass == pytest.approx(pin.computeTotalMass(model), rel=1e-14)
    q, v = ca.SX.sym("q", smodel.nq), ca.SX.sym("v", smodel.nv)
    kin = cpin.forward_kinematics(smodel, q, v)
    placements = []
    for name in frames:
        R, p = cpin.frame_placement(kin, name)
        placements += [ca.vec(R), p, cpin.frame_velocity(kin, name, cpin.LOCAL).vector()]
    kinematics = ca.Function("kin", [q, v], [ca.vertcat(*placements, cpin.center_of_mass(kin))])
    rnea = cpin.rnea_function(smodel, frames)
    crba = ca.Function("crba", [q], [cpin.crba(smodel, q)])
    aba = {m: cpin.aba_function(smodel, frames, m) for m in ("articulated", "crba")}
    momentum = ca.Function("h", [q, v], [cpin.centroidal_momentum(smodel, q, v)])
    rng = np.random.default_rng(12)
    for _ in range(5):
        q0, v0, a0 = random_state(model, rng)
        F = rng.normal(scale=50.0, size=3 * len(frames))
        pin.forwardKinematics(model, data, q0, v0)
        pin.updateFramePlacements(model, data)
        expected = []
        for name in frames:
            fid = model.getFrameId(name)
            M = data.oMf[fid]
            expected += [M.rotation.ravel(order="F"), M.translation]
            expected.append(pin.getFrameVelocity(model, data, fid, pin.LOCAL).vector)
        expected.append(pin.centerOfMass(model, data, q0))
        assert_close(np.array(kinematics(q0, v0)).ravel(), np.concatenate(expected))
        tau = pin.rnea(model, data, q0, v0, a0, pin_fext(model, data, q0, frames, F))
        assert_close(np.array(rnea(q0, v0, a0, F)).ravel(), tau)
        M = pin.crba(model, data, q0)
        assert_close(np.array(crba(q0)), np.triu(M) + np.triu(M, 1).T)
        for method, f in aba.items():
            assert_close(np.array(f(q0, v0, tau, F)).ravel(), a0, rtol=1e-9 * np.abs(tau).max()), method
        h = pin.computeCentroidalMomentum(model, data, q0, v0)
        assert_close(np.array(momentum(q0, v0)).ravel(), np.r_[h.linear, h.angular])


def test_a_single_free_body_matches_pinocchio():
    """The smallest supported model, a free flyer alone (one rigid body, e.g. a payload): its
    Newton-Euler equations with a point force, its inverse and its mass matrix."""
    model = _model(pin.JointModelFreeFlyer())
    model.addFrame(pin.Frame("corner", 1, 0, pin.SE3.Random(), pin.FrameType.OP_FRAME))
    data = model.createData()
    smodel = cpin.SymbolicModel(model)
    q = ca.SX.sym("q", smodel.nq)
    rnea = cpin.rnea_function(smodel, ["corner"])
    crba = ca.Function("crba", [q], [cpin.crba(smodel, q)])
    aba = {m: cpin.aba_function(smodel, ["corner"], m) for m in ("articulated", "crba")}
    rng = np.random.default_rng(13)
    for _ in range(3):
        q0, v0, a0 = random_state(model, rng)
        F = rng.normal(scale=10.0, size=3)
        tau = pin.rnea(model, data, q0, v0, a0, pin_fext(model, data, q0, ["corner"], F))
        assert_close(np.array(rnea(q0, v0, a0, F)).ravel(), tau)
        assert_close(np.array(crba(q0)), pin.crba(model, data, q0))
        for method, f in aba.items():
            assert_close(np.array(f(q0, v0, tau, F)).ravel(), a0), method


def test_a_second_free_flyer_is_refused():
    """A second free-floating body (a sibling of the root) is not a legged robot's tree."""
    model = _model(pin.JointModelFreeFlyer())
    j = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "box")
    model.appendBodyToJoint(j, pin.Inertia.Random(), pin.SE3.Identity())
    with pytest.raises(ValueError, match="free-flyer joint 'box' must be the root joint"):
        cpin.SymbolicModel(model)


def test_dof_parents_are_pinocchios_and_ltdl_factorises_the_mass_matrix():
    """``dof_parents`` is Featherstone's lambda (Pinocchio's ``parents_fromRow``), and ``ltdl`` factorises
    a tree-structured M as ``L^T D L`` (unit lower triangular L, no fill-in) that ``ltdl_solve`` inverts."""
    from wbmpc.cpin.aba import dof_parents, ltdl, ltdl_solve

    rng = np.random.default_rng(14)
    for model in (synthetic_robot(3).model, _every_joint_type_robot(15)[0], load_b1().model):
        data = model.createData()
        parents = dof_parents(cpin.SymbolicModel(model))
        assert parents == list(data.parents_fromRow)
        q0, _, _ = random_state(model, rng)
        M = pin.crba(model, data, q0)
        M = np.triu(M) + np.triu(M, 1).T
        L_rows, D = ltdl([list(row) for row in M], parents)
        n = model.nv
        ancestors = [set() for _ in range(n)]
        for k in range(n):
            i = parents[k]
            while i != -1:
                ancestors[k].add(i)
                i = parents[i]
        L = np.eye(n)
        for k in range(n):
            for i in ancestors[k]:
                L[k, i] = L_rows[k][i]
            for i in set(range(k)) - ancestors[k]:
                assert M[k, i] == 0.0 and L_rows[k][i] == 0.0  # not an ancestor: no fill-in
        np.testing.assert_allclose(L.T @ np.diag(D) @ L, M, rtol=0, atol=1e-12 * np.abs(M).max())
        b = rng.normal(size=n)
        np.testing.assert_allclose(ltdl_solve(L_rows, D, parents, list(b)), np.linalg.solve(M, b), rtol=1e-9)


def test_a_second_tree_attached_to_the_world_is_refused():
    """A joint on the world next to the free flyer (e.g. a fixed-base arm in the same model) used to be
    accepted, and RNEA and ABA then failed with an AttributeError (CRBA returned NaN)."""
    model = _model(pin.JointModelFreeFlyer(), pin.JointModelRX())
    j = model.addJoint(0, pin.JointModelRY(), pin.SE3.Random(), "world_arm")
    model.appendBodyToJoint(j, pin.Inertia.Random(), pin.SE3.Identity())
    with pytest.raises(ValueError, match="joint 'world_arm' is attached to the world"):
        cpin.SymbolicModel(model)


def test_aba_defaults_and_methods_of_aba_function():
    """``aba`` without a method is the articulated-body algorithm (what the forward-dynamics formulation
    calls); ``aba_function`` builds the method it is given, and is called "aba" by default."""
    robot = load_b1()
    model, data = robot.model, robot.model.createData()
    smodel = cpin.SymbolicModel(model)
    q, v, tau = ca.SX.sym("q", smodel.nq), ca.SX.sym("v", smodel.nv), ca.SX.sym("tau", smodel.nv)
    default = ca.Function("default", [q, v, tau], [cpin.aba(smodel, q, v, tau)])
    rng = np.random.default_rng(16)
    q0, v0, a0 = random_state(model, rng)
    tau0 = pin.rnea(model, data, q0, v0, a0)
    assert_close(np.array(default(q0, v0, tau0)).ravel(), a0, rtol=1e-9 * np.abs(tau0).max())
    assert default.n_instructions() == cpin.aba_function(smodel, []).n_instructions()
    assert cpin.aba_function(smodel, robot.contact_frames).name() == "aba"
    F = ca.SX.sym("F", 3 * len(robot.contact_frames))
    forces = {frame: F[3 * i : 3 * i + 3] for i, frame in enumerate(robot.contact_frames)}
    counts = {}
    for method in ("articulated", "crba"):
        direct = ca.Function("direct", [q, v, tau, F], [cpin.aba(smodel, q, v, tau, forces, method)])
        counts[method] = cpin.aba_function(smodel, robot.contact_frames, method).n_instructions()
        assert counts[method] == direct.n_instructions(), method
    assert counts["articulated"] != counts["crba"]
