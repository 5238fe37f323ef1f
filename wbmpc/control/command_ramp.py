"""Acceleration-limited base velocity commands, as a robot's command interface gives them.

A step in the commanded velocity (a gait schedule going from ``stand`` to ``trot@0.5``) asks the MPC for
an instant change the legs cannot deliver: the first solves after it take tens of iterations and push the
torques to their limits. :class:`CommandRamp` moves the commanded base velocity towards its target at no
more than a linear and an angular acceleration.
"""

from __future__ import annotations

import numpy as np

from wbmpc import checks

__all__ = ["CommandRamp"]


class CommandRamp:
    """Rate limiter of the base velocity command (heading frame).

    Args:
        linear: Largest change of the horizontal velocity command per second [m/s^2] (the norm of the
            change of ``(vx, vy)``).
        yaw: Largest change of the yaw-rate command per second [rad/s^2].

    Raises:
        ValueError: a limit that is not a positive finite number.
    """

    def __init__(self, linear: float = 1.0, yaw: float = 1.0):
        self.linear = checks.number("CommandRamp.linear", linear, low=0.0, low_open=True, unit="m/s^2")
        self.yaw = checks.number("CommandRamp.yaw", yaw, low=0.0, low_open=True, unit="rad/s^2")
        self._velocity: np.ndarray | None = None
        self._yaw_rate = 0.0
        self._t: float | None = None

    def __call__(self, t: float, velocity: np.ndarray, yaw_rate: float) -> tuple[np.ndarray, float]:
        """The command at time ``t`` [s] for the target ``velocity`` (3,) [m/s] and ``yaw_rate`` [rad/s];
        the first call passes its target through (the robot starts at that command)."""
        velocity = np.asarray(velocity, dtype=float)
        if self._velocity is None:
            self._velocity, self._yaw_rate, self._t = velocity.copy(), float(yaw_rate), float(t)
            return self._velocity.copy(), self._yaw_rate
        dt = max(0.0, float(t) - self._t)
        self._t = float(t)
        change = velocity[:2] - self._velocity[:2]
        norm = float(np.linalg.norm(change))
        if norm > self.linear * dt:
            change *= self.linear * dt / norm
        self._velocity = np.array([*(self._velocity[:2] + change), velocity[2]])
        self._yaw_rate += float(np.clip(yaw_rate - self._yaw_rate, -self.yaw * dt, self.yaw * dt))
        return self._velocity.copy(), self._yaw_rate
