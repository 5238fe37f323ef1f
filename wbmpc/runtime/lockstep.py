"""The runtime's controller and robot protocol, stepped in simulated time: deterministic, for tests.

:class:`LockstepLoop` is the simulated loop (:class:`wbmpc.sim.closed_loop.ClosedLoop`: the same schedule,
plant, MPC ticks, plan delays, observers and log) with its controller side replaced by the runtime's: at
every low-level tick the robot (:class:`~wbmpc.runtime.emulated.SimulatedRobot`) is read, the
:class:`~wbmpc.runtime.controller.RuntimeController` estimates and commands, the command is written back,
and the robot's drivers evaluate it at every plant step; plans reach the controller through a
:class:`~wbmpc.runtime.shared.PlanChannel` (shared memory, sequence numbers, epochs) when one is given,
and the readings and commands through the emulated robot's shared-memory wire (:mod:`~wbmpc.runtime.wire`)
when ``wire=True``: what the wall-clock run sends, encoded and decoded the same way.

With ``sensing.state="estimated"`` and ``low_level.joint_pd="drive"`` (the hardware preset
:func:`wbmpc.sim.presets.hardware_config`) and a fixed delay it reproduces :func:`run_closed_loop`
exactly: what it adds is the protocol, not a different controller.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from wbmpc.control.config import MPCSolution
from wbmpc.control.mpc import WholeBodyMPC
from wbmpc.runtime.controller import RuntimeController
from wbmpc.runtime.emulated import SimulatedRobot
from wbmpc.sim.closed_loop import ClosedLoop, ClosedLoopResult
from wbmpc.sim.loop_config import ClosedLoopConfig
from wbmpc.sim.loop_log import ClosedLoopLog
from wbmpc.sim.observers import FailureObserver, LogRecorder, LoopObserver

__all__ = ["LockstepLoop", "run_lockstep"]


class LockstepLoop(ClosedLoop):
    """:class:`ClosedLoop` whose controller is the runtime's, behind the robot protocol.

    Args:
        mpc, config, q0, observers: As :class:`ClosedLoop`; ``config.sensing.state`` must be
            ``"estimated"`` (a robot measures no floating base).
        channel: Optional plan channel the plans go through (``publish`` then ``latest``); ``None``: handed
            over directly.
        wire: Pass every reading and command through a shared-memory :class:`~wbmpc.runtime.wire.Wire`
            (both ends in this process; released by :meth:`close_wire`), as the wall-clock run does.

    Attributes:
        robot_side: The simulated robot (sensors, drivers); controller: the runtime controller.

    Raises:
        ValueError: ``sensing.state`` other than ``"estimated"``.
    """

    def __init__(
        self,
        mpc: WholeBodyMPC,
        config: ClosedLoopConfig,
        q0: np.ndarray | None = None,
        observers: Sequence[LoopObserver] = (),
        channel=None,
        wire: bool = False,
    ):
        if config.sensing.state != "estimated":
            raise ValueError(
                "the runtime estimates the state from the robot's sensors: use "
                f"SensingConfig(state='estimated'), got state={config.sensing.state!r}"
            )
        super().__init__(mpc, config, q0, observers)
        self.controller = RuntimeController(self.robot, config, self.contact_plan)
        self.low = self.controller.low  # the plan in use is the controller's
        hardware = config.plant.hardware
        # With joint_pd="controller" the plant's actuators carry the latency (make_plant), not the drivers.
        latency = None if config.low_level.joint_pd == "drive" else 0.0
        self.robot_side = SimulatedRobot(self.robot, config.plant.dt, self.controller.dt, hardware, latency)
        self.drive = self.robot_side.drive
        self.channel = channel
        self._plan_seq = 0
        self._wire = self._client = self._port = None
        if wire:
            from wbmpc.runtime.wire import SharedMemoryPort, SharedMemoryRobot, Wire

            description, *self._wire = Wire.create(self.robot.nj)
            self._port = SharedMemoryPort(description)
            self._client = SharedMemoryRobot(description, self.robot.joint_names)

    def close_wire(self) -> None:
        """Release the shared-memory wire (if any)."""
        if self._wire is None:
            return
        self._client.close()
        self._port.close()
        for slot in self._wire:
            slot.close()
            slot.unlink()
        self._wire = None

    def _start_sensing(self) -> None:
        self.robot_side.reset(self.state)
        self.controller.reset(self.state.q, self.state.v)
        self.q_meas, self.v_meas = self.controller.q_hat, self.controller.v_hat

    def _deliver(self, plan: MPCSolution) -> None:
        if self.channel is None:
            self.controller.offer(plan)
            return
        self._plan_seq += 1
        self.channel.publish(plan, epoch=0, observation_seq=self._plan_seq, observation_time=plan.t)
        received = self.channel.latest(after_seq=self._plan_seq - 1, epoch=0)
        if received is None:
            raise RuntimeError("the plan channel lost a plan it was just given")
        self.controller.offer(received[0])

    def _drive_torque(self) -> np.ndarray:
        return self.robot_side.torque(self.state)

    def _joint_commands(self) -> None:
        observation = self.robot_side.read(self.state, self.t)
        if self._wire is not None:
            self._port.publish(observation)
            observation = self._client.read()
        command = self.controller.tick(observation, self.t)
        if self._wire is not None:
            self._client.write(command)
            command = self._port.latest_command()
        self.robot_side.write(command)
        self.q_meas, self.v_meas = self.controller.q_hat, self.controller.v_hat
        if self.config.low_level.joint_pd == "controller":
            self.tau = command.tau


def run_lockstep(
    mpc: WholeBodyMPC,
    config: ClosedLoopConfig,
    q0: np.ndarray | None = None,
    channel=None,
    observers: Sequence[LoopObserver] = (),
    wire: bool = False,
) -> ClosedLoopResult:
    """Run :class:`LockstepLoop` to the config's duration or a fall (in memory; no progress bar).

    Args:
        mpc, config, q0, channel, observers, wire: As :class:`LockstepLoop`.

    Returns:
        The log and summary of :func:`wbmpc.sim.closed_loop.run_closed_loop`, plus the controller's
        ``runtime_problems`` and ``runtime_clipped`` counts in the summary.
    """
    config.steps()  # checks the config before anything is built
    log = ClosedLoopLog()
    observers = [LogRecorder(log), FailureObserver(), *observers]
    loop = LockstepLoop(mpc, config, q0, observers, channel, wire)
    try:
        fell = loop.run()
        summary = log.finish(lambda columns: loop.summary(columns, fell))
    finally:
        for observer in observers:
            observer.close()
        loop.plant.close()
        loop.close_wire()
    summary["runtime_problems"] = [reason for _, reason in loop.controller.problems]
    summary["runtime_clipped"] = dict(loop.controller.clipped)
    return ClosedLoopResult(log=log, summary=summary, fell=fell)
