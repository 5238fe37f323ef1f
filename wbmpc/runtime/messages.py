"""The Unitree Go2/B2 low-level wire format: ``LowCmd_`` / ``LowState_`` as DDS types, packing and CRC.

Layout. The types below are ``unitree_go::msg::dds_`` from Unitree's public SDK: the generated C++ classes
in the ``unitreerobotics/unitree_sdk2`` repository (``include/unitree/idl/go2/LowCmd_.hpp``,
``LowState_.hpp``, ``MotorCmd_.hpp``, ``MotorState_.hpp``, ``IMUState_.hpp``, ``BmsCmd_.hpp``,
``BmsState_.hpp``), cross-checked against the cyclonedds-Python classes of ``unitreerobotics/
unitree_sdk2_python`` (``unitree_sdk2py/idl/unitree_go/msg/dds_/``) and the ROS 2 messages of
``unitreerobotics/unitree_ros2`` (``cyclonedds_ws/src/unitree/unitree_go/msg/``). Field names, order,
types and array lengths are theirs; the structs are ``@final`` like the SDK's. Unitree's IDL declares the
8-bit fields ``octet`` (the C++ headers' XTypes blobs say TK_BYTE), so they are ``types.byte`` here: with
cyclonedds 11 ``types.uint8`` would be TK_UINT8, a different type to the XTypes matcher. (The ROS 2 ``.msg``
files say ``int8`` for the temperatures; on the wire that is the same one byte.) A ``LowCmd_`` carries 20
motor slots (a Go2 uses 0..11: FR, FL, RR, RL x hip, thigh, calf), the battery command, the remote's raw
bytes and a CRC; a ``LowState_`` carries the IMU, 20 motor states, the battery state, foot forces and a
1 kHz tick.

Units: joint angles ``q`` in rad, velocities ``dq`` in rad/s, accelerations ``ddq`` in rad/s^2, torques
``tau``/``tau_est`` in N m, gains ``kp`` in N m/rad and ``kd`` in N m s/rad; the IMU's gyroscope in rad/s,
its accelerometer in m/s^2 (specific force: about +9.81 on z at rest), ``rpy`` in rad. The quaternion is
ordered **w, x, y, z**, scalar first (Unitree's documentation: QwQxQyQz).

CRC. Every ``LowCmd_`` the robot accepts carries in ``crc`` the Unitree ``crc32_core`` (in the SDK's
``include/unitree/dds_wrapper/common/crc.h`` and its low-level examples) of the message laid out as the C++
struct (natural alignment, little endian, zero padding), taken over its 32-bit words except the last, the
``crc`` field itself: 202 of the 203 words of ``LowCmd_``, 294 of the 295 of ``LowState_``. ``crc32_core``
is CRC-32/MPEG-2 (poly 0x04C11DB7, init 0xFFFFFFFF, MSB first, no reflection, no final xor) fed one
32-bit word at a time from its top bit, i.e. the byte-wise CRC-32/MPEG-2 of the words' big-endian bytes.

Topics. The legs speak ``rt/lowcmd`` / ``rt/lowstate`` (Unitree's names). The Z1 arm's own interface is a
UDP SDK, not DDS, so wbmpc's emulated robot publishes the arm joints on ``rt/arm_lowcmd`` /
``rt/arm_lowstate`` with the same ``LowCmd_`` / ``LowState_`` layout (the runtime's ``slots`` map says
which slot is which joint); a real Z1 would need a bridge from these topics to its UDP SDK.
"""

import zlib
from dataclasses import dataclass, field

import numpy as np
from cyclonedds.idl import IdlStruct, types
from cyclonedds.idl import annotations as annotate

from wbmpc.runtime import cdr
from wbmpc.runtime.cdr import struct_dtype as struct_dtype  # re-exported: the C layout of a type

LEG_CMD_TOPIC = "rt/lowcmd"
LEG_STATE_TOPIC = "rt/lowstate"
ARM_CMD_TOPIC = "rt/arm_lowcmd"
ARM_STATE_TOPIC = "rt/arm_lowstate"

NUM_MOTORS = 20
HEAD = (0xFE, 0xEF)
LEVEL_FLAG_LOW = 0xFF  # low-level (joint) control, as the SDK's low-level examples set it
LEVEL_FLAG_HIGH = 0xEE
MOTOR_MODE_SERVO = 0x01  # PMSM servo mode; 0x00 is off
POS_STOP_F = 2.146e9  # the SDK's "no position target" sentinel for q
VEL_STOP_F = 16000.0  # the SDK's "no velocity target" sentinel for dq


def _zeros(n: int, value=0):
    return field(default_factory=lambda: [value] * n)


def _unitree_struct(cls):
    """The SDK's decorators: a dataclass, ``@final`` extensibility, sequential member ids."""
    return dataclass(annotate.final(annotate.autoid("sequential")(cls)))


# The class names are Unitree's (``LowCmd_``, with the trailing underscore of their IDL), hence noqa N801.


@_unitree_struct
class MotorCmd_(IdlStruct, typename="unitree_go.msg.dds_.MotorCmd_"):  # noqa: N801
    """One motor's command: ``tau_ff + kp (q - q_m) + kd (dq - dq_m)`` [N m] on the motor driver."""

    mode: types.byte = 0
    q: types.float32 = 0.0
    dq: types.float32 = 0.0
    tau: types.float32 = 0.0
    kp: types.float32 = 0.0
    kd: types.float32 = 0.0
    reserve: types.array[types.uint32, 3] = _zeros(3)


@_unitree_struct
class MotorState_(IdlStruct, typename="unitree_go.msg.dds_.MotorState_"):  # noqa: N801
    """One motor's measured state (q rad, dq rad/s, ddq rad/s^2, tau_est N m, temperature deg C)."""

    mode: types.byte = 0
    q: types.float32 = 0.0
    dq: types.float32 = 0.0
    ddq: types.float32 = 0.0
    tau_est: types.float32 = 0.0
    q_raw: types.float32 = 0.0
    dq_raw: types.float32 = 0.0
    ddq_raw: types.float32 = 0.0
    temperature: types.byte = 0
    lost: types.uint32 = 0
    reserve: types.array[types.uint32, 2] = _zeros(2)


@_unitree_struct
class IMUState_(IdlStruct, typename="unitree_go.msg.dds_.IMUState_"):  # noqa: N801
    """IMU: quaternion w-x-y-z, gyroscope rad/s, accelerometer m/s^2, rpy rad, temperature deg C."""

    quaternion: types.array[types.float32, 4] = _zeros(4, 0.0)
    gyroscope: types.array[types.float32, 3] = _zeros(3, 0.0)
    accelerometer: types.array[types.float32, 3] = _zeros(3, 0.0)
    rpy: types.array[types.float32, 3] = _zeros(3, 0.0)
    temperature: types.byte = 0


@_unitree_struct
class BmsCmd_(IdlStruct, typename="unitree_go.msg.dds_.BmsCmd_"):  # noqa: N801
    """Battery command (``off = 0xA5`` switches the battery off)."""

    off: types.byte = 0
    reserve: types.array[types.byte, 3] = _zeros(3)


@_unitree_struct
class BmsState_(IdlStruct, typename="unitree_go.msg.dds_.BmsState_"):  # noqa: N801
    """Battery state (current in mA, cell voltages in mV, as Unitree reports them)."""

    version_high: types.byte = 0
    version_low: types.byte = 0
    status: types.byte = 0
    soc: types.byte = 0
    current: types.int32 = 0
    cycle: types.uint16 = 0
    bq_ntc: types.array[types.byte, 2] = _zeros(2)
    mcu_ntc: types.array[types.byte, 2] = _zeros(2)
    cell_vol: types.array[types.uint16, 15] = _zeros(15)


@_unitree_struct
class LowCmd_(IdlStruct, typename="unitree_go.msg.dds_.LowCmd_"):  # noqa: N801
    """The low-level command on ``rt/lowcmd``: 20 motor slots, battery, LEDs, fans, CRC."""

    head: types.array[types.byte, 2] = _zeros(2)
    level_flag: types.byte = 0
    frame_reserve: types.byte = 0
    sn: types.array[types.uint32, 2] = _zeros(2)
    version: types.array[types.uint32, 2] = _zeros(2)
    bandwidth: types.uint16 = 0
    motor_cmd: types.array[MotorCmd_, 20] = field(default_factory=lambda: [MotorCmd_() for _ in range(20)])
    bms_cmd: BmsCmd_ = field(default_factory=BmsCmd_)
    wireless_remote: types.array[types.byte, 40] = _zeros(40)
    led: types.array[types.byte, 12] = _zeros(12)
    fan: types.array[types.byte, 2] = _zeros(2)
    gpio: types.byte = 0
    reserve: types.uint32 = 0
    crc: types.uint32 = 0


@_unitree_struct
class LowState_(IdlStruct, typename="unitree_go.msg.dds_.LowState_"):  # noqa: N801
    """The low-level state on ``rt/lowstate``: IMU, 20 motor states, battery, foot forces, tick, CRC."""

    head: types.array[types.byte, 2] = _zeros(2)
    level_flag: types.byte = 0
    frame_reserve: types.byte = 0
    sn: types.array[types.uint32, 2] = _zeros(2)
    version: types.array[types.uint32, 2] = _zeros(2)
    bandwidth: types.uint16 = 0
    imu_state: IMUState_ = field(default_factory=IMUState_)
    motor_state: types.array[MotorState_, 20] = field(
        default_factory=lambda: [MotorState_() for _ in range(20)]
    )
    bms_state: BmsState_ = field(default_factory=BmsState_)
    foot_force: types.array[types.int16, 4] = _zeros(4)
    foot_force_est: types.array[types.int16, 4] = _zeros(4)
    tick: types.uint32 = 0
    wireless_remote: types.array[types.byte, 40] = _zeros(40)
    bit_flag: types.byte = 0
    adc_reel: types.float32 = 0.0
    temperature_ntc1: types.byte = 0
    temperature_ntc2: types.byte = 0
    power_v: types.float32 = 0.0
    power_a: types.float32 = 0.0
    fan_frequency: types.array[types.uint16, 4] = _zeros(4)
    reserve: types.uint32 = 0
    crc: types.uint32 = 0


# The C struct layout, derived from the IDL classes above so that the two cannot drift apart
# (wbmpc.runtime.cdr); the fast CDR codecs are installed on LowCmd_ and LowState_ below.

# DataWriter.write / DataReader.take of these two types now use the fixed-layout codecs (about 20 times
# faster than cyclonedds's generic serializer); their numpy records skip Python objects altogether.
LOW_CMD_CDR = cdr.install(LowCmd_)
LOW_STATE_CDR = cdr.install(LowState_)
LOW_CMD_DTYPE = LOW_CMD_CDR.dtype  # = struct_dtype(LowCmd_)
LOW_STATE_DTYPE = LOW_STATE_CDR.dtype
LOW_CMD_SIZE = LOW_CMD_DTYPE.itemsize  # 812 bytes
LOW_STATE_SIZE = LOW_STATE_DTYPE.itemsize  # 1180 bytes


def pack_low_cmd(msg: LowCmd_) -> bytes:
    """The ``LowCmd_`` as the 812 bytes of the SDK's C++ struct (little endian, zero padding)."""
    return LOW_CMD_CDR.pack(msg)  # pad bytes are zero, as in the SDK's value-initialised structs


def pack_low_state(msg: LowState_) -> bytes:
    """The ``LowState_`` as the 1180 bytes of the SDK's C++ struct (little endian, zero padding)."""
    return LOW_STATE_CDR.pack(msg)


# CRC

_BIT_REVERSED = bytes(int(f"{b:08b}"[::-1], 2) for b in range(256))  # for bytes.translate


def crc32_mpeg2(words: np.ndarray) -> int:
    """Unitree's ``crc32_core`` over 32-bit words: CRC-32/MPEG-2 of the words' big-endian bytes.

    CRC-32/MPEG-2 is poly 0x04C11DB7, init 0xFFFFFFFF, MSB first, no reflection, no final xor. zlib's
    CRC-32 is the same polynomial run LSB first (reflected) with init and final xor 0xFFFFFFFF, so feeding
    it every byte bit-reversed and bit-reversing its un-xored result gives the MSB-first CRC; zlib's
    table-driven C loop then does the work (about 6 us for the 202 words of a ``LowCmd_``).

    Args:
        words: the 32-bit words (anything convertible to uint32; flattened in C order).

    Returns:
        The CRC as a Python int in [0, 2**32).
    """
    big_endian = np.ascontiguousarray(words, dtype=">u4").tobytes()
    reflected = zlib.crc32(big_endian.translate(_BIT_REVERSED)) ^ 0xFFFFFFFF
    return int(f"{reflected:032b}"[::-1], 2)


def _is_record(dtype: np.dtype) -> bool:
    # identity first: comparing structured dtypes costs microseconds
    return dtype is LOW_CMD_DTYPE or dtype is LOW_STATE_DTYPE or dtype in (LOW_CMD_DTYPE, LOW_STATE_DTYPE)


def _words(msg) -> np.ndarray:
    if isinstance(msg, np.ndarray) and msg.size == 1 and _is_record(msg.dtype):
        return np.frombuffer(msg, "<u4")[:-1]  # a C-layout record: its memory is the struct
    if isinstance(msg, LowCmd_):
        raw = pack_low_cmd(msg)
    elif isinstance(msg, LowState_):
        raw = pack_low_state(msg)
    else:
        raise TypeError(f"expected a LowCmd_ or LowState_ (or its C-layout record), got {type(msg).__name__}")
    return np.frombuffer(raw, dtype="<u4")[:-1]  # every word but the last, the crc field


def low_cmd_crc(msg) -> int:
    """The CRC the robot expects in ``msg.crc`` (a ``LowCmd_``; a ``LowState_`` is checked the same way).

    ``msg`` may also be a C-layout record (a 0-d array of :data:`LOW_CMD_DTYPE` or :data:`LOW_STATE_DTYPE`,
    as :meth:`~wbmpc.runtime.cdr.FixedCdr.decode` returns): then no packing is needed (about 6 us).
    """
    return crc32_mpeg2(_words(msg))


def stamp_crc(msg):
    """Set ``msg.crc`` (a record's ``"crc"`` field) to the message's CRC (call last, after every other
    field); returns ``msg``."""
    if isinstance(msg, np.ndarray):
        msg["crc"] = low_cmd_crc(msg)
    else:
        msg.crc = low_cmd_crc(msg)
    return msg


def crc_ok(msg) -> bool:
    """Whether ``msg.crc`` (a record's ``"crc"`` field) matches the rest of the message."""
    crc = int(msg["crc"]) if isinstance(msg, np.ndarray) else msg.crc
    return crc == low_cmd_crc(msg)


# Construction and numpy converters


def new_low_cmd() -> LowCmd_:
    """A ``LowCmd_`` with the header the SDK's low-level examples set (head 0xFE 0xEF, level_flag 0xFF,
    gpio 0) and every motor slot zero: mode 0 (off), no target, no gains, no torque. CRC not stamped."""
    msg = LowCmd_()
    msg.head = list(HEAD)
    msg.level_flag = LEVEL_FLAG_LOW
    msg.gpio = 0
    return msg


def new_low_state() -> LowState_:
    """A ``LowState_`` with head 0xFE 0xEF, level_flag 0xFF, every motor slot zero and the identity
    quaternion (w=1) so that a zeroed state is still a valid attitude. CRC not stamped."""
    msg = LowState_()
    msg.head = list(HEAD)
    msg.level_flag = LEVEL_FLAG_LOW
    msg.imu_state.quaternion = [1.0, 0.0, 0.0, 0.0]
    return msg


def _check_slots(slots, n_values: dict) -> np.ndarray:
    slots = np.asarray(slots)
    if slots.ndim != 1 or not np.issubdtype(slots.dtype, np.integer):
        raise ValueError(f"slots must be a 1-D integer array, got shape {slots.shape} dtype {slots.dtype}")
    if slots.size and (slots.min() < 0 or slots.max() >= NUM_MOTORS):
        raise ValueError(f"slots must lie in 0..{NUM_MOTORS - 1}, got {slots.tolist()}")
    if np.unique(slots).size != slots.size:
        raise ValueError(f"slots must be distinct, got {slots.tolist()}")
    for name, n in n_values.items():
        if n != slots.size:
            raise ValueError(f"{name} has {n} values for {slots.size} slots")
    return slots


def write_motor_commands(msg: LowCmd_, slots, q, dq, tau, kp, kd, mode: int = MOTOR_MODE_SERVO) -> LowCmd_:
    """Write joint commands into the motor slots ``slots`` of ``msg`` (other slots untouched).

    Values are rounded to float32 as stored, so the message holds exactly what goes on the wire.

    Args:
        msg: the command to fill.
        slots: (n,) distinct motor slots in 0..19, ``slots[i]`` being joint i's slot.
        q: (n,) target positions [rad].
        dq: (n,) target velocities [rad/s].
        tau: (n,) feed-forward torques [N m].
        kp: (n,) position gains [N m/rad].
        kd: (n,) velocity gains [N m s/rad].
        mode: motor mode written to every slot in ``slots`` (0x01 servo).

    Returns:
        ``msg`` (CRC not stamped: call :func:`stamp_crc` after the last change).
    """
    names = ("q", "dq", "tau", "kp", "kd")
    columns = [np.asarray(v, dtype=np.float32).reshape(-1).tolist() for v in (q, dq, tau, kp, kd)]
    slots = _check_slots(slots, dict(zip(names, map(len, columns), strict=True)))
    for slot, *values in zip(slots.tolist(), *columns, strict=True):
        motor = msg.motor_cmd[slot]
        motor.mode = mode
        motor.q, motor.dq, motor.tau, motor.kp, motor.kd = values
    return msg


def read_motor_states(msg: LowState_, slots) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Joint positions [rad], velocities [rad/s] and estimated torques [N m] from the motor ``slots``."""
    states = [msg.motor_state[s] for s in _check_slots(slots, {}).tolist()]
    return tuple(np.array([getattr(m, name) for m in states], dtype=float) for name in ("q", "dq", "tau_est"))


def read_imu(msg: LowState_) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The IMU: quaternion (4,) w-x-y-z, gyroscope (3,) [rad/s], accelerometer (3,) [m/s^2]."""
    imu = msg.imu_state
    return tuple(np.array(v, dtype=float) for v in (imu.quaternion, imu.gyroscope, imu.accelerometer))
