"""Closed-loop presets: configurations of :func:`~wbmpc.sim.closed_loop.run_closed_loop` for a purpose.

``hardware_config()`` is the emulated robot (:class:`~wbmpc.sim.hardware.HardwareProfile`) with the
controller a Unitree robot runs: the joint PD law in the motor drives, the measured computation delay,
compensated, and a ramped velocity command, e.g. ``run_closed_loop(mpc, hardware_config(duration=10.0))``.
"""

from __future__ import annotations

from dataclasses import replace

from wbmpc.control.command_schedule import CommandSchedule
from wbmpc.sim.hardware import HardwareProfile
from wbmpc.sim.loop_config import ClosedLoopConfig, LowLevelConfig, PlantConfig, SensingConfig

__all__ = ["HARDWARE_COMMAND_RAMP", "HARDWARE_LOW_LEVEL", "hardware_config"]

#: The hardware low level: a damping-only leg PD (pure feed-forward oscillated on hardware; Kd ~20 damps it)
#: and a small arm stiffness, evaluated by the motor drives at every plant step on the encoders.
HARDWARE_LOW_LEVEL = LowLevelConfig(kp=0.0, kd=20.0, arm_gains=(5.0, 1.0), joint_pd="drive")
#: Acceleration limits of the velocity commands on the robot: (linear [m/s^2], yaw [rad/s^2]).
HARDWARE_COMMAND_RAMP = (0.3, 0.5)


def hardware_config(
    profile: HardwareProfile | None = None,
    *,
    commands: CommandSchedule | None = None,
    state: str = "estimated",
    delay: str | float = "measured",
    velocity_cutoff_hz: float | None = 50.0,
    low_level: LowLevelConfig = HARDWARE_LOW_LEVEL,
    **loop,
) -> ClosedLoopConfig:
    """The "hardware" preset: a PyBullet closed loop on the emulated robot with a robot's controller.

    Args:
        profile: The emulated robot (default: :class:`HardwareProfile` with its documented values).
        commands: The command schedule; default: :class:`CommandSchedule`'s with the velocity ramp
            :data:`HARDWARE_COMMAND_RAMP`. A schedule given here gets the ramp unless it sets its own.
        state: ``"estimated"`` (the state estimator on the profile's IMU and encoders) or
            ``"ground_truth"``.
        delay: Computation delay: ``"measured"`` (each solve call's wall time), ``"off"`` or seconds; it is
            compensated (``delay_compensation``).
        velocity_cutoff_hz: Joint-velocity low-pass [Hz] of the controller's state.
        low_level: The joint level (default :data:`HARDWARE_LOW_LEVEL`).
        **loop: Any other :class:`~wbmpc.sim.loop_config.ClosedLoopConfig` field (``duration``,
            ``disturbances``, ``mpc_rate``, ...).

    Returns:
        A :class:`~wbmpc.sim.loop_config.ClosedLoopConfig`.
    """
    profile = profile or HardwareProfile()
    commands = commands or CommandSchedule()
    if commands.ramp is None:
        commands = replace(commands, ramp=HARDWARE_COMMAND_RAMP)
    preset = {
        "commands": commands,
        "plant": PlantConfig(kind="pybullet", hardware=profile),
        "low_level": low_level,
        "sensing": SensingConfig(state=state, velocity_cutoff_hz=velocity_cutoff_hz),
        "delay": delay,
        "delay_compensation": True,
    }
    return ClosedLoopConfig(**(preset | loop))
