"""What a run asks of the robot over time: base and arm commands, and the gait they walk with.

:class:`CommandSchedule` maps a time ``t`` [s] to the commands of that instant: constant values, the gait
schedule's per-segment velocities (``trot@0.5:4``; a stand segment stands still), then a user function of
time that overrides any of them. The closed loop (:func:`wbmpc.sim.closed_loop.run_closed_loop`) reads it at
every MPC tick and hands the gait to the MPC with the commands (:class:`wbmpc.control.config.Commands`), so
one schedule decides the MPC's stage contacts and the plant's, and the MPC's own configuration is never
edited by the loop.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from wbmpc import checks
from wbmpc.control.arm_task import ArmReference
from wbmpc.ocp.gait import Gait, GaitSchedule

__all__ = ["COMMAND_KEYS", "CommandSchedule"]

#: The commands a schedule gives at each instant (the keys of :meth:`CommandSchedule.at`).
COMMAND_KEYS = ("base_velocity", "base_yaw_rate", "ee_velocity", "ee_force")


@dataclass
class CommandSchedule:
    """Commands as functions of time, gait included.

    Attributes:
        base_velocity: Base linear velocity [m/s], heading frame, of the walking segments; a gait schedule's
            segments may name their own (``trot@0.5:4``, :meth:`GaitSchedule.velocity_at`) and a stand
            segment stands still unless it does.
        base_yaw_rate: Yaw rate [rad/s] of the walking segments (as ``base_velocity``).
        ee_velocity: End-effector velocity [m/s] used when there is no ``arm_reference``, in
            ``ee_velocity_frame``: zero holds the hand still.
        ee_velocity_frame: ``"heading"``: ``ee_velocity`` is relative to the heading frame, which carries the
            hand as the base walks and turns (a hold point moving at ``ee_velocity`` with the loop's
            ``arm_kp`` feedback); ``"world"``: the hand's world velocity held over the horizon (the paper's
            command; zero pins the hand in the world, which a walking base cannot sustain for long).
        ee_force: Force [N] the environment applies on the end effector, world axes.
        arm_reference: End-effector position reference (heading frame), or ``None`` for ``ee_velocity``.
        gait: The gait or :class:`~wbmpc.ocp.gait.GaitSchedule` walked (e.g.
            ``parse_gait_schedule("stand:2,trot:6,stand:2")``); ``None``: the MPC's configured gait.
        overrides: ``f(t) -> dict`` overriding commands over time: keys ``base_velocity``,
            ``base_yaw_rate``, ``ee_velocity``, ``ee_force`` (values as the fields of the same names).
        ramp: ``(linear [m/s^2], yaw [rad/s^2])`` acceleration limits of the base velocity command
            (:class:`wbmpc.control.command_ramp.CommandRamp`), e.g. between a gait schedule's segments;
            ``None``: commands change in steps.

    Raises:
        ValueError: On a vector of the wrong size, a non-finite value, an unknown frame, a gait that is no
            :class:`Gait` or :class:`GaitSchedule`, non-positive ramp limits or ``overrides`` that is not
            callable.
    """

    base_velocity: tuple[float, float, float] = (0.2, 0.0, 0.0)
    base_yaw_rate: float = 0.0
    ee_velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    ee_velocity_frame: str = "heading"
    ee_force: tuple[float, float, float] = (0.0, 0.0, 0.0)
    arm_reference: ArmReference | None = field(default_factory=ArmReference)
    gait: Gait | GaitSchedule | None = None
    overrides: Callable[[float], dict] | None = None
    ramp: tuple[float, float] | None = None

    def __post_init__(self):
        self.check()

    def check(self) -> None:
        """Validate every field (also after fields were changed in place); raises ``ValueError``."""
        name = "CommandSchedule."
        for key in ("base_velocity", "ee_velocity", "ee_force"):
            checks.vector(name + key, getattr(self, key), 3)
        checks.number(name + "base_yaw_rate", self.base_yaw_rate, unit="rad/s")
        checks.command_velocity(name + "base_velocity", linear=self.base_velocity)
        checks.command_velocity(name + "base_yaw_rate", yaw_rate=self.base_yaw_rate)
        checks.command_velocity(name + "ee_velocity", ee_velocity=self.ee_velocity)
        if self.ee_velocity_frame not in ("heading", "world"):
            raise ValueError(
                f"{name}ee_velocity_frame must be 'heading' or 'world', got {self.ee_velocity_frame!r}"
            )
        if self.arm_reference is not None and not isinstance(self.arm_reference, ArmReference):
            raise ValueError(
                f"{name}arm_reference must be an ArmReference or None, got {self.arm_reference!r}"
            )
        if self.gait is not None and not isinstance(self.gait, Gait | GaitSchedule):
            raise ValueError(f"{name}gait must be a Gait or GaitSchedule (wbmpc.ocp.gait), got {self.gait!r}")
        if self.gait is not None:
            checks.gait_velocities(name + "gait", self.gait)
        if self.overrides is not None and not callable(self.overrides):
            raise ValueError(f"{name}overrides must be a function f(t) -> dict, got {self.overrides!r}")
        if self.ramp is not None:
            limits = checks.vector(name + "ramp", self.ramp, 2)
            if np.any(limits <= 0):
                raise ValueError(f"{name}ramp (linear, yaw) limits must be > 0, got {self.ramp!r}")

    def at(self, t: float, gait: Gait | GaitSchedule | None = None) -> dict:
        """The commands at time ``t`` [s]: the constants, the gait schedule's segment velocity, the overrides.

        Args:
            t: Time [s].
            gait: The gait in use (``self.gait`` if set, else the MPC's); its segments' velocities apply.

        Returns:
            ``{"base_velocity": (3,), "base_yaw_rate": float, "ee_velocity": (3,), "ee_force": (3,)}``.

        Raises:
            ValueError: If ``overrides`` returns a key that is not a command.
        """
        cmd = {
            "base_velocity": self.base_velocity,
            "base_yaw_rate": self.base_yaw_rate,
            "ee_velocity": self.ee_velocity,
            "ee_force": self.ee_force,
        }
        gait = self.gait if self.gait is not None else gait
        segment = None if gait is None else gait.velocity_at(t)
        if segment is not None:
            cmd |= {"base_velocity": (segment[0], segment[1], 0.0), "base_yaw_rate": segment[2]}
        if self.overrides is not None:
            override = self.overrides(t) or {}
            unknown = set(override) - set(cmd)
            if unknown:
                raise ValueError(
                    f"CommandSchedule.overrides returned unknown keys {sorted(unknown)}; known: {sorted(cmd)}"
                )
            cmd |= override
        out = {k: np.asarray(v, dtype=float) for k, v in cmd.items()}
        out["base_yaw_rate"] = float(out["base_yaw_rate"])
        if self.overrides is not None:  # the first tick that cannot be planned stops the run, named
            where = f"CommandSchedule.overrides at t = {t:.3f} s"
            checks.command_velocity(where, out["base_velocity"], out["base_yaw_rate"], out["ee_velocity"])
        return out
