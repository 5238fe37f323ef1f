"""Signal filters of the estimators and the simulated sensors.

:class:`LowPassFilter` is the first-order low-pass the robots apply to their joint velocities (50 Hz on
Unitree robots, where the encoders' finite differences are noisy),

.. math::  \\hat v_k = \\hat v_{k-1} + \\alpha (v_k - \\hat v_{k-1}), \\qquad
           \\alpha = \\frac{\\Delta t}{\\Delta t + 1 / (2 \\pi f_c)}.
"""

from __future__ import annotations

import numbers

import numpy as np

__all__ = ["LowPassFilter"]


class LowPassFilter:
    """First-order low-pass filter of a vector signal sampled every ``dt``.

    Args:
        cutoff_hz: Cut-off frequency [Hz] (``None`` or ``inf``: no filtering).
        dt: Sampling period [s].
    """

    def __init__(self, cutoff_hz: float | None, dt: float):
        if not isinstance(dt, numbers.Real) or dt <= 0 or not np.isfinite(dt):
            raise ValueError(f"dt must be > 0 [s], got {dt}")
        if cutoff_hz is not None and (not isinstance(cutoff_hz, numbers.Real) or not cutoff_hz > 0):
            raise ValueError(f"cutoff_hz must be > 0 [Hz] or None, got {cutoff_hz}")
        self.alpha = (
            1.0 if cutoff_hz is None or np.isinf(cutoff_hz) else dt / (dt + 1.0 / (2 * np.pi * cutoff_hz))
        )
        self.value: np.ndarray | None = None

    def __call__(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        self.value = x.copy() if self.value is None else self.value + self.alpha * (x - self.value)
        return self.value.copy()

    def reset(self) -> None:
        self.value = None
