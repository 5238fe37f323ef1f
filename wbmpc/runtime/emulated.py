"""The robot's side of an emulated robot: motor drivers and sensors on a simulated plant.

:class:`SimulatedRobot` is what stands behind the :class:`~wbmpc.runtime.robot.Robot` protocol when the
robot is a simulation: it turns the plant's true state into the readings a Unitree robot publishes on
``rt/lowstate`` (encoders, measured torques, IMU with the hardware profile's noise and biases,
:class:`wbmpc.sim.hardware.SyntheticSensors`) and evaluates each written
:class:`~wbmpc.runtime.robot.MotorCommand` like the motor drivers do, at every plant step on the joint
encoders, after the profile's command latency (:class:`wbmpc.sim.motor_drive.MotorDrive`). The plant itself
is stepped by its owner: the lockstep loop (:mod:`wbmpc.runtime.lockstep`) or the emulated robot's own
process on the wall clock.
"""

from __future__ import annotations

import numpy as np

from wbmpc.runtime.robot import MotorCommand, Observation
from wbmpc.sim.hardware import HardwareProfile, SyntheticSensors
from wbmpc.sim.motor_drive import MotorDrive
from wbmpc.sim.plant import PlantState

__all__ = ["SimulatedRobot"]


class SimulatedRobot:
    """Sensors and motor drivers of a simulated robot.

    Args:
        robot: The robot model (joint names, torque limits).
        plant_dt: The plant's step [s] (the drivers' rate).
        sample_dt: The readings' period [s] (the IMU is synthesised over it).
        hardware: The profile of sensor errors and command latency (``None``: exact, no latency).
        latency: Command latency [s]; default the profile's ``torque_latency``.

    Attributes:
        drive: The motor drivers; sensors: the sensor synthesis; seq: readings taken so far.
        commands_written: Commands received.
    """

    def __init__(
        self,
        robot,
        plant_dt: float,
        sample_dt: float,
        hardware: HardwareProfile | None = None,
        latency: float | None = None,
    ):
        self.joint_names = tuple(robot.joint_names)
        nj = robot.nj
        if latency is None:
            latency = 0.0 if hardware is None else hardware.torque_latency
        zeros = np.zeros(nj)
        self.drive = MotorDrive(zeros, zeros, robot.joint_torque_limits, round(latency / plant_dt))
        self.sensors = SyntheticSensors(sample_dt, hardware)
        self.seq = 0
        self.commands_written = 0
        self._tau = np.zeros(nj)

    def reset(self, state: PlantState) -> None:
        """Start at the plant's state (before the first reading)."""
        self.sensors.reset(state.q, state.v)
        self.seq = 0

    def read(self, state: PlantState, t: float) -> Observation:
        """The readings of the true ``state`` at ``t`` [s] (one sample period after the previous one)."""
        imu, joints = self.sensors.readings(state.q, state.v)
        self.seq += 1
        return Observation(
            stamp=t,
            seq=self.seq,
            q=joints.positions,
            dq=joints.velocities,
            tau=self._tau.copy(),
            gyro=imu.gyro,
            accelerometer=imu.accelerometer,
            orientation=imu.orientation,
        )

    def write(self, command: MotorCommand) -> None:
        """Hand a command to the drivers (effective after the latency)."""
        self.drive.command(command.tau, command.q, command.dq, command.kp, command.kd)
        self.commands_written += 1

    def torque(self, state: PlantState) -> np.ndarray:
        """The drivers' torque (nj,) [N m] at this plant step; advances the drivers one step."""
        self._tau = self.drive.torque(state.q[7:], state.v[6:])
        return self._tau
