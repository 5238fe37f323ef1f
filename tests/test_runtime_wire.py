"""The emulated robot's shared-memory wire: readings and commands arrive as they were sent, and an IMU
without an orientation output stays without one (a wire that invents the identity tells the estimator the
base is level)."""

import numpy as np
import pytest

from wbmpc.runtime.robot import NO_ORIENTATION, MotorCommand, Observation, orientation_from_wire
from wbmpc.runtime.wire import SharedMemoryPort, SharedMemoryRobot, Wire

JOINTS = tuple(f"joint{i}" for i in range(5))


@pytest.fixture
def ends():
    description, *slots = Wire.create(len(JOINTS))
    port, robot = SharedMemoryPort(description), SharedMemoryRobot(description, JOINTS)
    yield robot, port
    robot.close()
    port.close()
    for slot in slots:
        slot.close()
        slot.unlink()


def _observation(seq, orientation):
    rng = np.random.default_rng(seq)
    n = len(JOINTS)
    return Observation(
        stamp=0.25 * seq,
        seq=seq,
        q=rng.normal(size=n),
        dq=rng.normal(size=n),
        tau=rng.normal(size=n),
        gyro=rng.normal(size=3),
        accelerometer=rng.normal(size=3),
        orientation=orientation,
    )


def test_a_reading_arrives_exactly_and_a_missing_orientation_stays_missing(ends):
    robot, port = ends
    assert robot.read() is None
    quat = np.array([0.1, -0.2, 0.3, 0.9])
    quat /= np.linalg.norm(quat)
    for seq, orientation in ((1, quat), (2, None)):
        sent = _observation(seq, orientation)
        port.publish(sent)
        got = robot.read()
        assert got.stamp == sent.stamp and got.seq == seq
        for name in ("q", "dq", "tau", "gyro", "accelerometer"):
            np.testing.assert_array_equal(getattr(got, name), getattr(sent, name), err_msg=name)
        if orientation is None:
            assert got.orientation is None  # not the identity: no orientation output
            assert got.imu().orientation is None
        else:
            np.testing.assert_array_equal(got.orientation, quat)
        assert robot.read() is None  # nothing new


def test_a_command_arrives_exactly(ends):
    robot, port = ends
    assert port.latest_command() is None
    rng = np.random.default_rng(3)
    n = len(JOINTS)
    sent = MotorCommand(*(rng.normal(size=n) for _ in range(3)), rng.uniform(0, 50, n), rng.uniform(0, 3, n))
    robot.write(sent)
    got = port.latest_command()
    for name in ("q", "dq", "tau", "kp", "kd"):
        np.testing.assert_array_equal(getattr(got, name), getattr(sent, name), err_msg=name)
    assert got.damping is False and port.latest_command() is None
    robot.write(MotorCommand.damping_mode(n, 3.0))
    assert port.latest_command().damping is True


def test_only_the_exact_zero_quaternion_means_no_orientation():
    assert orientation_from_wire(NO_ORIENTATION) is None
    tiny = np.array([0.0, 0.0, 0.0, 1e-300])
    assert orientation_from_wire(tiny) is not None
    nan = orientation_from_wire(np.full(4, np.nan))  # passed on, for Observation.problem to refuse
    assert nan is not None and "orientation" in _observation(1, nan).problem()
