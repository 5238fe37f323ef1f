"""Robot loading: sizes, locked joints at the reference pose, feet on the ground, limits, clear errors."""

import numpy as np
import pinocchio as pin
import pytest

from wbmpc.model.robot import RobotModelError, example_robot_data_dir, load, load_b1, load_b1_z1, load_robot

URDF = example_robot_data_dir() / "b1_description/urdf/b1-z1.urdf"
SRDF = example_robot_data_dir() / "b1_description/srdf/b1-z1.srdf"
FEET = ("FL_foot", "FR_foot", "RL_foot", "RR_foot")


@pytest.fixture(scope="module")
def robot():
    return load_b1_z1()


def test_default_robot_sizes(robot):
    assert (robot.nq, robot.nv, robot.nj) == (23, 22, 16)
    assert robot.foot_frames == FEET
    assert robot.contact_frames == (*FEET, "gripper_center")
    assert robot.arm_joint_names == ["joint1", "joint2", "joint3", "joint4"]
    assert set(robot.locked_joints) == {"joint5", "joint6", "jointGripper"}


def test_mass_is_kept_by_locking(robot):
    full = pin.buildModelFromUrdf(str(URDF), pin.JointModelFreeFlyer())
    assert robot.mass == pytest.approx(sum(i.mass for i in full.inertias), rel=1e-12)
    assert 55.0 < robot.mass < 70.0


@pytest.mark.parametrize(
    "pose", ["standing_with_arm_up", "standing_with_arm_home", "standing_with_arm_forward"]
)
def test_reference_poses_have_feet_on_ground(robot, pose):
    q = robot.pose(pose)
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, q)
    heights = [data.oMf[robot.frame_id(f)].translation[2] - robot.foot_radius for f in robot.foot_frames]
    np.testing.assert_allclose(heights, 0.0, atol=1e-12)
    assert np.linalg.norm(q[3:7]) == pytest.approx(1.0)


def test_joints_locked_at_the_reference_pose_not_zero():
    """With joint5 locked at 0.4 rad, the reduced model places the end effector as the full model does."""
    full = pin.buildModelFromUrdf(str(URDF), pin.JointModelFreeFlyer())
    q_full = pin.neutral(full)
    q_full[2] = 0.5
    for name, value in {"joint2": 1.0, "joint3": -0.8, "joint5": 0.4, "joint6": -0.3}.items():
        q_full[full.joints[full.getJointId(name)].idx_q] = value
    robot = load_robot(
        URDF,
        foot_frames=FEET,
        ee_frame="gripperMover",
        locked_joints=("joint5", "joint6", "jointGripper"),
        q_reference=q_full,
    )
    assert robot.locked_joints["joint5"] == pytest.approx(0.4)
    full_data = full.createData()
    pin.framesForwardKinematics(full, full_data, q_full)
    q = robot.q_nominal
    q[2] = q_full[2]  # undo the feet-on-ground shift to compare the same pose
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, q)
    expected = full_data.oMf[full.getFrameId("gripperMover")]
    got = data.oMf[robot.frame_id("gripperMover")]
    np.testing.assert_allclose(got.homogeneous, expected.homogeneous, atol=1e-12)


def test_limits(robot):
    lower, upper = robot.joint_position_limits
    assert lower.shape == upper.shape == (16,) and np.all(lower < upper)
    assert robot.joint_velocity_limits.shape == (16,) and np.all(robot.joint_velocity_limits > 0)
    tau_max = robot.joint_torque_limits
    assert tau_max[robot.joint_index_v("FL_calf_joint") - 6] == pytest.approx(140.0)
    assert tau_max[robot.joint_index_v("joint2") - 6] == pytest.approx(60.0)


def test_b1_without_arm():
    robot = load_b1()
    assert (robot.nq, robot.nv) == (19, 18)
    assert not robot.has_arm and robot.contact_frames == FEET


def test_load_by_name():
    assert load("b1").nv == 18
    with pytest.raises(RobotModelError, match="'b3'"):
        load("b3")


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"urdf": "/no/such/robot.urdf"}, "URDF file not found: /no/such/robot.urdf"),
        ({"srdf": "/no/such/robot.srdf"}, "SRDF file not found"),
        ({"locked_joints": ("joint9",)}, "unknown joint 'joint9'"),
        ({"foot_frames": ("FL_foot", "XX_foot")}, "unknown frame 'XX_foot'"),
        ({"ee_frame": "hand"}, "unknown frame 'hand'"),
        ({"reference_pose": "sitting"}, "SRDF pose 'sitting' not found"),
    ],
)
def test_bad_input_is_named(kwargs, message):
    args = {
        "urdf": URDF,
        "srdf": SRDF,
        "foot_frames": FEET,
        "reference_pose": "standing_with_arm_up",
        **kwargs,
    }
    with pytest.raises(RobotModelError, match=message):
        load_robot(args.pop("urdf"), args.pop("srdf"), **args)


def test_unknown_pose_lookup(robot):
    with pytest.raises(RobotModelError, match="unknown pose 'lying'"):
        robot.pose("lying")


def test_default_pose_follows_the_srdf_order():
    """The SRDF lists standing_with_arm_up before standing_with_arm_home (alphabetically first)."""
    robot = load_robot(URDF, SRDF, foot_frames=FEET, locked_joints=("joint5", "joint6", "jointGripper"))
    assert robot.default_pose == "standing_with_arm_up"
    assert list(robot.reference_poses) == ["standing_with_arm_up", "standing_with_arm_home"]


@pytest.mark.parametrize("urdf_name", ["b1-z1.urdf", "b1.urdf"])
def test_default_robots_inertials(urdf_name):
    """Every link of the default robots has an inertial PyBullet uses as written, except the root link
    ``base``: 1e-6 kg with every tensor entry 1e-6 kg m^2 (rank one, PyBullet zeroes it), a placeholder
    under 1e-5 of the trunk's inertia that the check accepts as negligible."""
    import xml.etree.ElementTree as ET

    from wbmpc.model.inertials import _inertia_defect, read_inertials

    urdf = URDF.parent / urdf_name
    inertials = read_inertials(urdf, ET.parse(urdf).getroot())
    defects = {name: _inertia_defect(i.inertia) for name, i in inertials.items()}
    assert {name for name, defect in defects.items() if defect} == {"base"}
    assert "not all positive" in defects["base"] and inertials["base"].mass == 1e-6
