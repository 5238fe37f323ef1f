"""Static equilibrium (wbmpc.model.statics) against the symbolic RNEA, virtual work and force balance."""

import numpy as np
import pinocchio as pin
import pytest

from wbmpc import cpin
from wbmpc.model.robot import load_b1, load_b1_z1
from wbmpc.model.statics import StaticEquilibrium, check_friction, static_equilibrium

ALL_FEET = [True, True, True, True]
TROT = [True, False, False, True]  # FL + RR
CALF = ["FL_calf_joint", "FR_calf_joint", "RL_calf_joint", "RR_calf_joint"]


@pytest.fixture(scope="module")
def robot():
    return load_b1_z1()


@pytest.fixture(scope="module")
def rnea(robot):
    return cpin.rnea_function(cpin.SymbolicModel(robot.model), robot.contact_frames)


def weight(robot):
    return robot.mass * robot.gravity


def assert_rnea_balanced(robot, rnea, q, eq: StaticEquilibrium):
    """The real test of the torque sign: RNEA at v = a = 0 with the forces gives [0; tau]."""
    F = np.concatenate([eq.forces.ravel(), eq.ee_force])
    zero = np.zeros(robot.nv)
    got = np.array(rnea(q, zero, zero, F)).ravel()
    np.testing.assert_allclose(got, np.concatenate([np.zeros(6), eq.tau]), atol=1e-9, rtol=0)


def feet_xy(robot, q):
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, q)
    return np.array([data.oMf[robot.frame_id(f)].translation for f in robot.foot_frames])


def com_offset_from_diagonal(robot, q):
    """Signed horizontal distance [m] of the centre of mass from the FL-RR line (left positive)."""
    p = feet_xy(robot, q)
    c = pin.centerOfMass(robot.model, robot.model.createData(), q)
    u = (p[0, :2] - p[3, :2]) / np.linalg.norm(p[0, :2] - p[3, :2])
    w = c[:2] - p[3, :2]
    return u[0] * w[1] - u[1] * w[0]


@pytest.fixture(scope="module")
def q_trot(robot):
    """Arm forward, yawed left until the CoM lies over the FL-RR diagonal: a 2-foot stance that can stand."""
    q = robot.pose("standing_with_arm_forward")
    i = robot.model.joints[robot.model.getJointId("joint1")].idx_q
    lo, hi = 0.65, 1.3  # offset < 0 at lo, > 0 at hi (bracket found by a scan)
    for _ in range(60):
        q[i] = 0.5 * (lo + hi)
        lo, hi = (q[i], hi) if com_offset_from_diagonal(robot, q) < 0 else (lo, q[i])
    assert abs(com_offset_from_diagonal(robot, q)) < 1e-12
    return q


# --- equilibrium ---------------------------------------------------------------------------------------
def test_all_feet_carry_the_weight(robot, rnea):
    q = robot.q_nominal
    eq = static_equilibrium(robot, q, ALL_FEET)
    assert eq.forces.shape == (4, 3) and eq.tau.shape == (robot.nj,) and eq.base_residual.shape == (6,)
    assert eq.forces[:, 2].sum() == pytest.approx(weight(robot), rel=1e-3)
    np.testing.assert_allclose(eq.forces[:, :2].sum(axis=0), 0.0, atol=1e-9)
    assert np.abs(eq.base_residual).max() < 1e-9
    assert np.all(eq.forces[:, 2] > 0) and check_friction(eq.forces, 0.5).all()
    assert np.all(np.abs(eq.tau) < robot.joint_torque_limits)
    assert_rnea_balanced(robot, rnea, q, eq)


def test_trot_stance_over_the_diagonal(robot, rnea, q_trot):
    eq = static_equilibrium(robot, q_trot, TROT)
    np.testing.assert_array_equal(eq.forces[[1, 2]], 0.0)
    assert eq.forces[:, 2].sum() == pytest.approx(weight(robot), rel=1e-3)
    assert np.abs(eq.base_residual).max() < 1e-9
    assert_rnea_balanced(robot, rnea, q_trot, eq)


def test_trot_stance_off_the_diagonal_reports_the_unbalanced_moment(robot):
    """At the nominal pose the CoM is ~6 mm off the FL-RR line: no two-foot forces can balance it."""
    q = robot.q_nominal
    eq = static_equilibrium(robot, q, TROT)
    assert eq.residual_norm > 1e-3
    assert abs(com_offset_from_diagonal(robot, q)) > 1e-3


def test_ee_load_adds_to_the_foot_forces(robot, rnea):
    q = robot.q_nominal
    free = static_equilibrium(robot, q, ALL_FEET)
    eq = static_equilibrium(robot, q, ALL_FEET, ee_force=[0.0, 0.0, -50.0])
    np.testing.assert_array_equal(eq.ee_force, [0.0, 0.0, -50.0])
    assert eq.forces[:, 2].sum() == pytest.approx(weight(robot) + 50.0, rel=1e-3)
    np.testing.assert_allclose(eq.total_force, [0.0, 0.0, weight(robot)], atol=1e-9)
    assert np.abs(eq.base_residual).max() < 1e-9
    # The gripper is ahead of the feet's centre: the load goes mostly to the front feet.
    assert eq.forces[:2, 2].sum() - free.forces[:2, 2].sum() > 50.0
    assert_rnea_balanced(robot, rnea, q, eq)


def test_front_rear_split_follows_the_lever_rule(robot):
    """Four level feet: the pitch balance fixes the front share at (x_com - x_rear) / (x_front - x_rear)."""
    q = robot.q_nominal
    eq = static_equilibrium(robot, q, ALL_FEET)
    x_feet = feet_xy(robot, q)[:, 0]
    x_com = pin.centerOfMass(robot.model, robot.model.createData(), q)[0]
    front_share = eq.forces[:2, 2].sum() / eq.forces[:, 2].sum()
    assert front_share == pytest.approx((x_com - x_feet[2:].mean()) / (x_feet[:2].mean() - x_feet[2:].mean()))
    assert abs(front_share - robot.front_force_ratio) < 0.05  # the CoM is near the middle: near the reference


def test_a_balanced_reference_is_kept(robot):
    """A reference that already balances the robot is returned unchanged (closest = itself)."""
    q = robot.q_nominal
    base = static_equilibrium(robot, q, ALL_FEET).forces
    squeeze = np.zeros((4, 3))
    squeeze[0, 0], squeeze[2, 0] = 20.0, -20.0  # FL and RL pull towards each other: an internal force
    eq = static_equilibrium(robot, q, ALL_FEET, reference_forces=base + squeeze)
    np.testing.assert_allclose(eq.forces, base + squeeze, atol=1e-9)


# --- torque sign -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("ee_force", [None, (10.0, -5.0, -50.0)])
def test_torques_obey_virtual_work(robot, ee_force):
    """tau_j = dV/dq_j - sum_c F_c . dp_c/dq_j by central differences of the CoM height and frame positions.

    Independent of Jacobians and RNEA: a virtual joint rotation does work against gravity and the contact
    forces that the motor must supply.
    """
    q = robot.q_nominal
    eq = static_equilibrium(robot, q, ALL_FEET, ee_force=ee_force)
    model, data = robot.model, robot.model.createData()
    forces = np.vstack([eq.forces, eq.ee_force])

    def energy_and_points(qq):
        com = pin.centerOfMass(model, data, qq)
        pin.framesForwardKinematics(model, data, qq)
        points = np.array([data.oMf[robot.frame_id(f)].translation for f in robot.contact_frames])
        return robot.mass * robot.gravity * com[2], points

    h = 1e-6
    for j in range(robot.nj):
        dq = np.zeros(robot.nv)
        dq[6 + j] = h
        V_p, p_p = energy_and_points(pin.integrate(model, q, dq))
        V_m, p_m = energy_and_points(pin.integrate(model, q, -dq))
        tau_vw = (V_p - V_m) / (2 * h) - np.sum(forces * (p_p - p_m)) / (2 * h)
        assert eq.tau[j] == pytest.approx(tau_vw, abs=1e-4), robot.joint_names[j]


def test_calf_motors_hold_the_knees(robot):
    """Increasing the calf angle straightens the leg and lowers the foot, which the ground pushes back up:
    the calf motors must push with positive torque (about 35-40 N m each for the 61 kg robot)."""
    q = robot.q_nominal
    eq = static_equilibrium(robot, q, ALL_FEET)
    z0 = feet_xy(robot, q)[:, 2]
    for k, name in enumerate(CALF):
        dq = np.zeros(robot.nv)
        dq[robot.joint_index_v(name)] = 1e-3  # base held still
        assert feet_xy(robot, pin.integrate(robot.model, q, dq))[k, 2] < z0[k], f"{name}: foot should go down"
        assert 20.0 < eq.tau[robot.joint_names.index(name)] < 60.0, name


# --- robot without an arm ----------------------------------------------------------------------------------
def test_b1_without_arm():
    b1 = load_b1()
    eq = static_equilibrium(b1, b1.q_nominal, ALL_FEET)
    assert eq.forces[:, 2].sum() == pytest.approx(b1.mass * b1.gravity, rel=1e-3)
    assert np.abs(eq.base_residual).max() < 1e-9
    np.testing.assert_array_equal(eq.ee_force, 0.0)
    with pytest.raises(ValueError, match="ee_force"):
        static_equilibrium(b1, b1.q_nominal, ALL_FEET, ee_force=[0.0, 0.0, -10.0])


# --- friction --------------------------------------------------------------------------------------------
def test_check_friction():
    forces = np.array([[0, 0, 100], [40, 30, 100], [60, 0, 100], [0, 0, -1], [0, 0, 0]], dtype=float)
    np.testing.assert_array_equal(check_friction(forces, 0.5), [True, True, False, False, True])
    assert check_friction([0.0, 0.0, 10.0], 0.5) is True
    with pytest.raises(ValueError, match="forces"):
        check_friction(np.zeros((4, 2)), 0.5)
    with pytest.raises(ValueError, match="mu"):
        check_friction(forces, -0.1)


# --- bad inputs ------------------------------------------------------------------------------------------
def _bad_q(robot):
    q = robot.q_nominal
    q[3:7] *= 2.0
    return q


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (lambda r: {"q": r.q_nominal[:-1]}, "q must have shape"),
        (lambda r: {"q": np.full(r.nq, np.nan)}, "q must be finite"),
        (lambda r: {"q": _bad_q(r)}, "q: base quaternion"),
        (lambda r: {"contact": [True, True, True]}, "contact"),
        (lambda r: {"contact": [False] * 4}, "at least one foot must be in contact"),
        (lambda r: {"ee_force": [0.0, -50.0]}, "ee_force must have shape"),
        (lambda r: {"ee_force": [0.0, 0.0, np.inf]}, "ee_force must be finite"),
        (lambda r: {"reference_forces": np.zeros(4)}, "reference_forces must have shape"),
        (lambda r: {"reference_forces": np.full((4, 3), np.nan)}, "reference_forces must be finite"),
        (lambda r: {"weight": 0.0}, "weight"),
    ],
)
def test_bad_inputs_are_named(robot, kwargs, match):
    args = {"q": robot.q_nominal, "contact": ALL_FEET, **kwargs(robot)}
    with pytest.raises(ValueError, match=match):
        static_equilibrium(robot, **args)
