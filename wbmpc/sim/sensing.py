"""What the controller sees of the simulated robot: ground truth, optional sensor noise, the 50 Hz filter.

The paper's simulation takes the state from the simulator (ground truth) and low-pass filters the joint
velocities at 50 Hz, as on hardware, where the encoders' finite differences are noisy. :class:`StateSensor`
reproduces that: Gaussian noise on the joint positions and velocities (and optionally on the base state),
then a first-order low-pass on the joint velocities,

.. math::  \\hat v_k = \\hat v_{k-1} + \\alpha (v_k - \\hat v_{k-1}), \\qquad
           \\alpha = \\frac{\\Delta t}{\\Delta t + 1 / (2 \\pi f_c)}.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from wbmpc.estimation.filters import LowPassFilter


@dataclass(frozen=True)
class SensorNoise:
    """Standard deviations of white Gaussian measurement noise (0 disables a channel).

    Attributes:
        joint_position: Joint encoder noise [rad].
        joint_velocity: Joint velocity noise [rad/s] (before the filter).
        base_position: Base position noise [m] (state estimator error).
        base_orientation: Base orientation noise [rad], a random rotation vector.
        base_velocity: Base linear [m/s] and angular [rad/s] velocity noise.
        seed: Seed of the noise generator (runs are reproducible).
    """

    joint_position: float = 0.0
    joint_velocity: float = 0.0
    base_position: float = 0.0
    base_orientation: float = 0.0
    base_velocity: float = 0.0
    seed: int = 0

    def __post_init__(self):
        for name in (
            "joint_position",
            "joint_velocity",
            "base_position",
            "base_orientation",
            "base_velocity",
        ):
            value = getattr(self, name)
            if (
                isinstance(value, bool)
                or not isinstance(value, numbers.Real)
                or not np.isfinite(value)
                or value < 0
            ):
                raise ValueError(
                    f"SensorNoise.{name} must be a finite standard deviation >= 0, got {value!r}"
                )
        if isinstance(self.seed, bool) or not isinstance(self.seed, numbers.Integral) or self.seed < 0:
            raise ValueError(f"SensorNoise.seed must be an integer >= 0, got {self.seed!r}")


class StateSensor:
    """Turns the true state into the measured one: noise, then the joint-velocity low-pass.

    Args:
        model: Pinocchio model (for the configuration manifold).
        dt: Sampling period [s] (the low-level rate, 500 Hz in the paper).
        noise: Measurement noise; ``None`` is ground truth.
        velocity_cutoff_hz: Joint-velocity filter cut-off [Hz] (paper: 50); ``None`` disables it.
    """

    def __init__(
        self,
        model: pin.Model,
        dt: float,
        noise: SensorNoise | None = None,
        velocity_cutoff_hz: float | None = None,
    ):
        self.model = model
        self.noise = noise or SensorNoise()
        self.filter = LowPassFilter(velocity_cutoff_hz, dt)
        self._rng = np.random.default_rng(self.noise.seed)

    @property
    def is_ground_truth(self) -> bool:
        n = self.noise
        noiseless = not any(
            (n.joint_position, n.joint_velocity, n.base_position, n.base_orientation, n.base_velocity)
        )
        return noiseless and self.filter.alpha == 1.0

    def measure(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Measured ``(q, v)`` from the true state (copies; the inputs are not modified)."""
        if self.is_ground_truth:
            return q.copy(), v.copy()
        n, rng = self.noise, self._rng
        q, v = q.copy(), v.copy()
        if n.base_position or n.base_orientation:
            dq = np.zeros(self.model.nv)
            dq[0:3] = n.base_position * rng.standard_normal(3)
            dq[3:6] = n.base_orientation * rng.standard_normal(3)
            q = pin.integrate(self.model, q, dq)
        q[7:] += n.joint_position * rng.standard_normal(q.size - 7)
        v[0:6] += n.base_velocity * rng.standard_normal(6)
        v[6:] += n.joint_velocity * rng.standard_normal(v.size - 6)
        v[6:] = self.filter(v[6:])
        return q, v

    def reset(self) -> None:
        self.filter.reset()
        self._rng = np.random.default_rng(self.noise.seed)
