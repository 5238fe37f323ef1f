"""A robot behind DDS: Unitree's low-level topics, the controller's end and the (emulated) robot's end.

The same two ends as the shared-memory wire (:mod:`wbmpc.runtime.wire`): :class:`DdsRobot` is the
controller's (the :class:`~wbmpc.runtime.robot.Robot` protocol), :class:`DdsRobotPort` the robot's
(``publish(observation)``, ``latest_command()``). The legs speak ``rt/lowcmd`` / ``rt/lowstate`` on
Unitree's motor slots (:meth:`JointMap.unitree_legs`: FR 0-2, FL 3-5, RR 6-8, RL 9-11), the arm
``rt/arm_lowcmd`` / ``rt/arm_lowstate`` with the same ``LowCmd_`` / ``LowState_`` layout, its joints on
consecutive slots from 0 in the model's order (:meth:`JointMap.in_order`); see :mod:`wbmpc.runtime.messages`.

Speed. No ``LowCmd_`` / ``LowState_`` object is built on either end: each keeps one C-layout numpy record
per topic (:class:`~wbmpc.runtime.cdr.FixedCdr`), fills or reads its motor fields with fancy indexing,
stamps and checks Unitree's CRC on the record's own memory, and hands DDS the serialized bytes
(:func:`~wbmpc.runtime.dds.write_serialized`, :meth:`~wbmpc.runtime.dds.DdsEndpoint.take_serialized`).
The bytes are those cyclonedds's own serializer makes, so a real robot or any cyclonedds reader sees the
usual types. Measured on the development machine (2 cores, loaded by other work; best / median of 3000
ticks): :meth:`DdsRobot.write` 41 / 76 us for both commands, :meth:`DdsRobot.read` 67 / 124 us for both
states, where the cyclonedds objects alone took about 400 us per message each way.

Reading. The legs' state drives the controller's end: :meth:`DdsRobot.read` returns an observation when
a new leg state was accepted, with the newest arm state accepted so far (which may be older: see
:attr:`DdsRobot.arm_stamp`), and ``None`` until the first arm state. The robot's end likewise returns a
command when either topic brought a new accepted command, once both have. On the robot's end a mapped
slot whose command mode is not servo (0x01) is a motor switched off: no torque, no gains.

Checks, on the controller's end (:meth:`DdsRobot.read`), for every state sample taken, in order: a wrong
CRC is refused (``refused_crc``); a tick equal to the last accepted one is a duplicate (``duplicates``), an
older one is out of order (``out_of_order``), both refused; a tick ahead by more than ``tick_step`` counts
the missing messages as ``lost``. Ticks are compared per writer: a sample from another writer (a restarted
robot, whose tick starts again) restarts the comparison. On the robot's end (:meth:`DdsRobotPort.
latest_command`): a command from a second writer while the first owns the topic is refused
(``refused_second_writer``; the writer is the sample's ``SampleInfo.publication_handle``, the instance
handle of the writer's GUID); ownership passes to another writer only after the owner has been silent for
more than :data:`OWNER_TIMEOUT_S` = 0.5 s (no accepted sample taken from it); a wrong CRC is refused
(``refused_crc``) and never makes its writer the owner. (DDS's own exclusive-ownership QoS would need the
writers' cooperation; this check needs none.)

Commands. Every mapped slot is written in servo mode (``mode`` 0x01), unmapped slots stay zero (mode 0,
off), with the SDK's header (head 0xFE 0xEF, ``level_flag`` 0xFF). The damping command
(:meth:`MotorCommand.damping_mode`) is servo mode too, with kp = 0, dq = 0, tau = 0 and kd > 0, so that
each driver applies ``-kd dq``; mode 0 would switch the motor off, which does not damp. The robot's end
recognises it by those values. As on the shared-memory wire, commands are not checked here: the robot's
side checks each one (:meth:`MotorCommand.problem`), as a motor driver must.
"""

from __future__ import annotations

import math
import time

import numpy as np

from wbmpc.runtime import messages as m
from wbmpc.runtime.dds import DEFAULT_DOMAIN, DdsEndpoint, write_serialized
from wbmpc.runtime.robot import (
    JointMap,
    MotorCommand,
    Observation,
    orientation_from_wire,
    orientation_to_wire,
)

__all__ = ["OWNER_TIMEOUT_S", "DdsRobot", "DdsRobotPort", "split_joints"]

OWNER_TIMEOUT_S = 0.5
DEPTH = 16  # samples a reader keeps between two takes (32 ms at 500 Hz)
_WXYZ_TO_XYZW = np.array([1, 2, 3, 0])


def split_joints(joint_names) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The leg joints (a Unitree leg prefix ``FR_``/``FL_``/``RR_``/``RL_`` and kind ``hip``/``thigh``/
    ``calf`` in the name) and the others (the arm), each in the model's order."""
    legs, arm = [], []
    for name in joint_names:
        try:
            JointMap.unitree_legs([name])
            legs.append(name)
        except ValueError:
            arm.append(name)
    return tuple(legs), tuple(arm)


def _maps(joint_names, leg_map, arm_map, arm_names) -> list[tuple[JointMap, np.ndarray]]:
    """The two maps (defaults: Unitree's leg slots, the arm in order) with each one's model indices."""
    legs = tuple(n for n in joint_names if n not in set(arm_names))
    leg_map = JointMap.unitree_legs(legs) if leg_map is None else leg_map
    arm_map = JointMap.in_order(tuple(arm_names)) if arm_map is None else arm_map
    mapped = leg_map.joint_names + arm_map.joint_names
    if sorted(mapped) != sorted(joint_names) or leg_map.nj == 0:
        raise ValueError(
            f"the leg and arm maps must cover every joint once, the legs at least one: joints "
            f"{list(joint_names)}, legs {list(leg_map.joint_names)}, arm {list(arm_map.joint_names)}"
        )
    if any(slot >= m.NUM_MOTORS for slot in leg_map.slots + arm_map.slots):
        raise ValueError(f"a LowCmd_ has {m.NUM_MOTORS} motor slots: leg map {leg_map}, arm map {arm_map}")
    index = {name: i for i, name in enumerate(joint_names)}
    return [(jm, np.array([index[n] for n in jm.joint_names], dtype=int)) for jm in (leg_map, arm_map)]


class _Channel:
    """One topic of one end: its C-layout record, the model joints' indices and slots in it."""

    def __init__(self, codec, joint_map: JointMap, index: np.ndarray, record: np.ndarray):
        self.codec, self.map, self.index = codec, joint_map, index
        self.slots = np.array(joint_map.slots, dtype=int)
        self.record = record
        # views of the record's fields, made once: making a view of a nested structured array costs
        # about a microsecond, and copying the record through its dtype tens of them
        self.field = _fields(record)
        self.raw = np.frombuffer(record, np.uint8)

    def stamp_crc(self) -> None:
        """Stamp Unitree's CRC on the record."""
        self.field["crc"][...] = m.crc32_mpeg2(self.field["words"])


def _fields(record: np.ndarray) -> dict[str, np.ndarray]:
    """The views of a record: its motors' fields by name (``q``, ``kp``, ``tau_est``, ...), the IMU's
    (``quaternion``, ...), the other top-level fields, and ``words``: the 32-bit words the CRC covers."""
    fields = {name: record[name] for name in record.dtype.names}
    motors = fields.pop("motor_cmd" if "motor_cmd" in fields else "motor_state")
    fields.update({name: motors[name] for name in motors.dtype.names})
    if "imu_state" in fields:
        imu = fields.pop("imu_state")
        fields.update({name: imu[name] for name in ("quaternion", "gyroscope", "accelerometer", "rpy")})
    fields["words"] = np.frombuffer(record, "<u4")[:-1]
    return fields


class _Inbox(_Channel):
    """A reader's side: takes every queued sample, refuses bad ones, keeps the newest accepted one.

    Attributes:
        received, refused_crc, duplicates, out_of_order, lost, refused_second_writer: counters;
        stamp: ``time.monotonic()`` [s] when the newest accepted sample was taken (None before).
    """

    def __init__(self, endpoint, reader, codec, joint_map, index, *, ticks: bool, single_writer: bool):
        super().__init__(codec, joint_map, index, codec.zeros())
        self.endpoint, self.reader = endpoint, reader
        self.ticks, self.single_writer = ticks, single_writer
        self.tick_step = 1
        self._scratch = codec.zeros()
        self._scratch_raw = np.frombuffer(self._scratch, np.uint8)
        self._scratch_words = np.frombuffer(self._scratch, "<u4")
        self._tick_word = self.record.dtype.fields["tick"][1] // 4 if ticks else None
        self._writer = self._tick = None
        self._writer_seen = -np.inf
        self.received = self.refused_crc = self.duplicates = self.out_of_order = 0
        self.lost = self.refused_second_writer = 0
        self.stamp = None

    def take(self) -> bool:
        """Take the queued samples; True if one was accepted (then in :attr:`record`)."""
        accepted = False
        words = self._scratch_words
        for data, info in self.endpoint.take_serialized(self.reader):
            now = time.monotonic()
            self.received += 1
            writer = info.publication_handle
            if self.single_writer and writer != self._writer and now - self._writer_seen <= OWNER_TIMEOUT_S:
                self.refused_second_writer += 1
                continue
            self.codec.decode(data, self._scratch)
            if int(words[-1]) != m.crc32_mpeg2(words[:-1]):  # the crc is the last word
                self.refused_crc += 1
                continue
            if self.ticks and not self._tick_ok(int(words[self._tick_word]), writer):
                continue
            self._writer, self._writer_seen, self.stamp = writer, now, now
            self.raw[:] = self._scratch_raw
            accepted = True
        return accepted

    def _tick_ok(self, tick: int, writer: int) -> bool:
        if writer == self._writer and self._tick is not None:
            ahead = (tick - self._tick + 2**31) % 2**32 - 2**31  # uint32 ticks wrap
            if ahead == 0:
                self.duplicates += 1
                return False
            if ahead < 0:
                self.out_of_order += 1
                return False
            self.lost += max(ahead // self.tick_step - 1, 0)
        self._tick = tick
        return True


def _total(name: str) -> property:
    """A counter of the end: the sum of its topics' (legs and arm)."""
    return property(lambda self: sum(getattr(inbox, name) for inbox in self._inboxes), doc=f"Total {name}.")


class _End:
    """What the two ends share: one DDS participant, its channels, matching and closing."""

    received = _total("received")
    refused_crc = _total("refused_crc")

    _OUT = _IN = (None, ())  # (codec, (leg topic, arm topic)) of what the end writes and reads

    def _open(self, domain: int, interface: str, joint_names, maps) -> None:
        """The participant, then per map (legs, arm) a writer on its ``_OUT`` topic and a reader on its
        ``_IN`` topic."""
        (out_codec, out_topics), (in_codec, in_topics) = self._OUT, self._IN
        self.joint_names = tuple(joint_names)
        self.endpoint = DdsEndpoint(domain, interface)
        self._outboxes, self._inboxes, self._writers = [], [], []
        try:
            for (joint_map, index), out_topic, in_topic in zip(maps, out_topics, in_topics, strict=True):
                if joint_map.nj == 0:
                    continue  # a robot without an arm has no arm topics
                record = self._new_record(out_codec)
                self._outboxes.append(_Channel(out_codec, joint_map, index, record))
                self._writers.append(self.endpoint.writer(out_topic, out_codec.data_type))
                reader = self.endpoint.reader(in_topic, in_codec.data_type, depth=DEPTH)
                self._inboxes.append(self._new_inbox(reader, in_codec, joint_map, index))
        except Exception:
            self.endpoint.close()
            raise

    def wait_for_match(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` [s] until every writer matched a reader and every reader a writer."""
        deadline = time.monotonic() + timeout_s
        for entity in self._writers + [inbox.reader for inbox in self._inboxes]:
            if not self.endpoint.wait_for_match(entity, max(deadline - time.monotonic(), 0.0)):
                return False
        return True

    def _send(self) -> None:
        for channel, writer in zip(self._outboxes, self._writers, strict=True):
            channel.stamp_crc()
            write_serialized(writer, channel.codec.encode(channel.record))

    def close(self) -> None:
        """Delete the DDS participant with its writers and readers (idempotent)."""
        self.endpoint.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class DdsRobot(_End):
    """The controller's end of the DDS wire (:class:`~wbmpc.runtime.robot.Robot`).

    Args:
        robot: The robot model (``joint_names``, ``arm_joint_names``).
        domain: DDS domain id (default 42, wbmpc's own; a real Unitree robot is 0).
        interface: Network interface (default ``"lo"``; the robot's Ethernet for a real robot).
        leg_map: The leg joints' slots on ``rt/lowcmd``/``rt/lowstate`` (default
            ``JointMap.unitree_legs`` of the joints not in ``arm_joint_names``).
        arm_map: The arm joints' slots on ``rt/arm_lowcmd``/``rt/arm_lowstate`` (default
            ``JointMap.in_order(arm_joint_names)``).
        tick_step: Ticks the robot's ``tick`` advances per state message (1 for :class:`DdsRobotPort`; a
            robot whose 1 kHz tick is published at 500 Hz would need 2, else every message counts a loss).

    Attributes:
        joint_names: The model joints (model order); endpoint: the :class:`~wbmpc.runtime.dds.DdsEndpoint`.
        received, refused_crc, duplicates, out_of_order, lost: Counters of state samples over both topics
            (received: every sample taken, refused ones included; lost: messages missing in tick gaps).
        arm_stamp: ``time.monotonic()`` [s] when the arm state in the last observation was taken.

    Raises:
        ValueError: maps that do not cover every joint exactly once (or no leg joint), a slot beyond the
            20 of a ``LowCmd_``, ``tick_step`` < 1; a bad domain or interface.
    """

    _OUT = (m.LOW_CMD_CDR, (m.LEG_CMD_TOPIC, m.ARM_CMD_TOPIC))
    _IN = (m.LOW_STATE_CDR, (m.LEG_STATE_TOPIC, m.ARM_STATE_TOPIC))
    duplicates = _total("duplicates")
    out_of_order = _total("out_of_order")
    lost = _total("lost")

    def __init__(
        self,
        robot,
        domain: int = DEFAULT_DOMAIN,
        interface: str = "lo",
        leg_map=None,
        arm_map=None,
        *,
        tick_step: int = 1,
    ):
        maps = _maps(robot.joint_names, leg_map, arm_map, getattr(robot, "arm_joint_names", ()))
        if int(tick_step) < 1:
            raise ValueError(f"tick_step must be >= 1, got {tick_step}")
        self._tick_step = int(tick_step)
        self._open(domain, interface, robot.joint_names, maps)
        self.arm_stamp = None

    @property
    def seq_step(self) -> int:
        """How much an observation's ``seq`` (the leg state's tick) advances per state message."""
        return self._tick_step

    @staticmethod
    def _new_record(codec):
        record = codec.zeros()
        record["head"], record["level_flag"] = m.HEAD, m.LEVEL_FLAG_LOW
        return record

    def _new_inbox(self, reader, codec, joint_map, index):
        inbox = _Inbox(self.endpoint, reader, codec, joint_map, index, ticks=True, single_writer=False)
        inbox.tick_step = self._tick_step
        return inbox

    def read(self) -> Observation | None:
        """The newest leg state since the last call with the newest arm state (which may be older; see
        :attr:`arm_stamp`), or ``None``: no new accepted leg state, or no arm state yet.

        The observation's ``stamp`` is ``time.monotonic()`` when the leg state was taken, its ``seq`` the
        leg state's tick, its orientation the IMU's quaternion as ``(x, y, z, w)`` (``None`` for the
        zero quaternion: no orientation output, :data:`~wbmpc.runtime.robot.NO_ORIENTATION`), its
        ``foot_force`` the four wire values [robot units] in Unitree's FR, FL, RR, RL order.
        """
        legs, *arm = self._inboxes
        new = legs.take()
        for inbox in arm:
            inbox.take()
        if not new or any(inbox.stamp is None for inbox in arm):
            return None
        nj = len(self.joint_names)
        q, dq, tau = np.empty(nj), np.empty(nj), np.empty(nj)
        for inbox in self._inboxes:
            field, slots, index = inbox.field, inbox.slots, inbox.index
            q[index] = field["q"][slots]
            dq[index] = field["dq"][slots]
            tau[index] = field["tau_est"][slots]
        field = legs.field
        self.arm_stamp = arm[0].stamp if arm else None
        return Observation(
            stamp=legs.stamp,
            seq=int(field["tick"]),
            q=q,
            dq=dq,
            tau=tau,
            gyro=field["gyroscope"].astype(float),
            accelerometer=field["accelerometer"].astype(float),
            orientation=orientation_from_wire(field["quaternion"][_WXYZ_TO_XYZW]),
            foot_force=field["foot_force"].astype(float),
        )

    def write(self, command: MotorCommand) -> None:
        """Send the command: the leg joints on ``rt/lowcmd``, the arm's on ``rt/arm_lowcmd``, servo mode,
        CRC stamped (values rounded to float32 on the wire)."""
        for channel in self._outboxes:
            field, slots, index = channel.field, channel.slots, channel.index
            field["mode"][slots] = m.MOTOR_MODE_SERVO
            field["q"][slots] = np.asarray(command.q)[index]
            field["dq"][slots] = np.asarray(command.dq)[index]
            field["tau"][slots] = np.asarray(command.tau)[index]
            field["kp"][slots] = np.asarray(command.kp)[index]
            field["kd"][slots] = np.asarray(command.kd)[index]
        self._send()


class DdsRobotPort(_End):
    """The robot's end of the DDS wire: publishes its state, takes the newest command.

    Args:
        domain: DDS domain id (default 42); interface: network interface (default ``"lo"``).
        joint_names: The model joints (default: the default robot's, ``load_b1_z1().joint_names``); the
            leg joints are found by name (:func:`split_joints`), the others are the arm's.
        leg_map, arm_map: The slots (defaults as :class:`DdsRobot`'s).

    Attributes:
        joint_names: The model joints (model order); endpoint: the :class:`~wbmpc.runtime.dds.DdsEndpoint`.
        commands: Commands returned by :meth:`latest_command`.
        received, refused_crc, refused_second_writer: Counters of command samples over both topics.
    """

    _OUT = (m.LOW_STATE_CDR, (m.LEG_STATE_TOPIC, m.ARM_STATE_TOPIC))
    _IN = (m.LOW_CMD_CDR, (m.LEG_CMD_TOPIC, m.ARM_CMD_TOPIC))
    refused_second_writer = _total("refused_second_writer")

    def __init__(
        self,
        domain: int = DEFAULT_DOMAIN,
        interface: str = "lo",
        joint_names=None,
        leg_map=None,
        arm_map=None,
    ):
        if joint_names is None:
            from wbmpc.model.robot import load_b1_z1

            joint_names = load_b1_z1().joint_names
        joint_names = tuple(joint_names)
        arm_names = split_joints(joint_names)[1] if arm_map is None else arm_map.joint_names
        maps = _maps(joint_names, leg_map, arm_map, arm_names)
        self._open(domain, interface, joint_names, maps)
        self.commands = 0

    @staticmethod
    def _new_record(codec):
        record = codec.zeros()
        record["head"], record["level_flag"] = m.HEAD, m.LEVEL_FLAG_LOW
        return record

    def _new_inbox(self, reader, codec, joint_map, index):
        return _Inbox(self.endpoint, reader, codec, joint_map, index, ticks=False, single_writer=True)

    def publish(self, observation: Observation) -> None:
        """Publish the observation on both state topics: tick = ``observation.seq`` (modulo 2^32), the
        IMU (quaternion w-x-y-z, its rpy) and foot forces on the leg topic, CRC stamped."""
        tick = int(observation.seq) % 2**32
        for k, channel in enumerate(self._outboxes):
            field, slots, index = channel.field, channel.slots, channel.index
            field["mode"][slots] = m.MOTOR_MODE_SERVO
            field["q"][slots] = np.asarray(observation.q)[index]
            field["dq"][slots] = np.asarray(observation.dq)[index]
            field["tau_est"][slots] = np.asarray(observation.tau)[index]
            field["tick"][...] = tick
            if k == 0:
                _write_imu(field, observation)
        self._send()

    def latest_command(self) -> MotorCommand | None:
        """The newest command since the last call (legs and arm in model order, each from its topic's
        newest accepted sample), or ``None``: no new accepted sample, or none yet on one of the topics."""
        new = [inbox.take() for inbox in self._inboxes]
        if not any(new) or any(inbox.stamp is None for inbox in self._inboxes):
            return None
        nj = len(self.joint_names)
        values = {name: np.empty(nj) for name in ("q", "dq", "tau", "kp", "kd")}
        for inbox in self._inboxes:
            field, slots, index = inbox.field, inbox.slots, inbox.index
            for name, out in values.items():
                out[index] = field[name][slots]
            off = index[field["mode"][slots] != m.MOTOR_MODE_SERVO]  # any other mode: the motor is off
            if off.size:
                for name in ("tau", "kp", "kd"):
                    values[name][off] = 0.0
        self.commands += 1
        v = values
        damping = not v["kp"].any() and not v["tau"].any() and not v["dq"].any() and bool(np.all(v["kd"] > 0))
        return MotorCommand(v["q"], v["dq"], v["tau"], v["kp"], v["kd"], damping=damping)


def _write_imu(field: dict, observation: Observation) -> None:
    """The IMU (quaternion w-x-y-z, gyroscope, accelerometer, rpy ZYX [rad]) and foot forces of a
    ``LowState_`` (its record's views)."""
    x, y, z, w = (float(v) for v in orientation_to_wire(observation.orientation))
    field["quaternion"][:] = (w, x, y, z)  # zero: the IMU reports no orientation (NO_ORIENTATION)
    field["gyroscope"][:] = observation.gyro
    field["accelerometer"][:] = observation.accelerometer
    field["rpy"][:] = (
        math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y)),
        math.asin(min(max(2 * (w * y - z * x), -1.0), 1.0)),
        math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)),
    )
    if observation.foot_force is not None:
        force = np.clip(np.rint(np.asarray(observation.foot_force, dtype=float)[:4]), -32768, 32767)
        field["foot_force"][: force.size] = force
