"""Base commands other than the forward speed, in closed loop on the rigid plant: a yaw rate turns the robot
the commanded way, a base height raises or lowers the base to it. Outcomes are signed: a command with the
wrong sign, or one ignored, fails."""

from dataclasses import replace

import numpy as np
import pytest

from wbmpc.control.mpc import Commands, MPCConfig, WholeBodyMPC
from wbmpc.model.robot import heading, load_b1_z1
from wbmpc.ocp import OCPSettings
from wbmpc.ocp.gait import make_gait
from wbmpc.sim.closed_loop import ClosedLoopConfig, run_closed_loop
from wbmpc.sim.loop_config import CommandSchedule


@pytest.fixture(scope="module")
def robot():
    return load_b1_z1()


def test_a_yaw_rate_command_turns_the_robot_the_commanded_way(robot):
    """Trotting in place with +0.4 rad/s commanded (left, counter-clockwise seen from above) for 1.2 s:
    the heading grows by at least 40 % of the commanded 0.48 rad (the robot starts at rest), the yaw rate
    of the last 0.4 s is positive, and the base stays near its start."""
    yaw_rate, duration = 0.4, 1.2
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=10), MPCConfig(gait=make_gait("trot")))
    mpc.verbose = False
    config = ClosedLoopConfig(
        duration=duration,
        commands=CommandSchedule(base_velocity=(0.0, 0.0, 0.0), base_yaw_rate=yaw_rate, arm_reference=None),
    )
    result = run_closed_loop(mpc, config, progress=False)
    assert not result.fell and result.summary["converged_fraction"] >= 0.95
    log = result.log.arrays()
    yaw = np.unwrap([heading(q) for q in log["q"]])
    turned = yaw[-1] - yaw[0]
    assert turned > 0.4 * yaw_rate * duration, turned
    assert turned < 1.5 * yaw_rate * duration, turned
    late = log["t"] > duration - 0.4
    rate = np.polyfit(log["t"][late], yaw[late], 1)[0]
    assert rate > 0.5 * yaw_rate, rate
    assert np.linalg.norm(log["q"][-1, :2] - log["q"][0, :2]) < 0.1  # turning in place, not walking away


OFFSETS = {"lower": -0.06, "higher": 0.03}  # [m] from the nominal base height


@pytest.fixture(scope="module")
def heights(robot):
    """Standing 1 s with ``Commands.base_height`` 6 cm below and 3 cm above the nominal height: the logged
    base heights per run. The closed loop has no base-height setting, so each solve's commands get it."""
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=8), MPCConfig(gait=make_gait("stand")))
    mpc.verbose = False
    solve = mpc.solve
    out = {}
    for name, offset in OFFSETS.items():
        target = float(robot.q_nominal[2] + offset)

        def solve_at_height(q_hat, v_hat, t=0.0, commands=None, warm_start=True, target=target):
            return solve(q_hat, v_hat, t, replace(commands or Commands(), base_height=target), warm_start)

        mpc.solve = solve_at_height
        config = ClosedLoopConfig(
            duration=1.0, commands=CommandSchedule(base_velocity=(0.0, 0.0, 0.0), arm_reference=None)
        )
        result = run_closed_loop(mpc, config, progress=False)
        assert not result.fell and result.summary["converged_fraction"] >= 0.95
        out[name] = (target, result.log.arrays()["q"][:, 2])
    del mpc.solve
    return out


def test_a_base_height_command_moves_the_base_the_commanded_way(heights):
    """The base ends lower under the lower command than under the higher one; a sign error or an ignored
    command gives <= 0."""
    (_, lower), (_, higher) = heights["lower"], heights["higher"]
    assert lower[0] == higher[0]
    assert higher[-1] - lower[-1] > 1e-3, (lower[-1], higher[-1])
    assert lower[-1] < lower[0] - 1e-3


@pytest.mark.parametrize("name", list(OFFSETS))
def test_a_base_height_command_reaches_the_height(heights, name):
    """Within 1 cm of the commanded height after 1 s: the leg joints are desired at the pose that keeps the
    feet on the ground at that height (``WholeBodyMPC.pose_at_height``; before, only the base's row of the
    posture cost moved and a -6 cm command ended 1.9 mm lower)."""
    target, z = heights[name]
    assert abs(z[-1] - target) < 0.01, (z[-1], target)


def test_pose_at_height_keeps_the_feet_where_they_were(robot):
    import pinocchio as pin

    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=4), MPCConfig(gait=make_gait("stand")))
    model, data = robot.model, robot.model.createData()
    ids = [robot.frame_id(f) for f in robot.foot_frames]
    pin.framesForwardKinematics(model, data, robot.q_nominal)
    nominal = np.array([data.oMf[i].translation for i in ids])
    for offset in (-0.08, 0.04):
        height = round(robot.q_nominal[2] + offset, 4)  # on the cache's 0.1 mm grid
        q = mpc.pose_at_height(height)
        assert q[2] == height
        pin.framesForwardKinematics(model, data, q)
        np.testing.assert_allclose([data.oMf[i].translation for i in ids], nominal, atol=1e-6)
        arm = [robot.joint_index_v(n) + 1 for n in robot.arm_joint_names]  # q index = v index + 1
        np.testing.assert_array_equal(q[arm], robot.q_nominal[arm])
