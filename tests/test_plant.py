"""Tests of the closed-loop rigid-contact plant on the Unitree B1 + Z1 arm model."""

from __future__ import annotations

import importlib.metadata
import xml.etree.ElementTree as ET
from types import SimpleNamespace

import numpy as np
import pinocchio as pin
import pytest

from wbmpc.sim.plant import ContactPlant, PlantState, fallen

FEET = ("FL_foot", "FR_foot", "RL_foot", "RR_foot")
LOCKED_JOINTS = ("joint5", "joint6", "jointGripper")
#: Radius of the B1 foot collision spheres, centred on the foot frames (checked against the URDF below) [m].
FOOT_RADIUS = 0.04
ALL = np.ones(4, dtype=bool)
NONE = np.zeros(4, dtype=bool)


def _robots_dir():
    dist = importlib.metadata.distribution("example-robot-data")
    return dist.locate_file("cmeel.prefix/share/example-robot-data/robots")


@pytest.fixture(scope="module")
def robot():
    """B1 + Z1 with the wrist and gripper locked at "standing_with_arm_up", feet resting on z = 0."""
    root = _robots_dir() / "b1_description"
    full = pin.buildModelFromUrdf(str(root / "urdf/b1-z1.urdf"), pin.JointModelFreeFlyer())
    pin.loadReferenceConfigurations(full, str(root / "srdf/b1-z1.srdf"))
    refs = {item.key(): item.data() for item in full.referenceConfigurations}
    model = pin.buildReducedModel(
        full, [full.getJointId(j) for j in LOCKED_JOINTS], refs["standing_with_arm_up"]
    )
    q = {item.key(): item.data() for item in model.referenceConfigurations}["standing_with_arm_up"].copy()
    data = model.createData()
    foot_ids = [model.getFrameId(f) for f in FEET]
    pin.framesForwardKinematics(model, data, q)
    # The foot frames are sphere centres: the sphere touches z = 0 when the frame is at z = FOOT_RADIUS.
    q[2] -= min(data.oMf[f].translation[2] for f in foot_ids) - FOOT_RADIUS
    return SimpleNamespace(
        model=model,
        q=q,
        foot_ids=foot_ids,
        mass=pin.computeTotalMass(model),
        urdf=root / "urdf/b1-z1.urdf",
    )


def make_plant(robot, **kwargs):
    kwargs.setdefault("foot_radius", FOOT_RADIUS)
    return ContactPlant(robot.model, FEET, **kwargs)


def foot_jacobians(model, q, foot_ids):
    """Stacked LOCAL_WORLD_ALIGNED linear foot Jacobians (3 n_feet, nv)."""
    data = model.createData()
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    return np.vstack([pin.getFrameJacobian(model, data, f, pin.LOCAL_WORLD_ALIGNED)[:3] for f in foot_ids])


def foot_state(model, q, v, foot_ids):
    """World positions (n, 3) and LOCAL_WORLD_ALIGNED linear velocities (n, 3) of the feet."""
    data = model.createData()
    pin.forwardKinematics(model, data, q, v)
    pin.updateFramePlacements(model, data)
    pos = np.array([data.oMf[f].translation for f in foot_ids])
    vel = np.array([pin.getFrameVelocity(model, data, f, pin.LOCAL_WORLD_ALIGNED).linear for f in foot_ids])
    return pos, vel


def static_torques(robot, q, wrench=None):
    """Joint torques and foot forces holding ``q`` at rest with all feet in contact.

    With a = 0, v = 0 the dynamics reduce to ``g(q) - tau_ext = S^T tau + J^T lambda``: the 6 base rows fix
    the contact forces (minimum-norm least squares), the joint rows then give ``tau``. An external wrench
    (world axes, about the base origin) enters through Pinocchio's ``fext`` on the root joint, expressed in
    the joint frame: an independent path from the plant's own conversion.
    """
    model = robot.model
    data = model.createData()
    zero = np.zeros(model.nv)
    if wrench is None:
        gen = pin.rnea(model, data, q, zero, zero)
    else:
        pin.forwardKinematics(model, data, q)
        base = data.oMi[1]
        # World-frame spatial force about the world origin, then into the joint frame.
        world = pin.Force(wrench[:3], wrench[3:] + np.cross(base.translation, wrench[:3]))
        fext = pin.StdVec_Force()
        for _ in range(model.njoints):
            fext.append(pin.Force.Zero())
        fext[1] = base.actInv(world)
        gen = pin.rnea(model, data, q, zero, zero, fext)
    jac = foot_jacobians(model, q, robot.foot_ids)
    lam = np.linalg.lstsq(jac[:, :6].T, gen[:6], rcond=None)[0]
    return gen[6:] - jac[:, 6:].T @ lam, lam.reshape(4, 3)


# --------------------------------------------------------------------------- the robot data


def test_foot_frames_are_collision_sphere_centres(robot):
    """Documents the URDF geometry behind FOOT_RADIUS: each foot link has a collision sphere at its origin."""
    links = {link.get("name"): link for link in ET.parse(robot.urdf).getroot().iter("link")}
    for name in FEET:
        collision = links[name].find("collision")
        origin = collision.find("origin")
        assert np.allclose([float(x) for x in origin.get("xyz").split()], 0.0)
        assert float(collision.find("geometry/sphere").get("radius")) == pytest.approx(FOOT_RADIUS)


def test_model_sizes(robot):
    assert (robot.model.nq, robot.model.nv) == (23, 22)
    assert robot.mass == pytest.approx(61.0, abs=0.5)
    plant = make_plant(robot)
    assert (plant.nq, plant.nv) == (23, 22)


# --------------------------------------------------------------------------- 1. static hold


def test_static_hold(robot):
    tau, lam = static_torques(robot, robot.q)
    assert np.all(lam[:, 2] > 0.0)  # the reference forces are physical
    plant = make_plant(robot)
    plant.reset(robot.q, np.zeros(robot.model.nv))
    weight = robot.mass * np.linalg.norm(robot.model.gravity.linear)
    for _ in range(1000):  # 1 s at 1 kHz
        state = plant.step(tau, ALL)
        forces = plant.last_contact_forces
        assert forces.sum(axis=0)[2] == pytest.approx(weight, rel=5e-3)
    assert state.t == pytest.approx(1.0)
    assert np.linalg.norm(state.q[:3] - robot.q[:3]) < 1e-3
    assert np.linalg.norm(pin.difference(robot.model, robot.q, state.q)) < 1e-3
    np.testing.assert_allclose(forces, lam, atol=1e-6)
    assert all(not counts.any() for counts in plant.violation_counts.values())


# --------------------------------------------------------------------------- 2. collapse in contact


def test_zero_torques_collapse_but_feet_stay_anchored(robot):
    plant = make_plant(robot)
    plant.reset(robot.q, np.zeros(robot.model.nv))
    start, _ = foot_state(robot.model, robot.q, np.zeros(robot.model.nv), robot.foot_ids)
    for _ in range(200):
        state = plant.step(np.zeros(16), ALL)
        pos, _ = foot_state(robot.model, state.q, state.v, robot.foot_ids)
        assert np.abs(pos - start).max() < 1e-3
    np.testing.assert_allclose(plant.anchors, start, atol=1e-12)  # feet started exactly on the ground
    assert state.q[2] < robot.q[2] - 0.02  # the base sinks...
    assert np.abs(state.v[6:]).max() > 0.1  # ...by folding the legs


# --------------------------------------------------------------------------- 3. free fall


def test_free_fall(robot):
    model = robot.model
    dt, steps = 1e-3, 100
    plant = make_plant(robot, dt=dt)
    plant.reset(robot.q, np.zeros(model.nv))
    for _ in range(steps):
        state = plant.step(np.zeros(16), NONE)
    g, t = 9.81, steps * dt
    drop = robot.q[2] - state.q[2]
    assert drop == pytest.approx(g * t**2 / 2, abs=1e-3)
    # Semi-implicit Euler exactly: z_N = z_0 - g dt^2 N (N + 1) / 2.
    assert drop == pytest.approx(g * dt**2 * steps * (steps + 1) / 2, abs=1e-9)
    np.testing.assert_allclose(state.q[3:], robot.q[3:], atol=1e-9)  # nothing moves relative to the base
    data = model.createData()
    h_end = pin.computeCentroidalMomentum(model, data, state.q, state.v).angular
    np.testing.assert_allclose(h_end, 0.0, atol=1e-6)
    assert not plant.last_contact_forces.any()


@pytest.mark.parametrize("dt", [1e-3, 5e-4])
def test_free_fall_spinning_conserves_centroidal_angular_momentum(robot, dt):
    """With spin and joint motion the drift is the first-order integrator error, not missing physics."""
    model = robot.model
    rng = np.random.default_rng(1)
    v = np.zeros(model.nv)
    v[:6] = [0.2, 0.0, 1.0, 0.5, -0.3, 0.8]
    v[6:] = 0.5 * rng.normal(size=16)
    data = model.createData()
    h0 = pin.computeCentroidalMomentum(model, data, robot.q, v).angular.copy()
    plant = make_plant(robot, dt=dt)
    plant.reset(robot.q, v)
    for _ in range(round(0.1 / dt)):
        state = plant.step(np.zeros(16), NONE)
    h1 = pin.computeCentroidalMomentum(model, data, state.q, state.v).angular
    # Measured: 1.5e-4 at 1 ms and 7.6e-5 at 0.5 ms (|h0| = 4.7 kg m^2/s): O(dt).
    assert np.linalg.norm(h1 - h0) < 0.05 * dt * np.linalg.norm(h0)


# --------------------------------------------------------------------------- 4. touchdown impact


def _touchdown(robot, dt, vz=-0.5):
    model = robot.model
    v = np.zeros(model.nv)
    v[2] = vz  # base frame = world axes at this pose
    plant = make_plant(robot, dt=dt)
    plant.reset(robot.q, v)  # after reset every foot is in swing
    tau, _ = static_torques(robot, robot.q)
    state = plant.step(tau, ALL)  # touchdown of the four feet, exactly on the ground
    return plant, v, state


def test_touchdown_impulse_zeroes_stance_foot_velocities(robot):
    model = robot.model
    plant, v_before, state = _touchdown(robot, dt=1e-3)
    impulses = plant.last_impulses
    assert impulses[:, 2].sum() > 0.5  # the ground pushes up [N s]
    # Velocity right after the impact, rebuilt from the reported impulses: M (v+ - v-) = J^T Lambda.
    data = model.createData()
    mass_matrix = pin.crba(model, data, robot.q)
    mass_matrix = np.triu(mass_matrix) + np.triu(mass_matrix, 1).T
    jac = foot_jacobians(model, robot.q, robot.foot_ids)
    v_after = v_before + np.linalg.solve(mass_matrix, jac.T @ impulses.ravel())
    assert np.abs(jac @ v_before).max() == pytest.approx(0.5)
    assert np.abs(jac @ v_after).max() < 1e-9
    # After the whole step only the O(dt^2) integration residual is left (it was 0.5 m/s).
    _, vel = foot_state(model, state.q, state.v, robot.foot_ids)
    assert np.linalg.norm(vel, axis=1).max() < 2e-6


def test_touchdown_residual_velocity_is_second_order_in_dt(robot):
    residual = []
    for dt in (1e-3, 5e-4):
        _, _, state = _touchdown(robot, dt)
        _, vel = foot_state(robot.model, state.q, state.v, robot.foot_ids)
        residual.append(np.linalg.norm(vel, axis=1).max())
    assert residual[0] / residual[1] == pytest.approx(4.0, rel=0.15)


def test_anchor_is_clipped_to_the_ground_and_foot_pulled_down(robot):
    model = robot.model
    q = robot.q.copy()
    q[2] += 0.01  # feet 1 cm above the ground at touchdown
    plant = make_plant(robot)
    plant.reset(q, np.zeros(model.nv))
    start, _ = foot_state(model, q, np.zeros(model.nv), robot.foot_ids)
    tau, _ = static_torques(robot, robot.q)
    plant.step(tau, ALL)
    np.testing.assert_allclose(plant.anchors[:, :2], start[:, :2], atol=1e-12)
    np.testing.assert_allclose(plant.anchors[:, 2], FOOT_RADIUS)
    for _ in range(300):  # 15 time constants of the default critically damped correction
        state = plant.step(tau, ALL)
    pos, _ = foot_state(model, state.q, state.v, robot.foot_ids)
    np.testing.assert_allclose(pos[:, 2], FOOT_RADIUS, atol=1e-4)
    plant.step(tau, np.array([False, True, True, True]))  # lift-off drops the anchor
    assert np.isnan(plant.anchors[0]).all() and not np.isnan(plant.anchors[1:]).any()


# --------------------------------------------------------------------------- 5. external wrench


def test_external_wrench_matches_root_joint_fext(robot):
    """Tilted, displaced base, no contact: the plant's wrench equals Pinocchio's fext on the root joint."""
    model = robot.model
    q = robot.q.copy()
    q[:3] += [0.3, -0.2, 0.1]
    q[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(0.3, -0.2, 0.7)).coeffs()
    rng = np.random.default_rng(2)
    v = 0.3 * rng.normal(size=model.nv)
    tau = rng.normal(size=16)
    wrench = np.array([20.0, -35.0, 10.0, 3.0, -4.0, 5.0])
    dt = 1e-3
    plant = make_plant(robot, dt=dt)
    plant.reset(q, v)
    state = plant.step(tau, NONE, external_wrench=wrench)

    data = model.createData()
    pin.forwardKinematics(model, data, q)
    base = data.oMi[1]
    fext = pin.StdVec_Force()
    for _ in range(model.njoints):
        fext.append(pin.Force.Zero())
    fext[1] = base.actInv(pin.Force(wrench[:3], wrench[3:] + np.cross(base.translation, wrench[:3])))
    acc = pin.aba(model, data, q, v, np.concatenate([np.zeros(6), tau]), fext)
    np.testing.assert_allclose((state.v - v) / dt, acc, atol=1e-8)
    without = make_plant(robot, dt=dt)
    without.reset(q, v)
    assert np.abs(without.step(tau, NONE).v - state.v).max() > 1e-3


def test_external_wrench_momentum_balance_in_contact(robot):
    """Newton-Euler on the whole robot: d h_G / dt = sum of ground forces + push + weight (and moments)."""
    model = robot.model
    wrench = np.array([30.0, -10.0, 0.0, 0.0, 0.0, 4.0])
    tau, _ = static_torques(robot, robot.q)
    dt = 1e-3
    plant = make_plant(robot, dt=dt)
    plant.reset(robot.q, np.zeros(model.nv))
    state = plant.step(tau, ALL, external_wrench=wrench)
    acc = state.v / dt  # v0 = 0
    data = model.createData()
    dh = pin.computeCentroidalMomentumTimeVariation(model, data, robot.q, np.zeros(model.nv), acc)
    com = data.com[0]
    feet, _ = foot_state(model, robot.q, np.zeros(model.nv), robot.foot_ids)
    forces = plant.last_contact_forces
    weight = robot.mass * robot.model.gravity.linear
    np.testing.assert_allclose(dh.linear, forces.sum(axis=0) + wrench[:3] + weight, atol=1e-8)
    moment = np.cross(feet - com, forces).sum(axis=0) + np.cross(robot.q[:3] - com, wrench[:3]) + wrench[3:]
    np.testing.assert_allclose(dh.angular, moment, atol=1e-8)


def test_external_push_balanced_quasi_statically(robot):
    """Torques holding gravity *and* the push: the ground absorbs exactly the push, the robot stays still."""
    model = robot.model
    push = np.array([30.0, -15.0, 0.0, 0.0, 0.0, 0.0])
    tau_g, lam_g = static_torques(robot, robot.q)
    tau, _ = static_torques(robot, robot.q, push)
    plant = make_plant(robot)
    plant.reset(robot.q, np.zeros(model.nv))
    for _ in range(500):
        state = plant.step(tau, ALL, external_wrench=push)
    change = plant.last_contact_forces.sum(axis=0) - lam_g.sum(axis=0)
    np.testing.assert_allclose(change[:2], -push[:2], rtol=0.02)
    assert abs(change[2]) < 0.02 * np.linalg.norm(push)
    assert np.linalg.norm(state.q[:3] - robot.q[:3]) < 1e-3


# --------------------------------------------------------------------------- 6. violations


def _leg_torques_for_foot_force(robot, foot, force):
    """Joint torques making the robot push on foot ``foot`` as if a force ``force`` [N] acted on it."""
    jac = foot_jacobians(robot.model, robot.q, [robot.foot_ids[foot]])
    return jac[:, 6:].T @ force


def test_pulling_a_stance_foot_up_is_counted(robot):
    tau, _ = static_torques(robot, robot.q)
    tau = tau + _leg_torques_for_foot_force(robot, 0, np.array([0.0, 0.0, 600.0]))
    plant = make_plant(robot)
    plant.reset(robot.q, np.zeros(robot.model.nv))
    for _ in range(3):
        plant.step(tau, ALL)
    assert plant.last_contact_forces[0, 2] < 0.0
    assert plant.last_violations["pulling"].tolist() == [True, False, False, False]
    assert plant.violation_counts["pulling"].tolist() == [3, 0, 0, 0]
    plant.reset(robot.q, np.zeros(robot.model.nv))
    assert not plant.violation_counts["pulling"].any()


def test_slipping_and_penetration_are_counted(robot):
    tau, _ = static_torques(robot, robot.q)
    tau = tau + _leg_torques_for_foot_force(robot, 1, np.array([0.0, 400.0, 0.0]))
    plant = make_plant(robot, mu=0.5)
    plant.reset(robot.q, np.zeros(robot.model.nv))
    plant.step(tau, ALL)
    f = plant.last_contact_forces[1]
    assert f[2] > 0.0 and np.hypot(f[0], f[1]) > 0.5 * f[2]
    assert plant.last_violations["slipping"][1] and not plant.last_violations["pulling"].any()

    q = robot.q.copy()
    q[2] -= 0.01  # every foot 1 cm into the ground, only the front ones scheduled in stance
    plant.reset(q, np.zeros(robot.model.nv))
    plant.step(tau, np.array([True, True, False, False]))
    assert plant.last_violations["penetrating"].tolist() == [False, False, True, True]


# --------------------------------------------------------------------------- 7. bad input


@pytest.mark.parametrize(
    ("args", "match"),
    [
        ((np.zeros(15), ALL), r"tau_joints.*\(16,\)"),
        ((np.zeros((16, 1)), ALL), r"tau_joints.*\(16,\)"),
        ((np.full(16, np.nan), ALL), "tau_joints.*NaN"),
        ((np.zeros(16), np.ones(3, dtype=bool)), r"contact.*\(4,\)"),
        ((np.zeros(16), np.array([0, 1, 2, 1])), "contact"),
        ((np.zeros(16), ALL, np.zeros(3)), r"external_wrench.*\(6,\)"),
        ((np.zeros(16), ALL, np.array([0, 0, np.inf, 0, 0, 0])), "external_wrench"),
    ],
)
def test_step_rejects_bad_input(robot, args, match):
    plant = make_plant(robot)
    plant.reset(robot.q, np.zeros(robot.model.nv))
    with pytest.raises(ValueError, match=match):
        plant.step(*args)


def test_reset_rejects_bad_state(robot):
    plant = make_plant(robot)
    q_nan = robot.q.copy()
    q_nan[8] = np.nan
    with pytest.raises(ValueError, match="q.*NaN"):
        plant.reset(q_nan, np.zeros(22))
    with pytest.raises(ValueError, match="v.*NaN"):
        plant.reset(robot.q, np.full(22, np.nan))
    with pytest.raises(ValueError, match=r"q.*\(23,\)"):
        plant.reset(robot.q[:-1], np.zeros(22))
    with pytest.raises(ValueError, match=r"v.*\(22,\)"):
        plant.reset(robot.q, np.zeros(23))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"foot_frames": ("FL_foot", "FR_foot", "RL_foot", "XX_foot")}, "XX_foot"),
        ({"dt": 0.0}, "dt"),
        ({"dt": -1e-3}, "dt"),
        ({"baumgarte": (-1.0, 10.0)}, "baumgarte"),
        ({"baumgarte": (1e4, 2500.0)}, "baumgarte.*unstable"),
        ({"foot_radius": -0.01}, "foot_radius"),
        ({"mu": -0.1}, "mu"),
    ],
)
def test_constructor_rejects_bad_arguments(robot, kwargs, match):
    kwargs = {"foot_frames": FEET, **kwargs}
    with pytest.raises(ValueError, match=match):
        ContactPlant(robot.model, **kwargs)


def test_constructor_needs_a_floating_base(robot):
    fixed = pin.buildModelFromUrdf(str(robot.urdf))
    with pytest.raises(ValueError, match="free-flyer"):
        ContactPlant(fixed, FEET)


# --------------------------------------------------------------------------- fallen


def test_fallen(robot):
    q = robot.q.copy()
    assert not fallen(PlantState(q, np.zeros(22), 0.0))
    low = q.copy()
    low[2] = 0.2
    assert fallen(PlantState(low, np.zeros(22), 0.0))
    assert not fallen(PlantState(low, np.zeros(22), 0.0), min_base_height=0.1)
    for rpy, expected in [((1.1, 0.0, 0.0), True), ((0.0, -1.1, 0.0), True), ((0.6, 0.6, 3.0), False)]:
        tilted = q.copy()
        tilted[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(*rpy)).coeffs()
        assert fallen(PlantState(tilted, np.zeros(22), 0.0)) is expected, rpy
