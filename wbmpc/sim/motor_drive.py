"""The robot's motor drivers: the joint PD law evaluated at the drive, on the drive's own encoder.

On Unitree's legged robots (the B1/B2 low-level interface, ``rt/lowcmd``) the controller does not send
torques: it sends, per motor, a position and velocity setpoint, a feed-forward torque and the gains, and
the motor driver closes the loop at its own rate on its own encoder,

.. math::  \\tau = \\mathrm{clip}\\big(\\tau_{ff} + k_p (q_{des} - q) + k_d (\\dot q_{des} - \\dot q)\\big).

The communication latency then delays the *setpoints*, never the damping loop, and the controller's
velocity filter is not inside it. :class:`MotorDrive` emulates that: the low level hands it a command at
500 Hz (:meth:`MotorDrive.command`), which takes effect ``latency_steps`` plant steps later and is held
until the next one; :meth:`MotorDrive.torque` evaluates the law at every plant step on the joint state
the plant measures.
"""

from __future__ import annotations

from collections import deque

import numpy as np

__all__ = ["MotorDrive"]


class MotorDrive:
    """Joint PD + feed-forward at the motor driver, with a command latency.

    Args:
        kp: Stiffness [N m/rad], scalar or (nj,).
        kd: Damping [N m s/rad], scalar or (nj,).
        torque_limits: Symmetric motor limits [N m] (nj,) the torque is clipped to.
        latency_steps: Plant steps between a command being sent and the drive using it (>= 0).

    Attributes:
        violations: Plant steps at which the law asked for more than ``torque_limits`` (clipped).
        clipped_steps: Per joint (nj,), the plant steps at which that joint was clipped.

    Raises:
        ValueError: negative or non-finite gains or limits, a negative latency.
    """

    def __init__(self, kp, kd, torque_limits: np.ndarray, latency_steps: int = 0):
        self.kp = np.asarray(kp, dtype=float)
        self.kd = np.asarray(kd, dtype=float)
        self.torque_limits = np.asarray(torque_limits, dtype=float)
        for name, value in (("kp", self.kp), ("kd", self.kd), ("torque_limits", self.torque_limits)):
            if not np.all(np.isfinite(value)) or np.any(value < 0):
                raise ValueError(f"MotorDrive {name} must be finite and >= 0, got {value!r}")
        if int(latency_steps) != latency_steps or latency_steps < 0:
            raise ValueError(f"MotorDrive latency_steps must be an integer >= 0, got {latency_steps!r}")
        self.latency_steps = int(latency_steps)
        self.violations = 0
        self.clipped_steps = np.zeros(self.torque_limits.shape, dtype=int)
        self._queue: deque = deque()
        self._limits = None  # torque_limits of the cached bounds _tolerated, _lower
        self._active = None  # (tau_ff, q_des, v_des, kp, kd) in force
        self._step = 0

    def command(self, tau_ff: np.ndarray, q_des: np.ndarray, v_des: np.ndarray, kp=None, kd=None) -> None:
        """Send a command (nj each; [N m], [rad], [rad/s]); it takes effect ``latency_steps`` steps later.

        ``kp`` [N m/rad] and ``kd`` [N m s/rad] (nj,) replace the drive's gains for this command, as each
        ``rt/lowcmd`` message carries its own (``None``: the gains given at construction).
        """
        kp = self.kp if kp is None else np.array(kp, dtype=float)
        kd = self.kd if kd is None else np.array(kd, dtype=float)
        entry = (self._step + self.latency_steps, np.array(tau_ff), np.array(q_des), np.array(v_des), kp, kd)
        if self._active is None:  # the drive starts on the first command
            self._active = entry[1:]
        self._queue.append(entry)

    def torque(self, q_joint: np.ndarray, v_joint: np.ndarray) -> np.ndarray:
        """Motor torque (nj,) [N m] at this plant step for the measured joint positions and rates; then
        advances one step. Zero before the first command.
        """
        while self._queue and self._queue[0][0] <= self._step:
            self._active = self._queue.popleft()[1:]
        self._step += 1
        if self._active is None:
            return np.zeros_like(self.torque_limits)
        tau_ff, q_des, v_des, kp, kd = self._active
        limits = self.torque_limits
        if limits is not self._limits:  # the bounds and scratch of the checks below, once per set of limits
            self._limits, self._tolerated, self._lower = limits, limits * (1 + 1e-6), -limits
            self._work, self._over = np.empty(limits.shape), np.empty(limits.shape, dtype=bool)
        # tau_ff + kp (q_des - q) + kd (v_des - v), the operations in that order (fewer allocations).
        tau, work = np.subtract(q_des, q_joint, dtype=float), self._work
        np.multiply(kp, tau, out=tau)
        np.add(tau_ff, tau, out=tau)
        np.subtract(v_des, v_joint, out=work)
        tau += np.multiply(kd, work, out=work)
        magnitude = np.abs(tau, out=work)
        if not np.count_nonzero(np.greater(magnitude, limits, out=self._over)):
            return tau  # within the limits: nothing to clip or count (.any() costs more on 16 joints)
        over = np.greater(magnitude, self._tolerated, out=self._over)
        if np.count_nonzero(over):
            self.violations += 1
            self.clipped_steps += over
        np.maximum(tau, self._lower, out=tau)  # np.clip, without its checks
        return np.minimum(tau, limits, out=tau)
