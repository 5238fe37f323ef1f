"""Closed-loop presets: configurations of :func:`~wbmpc.sim.closed_loop.run_closed_loop` for a purpose.

``hardware_config()`` is the emulated robot (:class:`~wbmpc.sim.hardware.HardwareProfile`) with the
controller a Unitree robot runs: the joint PD law in the motor drives, the measured computation delay,
compensated, and a ramped velocity command, e.g. ``run_closed_loop(mpc, hardware_config(duration=10.0))``.
"""

from __future__ import annotations

from wbmpc.sim.closed_loop import ClosedLoopConfig
from wbmpc.sim.hardware import HardwareProfile

__all__ = ["hardware_config"]


def hardware_config(profile: HardwareProfile | None = None, **overrides):
    """The "hardware" preset: a PyBullet closed loop on the emulated robot with the profile's controller.

    Args:
        profile: The emulated robot (default: :class:`HardwareProfile` with its documented values).
        **overrides: Any other :class:`~wbmpc.sim.closed_loop.ClosedLoopConfig` field (duration, gait, ...),
            including the preset's own (``kp``, ``kd``, ``arm_gains``, ``delay``, ``state``, ...).

    Returns:
        A :class:`~wbmpc.sim.closed_loop.ClosedLoopConfig`.
    """
    profile = profile or HardwareProfile()
    preset = {
        "plant": "pybullet",
        "hardware": profile,
        "state": profile.state,
        "delay": profile.delay,
        "kp": profile.leg_gains[0],
        "kd": profile.leg_gains[1],
        "arm_gains": tuple(profile.arm_gains),
        "velocity_cutoff_hz": profile.velocity_cutoff_hz,
        "joint_pd": "drive",
        "delay_compensation": True,
        "command_ramp": (0.3, 0.5),
    }
    return ClosedLoopConfig(**(preset | overrides))
