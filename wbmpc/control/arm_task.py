"""Arm end-effector references turned into the MPC's velocity command by position feedback.

The MPC constrains the end-effector *velocity* (world axes). To track a *position* reference the command is

.. math::  v^{cmd} = \\dot p^{ref}(t) + K_p\\,(p^{ref}(t) - p_{ee}),

with the reference expressed in the heading frame of the robot (origin below the base at the ground,
x forward, z up, rotating with the base yaw), so that it travels with the robot while it walks: the command
carries the heading frame's own velocity at the hand, the commanded base velocity plus
:math:`\\omega_z \\times (p_{ee} - p_{base})` for a yaw-rate command.

"Hold the arm still" means still in the heading frame (:meth:`ArmReference.still`): a hand held still in
the world while the base walks anchors the robot until the arm's reach runs out (the MPC's precheck
``ee_world_hold_with_walking_base`` says when).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pinocchio as pin

from wbmpc import checks
from wbmpc.control.mpc import heading


@dataclass
class ArmReference:
    """A smooth reference in the heading frame: ``p(t) = center + amplitude * sin(2 pi t / period + phase)``.

    The default moves the end effector 15 cm down and up around its start position (low and high) with a
    5 cm fore-aft motion. (At 20 cm the Z1 elbow reaches its limit at the low point while the paper's
    weights keep the base level; some solves then hit the iteration cap.)

    Attributes:
        center: Mean position [m] in the heading frame (x forward of the base, z above ground); ``None``
            means the start position of the end effector (see :meth:`centered_at`).
        amplitude: Per-axis amplitude [m].
        period: Period [s] of the motion.
        phase: Per-axis phase [rad].
        ramp: Duration [s] over which the amplitude ramps up from 0 (smooth start).
    """

    center: tuple[float, float, float] | None = None
    amplitude: tuple[float, float, float] = (0.05, 0.0, 0.15)
    period: float = 5.0
    phase: tuple[float, float, float] = (0.0, 0.0, 0.0)
    ramp: float = 1.0

    def __post_init__(self):
        checks.number("ArmReference.period", self.period, low=0.0, low_open=True, unit="s")
        checks.number("ArmReference.ramp", self.ramp, low=0.0, unit="s")
        if self.center is not None:
            checks.vector("ArmReference.center", self.center, 3, unit="m")
        checks.vector("ArmReference.amplitude", self.amplitude, 3, unit="m")
        checks.vector("ArmReference.phase", self.phase, 3, unit="rad")

    @classmethod
    def still(cls, center: tuple[float, float, float] | None = None) -> ArmReference:
        """Hold the end effector still in the heading frame (at ``center``, or where it starts)."""
        return cls(center=center, amplitude=(0.0, 0.0, 0.0), ramp=0.0)

    def centered_at(self, q: np.ndarray, ee_position: np.ndarray) -> ArmReference:
        """This reference with its centre at a world position, expressed in the heading frame of ``q``."""
        R, origin = heading_frame(q)
        return replace(self, center=tuple(R.T @ (np.asarray(ee_position) - origin)))

    def local(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Position [m] and velocity [m/s] of the reference in the heading frame at time ``t``."""
        p, v = self.local_at(np.array([t], dtype=float))
        return p[0], v[0]

    def local_at(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions [m] and velocities [m/s] (n, 3) of the reference in the heading frame at ``times`` (n,)
        (one evaluation for the MPC's node times)."""
        if self.center is None:
            raise ValueError("ArmReference.center is None: call centered_at(q, ee_position) first")
        times = np.asarray(times, dtype=float).reshape(-1, 1)
        w = 2 * np.pi / self.period
        arg = w * times + np.asarray(self.phase)
        amp = np.asarray(self.amplitude)
        s, ds = np.ones_like(times), np.zeros_like(times)
        if self.ramp > 0:
            # Smoothstep ramp s(t) so that the reference starts at rest.
            x = np.minimum(times / self.ramp, 1.0)
            s, ds = 3 * x**2 - 2 * x**3, np.where(x < 1.0, (6 * x - 6 * x**2) / self.ramp, 0.0)
        sin = np.sin(arg)
        p = np.asarray(self.center) + s * amp * sin
        v = s * amp * w * np.cos(arg) + ds * amp * sin
        return p, v


def heading_frame(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (yaw only) and origin (base x, y at z = 0) of the heading frame of configuration ``q``."""
    R = pin.rpy.rpyToMatrix(0.0, 0.0, heading(q))
    return R, np.array([q[0], q[1], 0.0])


def world_reference(reference: ArmReference, q: np.ndarray, t: float) -> np.ndarray:
    """Reference position [m] in the world at time ``t`` for the measured base configuration ``q``."""
    R, origin = heading_frame(q)
    return origin + R @ reference.local(t)[0]


def velocity_command(
    reference: ArmReference,
    q: np.ndarray,
    ee_position: np.ndarray,
    t: float,
    base_velocity_world: np.ndarray,
    kp: float = 4.0,
    node_times: np.ndarray | None = None,
    max_speed: float = 0.6,
    yaw_rate: float = 0.0,
    local_velocity: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """End-effector velocity command [m/s] (world) and the world reference position [m] at ``t``.

    Without ``node_times`` the command is the paper's: one velocity held over the horizon,
    ``v = pdot_ref(t) + Kp e(t)``. With the MPC's node times ``t_k`` it is one command per stage,
    ``v_k = pdot_ref(t_k) + Kp e(t) exp(-Kp (t_k - t))``: the reference's own future velocity plus the
    decaying correction of the current error, so the plan does not overshoot where the reference slows
    down (e.g. at its lowest point, near the arm's joint limits).

    Args:
        reference: The reference in the heading frame.
        q: Measured configuration.
        ee_position: Measured end-effector position [m], world.
        t: Time [s].
        base_velocity_world: Commanded base linear velocity [m/s] in world axes (feed-forward of the
            moving heading frame).
        kp: Position gain [1/s].
        node_times: Times [s] of the MPC stages (N-1,), or ``None`` for a single command.
        max_speed: Norm cap [m/s] on each command (keeps a hard velocity constraint feasible).
        yaw_rate: Commanded yaw rate [rad/s]: the heading frame turns, carrying the hand at
            ``omega_z x (p_ee - p_base)`` (horizontal).
        local_velocity: Extra velocity [m/s] (3,) of the reference in the heading frame (e.g. a moving
            hold point); ``None``: none.

    Returns:
        ``(v, p_ref)``: command (3,) or (3, N-1), and the reference position (3,).
    """
    R, origin = heading_frame(q)
    p_ref = origin + R @ reference.local(t)[0]
    error = p_ref - np.asarray(ee_position)
    lever = np.asarray(ee_position, dtype=float) - np.array([q[0], q[1], 0.0])
    # The heading frame carries the hand: commanded base velocity plus the yaw rate about the base.
    carry = np.array([base_velocity_world[0], base_velocity_world[1], 0.0])
    carry += yaw_rate * np.array([-lever[1], lever[0], 0.0])
    if local_velocity is not None:
        carry = carry + R @ checks.vector("local_velocity", local_velocity, 3, unit="m/s")
    times = np.array([t]) if node_times is None else np.asarray(node_times, dtype=float)
    decay = np.ones(times.size) if node_times is None else np.exp(-kp * (times - t))
    commands = R @ reference.local_at(times)[1].T + carry[:, None] + kp * error[:, None] * decay
    speed = np.sqrt(np.sum(commands * commands, axis=0))
    commands *= np.where(speed > max_speed, max_speed / np.maximum(speed, 1e-300), 1.0)
    return (commands[:, 0] if node_times is None else commands), p_ref
