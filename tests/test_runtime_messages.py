"""The Unitree low-level wire format: IDL layout, packed C struct, Unitree's CRC, the numpy converters."""

import struct
import typing

import numpy as np
import pytest

pytest.importorskip("cyclonedds", reason="cyclonedds is not installed (pip install cyclonedds==11.0.1)")

from cyclonedds.idl import IdlStruct, types  # noqa: E402

from wbmpc.runtime import messages as m  # noqa: E402

# ------------------------------------------------------------------ reference CRCs, written bit by bit


def mpeg2_bytewise(data: bytes) -> int:
    """CRC-32/MPEG-2 by its definition: poly 0x04C11DB7, init all ones, each byte MSB first, no xor out."""
    crc = 0xFFFFFFFF
    for byte in data:
        crc ^= byte << 24
        for _ in range(8):
            crc = ((crc << 1) ^ 0x04C11DB7) if crc & 0x80000000 else (crc << 1)
            crc &= 0xFFFFFFFF
    return crc


def unitree_crc32_core(words) -> int:
    """Unitree's crc32_core as the SDK states it: per word, 32 steps from the top bit; each step shifts the
    register, xors the polynomial if the bit shifted out was set, and xors it again if the data bit is."""
    crc = 0xFFFFFFFF
    for word in words:
        word = int(word)
        for bit in range(31, -1, -1):
            top = crc & 0x80000000
            crc = (crc << 1) & 0xFFFFFFFF
            if top:
                crc ^= 0x04C11DB7
            if (word >> bit) & 1:
                crc ^= 0x04C11DB7
    return crc


def _random_words(n, seed=0):
    return np.random.default_rng(seed).integers(0, 2**32, size=n, dtype=np.uint64).astype(np.uint32)


def test_bytewise_reference_matches_the_catalogue_check_value():
    assert mpeg2_bytewise(b"123456789") == 0x0376E6E7  # the CRC-32/MPEG-2 check value of the CRC catalogue
    assert mpeg2_bytewise(b"") == 0xFFFFFFFF


def test_unitree_wordwise_crc_is_mpeg2_of_the_big_endian_bytes_of_the_words():
    # Feeding word bits MSB first while the register shifts is the same as xoring the word into the
    # register first: crc32_core(words) = CRC-32/MPEG-2 of the words written big endian. Unitree's own
    # Python SDK (unitree_sdk2_python, unitree_sdk2py/utils/crc.py) computes it exactly so: words to
    # big-endian bytes, then an MPEG-2 CRC.
    assert unitree_crc32_core([0x31323334, 0x35363738]) == mpeg2_bytewise(b"12345678")
    assert unitree_crc32_core([]) == 0xFFFFFFFF
    for seed in range(5):
        words = _random_words(1 + 7 * seed, seed)
        expected = mpeg2_bytewise(words.astype(">u4").tobytes())
        assert unitree_crc32_core(words) == expected
        assert m.crc32_mpeg2(words) == expected


def test_crc_over_the_little_endian_struct_is_not_the_bytewise_crc_of_its_memory():
    # The struct sits in memory little endian, so its bytes must be regrouped per word (reversed in each
    # 4-byte group) before a byte-wise MPEG-2 CRC: the naive CRC of the memory bytes is a different number.
    raw = m.pack_low_cmd(_busy_low_cmd())
    words = np.frombuffer(raw, dtype="<u4")[:-1]
    regrouped = b"".join(raw[i : i + 4][::-1] for i in range(0, len(raw) - 4, 4))
    assert m.crc32_mpeg2(words) == mpeg2_bytewise(regrouped) == unitree_crc32_core(words)
    assert m.crc32_mpeg2(words) != mpeg2_bytewise(raw[:-4])


def test_fast_crc_matches_the_reference_on_full_messages():
    for msg in (_busy_low_cmd(), m.new_low_cmd(), _busy_low_state()):
        raw = m.pack_low_cmd(msg) if isinstance(msg, m.LowCmd_) else m.pack_low_state(msg)
        assert m.low_cmd_crc(msg) == unitree_crc32_core(np.frombuffer(raw, dtype="<u4")[:-1])


# ------------------------------------------------------------------ layout

# LowCmd_ (natural alignment): head 2 + level_flag 1 + frame_reserve 1 = 4; sn 2x4 -> 12; version 2x4 -> 20;
# bandwidth 2 -> 22, pad 2 -> 24. MotorCmd_: mode 1 + pad 3 + q dq tau kp kd 5x4 + reserve 3x4 = 36, times
# 20 -> 744. BmsCmd_ 1 + 3 = 4 -> 748. wireless_remote 40 -> 788, led 12 -> 800, fan 2 -> 802, gpio 1 -> 803,
# pad 1 -> 804, reserve 4 -> 808, crc 4 -> 812 = 203 words; the CRC covers the first 202.
LOW_CMD_SIZE = 812
# LowState_: the same 24-byte header. IMUState_: quaternion 16 + gyroscope 12 + accelerometer 12 + rpy 12 +
# temperature 1 = 53, padded to 56 -> 80. MotorState_: mode 1 + pad 3 + 7 floats 28 + temperature 1 + pad 3
# + lost 4 + reserve 2x4 = 48, times 20 -> 1040. BmsState_: 4 bytes + current 4 + cycle 2 + bq_ntc 2 +
# mcu_ntc 2 + cell_vol 15x2 = 44 -> 1084. foot_force 4x2 -> 1092, foot_force_est 4x2 -> 1100, tick 4 -> 1104,
# wireless_remote 40 -> 1144, bit_flag 1 + pad 3 -> 1148, adc_reel 4 -> 1152, temperature_ntc1/2 2 + pad 2
# -> 1156, power_v 4 -> 1160, power_a 4 -> 1164, fan_frequency 4x2 -> 1172, reserve 4 -> 1176, crc 4 -> 1180.
LOW_STATE_SIZE = 1180
SUBSTRUCT_SIZES = {"MotorCmd_": 36, "MotorState_": 48, "IMUState_": 56, "BmsCmd_": 4, "BmsState_": 44}


def test_packed_sizes_are_the_c_struct_sizes():
    assert m.LOW_CMD_SIZE == LOW_CMD_SIZE == len(m.pack_low_cmd(m.new_low_cmd()))
    assert m.LOW_STATE_SIZE == LOW_STATE_SIZE == len(m.pack_low_state(m.new_low_state()))
    for name, size in SUBSTRUCT_SIZES.items():
        assert m.struct_dtype(getattr(m, name)).itemsize == size, name


def test_packed_fields_sit_at_their_c_offsets():
    cmd = m.new_low_cmd()
    cmd.motor_cmd[1].q, cmd.motor_cmd[19].kd, cmd.bms_cmd.off = 1.5, -2.25, 0xA5
    cmd.gpio, cmd.reserve, cmd.crc = 7, 0xDEADBEEF, 0x01020304
    raw = m.pack_low_cmd(cmd)
    assert raw[:4] == bytes([0xFE, 0xEF, 0xFF, 0x00])
    assert struct.unpack_from("<f", raw, 24 + 36 + 4) == (1.5,)
    assert struct.unpack_from("<f", raw, 24 + 19 * 36 + 20) == (-2.25,)
    assert raw[744] == 0xA5 and raw[802] == 7 and raw[803] == 0  # gpio, then one pad byte
    assert struct.unpack_from("<II", raw, 804) == (0xDEADBEEF, 0x01020304)

    state = m.new_low_state()
    state.motor_state[0].tau_est, state.bms_state.current, state.foot_force = 3.0, -1234, [1, -2, 3, -4]
    state.tick, state.power_a, state.fan_frequency = 99, 0.5, [10, 20, 30, 40]
    raw = m.pack_low_state(state)
    assert struct.unpack_from("<4f", raw, 24) == (1.0, 0.0, 0.0, 0.0)
    assert struct.unpack_from("<f", raw, 80 + 16) == (3.0,)
    assert struct.unpack_from("<i", raw, 1040 + 4) == (-1234,)
    assert struct.unpack_from("<4h", raw, 1084) == (1, -2, 3, -4)
    assert struct.unpack_from("<I", raw, 1100) == (99,)
    assert struct.unpack_from("<f", raw, 1160) == (0.5,)
    assert struct.unpack_from("<4H", raw, 1164) == (10, 20, 30, 40)


def test_padding_bytes_are_zero():
    raw = np.frombuffer(m.pack_low_cmd(_busy_low_cmd()), dtype=np.uint8)
    pads = [22, 23, 803] + [24 + 36 * i + k for i in range(20) for k in (1, 2, 3)]
    assert not raw[pads].any()


# The public IDL, member by member (unitree_sdk2: include/unitree/idl/go2/*.hpp; octet = types.byte).
IDL = {
    "MotorCmd_": "mode octet, q float, dq float, tau float, kp float, kd float, reserve ulong[3]",
    "MotorState_": "mode octet, q float, dq float, ddq float, tau_est float, q_raw float, dq_raw float, "
    "ddq_raw float, temperature octet, lost ulong, reserve ulong[2]",
    "IMUState_": "quaternion float[4], gyroscope float[3], accelerometer float[3], rpy float[3], "
    "temperature octet",
    "BmsCmd_": "off octet, reserve octet[3]",
    "BmsState_": "version_high octet, version_low octet, status octet, soc octet, current long, "
    "cycle ushort, bq_ntc octet[2], mcu_ntc octet[2], cell_vol ushort[15]",
    "LowCmd_": "head octet[2], level_flag octet, frame_reserve octet, sn ulong[2], version ulong[2], "
    "bandwidth ushort, motor_cmd MotorCmd_[20], bms_cmd BmsCmd_, wireless_remote octet[40], led octet[12], "
    "fan octet[2], gpio octet, reserve ulong, crc ulong",
    "LowState_": "head octet[2], level_flag octet, frame_reserve octet, sn ulong[2], version ulong[2], "
    "bandwidth ushort, imu_state IMUState_, motor_state MotorState_[20], bms_state BmsState_, "
    "foot_force short[4], foot_force_est short[4], tick ulong, wireless_remote octet[40], bit_flag octet, "
    "adc_reel float, temperature_ntc1 octet, temperature_ntc2 octet, power_v float, power_a float, "
    "fan_frequency ushort[4], reserve ulong, crc ulong",
}
_IDL_NAMES = {"byte": "octet", "float32": "float", "uint32": "ulong", "int32": "long"}
_IDL_NAMES.update(uint16="ushort", int16="short")


def _idl_spelling(hint) -> str:
    if isinstance(hint, type) and issubclass(hint, IdlStruct):
        return hint.__name__
    meta = typing.get_args(hint)[1]
    if isinstance(meta, types.array):
        return f"{_idl_spelling(meta.subtype)}[{meta.length}]"
    return _IDL_NAMES[meta]


@pytest.mark.parametrize("name", sorted(IDL))
def test_fields_are_the_public_idl_in_order(name):
    cls = getattr(m, name)
    hints = typing.get_type_hints(cls, include_extras=True)
    ours = ", ".join(f"{field} {_idl_spelling(hints[field])}" for field in cls.__dataclass_fields__)
    assert ours == IDL[name]
    assert cls.__idl_typename__ == f"unitree_go.msg.dds_.{name}"
    assert cls.__idl_annotations__["extensibility"] == "final"


# XTypes type identifiers (14-byte MD5 prefixes of the minimal and complete TypeObjects) of the SDK's C++
# types, read from the type_info_blob of unitree_sdk2's include/unitree/idl/go2/<type>.hpp. They hash every
# member's name, type, order and the extensibility, so equal hashes mean the DDS types are identical.
SDK_TYPE_IDS = {
    "LowCmd_": ("832876ceec9737d69f6ed62a3f63", "52cc8eb0d427d692aa2b20a90540"),
    "LowState_": ("853a99e23d0daa1610b65c526b40", "08f239c471d3a27e67e7c7723184"),
    "MotorCmd_": ("c8e5835b0f0c1765bc231dfa02ff", "421fa5b2db2deff5c03fff16303b"),
    "MotorState_": ("42a2288b798af8db05e12736b1be", "d2bcfb97be37a8bc9c41e50ba1c9"),
    "IMUState_": ("4b1bf4af32e5bc6710efc8293115", "c4ecb49cd7b225d22628b6b764cc"),
    "BmsCmd_": ("3e8eb67c25fde07e52cf51ed4a23", "31a85924056b7af3d3f16b342233"),
    "BmsState_": ("e118af070ba20bc2e0370cec4cbb", "2ed857ecb6b30579808c15fd143d"),
}


@pytest.mark.parametrize("name", sorted(SDK_TYPE_IDS))
def test_xtypes_type_ids_equal_the_unitree_sdk_ones(name):
    info = getattr(m, name).__idl__.get_type_info()
    ours = (
        info.minimal.typeid_with_size.type_id.value.hex(),
        info.complete.typeid_with_size.type_id.value.hex(),
    )
    assert ours == SDK_TYPE_IDS[name]


# ------------------------------------------------------------------ CRC on messages


def _busy_low_cmd() -> m.LowCmd_:
    cmd = m.new_low_cmd()
    rng = np.random.default_rng(1)
    m.write_motor_commands(cmd, np.arange(12), *rng.normal(size=(5, 12)))
    cmd.led, cmd.sn, cmd.bandwidth = list(range(12)), [123, 456], 0x3A4
    return cmd


def _busy_low_state() -> m.LowState_:
    state = m.new_low_state()
    for i, motor in enumerate(state.motor_state):
        motor.q, motor.dq, motor.tau_est, motor.temperature = 0.1 * i, -0.2 * i, 0.3 * i, 30 + i
    state.imu_state.gyroscope, state.imu_state.accelerometer = [0.1, -0.2, 0.3], [0.0, 0.5, 9.81]
    state.foot_force, state.tick = [40, 41, 42, 43], 123456
    return state


def test_stamp_then_check_and_any_change_breaks_the_crc():
    cmd = m.stamp_crc(_busy_low_cmd())
    assert m.crc_ok(cmd)
    cmd.motor_cmd[7].kd += 1e-3
    assert not m.crc_ok(cmd)
    state = m.stamp_crc(_busy_low_state())
    assert m.crc_ok(state)
    state.tick += 1
    assert not m.crc_ok(state)


def test_a_corrupted_byte_changes_the_crc_and_the_crc_field_is_not_covered():
    raw = bytearray(m.pack_low_cmd(m.stamp_crc(_busy_low_cmd())))
    good = m.crc32_mpeg2(np.frombuffer(bytes(raw), dtype="<u4")[:-1])
    for position in (0, 2, 23, 24 + 36 * 5 + 4, 500, 803, 807):
        corrupted = raw.copy()
        corrupted[position] ^= 0x10
        assert m.crc32_mpeg2(np.frombuffer(bytes(corrupted), dtype="<u4")[:-1]) != good, position
    raw[810] ^= 0xFF  # inside the crc field itself
    assert m.crc32_mpeg2(np.frombuffer(bytes(raw), dtype="<u4")[:-1]) == good


def test_crc_survives_dds_serialisation():
    cmd = m.stamp_crc(_busy_low_cmd())
    received = m.LowCmd_.deserialize(cmd.serialize())  # octet arrays come back as bytes
    assert isinstance(received.head, bytes)
    assert m.crc_ok(received) and m.pack_low_cmd(received) == m.pack_low_cmd(cmd)


def test_out_of_range_fields_are_refused_when_packed():
    cmd = m.new_low_cmd()
    cmd.head = [0x1FE, 0xEF]
    with pytest.raises(ValueError, match="LowCmd_"):
        m.low_cmd_crc(cmd)
    with pytest.raises(TypeError, match="LowCmd_ or LowState_"):
        m.low_cmd_crc(m.MotorCmd_())


# ------------------------------------------------------------------ constructors and numpy converters


def test_new_messages_have_the_sdk_header_and_zero_slots():
    cmd, state = m.new_low_cmd(), m.new_low_state()
    assert list(cmd.head) == [0xFE, 0xEF] and cmd.level_flag == 0xFF and cmd.gpio == 0
    assert all(mc == m.MotorCmd_() for mc in cmd.motor_cmd) and len(cmd.motor_cmd) == m.NUM_MOTORS
    assert list(state.head) == [0xFE, 0xEF] and state.imu_state.quaternion == [1.0, 0.0, 0.0, 0.0]
    assert all(ms == m.MotorState_() for ms in state.motor_state)
    assert cmd.motor_cmd[0] is not cmd.motor_cmd[1] and m.new_low_cmd().motor_cmd[0] is not cmd.motor_cmd[0]


def test_write_motor_commands_fills_the_mapped_slots_only():
    slots = np.array([3, 0, 17])
    q, dq, tau, kp, kd = np.array(
        [[0.1, -0.7, 1.3], [1.0, 2.0, 3.0], [-5.0, 0.0, 5.0], [60.0] * 3, [5.0] * 3]
    )
    cmd = m.write_motor_commands(m.new_low_cmd(), slots, q, dq, tau, kp, kd)
    for i, slot in enumerate(slots):
        motor = cmd.motor_cmd[slot]
        got = [motor.q, motor.dq, motor.tau, motor.kp, motor.kd]
        np.testing.assert_array_equal(got, np.float32([q[i], dq[i], tau[i], kp[i], kd[i]]))
        assert motor.mode == m.MOTOR_MODE_SERVO
    untouched = set(range(20)) - set(slots.tolist())
    assert all(cmd.motor_cmd[s] == m.MotorCmd_() for s in untouched)


def test_state_and_imu_round_trip_through_the_wire():
    slots = np.array([5, 1, 9, 0])
    state = _busy_low_state()
    state.imu_state.quaternion = [0.9238795, 0.0, 0.3826834, 0.0]
    received = m.LowState_.deserialize(m.stamp_crc(state).serialize())
    assert m.crc_ok(received)
    q, dq, tau = m.read_motor_states(received, slots)
    np.testing.assert_allclose(q, 0.1 * slots, rtol=1e-6)
    np.testing.assert_allclose(dq, -0.2 * slots, rtol=1e-6)
    np.testing.assert_allclose(tau, 0.3 * slots, rtol=1e-6)
    quat, gyro, accel = m.read_imu(received)
    np.testing.assert_allclose(quat, [0.9238795, 0.0, 0.3826834, 0.0], rtol=1e-6)  # w, x, y, z
    np.testing.assert_allclose(gyro, [0.1, -0.2, 0.3], rtol=1e-6)
    np.testing.assert_allclose(accel, [0.0, 0.5, 9.81], rtol=1e-6)


def test_commands_round_trip_through_the_wire():
    slots = np.arange(12)[::-1]
    values = np.random.default_rng(2).normal(size=(5, 12))
    cmd = m.stamp_crc(m.write_motor_commands(m.new_low_cmd(), slots, *values))
    received = m.LowCmd_.deserialize(cmd.serialize())
    assert m.crc_ok(received)
    back = np.array(
        [[getattr(received.motor_cmd[s], f) for s in slots] for f in ("q", "dq", "tau", "kp", "kd")]
    )
    np.testing.assert_array_equal(back, values.astype(np.float32))


@pytest.mark.parametrize(
    "slots, n, match",
    [
        ([0, 20], 2, "0..19"),
        ([-1], 1, "0..19"),
        ([2, 2], 2, "distinct"),
        ([0, 1], 3, "3 values for 2"),
        ([[0, 1]], 2, "1-D"),
        ([0.0, 1.0], 2, "integer"),
    ],
)
def test_bad_slot_maps_are_refused(slots, n, match):
    with pytest.raises(ValueError, match=match):
        m.write_motor_commands(m.new_low_cmd(), slots, *np.zeros((5, n)))
    if n == len(np.ravel(slots)) and "values" not in match:
        with pytest.raises(ValueError, match=match):
            m.read_motor_states(m.new_low_state(), slots)


def test_topic_names():
    assert (m.LEG_CMD_TOPIC, m.LEG_STATE_TOPIC) == ("rt/lowcmd", "rt/lowstate")
    assert (m.ARM_CMD_TOPIC, m.ARM_STATE_TOPIC) == ("rt/arm_lowcmd", "rt/arm_lowstate")
