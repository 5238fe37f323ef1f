"""The fast CDR codec (byte-equal to cyclonedds's) and the two DDS ends of a robot on loopback."""

import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("cyclonedds", reason="cyclonedds is not importable (pip install cyclonedds==11.0.1)")

from wbmpc.runtime import cdr, dds  # noqa: E402
from wbmpc.runtime import messages as m  # noqa: E402
from wbmpc.runtime.dds_robot import OWNER_TIMEOUT_S, DdsRobot, DdsRobotPort, split_joints  # noqa: E402
from wbmpc.runtime.robot import JointMap, MotorCommand, Observation, Robot  # noqa: E402

REPO_ROOT = Path(__file__).resolve().parents[1]
MATCH_TIMEOUT_S = 3.0  # discovery on loopback takes well under a second
ARRIVAL_TIMEOUT_S = 1.0

LEGS = tuple(f"{leg}_{kind}_joint" for leg in ("FL", "FR", "RL", "RR") for kind in ("hip", "thigh", "calf"))
ARM = ("joint1", "joint2", "joint3", "joint4")
JOINTS = LEGS + ARM  # the default robot's order (load_b1_z1().joint_names), without loading the model


class _Model:
    joint_names, arm_joint_names, nj = JOINTS, ARM, len(JOINTS)


# ------------------------------------------------------------------ helpers


@pytest.fixture
def domain() -> int:
    domain = dds.free_domain()
    if domain is None:
        pytest.skip("no DDS domain with free UDP ports found in 100..232")
    return domain


def _random_value(rng, dtype: np.dtype):
    if dtype.kind == "f":
        return float(np.float32(rng.uniform(-1e4, 1e4)))  # exactly representable: the wire's value
    info = np.iinfo(dtype)
    return int(rng.integers(info.min, info.max, endpoint=True))


def _random(cls, rng):
    """An instance with every field random within its IDL type (octet arrays as bytes or lists)."""
    obj = cls()
    for name, kind, element, length, octet in cdr._members(cls):
        if kind == cdr._SCALAR:
            value = _random_value(rng, element)
        elif kind == cdr._SCALARS:
            value = [_random_value(rng, element) for _ in range(length)]
            value = bytes(value) if octet and rng.random() < 0.5 else value
        elif kind == cdr._STRUCT:
            value = _random(element, rng)
        else:
            value = [_random(element, rng) for _ in range(length)]
        setattr(obj, name, value)
    return obj


def _poll(function, timeout_s: float = ARRIVAL_TIMEOUT_S):
    """``function()`` until it returns something other than None, for at most ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while (value := function()) is None and time.monotonic() < deadline:
        time.sleep(0.002)
    return value


def _until(step, condition, timeout_s: float = ARRIVAL_TIMEOUT_S) -> list:
    """Call ``step()`` until ``condition()`` holds (AssertionError after ``timeout_s``); its results."""
    deadline, results = time.monotonic() + timeout_s, []
    while True:
        results.append(step())
        if condition():
            return results
        assert time.monotonic() < deadline, "condition not reached in time"
        time.sleep(0.002)


def _observation(seq: int, rng=None) -> Observation:
    rng = rng or np.random.default_rng(seq)
    quat = rng.normal(size=4)
    return Observation(
        stamp=0.0,
        seq=seq,
        q=rng.uniform(-2, 2, len(JOINTS)),
        dq=rng.normal(size=len(JOINTS)),
        tau=rng.normal(size=len(JOINTS)) * 20,
        gyro=rng.normal(size=3),
        accelerometer=rng.normal(size=3) + [0, 0, 9.81],
        orientation=quat / np.linalg.norm(quat),
        foot_force=np.array([10.0, 20.0, -30.0, 40.0]),
    )


def _command(rng) -> MotorCommand:
    n = len(JOINTS)
    return MotorCommand(
        rng.uniform(-2, 2, n),
        rng.normal(size=n),
        rng.normal(size=n) * 10,
        rng.uniform(0, 80, n),
        rng.uniform(0, 5, n),
    )


@pytest.fixture
def pair(domain):
    """A controller's end and a robot's end on ``domain``, matched."""
    with DdsRobot(_Model(), domain, "lo") as robot, DdsRobotPort(domain, "lo", JOINTS) as port:
        assert robot.wait_for_match(MATCH_TIMEOUT_S) and port.wait_for_match(MATCH_TIMEOUT_S), (
            "no match on lo"
        )
        yield robot, port


def _raw_writer(endpoint, topic, data_type):
    writer = endpoint.writer(topic, data_type)
    assert endpoint.wait_for_match(writer, MATCH_TIMEOUT_S)
    return writer


# ------------------------------------------------------------------ the codec against cyclonedds's


@pytest.mark.parametrize("cls", [m.LowCmd_, m.LowState_])
def test_fast_codec_is_byte_equal_to_cyclonedds_on_random_messages(cls):
    codec = m.LOW_CMD_CDR if cls is m.LowCmd_ else m.LOW_STATE_CDR
    rng = np.random.default_rng(7)
    for _ in range(40):
        msg = _random(cls, rng)
        reference = cls.__idl__.serialize(msg)  # cyclonedds's own serializer
        assert len(reference) == codec.size and reference[:4] == cdr.CDR_LE_HEADER
        assert msg.serialize() == reference  # the hooked method DataWriter.write calls
        record = codec.from_object(msg)
        assert codec.encode(record) == reference  # numpy record -> wire
        assert codec.decode(reference).tobytes() == record.tobytes()  # wire -> numpy record
        plain = cls.__idl__.deserialize(reference)
        assert cls.deserialize(reference) == plain  # field by field (dataclass equality), types included
        assert codec.to_object(record) == plain
        assert isinstance(cls.deserialize(reference).head, bytes)  # octet arrays are bytes, as cyclonedds's
        version2 = cls.__idl__.serialize(msg, use_version_2=True)  # XCDR2: cyclonedds's path, both ways
        assert msg.serialize(use_version_2=True) == version2
        assert cls.deserialize(version2) == plain and codec.decode(version2).tobytes() == record.tobytes()


def test_cdr_layout_is_not_the_c_layout():
    # In CDR a struct has no trailing padding: the first MotorState_ starts right after the IMU's
    # one-byte temperature, where the C struct pads the IMU to 56 bytes.
    assert (m.LOW_CMD_CDR.size, m.LOW_STATE_CDR.size) == (812, 1180)
    state = m.new_low_state()
    state.imu_state.temperature = 0x5A
    state.motor_state[0].mode = 0xA5
    raw = state.serialize()
    c_offset = m.LOW_STATE_DTYPE.fields["imu_state"][1]
    cdr_offset = 4 + c_offset  # the header, then the same offsets up to the IMU
    assert raw[cdr_offset + 52 : cdr_offset + 54] == b"\x5a\xa5"
    assert m.pack_low_state(state)[c_offset + 52 : c_offset + 57] == b"\x5a\x00\x00\x00\xa5"


def test_fast_serialize_refuses_what_cyclonedds_refuses():
    cmd = m.new_low_cmd()
    cmd.head = [0x1FE, 0xEF]
    with pytest.raises(ValueError, match="out of its IDL type's range"):
        cmd.serialize()
    cmd = m.new_low_cmd()
    cmd.motor_cmd = cmd.motor_cmd[:19]
    with pytest.raises(ValueError, match=r"LowCmd_.motor_cmd has 19 elements, not 20"):
        cmd.serialize()


def test_codec_times_are_informative_and_far_below_cyclonedds():
    msg = m.stamp_crc(_random(m.LowState_, np.random.default_rng(1)))
    reference = m.LowState_.__idl__.serialize(msg)
    record = m.LOW_STATE_CDR.decode(reference)

    def best(function, n=200):
        times = []
        for _ in range(n):
            start = time.perf_counter()
            function()
            times.append(time.perf_counter() - start)
        return min(times)

    fast = max(best(lambda: m.LOW_STATE_CDR.encode(record)), best(lambda: m.LOW_STATE_CDR.decode(reference)))
    hooked = max(best(msg.serialize), best(lambda: m.LowState_.deserialize(reference)))
    generic = best(lambda: m.LowState_.__idl__.deserialize(reference), n=20)
    assert fast < 50e-6 and hooked < generic / 3, (fast, hooked, generic)


# ------------------------------------------------------------------ wire compatibility on DDS


def test_fast_bytes_and_plain_cyclonedds_read_each_other(domain):
    rng = np.random.default_rng(3)
    with dds.DdsEndpoint(domain, "lo") as endpoint:
        writer = endpoint.writer(m.LEG_CMD_TOPIC, m.LowCmd_)
        reader = endpoint.reader(m.LEG_CMD_TOPIC, m.LowCmd_, depth=4)
        assert endpoint.wait_for_match(writer, MATCH_TIMEOUT_S)
        # the fast path writes, cyclonedds's own deserializer reads the bytes DDS delivered
        msg = m.stamp_crc(_random(m.LowCmd_, rng))
        dds.write_serialized(writer, m.LOW_CMD_CDR.encode(m.LOW_CMD_CDR.from_object(msg)))
        ((data, info),) = endpoint.take_serialized(reader, ARRIVAL_TIMEOUT_S)
        assert info.valid_data and m.LowCmd_.__idl__.deserialize(data) == m.LowCmd_.__idl__.deserialize(
            m.LowCmd_.__idl__.serialize(msg)
        )
        # cyclonedds's own serializer writes, DataReader.take (the hooked deserialize) reads
        msg = m.stamp_crc(_random(m.LowCmd_, rng))
        dds.write_serialized(writer, m.LowCmd_.__idl__.serialize(msg))
        got = endpoint.take_latest(reader, ARRIVAL_TIMEOUT_S)
        assert got == m.LowCmd_.__idl__.deserialize(m.LowCmd_.__idl__.serialize(msg)) and m.crc_ok(got)
        # DataWriter.write (the hooked serialize) puts cyclonedds's bytes on the wire
        writer.write(msg)
        ((data, _),) = endpoint.take_serialized(reader, ARRIVAL_TIMEOUT_S)
        assert data == m.LowCmd_.__idl__.serialize(msg)


def test_a_plain_cyclonedds_process_and_a_dds_robot_understand_each_other(domain):
    # The other process removes the fast hooks (plain IdlStruct methods): it is cyclonedds as shipped.
    script = textwrap.dedent(
        f"""
        import sys
        from wbmpc.runtime import dds, messages as m
        for cls in (m.LowCmd_, m.LowState_):
            del cls.serialize, cls.deserialize
        assert m.LowCmd_.serialize is m.IdlStruct.serialize
        with dds.DdsEndpoint({domain}, "lo") as ep:
            reader = ep.reader(m.LEG_CMD_TOPIC, m.LowCmd_)
            writer = ep.writer(m.LEG_STATE_TOPIC, m.LowState_)
            if not (ep.wait_for_match(reader, 4.0) and ep.wait_for_match(writer, 4.0)):
                sys.exit(3)
            cmd = ep.take_latest(reader, 4.0)
            if cmd is None or not m.crc_ok(cmd):
                sys.exit(4)
            state = m.new_low_state()
            state.tick = 77
            state.motor_state[3].q = cmd.motor_cmd[3].q  # FL hip: Unitree slot 3
            state.imu_state.quaternion = [0.5, 0.5, -0.5, 0.5]
            writer.write(m.stamp_crc(state))
            ep.take_latest(reader, 1.0)  # stay until the state is out (the robot sends one more command)
        """
    )
    command = _command(np.random.default_rng(5))
    with DdsRobot(_Model(), domain, "lo") as robot:
        other = subprocess.Popen([sys.executable, "-c", script], cwd=REPO_ROOT)
        try:
            # the arm topics have no peer here: wait for the legs' only
            for entity in (robot._writers[0], robot._inboxes[0].reader):
                assert robot.endpoint.wait_for_match(entity, MATCH_TIMEOUT_S + 1)
            deadline = time.monotonic() + MATCH_TIMEOUT_S
            while robot.received == 0 and time.monotonic() < deadline:
                robot.write(command)
                robot.read()  # no arm state: None, but the leg state is taken and counted
                time.sleep(0.01)
            robot.write(command)
        finally:
            other.wait(timeout=10)
        assert other.returncode == 0
        legs = robot._inboxes[0]
        assert robot.received >= 1 and robot.refused_crc == 0 and int(legs.field["tick"]) == 77
        assert legs.field["q"][3] == np.float32(command.q[JOINTS.index("FL_hip_joint")])
        np.testing.assert_array_equal(legs.field["quaternion"], [0.5, 0.5, -0.5, 0.5])


# ------------------------------------------------------------------ the two ends


def test_observation_round_trip_respects_the_joint_maps(pair):
    robot, port = pair
    assert isinstance(robot, Robot) and robot.joint_names == JOINTS
    assert robot.read() is None
    sent = _observation(41)
    before = time.monotonic()
    port.publish(sent)
    got = _poll(robot.read)
    assert got is not None and before <= got.stamp <= time.monotonic()
    assert got.seq == 41
    for name in ("q", "dq", "tau", "gyro", "accelerometer", "orientation"):
        np.testing.assert_array_equal(
            getattr(got, name), getattr(sent, name).astype(np.float32), err_msg=name
        )
    np.testing.assert_array_equal(got.foot_force, sent.foot_force)
    # FL_hip is model joint 0 and Unitree slot 3; joint1 of the arm is slot 0 of the arm's topic
    legs, arm = robot._inboxes
    assert legs.field["q"][3] == np.float32(sent.q[0]) and legs.field["q"][0] == np.float32(sent.q[3])
    assert arm.field["q"][0] == np.float32(sent.q[12]) and not arm.field["q"][4:].any()
    x, y, z, w = sent.orientation
    np.testing.assert_allclose(legs.field["quaternion"], [w, x, y, z], rtol=1e-6)  # w first on the wire
    assert robot.read() is None  # nothing new
    assert (robot.received, robot.lost, robot.duplicates, robot.out_of_order, robot.refused_crc) == (
        2,
        0,
        0,
        0,
        0,
    )


def test_an_imu_without_orientation_output_stays_without_one(pair):
    """The zero quaternion on the wire, ``None`` at the controller: never the identity (which the
    estimator would trust as a measurement that the base is level)."""
    robot, port = pair
    sent = _observation(43)
    sent.orientation = None
    port.publish(sent)
    got = _poll(robot.read)
    assert got is not None and got.orientation is None
    legs = robot._inboxes[0]
    assert not legs.field["quaternion"].any() and not legs.field["rpy"].any()


def test_command_round_trip_respects_the_joint_maps(pair, domain):
    robot, port = pair
    sent = _command(np.random.default_rng(11))
    with dds.DdsEndpoint(domain, "lo") as spy:
        leg_reader = spy.reader(m.LEG_CMD_TOPIC, m.LowCmd_)
        assert spy.wait_for_match(leg_reader, MATCH_TIMEOUT_S)
        robot.write(sent)
        got = _poll(port.latest_command)
        wire = spy.take_latest(leg_reader, ARRIVAL_TIMEOUT_S)
    assert got is not None and port.commands == 1 and not got.damping
    for name in ("q", "dq", "tau", "kp", "kd"):
        np.testing.assert_array_equal(
            getattr(got, name), getattr(sent, name).astype(np.float32), err_msg=name
        )
    assert port.latest_command() is None  # nothing new
    assert m.crc_ok(wire) and list(wire.head) == [0xFE, 0xEF] and wire.level_flag == 0xFF
    assert wire.motor_cmd[3].q == np.float32(sent.q[0])  # FL_hip in Unitree slot 3
    assert wire.motor_cmd[9].kp == np.float32(sent.kp[JOINTS.index("RL_hip_joint")])  # RL: slots 9-11
    assert [mc.mode for mc in wire.motor_cmd] == [m.MOTOR_MODE_SERVO] * 12 + [0] * 8


def test_the_damping_command_stays_in_servo_mode_and_is_recognised(pair):
    robot, port = pair
    robot.write(MotorCommand.damping_mode(len(JOINTS), 2.0))
    got = _poll(port.latest_command)
    assert got is not None and got.damping and not got.kp.any() and np.all(got.kd == 2.0)
    legs = port._inboxes[0]
    assert np.all(legs.field["mode"][:12] == m.MOTOR_MODE_SERVO)


def test_a_bad_crc_is_refused_and_counted_on_both_ends(domain):
    with (
        DdsRobot(_Model(), domain, "lo") as robot,
        DdsRobotPort(domain, "lo", JOINTS) as port,
        dds.DdsEndpoint(domain, "lo") as other,
    ):
        # the controller's end: a corrupted state
        state_writer = _raw_writer(other, m.LEG_STATE_TOPIC, m.LowState_)
        assert robot.wait_for_match(MATCH_TIMEOUT_S) and port.wait_for_match(MATCH_TIMEOUT_S)
        port.publish(_observation(1))
        assert _poll(robot.read) is not None
        state = m.stamp_crc(m.new_low_state())
        state.tick = 2
        state.crc ^= 1
        state_writer.write(state)
        seen = _until(robot.read, lambda: robot.refused_crc == 1)
        assert all(obs is None for obs in seen) and robot.read() is None
        # the robot's end: a corrupted command from the first writer, then a good one from it
        command_writer = _raw_writer(other, m.LEG_CMD_TOPIC, m.LowCmd_)
        arm_writer = _raw_writer(other, m.ARM_CMD_TOPIC, m.LowCmd_)
        arm_writer.write(m.stamp_crc(m.new_low_cmd()))
        bad = m.stamp_crc(m.write_motor_commands(m.new_low_cmd(), [3], [0.5], [0], [0], [30], [1]))
        bad.crc ^= 1 << 31
        command_writer.write(bad)
        seen = _until(port.latest_command, lambda: port.refused_crc == 1)
        assert all(command is None for command in seen) and port.commands == 0
        bad.crc ^= 1 << 31
        command_writer.write(bad)
        got = _poll(port.latest_command)
        assert got is not None and got.q[0] == 0.5 and got.kp[0] == 30 and port.refused_crc == 1


def test_a_second_writer_is_refused_until_the_owner_is_silent(domain):
    first_command, second_command = (_command(np.random.default_rng(seed)) for seed in (1, 2))
    with (
        DdsRobotPort(domain, "lo", JOINTS) as port,
        DdsRobot(_Model(), domain, "lo") as first,
        DdsRobot(_Model(), domain, "lo") as second,
    ):
        for end in (port, first, second):
            assert end.wait_for_match(MATCH_TIMEOUT_S)
        assert port.endpoint.wait_for_match(port._inboxes[0].reader, MATCH_TIMEOUT_S, count=2)
        first.write(first_command)
        got = _poll(port.latest_command)
        np.testing.assert_array_equal(got.q, first_command.q.astype(np.float32))
        second.write(second_command)
        first.write(first_command)
        got = _poll(port.latest_command)
        np.testing.assert_array_equal(got.q, first_command.q.astype(np.float32))
        assert port.refused_second_writer == 2  # legs and arm
        time.sleep(OWNER_TIMEOUT_S + 0.1)  # the owner falls silent: the next writer takes over
        second.write(second_command)
        got = _poll(port.latest_command)
        np.testing.assert_array_equal(got.q, second_command.q.astype(np.float32))
        first.write(first_command)  # now the first one is the intruder
        seen = _until(port.latest_command, lambda: port.refused_second_writer == 4)
        assert all(command is None for command in seen)


def test_tick_gaps_are_lost_a_repeat_is_a_duplicate_and_a_step_back_is_out_of_order(pair):
    robot, port = pair
    for seq in (1, 2, 5):  # two missing: 3 and 4
        port.publish(_observation(seq))
    got = _poll(robot.read)
    assert got.seq == 5 and robot.lost == 2 * 2  # counted on the leg and the arm topic
    port.publish(_observation(5))
    assert all(obs is None for obs in _until(robot.read, lambda: robot.duplicates == 2))
    port.publish(_observation(4))
    assert all(obs is None for obs in _until(robot.read, lambda: robot.out_of_order == 2))
    port.publish(_observation(6))
    assert _poll(robot.read).seq == 6
    assert (robot.received, robot.lost, robot.duplicates, robot.out_of_order) == (12, 4, 2, 2)


# ------------------------------------------------------------------ maps


def test_joint_maps_default_from_the_names_and_bad_maps_are_refused():
    assert split_joints(JOINTS) == (LEGS, ARM)
    with pytest.raises(ValueError, match="cover every joint once"):
        DdsRobot(_Model(), 150, "lo", arm_map=JointMap.in_order(ARM[:3]))
    with pytest.raises(ValueError, match="20 motor slots"):
        DdsRobotPort(150, "lo", JOINTS, arm_map=JointMap.in_order(ARM, first_slot=18, n_slots=24))
    assert 150 not in dds._domains  # nothing was created
