"""PyBullet plant: state conventions, kinematics and dynamics against Pinocchio, contacts, scene, inputs."""

import re

import numpy as np
import pinocchio as pin
import pybullet as p
import pytest

from wbmpc.model import robot as robots
from wbmpc.model.statics import static_equilibrium
from wbmpc.sim.pybullet_plant import Box, Payload, PyBulletPlant, Wall

G = 9.81


@pytest.fixture(scope="module")
def robot():
    return robots.load_b1_z1()


@pytest.fixture(scope="module")
def trunk_root_robot(tmp_path_factory):
    """B1 + Z1 without the massless dummy ``base`` link: the root link is the trunk, whose inertial frame is
    offset (~1 cm) and rotated (PyBullet diagonalises the inertia) from the link frame, so the inertial-frame
    corrections are exercised (the default robot's dummy root has an identity inertial frame)."""
    urdf = robots.example_robot_data_dir() / "b1_description/urdf/b1-z1.urdf"
    text = urdf.read_text()
    text = re.sub(r'<link name="base">.*?</link>', "", text, count=1, flags=re.S)
    text = re.sub(r'<joint name="floating_base".*?</joint>', "", text, count=1, flags=re.S)
    path = tmp_path_factory.mktemp("urdf") / "b1-z1-trunk-root.urdf"
    path.write_text(text)
    return robots.load_robot(
        path,
        robots.example_robot_data_dir() / "b1_description/srdf/b1-z1.srdf",
        foot_frames=robots.UNITREE_FOOT_FRAMES,
        ee_frame=robots.B1_Z1_EE_FRAME,
        locked_joints=robots.B1_Z1_LOCKED_JOINTS,
        reference_pose="standing_with_arm_up",
        extra_frames={robots.B1_Z1_EE_FRAME: ("gripperMover", (0.05, 0.0, 0.0))},
    )


@pytest.fixture(scope="module")
def plant(robot):
    with PyBulletPlant(robot) as plant:
        yield plant


@pytest.fixture(scope="module")
def rigid_plant(robot):
    """No joint damping or friction: the rigid-body model of Pinocchio."""
    with PyBulletPlant(robot, joint_damping=False) as plant:
        yield plant


def random_state(robot, rng, height=2.0, speed=1.0):
    """Random base pose and velocity, joints inside their limits (away from them: no limit impulses)."""
    lo, hi = robot.joint_position_limits
    q = robot.q_nominal
    q[:2] = rng.normal(size=2)
    q[2] = height
    quat = rng.normal(size=4)
    q[3:7] = quat / np.linalg.norm(quat)
    q[7:] = lo + (hi - lo) * rng.uniform(0.2, 0.8, size=robot.nj)
    return q, speed * rng.normal(size=robot.nv)


def rotation(q):
    return pin.Quaternion(q[3:7]).toRotationMatrix()


def stand(plant, robot, steps, wrench=None, ee_force=None, callback=None):
    """Gravity compensation from the static equilibrium + joint PD (Kp 100, Kd 5) around the nominal pose."""
    q0 = robot.q_nominal
    tau_g = static_equilibrium(robot, q0, [True] * robot.n_feet, ee_force=ee_force).tau
    state = plant.state
    for _ in range(steps):
        before = state
        state = plant.step(tau_g + 100.0 * (q0[7:] - state.q[7:]) - 5.0 * state.v[6:], external_wrench=wrench)
        if callback is not None:
            callback(before, state)
    return state


# --------------------------------------------------------------------------------------------- conventions
@pytest.mark.parametrize("which", ["robot", "trunk_root_robot"])
def test_state_round_trip(which, request):
    robot = request.getfixturevalue(which)
    rng = np.random.default_rng(0)
    with PyBulletPlant(robot) as plant:
        if which == "trunk_root_robot":
            assert np.linalg.norm(plant._r_li) > 5e-3 and abs(plant._q_li[3]) < 0.9999  # non-trivial frame
        for _ in range(5):
            q, v = random_state(robot, rng)
            state = plant.reset(q, v, t=1.5)
            assert state.t == 1.5
            np.testing.assert_allclose(state.q, q, atol=1e-6, rtol=0)
            np.testing.assert_allclose(state.v, v, atol=1e-6, rtol=0)
            # The state is read back from PyBullet, not echoed.
            q_back, v_back = plant._read_state()
            np.testing.assert_allclose(q_back, q, atol=1e-6, rtol=0)
            np.testing.assert_allclose(v_back, v, atol=1e-6, rtol=0)


@pytest.mark.parametrize("which", ["robot", "trunk_root_robot"])
def test_kinematics_match_pinocchio(which, request):
    """Foot and end-effector placements and velocities: checks the joint mapping and the base-frame
    corrections of both position and velocity."""
    robot = request.getfixturevalue(which)
    model = robot.model
    data = model.createData()
    rng = np.random.default_rng(1)
    with PyBulletPlant(robot) as plant:
        for _ in range(3):
            q, v = random_state(robot, rng)
            plant.reset(q, v)
            pin.forwardKinematics(model, data, q, v)
            pin.updateFramePlacements(model, data)
            for frame in (*robot.foot_frames, robot.ee_frame):
                fid = model.getFrameId(frame)
                placement = plant.frame_placement(frame)
                np.testing.assert_allclose(placement.translation, data.oMf[fid].translation, atol=1e-5)
                np.testing.assert_allclose(placement.rotation, data.oMf[fid].rotation, atol=1e-5)
                expected = pin.getFrameVelocity(model, data, fid, pin.LOCAL_WORLD_ALIGNED).vector
                np.testing.assert_allclose(plant.frame_velocity(frame), expected, atol=1e-5)
            expected_feet = [data.oMf[model.getFrameId(f)].translation for f in robot.foot_frames]
            np.testing.assert_allclose(plant.foot_positions, expected_feet, atol=1e-5)


def test_dynamics_match_aba(robot, rigid_plant):
    """One 1 ms step in the air with random torques: the velocity change is dt * aba.

    Compared in world axes: PyBullet integrates the world velocity of the base inertial frame, Pinocchio the
    base-frame velocity, and the two semi-implicit Euler steps differ by O(dt^2 |omega| |a|) ~ 1e-4 when
    expressed in the (rotating) base frame, but agree exactly in world axes (expected change of the base
    origin velocity: R (a_lin + omega x v_lin) dt). The remaining difference is ~1e-8 (velocity changes are
    ~1): the tolerance 1e-6 leaves margin but is 1e5 below what a swapped joint, a wrong frame or the arm's
    joint damping (removed here; its effect is tested below) would cause.
    """
    model = robot.model
    data = model.createData()
    rng = np.random.default_rng(2)
    dt = rigid_plant.dt
    for _ in range(4):
        q, v = random_state(robot, rng, speed=0.5)
        tau = rng.uniform(-0.5, 0.5, size=robot.nj) * robot.joint_torque_limits
        rigid_plant.reset(q, v)
        after = rigid_plant.step(tau)
        assert not rigid_plant.foot_contacts().any()
        a = pin.aba(model, data, q, v, np.concatenate([np.zeros(6), tau]))
        R0, R1 = rotation(q), rotation(after.q)
        lin = R0 @ (v[:3] + dt * (a[:3] + np.cross(v[3:6], v[:3])))
        ang = R0 @ (v[3:6] + dt * a[3:6])
        assert np.abs(dt * a).max() > 0.5  # the check is not vacuous
        np.testing.assert_allclose(R1 @ after.v[:3], lin, atol=1e-6, rtol=0)
        np.testing.assert_allclose(R1 @ after.v[3:6], ang, atol=1e-6, rtol=0)
        np.testing.assert_allclose(after.v[6:] - v[6:], dt * a[6:], atol=1e-6, rtol=0)


def test_joint_damping_and_friction_from_urdf(robot, plant, rigid_plant):
    """With ``joint_damping`` the arm joints feel -(d qdot + f sign(qdot)) (URDF damping and friction)."""
    model = robot.model
    data = model.createData()
    j = robot.joint_names.index("joint2")  # URDF: damping 2 N m s/rad, friction 2 N m
    q = robot.q_nominal
    q[2] = 2.0
    for speed in (1.0, 3.0):
        v = np.zeros(robot.nv)
        v[6 + j] = speed
        implied = {}
        for name, sim in (("damped", plant), ("rigid", rigid_plant)):
            sim.reset(q, v)
            after = sim.step(np.zeros(robot.nj))
            a = pin.aba(model, data, q, v, np.zeros(robot.nv))
            # Generalised force that explains the deviation from the rigid-body acceleration.
            implied[name] = pin.crba(model, data, q) @ ((after.v - v) / sim.dt - a)
        assert implied["rigid"][6 + j] == pytest.approx(0.0, abs=1e-3)
        assert implied["damped"][6 + j] == pytest.approx(-(2.0 * speed + 2.0), rel=1e-3)
    # Coulomb friction holds the joint against a torque below the friction level (gravity-free arm joint1).
    j1 = robot.joint_names.index("joint1")
    tau = np.zeros(robot.nj)
    tau[j1] = 0.5  # < 1 N m friction
    plant.reset(q, np.zeros(robot.nv))
    for _ in range(50):
        state = plant.step(tau)
    assert abs(state.q[7 + j1] - q[7 + j1]) < 1e-6


# --------------------------------------------------------------------------------------------- contacts
def test_standing(robot, plant):
    plant.reset(robot.q_nominal, np.zeros(robot.nv))
    heights = []
    state = stand(plant, robot, 1000, callback=lambda _, s: heights.append(s.q[2]))
    assert np.max(np.abs(np.array(heights) - robot.q_nominal[2])) < 0.02
    assert plant.foot_contacts().all()
    forces = plant.contact_forces()
    assert forces.shape == (4, 3)
    assert forces[:, 2].sum() == pytest.approx(robot.mass * G, rel=0.05)
    assert (forces[:, 2] > 0.2 * robot.mass * G / 4).all()  # every foot carries weight
    assert not plant.fallen(state)
    np.testing.assert_array_equal(plant.last_contact_forces, forces)
    assert plant.violation_counts["slipping"].sum() == 0
    assert plant.torque_clip_counts.sum() == 0


def test_contact_forces_obey_newton(robot, plant):
    """m dv_com/dt = sum of foot forces + external force + m g at every step, including under a lateral
    push: the forces read from the contact points (normal + both friction directions, signs) are complete."""
    model = robot.model
    data = model.createData()
    mass = robot.mass
    push = np.array([60.0, -30.0, 0.0, 0.0, 0.0, 0.0])
    errors = []

    def check(before, after):
        pin.centerOfMass(model, data, before.q, before.v)
        v0 = data.vcom[0].copy()
        pin.centerOfMass(model, data, after.q, after.v)
        lhs = mass * (data.vcom[0] - v0) / plant.dt
        errors.append(lhs - (plant.contact_forces().sum(axis=0) + push[:3] - [0.0, 0.0, mass * G]))

    plant.reset(robot.q_nominal, np.zeros(robot.nv))
    stand(plant, robot, 300, wrench=push, callback=check)
    assert np.abs(plant.contact_forces()[:, :2].sum(axis=0)).max() > 1.0  # friction is involved
    assert np.abs(errors).max() < 0.05  # [N], against forces of ~600 N


def test_zero_torque_collapses(robot, plant):
    plant.reset(robot.q_nominal, np.zeros(robot.nv))
    for _ in range(1000):
        state = plant.step(np.zeros(robot.nj))
    assert state.q[2] < robot.q_nominal[2] - 0.05


# --------------------------------------------------------------------------------------------- disturbances
def test_external_wrench_changes_momentum(robot, rigid_plant):
    """In the air, a base force changes the linear momentum by F T and a torque the angular momentum by
    tau T (compared with the same run without the wrench, so gravity cancels)."""
    model = robot.model
    data = model.createData()
    q = robot.q_nominal
    q[2] = 2.0
    steps = 20
    duration = steps * rigid_plant.dt

    def momentum(wrench):
        rigid_plant.reset(q, np.zeros(robot.nv))
        for _ in range(steps):
            state = rigid_plant.step(np.zeros(robot.nj), external_wrench=wrench)
        pin.computeCentroidalMomentum(model, data, state.q, state.v)
        return data.hg.vector.copy()

    free = momentum(None)
    force = np.array([50.0, -20.0, 30.0])
    np.testing.assert_allclose(
        momentum(np.r_[force, 0.0, 0.0, 0.0])[:3] - free[:3], force * duration, rtol=1e-3
    )
    torque = np.array([0.0, 0.0, 20.0])
    h = momentum(np.r_[0.0, 0.0, 0.0, torque])
    # A pure torque does not move the centre of mass (1e-4: discretisation, vs 0.6 N s for the force above).
    np.testing.assert_allclose(h[:3], free[:3], atol=1e-4)
    np.testing.assert_allclose(
        h[3:] - free[3:], torque * duration, atol=0.02 * np.linalg.norm(torque) * duration
    )


def test_velocity_kick(robot, plant):
    plant.reset(robot.q_nominal, np.zeros(robot.nv))
    stand(plant, robot, 50)
    before = plant.state
    after = plant.apply_base_velocity_kick([0.5, -0.2, 0.0])
    dv = rotation(after.q) @ after.v[:3] - rotation(before.q) @ before.v[:3]
    np.testing.assert_allclose(dv, [0.5, -0.2, 0.0], atol=1e-9)
    np.testing.assert_allclose(after.q, before.q, atol=1e-12)
    state = stand(plant, robot, 100)
    assert state.q[0] - before.q[0] > 0.01 and state.q[1] - before.q[1] < -0.005  # it moves that way
    plant.apply_base_velocity_kick([0.0, 0.0, 0.0, 0.0, 0.0, 1.0])  # (6,): linear and angular
    assert (rotation(plant.state.q) @ plant.state.v[3:6])[2] == pytest.approx(1.0 + state.v[5], abs=0.05)


# --------------------------------------------------------------------------------------------- scene
def test_carried_payload_adds_weight(robot):
    payload = 5.0
    with PyBulletPlant(robot, scene={"load": Payload(payload, attach="rigid")}) as plant:
        top = plant.body_pose("load")[0] + [0.0, 0.0, 0.05]
        np.testing.assert_allclose(top, plant.ee_position(), atol=1e-9)
        stand(plant, robot, 500, ee_force=[0.0, 0.0, -payload * G])
        assert plant.contact_forces()[:, 2].sum() == pytest.approx((robot.mass + payload) * G, rel=0.02)
        assert np.linalg.norm(plant.body_pose("load")[0] + [0, 0, 0.05] - plant.ee_position()) < 0.01
        plant.detach_payload("load")
        for _ in range(100):
            plant.step(np.zeros(robot.nj))
        assert plant.body_velocity("load")[0][2] < -0.5  # released: it falls


def test_tether_pulls_payload(robot):
    """A rope from the gripper to a 2 kg ball 1.29 m away: slack, the ball stays; taut, it is dragged."""
    with PyBulletPlant(robot) as plant:
        ee = plant.ee_position()
        plant.add(
            Payload(2.0, position=(ee[0] - 1.0, 0.0, 0.05), attach="tether", tether_length=1.33), "ball"
        )
        stand(plant, robot, 100)
        assert abs(plant.body_pose("ball")[0][0] - (ee[0] - 1.0)) < 1e-3
        stand(plant, robot, 400, wrench=[80.0, 0.0, 0.0, 0.0, 0.0, 0.0])
        assert plant.body_pose("ball")[0][0] > ee[0] - 1.0 + 0.01


def test_wall_contact_force_on_gripper(robot, plant):
    """Pushing the robot into a wall just ahead of the gripper: the wall pushes the gripper back."""
    plant.reset(robot.q_nominal, np.zeros(robot.nv))
    ee = plant.ee_position()
    name = "test_wall"
    plant.add(Wall(position=(ee[0] + 0.03, 0.0, ee[2]), normal=(-1.0, 0.0, 0.0), size=(0.6, 0.6)), name)
    try:
        stand(plant, robot, 300, wrench=[80.0, 0.0, 0.0, 0.0, 0.0, 0.0])
        force = plant.ee_contact_force()
        assert force[0] < -30.0
        assert abs(force[0]) > 3 * abs(force[1])
    finally:
        p.removeBody(plant.body(name), physicsClientId=plant.client)
        plant._bodies.pop(name)


def test_box_rests_on_ground_and_instances_coexist(robot):
    with (
        PyBulletPlant(robot, scene=[Box((0.2, 0.2, 0.2), (1.0, 0.0, 0.5), mass=2.0)]) as a,
        PyBulletPlant(robot, dt=0.002) as b,
    ):
        assert a.client != b.client
        q = robot.q_nominal
        q[2] += 1.0
        b.reset(q, np.zeros(robot.nv))
        for _ in range(500):
            a.step(np.zeros(robot.nj))
        position, _ = a.body_pose("box0")
        assert position[2] == pytest.approx(0.1, abs=2e-3)
        assert b.state.q[2] == q[2] and b.time == 0.0  # untouched by the other client
        assert a.time == pytest.approx(0.5)
    with pytest.raises(p.error):
        p.getNumBodies(physicsClientId=a.client)  # closed


# --------------------------------------------------------------------------------------------- inputs
def test_bad_input(robot, plant):
    plant.reset(robot.q_nominal, np.zeros(robot.nv))
    with pytest.raises(ValueError, match="tau_joints"):
        plant.step(np.zeros(robot.nj + 1))
    tau = np.zeros(robot.nj)
    tau[3] = np.nan
    with pytest.raises(ValueError, match="tau_joints"):
        plant.step(tau)
    with pytest.raises(ValueError, match="external_wrench"):
        plant.step(np.zeros(robot.nj), external_wrench=np.zeros(3))
    with pytest.raises(ValueError, match="q"):
        plant.reset(robot.q_nominal[:-1], np.zeros(robot.nv))
    with pytest.raises(ValueError, match="delta_v_world"):
        plant.apply_base_velocity_kick([1.0, 0.0])
    assert plant.time == 0.0  # rejected steps do not advance time


def test_torque_clipping_is_counted(robot, plant):
    plant.reset(robot.q_nominal, np.zeros(robot.nv))
    tau = np.zeros(robot.nj)
    tau[0] = 10.0 * robot.joint_torque_limits[0]
    plant.step(tau)
    plant.step(tau)
    expected = np.zeros(robot.nj, dtype=int)
    expected[0] = 2
    np.testing.assert_array_equal(plant.torque_clip_counts, expected)
