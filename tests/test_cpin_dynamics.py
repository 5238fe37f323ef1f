"""Dynamics of the CasADi mirror (wbmpc.cpin): CRBA, ABA, centroidal map and static torques vs Pinocchio."""

import functools
from types import SimpleNamespace

import casadi as ca
import numpy as np
import pinocchio as pin
import pytest
from test_cpin import pin_fext, random_state

from wbmpc import cpin
from wbmpc.cpin.aba import aba, aba_function
from wbmpc.cpin.centroidal import (
    centroidal_map,
    centroidal_map_time_variation,
    centroidal_momentum,
    centroidal_momentum_rate,
    generalized_gravity,
    static_torque_estimate,
)
from wbmpc.cpin.crba import crba
from wbmpc.model.robot import load_b1, load_b1_z1
from wbmpc.model.statics import static_equilibrium

RTOL = 1e-9  # relative to the largest magnitude of the expected value
N_STATES = 20
PAPER_FORWARD_DYNAMICS_INSTRUCTIONS = 7764


def assert_close(got, expected, rtol=RTOL):
    got, expected = np.asarray(got, dtype=float), np.asarray(expected, dtype=float)
    np.testing.assert_allclose(got, expected, rtol=0, atol=rtol * max(1.0, np.abs(expected).max()))


class Functions:
    """Every symbolic function of the module for one robot, each built on its first use.

    A fresh instance per test (:func:`robot_and_functions`): a function is built inside every test that
    uses it, so that mutation testing, which runs only the tests that call a mutated function, runs all
    of them (with functions built once per robot and cached, only the first test would see a mutant).
    """

    def __init__(self, robot):
        self.robot = robot
        self.smodel = cpin.SymbolicModel(robot.model)
        self.q, self.v = ca.SX.sym("q", self.smodel.nq), ca.SX.sym("v", self.smodel.nv)
        self.F = ca.SX.sym("F", 3 * len(robot.contact_frames))
        self.forces = {name: self.F[3 * i : 3 * i + 3] for i, name in enumerate(robot.contact_frames)}

    @functools.cached_property
    def crba(self):
        return ca.Function("crba", [self.q], [crba(self.smodel, self.q)])

    @functools.cached_property
    def aba(self):
        frames = self.robot.contact_frames
        return {m: aba_function(self.smodel, frames, method=m) for m in ("articulated", "crba")}

    @functools.cached_property
    def rnea(self):
        return cpin.rnea_function(self.smodel, self.robot.contact_frames)

    @functools.cached_property
    def A(self):
        return ca.Function("A", [self.q], [centroidal_map(self.smodel, self.q)])

    @functools.cached_property
    def dA(self):
        q, v = self.q, self.v
        return ca.Function("dA", [q, v], [centroidal_map_time_variation(self.smodel, q, v)])

    @functools.cached_property
    def h(self):
        return ca.Function("h", [self.q, self.v], [centroidal_momentum(self.smodel, self.q, self.v)])

    @functools.cached_property
    def hdot(self):
        q, F = self.q, self.F
        return ca.Function("hdot", [q, F], [centroidal_momentum_rate(self.smodel, q, self.forces)])

    @functools.cached_property
    def g(self):
        return ca.Function("g", [self.q], [generalized_gravity(self.smodel, self.q)])

    @functools.cached_property
    def static(self):
        q, F = self.q, self.F
        return ca.Function("static", [q, F], [static_torque_estimate(self.smodel, q, self.forces)])

    @functools.cached_property
    def v_b(self):
        q, v, h = self.q, self.v, ca.SX.sym("h", 6)
        return ca.Function("v_b", [q, h, v[6:]], [cpin.centroidal_base_velocity(self.smodel, q, h, v[6:])])

    @functools.cached_property
    def a_b(self):
        q, v, F, a_j = self.q, self.v, self.F, ca.SX.sym("a_j", self.smodel.nv - 6)
        a_b = cpin.centroidal_base_acceleration(self.smodel, q, v, a_j, self.forces)
        return ca.Function("a_b", [q, v, a_j, F], [a_b])


def synthetic_robot(seed=0):
    """A random tree that the B1 models do not exercise: prismatic and unaligned joints, rotated joint
    placements, a branch below the base, random inertias, and a contact frame on the base itself."""
    pin.seed(seed)
    rng = np.random.default_rng(seed)
    model = pin.Model()

    def add(parent, joint, name):
        placement = pin.SE3.Identity() if parent == 0 else pin.SE3.Random()
        j = model.addJoint(parent, joint, placement, name)
        model.appendBodyToJoint(j, pin.Inertia.Random(), pin.SE3.Identity())
        return j

    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    root = add(0, pin.JointModelFreeFlyer(), "root")
    a = add(
        add(add(root, pin.JointModelRY(), "a1"), pin.JointModelPZ(), "a2"),
        pin.JointModelRevoluteUnaligned(axis),
        "a3",
    )
    b = add(root, pin.JointModelPX(), "b1")
    b_tip = add(add(b, pin.JointModelPrismaticUnaligned(axis[::-1].copy()), "b2"), pin.JointModelRX(), "b3")
    c = add(b, pin.JointModelRZ(), "c1")  # second child of b1
    frames = ("tip_a", "tip_b", "tip_c", "on_base")
    for joint, name in zip((a, b_tip, c, root), frames, strict=True):
        model.addFrame(pin.Frame(name, joint, 0, pin.SE3.Random(), pin.FrameType.OP_FRAME))
    model.lowerPositionLimit = -np.ones(model.nq)
    model.upperPositionLimit = np.ones(model.nq)
    return SimpleNamespace(model=model, contact_frames=frames, nv=model.nv)


@functools.cache
def load(name):
    return {"b1_z1": load_b1_z1, "b1": load_b1, "synthetic": synthetic_robot}[name]()


def robot_and_functions(name):
    """The robot (loaded once) and its functions (:class:`Functions`, built anew in each test)."""
    robot = load(name)
    return robot, Functions(robot)


@pytest.fixture(params=["b1_z1", "b1", "synthetic"])
def setup(request):
    return robot_and_functions(request.param)


def states(robot, seed):
    """Seeded random (q, v, F): unit quaternion, joints within limits, ~100 N forces."""
    rng = np.random.default_rng(seed)
    for _ in range(N_STATES):
        q, v, _ = random_state(robot.model, rng)
        yield q, v, rng.normal(scale=100.0, size=3 * len(robot.contact_frames)), rng


def test_crba_matches_pinocchio(setup):
    robot, f = setup
    model, data = robot.model, robot.model.createData()
    for q, _, _, _ in states(robot, 10):
        M = np.array(f.crba(q))
        expected = pin.crba(model, data, q)
        expected = np.triu(expected) + np.triu(expected, 1).T  # Pinocchio fills the upper triangle only
        np.testing.assert_array_equal(M, M.T)
        assert_close(M, expected)


@pytest.mark.parametrize("method", ["articulated", "crba"])
def test_aba_matches_pinocchio(setup, method):
    robot, f = setup
    model, data = robot.model, robot.model.createData()
    for q, v, F, rng in states(robot, 11):
        tau = rng.normal(scale=20.0, size=model.nv)  # a base wrench too: both sides treat it alike
        expected = pin.aba(model, data, q, v, tau, pin_fext(model, data, q, robot.contact_frames, F))
        assert_close(np.array(f.aba[method](q, v, tau, F)).ravel(), expected)


@pytest.mark.parametrize("method", ["articulated", "crba"])
def test_aba_inverts_rnea(setup, method):
    robot, f = setup
    for q, v, F, rng in states(robot, 12):
        a = rng.normal(size=robot.nv)
        tau = np.array(f.rnea(q, v, a, F)).ravel()
        # Absolute error on a ~ 1 after a round trip through torques of ~100 N m.
        assert_close(np.array(f.aba[method](q, v, tau, F)).ravel(), a, rtol=1e-9 * np.abs(tau).max())


def test_centroidal_map_and_momentum_match_pinocchio(setup):
    robot, f = setup
    model, data = robot.model, robot.model.createData()
    for q, v, _, _ in states(robot, 13):
        A = np.array(f.A(q))
        assert_close(A, pin.computeCentroidalMap(model, data, q))
        h = np.array(f.h(q, v)).ravel()
        assert_close(h, pin.computeCentroidalMomentum(model, data, q, v).vector)
        assert_close(h, A @ v)


def test_centroidal_base_velocity_inverts_the_momentum(setup):
    """v_b = A_b^-1 (h - A_j v_j) recovers the base twist from Pinocchio's centroidal momentum."""
    robot, f = setup
    model, data = robot.model, robot.model.createData()
    for q, v, _, _ in states(robot, 17):
        h = pin.computeCentroidalMomentum(model, data, q, v).vector
        assert_close(np.array(f.v_b(q, h, v[6:])).ravel(), v[:6])


def test_centroidal_base_acceleration_matches_forward_dynamics(setup):
    """a_b = A_b^-1 (hdot - Adot v - A_j a_j) equals the base part of pinocchio.aba for the same joint
    accelerations and contact forces (the base is unactuated)."""
    robot, f = setup
    model, data = robot.model, robot.model.createData()
    for q, v, F, rng in states(robot, 19):
        tau = np.concatenate([np.zeros(6), rng.normal(scale=20.0, size=model.nv - 6)])
        a = pin.aba(model, data, q, v, tau, pin_fext(model, data, q, robot.contact_frames, F))
        assert_close(np.array(f.a_b(q, v, a[6:], F)).ravel(), a[:6], rtol=1e-8)


def test_centroidal_map_time_variation_matches_pinocchio(setup):
    robot, f = setup
    model, data = robot.model, robot.model.createData()
    for q, v, _, _ in states(robot, 14):
        dA = np.array(f.dA(q, v))
        assert_close(dA, pin.dccrba(model, data, q, v))
        # computeCentroidalMapTimeVariation reads data.vcom[0] without computing it: refresh it first.
        pin.computeCentroidalMomentum(model, data, q, v)
        assert_close(dA, pin.computeCentroidalMapTimeVariation(model, data, q, v))


def test_centroidal_map_time_variation_is_the_time_derivative(setup):
    """dA/dt against a central difference of A along q(t) = q (+) v t (Pinocchio-independent)."""
    robot, f = setup
    model, step = robot.model, 1e-6
    for q, v, _, _ in states(robot, 15):
        A_plus = np.array(f.A(pin.integrate(model, q, v * step)))
        A_minus = np.array(f.A(pin.integrate(model, q, -v * step)))
        # Central difference: truncation ~ step^2, rounding ~ 1e-16 |A| / step ~ 1e-8 of the scale.
        assert_close(np.array(f.dA(q, v)), (A_plus - A_minus) / (2 * step), rtol=1e-7)


def test_momentum_rate_only_depends_on_external_forces(setup):
    """A a + dA v = [m g + sum F; sum (p - c) x F] under any joint torques (they are internal)."""
    robot, f = setup
    model, data = robot.model, robot.model.createData()
    for q, v, F, rng in states(robot, 16):
        tau = np.concatenate([np.zeros(6), rng.normal(scale=20.0, size=model.nv - 6)])
        a = pin.aba(model, data, q, v, tau, pin_fext(model, data, q, robot.contact_frames, F))
        hdot = np.array(f.A(q)) @ a + np.array(f.dA(q, v)) @ v
        assert_close(np.array(f.hdot(q, F)).ravel(), hdot, rtol=1e-8)


def test_generalized_gravity_and_static_torques_match_rnea(setup):
    robot, f = setup
    model, data = robot.model, robot.model.createData()
    zero = np.zeros(model.nv)
    for q, _, F, _ in states(robot, 17):
        g = np.array(f.g(q)).ravel()
        assert_close(g, pin.computeGeneralizedGravity(model, data, q))
        assert_close(g, np.array(f.rnea(q, zero, zero, np.zeros_like(F))).ravel())
        expected = pin.rnea(model, data, q, zero, zero, pin_fext(model, data, q, robot.contact_frames, F))
        assert_close(np.array(f.static(q, F)).ravel(), expected[6:])


@pytest.mark.parametrize("name", ["b1_z1", "b1"])
def test_static_torque_estimate_holds_the_nominal_pose(name):
    """At a static equilibrium rnea(q, 0, 0, F) = [0; tau]: tau = g_j - J_j^T F, not J_j^T F - g_j."""
    robot, f = robot_and_functions(name)
    q = robot.q_nominal
    ee_force = (0.0, 0.0, -50.0) if robot.has_arm else None  # the arm carries a 5 kg load
    eq = static_equilibrium(robot, q, [True] * 4, ee_force=ee_force)
    F = np.concatenate([eq.forces.ravel(), eq.ee_force if robot.has_arm else []])
    tau = np.array(f.static(q, F)).ravel()
    assert_close(tau, eq.tau)
    zero = np.zeros(robot.nv)
    assert_close(np.array(f.rnea(q, zero, zero, F)).ravel(), np.concatenate([np.zeros(6), eq.tau]))
    # The legs hold the body with tens of N m, so the opposite sign (J_j^T F - g_j = -tau) cannot pass.
    assert np.abs(eq.tau).max() > 10.0


def test_instruction_counts():
    """The forward dynamics stays below the paper's constraint (7,764 instructions, 5 contact frames), and
    the default algorithm is the smaller one."""
    robot = load_b1_z1()
    smodel = cpin.SymbolicModel(robot.model)
    counts = {
        m: aba_function(smodel, robot.contact_frames, m).n_instructions() for m in ("articulated", "crba")
    }
    assert counts["articulated"] <= counts["crba"] <= PAPER_FORWARD_DYNAMICS_INSTRUCTIONS
    assert aba_function(smodel, robot.contact_frames).n_instructions() == counts["articulated"]
    q = ca.SX.sym("q", smodel.nq)
    zero = ca.SX.zeros(smodel.nv)
    via_rnea = ca.Function("g", [q], [cpin.rnea(smodel, q, zero, zero)]).n_instructions()
    assert ca.Function("g", [q], [generalized_gravity(smodel, q)]).n_instructions() < via_rnea


def test_errors_are_named():
    smodel = cpin.SymbolicModel(load_b1().model)
    q, v = ca.SX.sym("q", smodel.nq), ca.SX.sym("v", smodel.nv)
    with pytest.raises(ValueError, match="unknown forward-dynamics method"):
        aba(smodel, q, v, v, method="lu")
    with pytest.raises(ValueError, match="no_such_foot"):
        static_torque_estimate(smodel, q, {"no_such_foot": ca.SX.zeros(3)})
    with pytest.raises(ValueError, match="no_such_foot"):
        centroidal_momentum_rate(smodel, q, {"no_such_foot": ca.SX.zeros(3)})
