"""Signal helpers of the identification: Savitzky-Golay smoothing of evenly spaced samples, erosion and
dilation of boolean sample masks."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["dilate", "erode", "savgol"]


def savgol(y: np.ndarray, half: int, derivative: int, dt: float, order: int = 3) -> np.ndarray:
    """Savitzky-Golay smoothing (``derivative=0``) or derivative (``1``) along axis 0 of evenly spaced
    samples ``y`` (T, ...), with a polynomial of ``order`` over ``2 half + 1`` samples; the ``half``
    samples at each end are NaN.

    Args:
        y: Samples (T, ...); half: half width [samples] (>= 1, ``2 half + 1 > order``); dt: period [s].

    Raises:
        ValueError: for a window too short for the order or a derivative above it.
    """
    if half < 1 or 2 * half + 1 <= order or not 0 <= derivative <= order:
        raise ValueError(f"Savitzky-Golay needs 2 half + 1 > order >= derivative, got {half=}, {order=}")
    x = np.arange(-half, half + 1) * float(dt)
    coefficients = np.linalg.pinv(np.vander(x, order + 1, increasing=True))[derivative]
    coefficients *= math.factorial(derivative)
    y = np.asarray(y, dtype=float)
    out = np.full(y.shape, np.nan)
    if y.shape[0] > 2 * half:
        windows = np.lib.stride_tricks.sliding_window_view(y, 2 * half + 1, axis=0)  # (T - 2h, ..., 2h+1)
        out[half:-half] = windows @ coefficients
    return out


def erode(mask: np.ndarray, steps: int) -> np.ndarray:
    """``mask`` (T,) True only where it is True ``steps`` samples on both sides too (False at the ends)."""
    out = mask.copy()
    for s in range(1, steps + 1):
        out[s:] &= mask[:-s]
        out[:-s] &= mask[s:]
        out[:s] = False
        out[-s:] = False
    return out


def dilate(mask: np.ndarray, steps: int) -> np.ndarray:
    """``mask`` (T,) True wherever it is True within ``steps`` samples."""
    out = mask.copy()
    for s in range(1, steps + 1):
        out[s:] |= mask[:-s]
        out[:-s] |= mask[s:]
    return out
