"""A robot behind shared memory: the emulated robot's wire when it runs in a process beside the controller.

Two latest-only slots (:class:`~wbmpc.runtime.shared.LatestSlot`): the robot writes its state (the fields
of :class:`~wbmpc.runtime.robot.Observation`), the controller writes its command (those of
:class:`~wbmpc.runtime.robot.MotorCommand`). :class:`SharedMemoryRobot` is the controller's end (the
:class:`~wbmpc.runtime.robot.Robot` protocol), :class:`SharedMemoryPort` the robot's. The command slot does
not refuse NaN: the robot side checks every command itself, as a motor driver must
(:meth:`MotorCommand.problem`). DDS (:mod:`wbmpc.runtime.dds`) is the other wire, with the same ends.
"""

from __future__ import annotations

from dataclasses import dataclass

from wbmpc.runtime.robot import MotorCommand, Observation, orientation_from_wire, orientation_to_wire
from wbmpc.runtime.shared import LatestSlot, SlotDescription

__all__ = ["SharedMemoryPort", "SharedMemoryRobot", "Wire"]


def _state_fields(nj: int) -> dict:
    return {
        "stamp": (),
        "seq": (),
        "q": (nj,),
        "dq": (nj,),
        "tau": (nj,),
        "gyro": (3,),
        "accelerometer": (3,),
        "orientation": (4,),
    }


def _command_fields(nj: int) -> dict:
    return {"q": (nj,), "dq": (nj,), "tau": (nj,), "kp": (nj,), "kd": (nj,), "damping": ()}


@dataclass(frozen=True)
class Wire:
    """The two slots' descriptions (picklable: handed to the robot's process).

    Attributes:
        state, command: The slots' descriptions; nj: joints.
    """

    state: SlotDescription
    command: SlotDescription
    nj: int

    @classmethod
    def create(cls, nj: int) -> tuple[Wire, LatestSlot, LatestSlot]:
        """New slots for ``nj`` joints; returns the wire and the two slots (the creator unlinks them)."""
        state = LatestSlot.create(_state_fields(nj), meta={"wire": "state", "nj": nj})
        command = LatestSlot.create(_command_fields(nj), meta={"wire": "command", "nj": nj})
        return cls(state.description, command.description, nj), state, command


class SharedMemoryRobot:
    """The controller's end of a shared-memory wire (:class:`~wbmpc.runtime.robot.Robot`).

    Args:
        wire: The slots to attach to.
        joint_names: The model joints (model order; the wire carries them in that order).
    """

    def __init__(self, wire: Wire, joint_names):
        self.joint_names = tuple(joint_names)
        if len(self.joint_names) != wire.nj:
            raise ValueError(f"the wire carries {wire.nj} joints, the model has {len(self.joint_names)}")
        self._state = LatestSlot.attach(wire.state)
        self._command = LatestSlot.attach(wire.command)
        self._last = 0

    def read(self) -> Observation | None:
        if self._state.seq <= self._last or (record := self._state.read()) is None:
            return None
        self._last = record.seq
        v = record.values
        return Observation(
            stamp=float(v["stamp"]),
            seq=int(v["seq"]),
            q=v["q"].copy(),
            dq=v["dq"].copy(),
            tau=v["tau"].copy(),
            gyro=v["gyro"].copy(),
            accelerometer=v["accelerometer"].copy(),
            orientation=orientation_from_wire(v["orientation"].copy()),
        )

    def write(self, command: MotorCommand) -> None:
        self._command.write(
            {
                "q": command.q,
                "dq": command.dq,
                "tau": command.tau,
                "kp": command.kp,
                "kd": command.kd,
                "damping": float(command.damping),
            }
        )

    def close(self) -> None:
        self._state.close()
        self._command.close()


class SharedMemoryPort:
    """The robot's end: publishes its state, takes the newest command.

    Attributes:
        commands: Commands taken (the newest of each tick; older ones are skipped).
    """

    def __init__(self, wire: Wire):
        self._state = LatestSlot.attach(wire.state)
        self._command = LatestSlot.attach(wire.command)
        self._last = 0
        self.commands = 0

    def publish(self, observation: Observation) -> None:
        self._state.write(
            {
                "stamp": observation.stamp,
                "seq": float(observation.seq),
                "q": observation.q,
                "dq": observation.dq,
                "tau": observation.tau,
                "gyro": observation.gyro,
                "accelerometer": observation.accelerometer,
                "orientation": orientation_to_wire(observation.orientation),
            }
        )

    def latest_command(self) -> MotorCommand | None:
        """The newest command since the last call, or ``None``."""
        if self._command.seq <= self._last or (record := self._command.read()) is None:
            return None
        self._last = record.seq
        self.commands += 1
        v = record.values
        return MotorCommand(
            v["q"].copy(), v["dq"].copy(), v["tau"].copy(), v["kp"].copy(), v["kd"].copy(), bool(v["damping"])
        )

    def close(self) -> None:
        self._state.close()
        self._command.close()
