"""Argument checks shared by the public API: every bad input is refused up front with a ``ValueError``
whose message names the argument, the value given and what is allowed.

Example:
    >>> number("ClosedLoopConfig.kp", -1.0, low=0.0)
    ValueError: ClosedLoopConfig.kp must be a finite number >= 0, got -1.0
"""

from __future__ import annotations

import math
import numbers

import numpy as np


def number(
    name: str,
    value,
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
    unit: str = "",
    finite: bool = True,
) -> float:
    """``value`` as a float, or ``ValueError`` naming ``name`` unless it is a real number in the range.

    Args:
        name: How the user spells the argument (e.g. ``"ClosedLoopConfig.kp"``).
        value: The value given.
        low, high: Bounds (``None``: unbounded); inclusive unless ``low_open`` / ``high_open``.
        unit: Unit shown in the message (e.g. ``"s"``).
        finite: Refuse NaN and inf (NaN is always refused).
    """
    # The message is written only for a refusal: this runs several times in every control tick.
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        x = None
    else:
        x = float(value)
        if (
            math.isnan(x)
            or (finite and math.isinf(x))
            or (low is not None and (x < low or (low_open and x == low)))
            or (high is not None and (x > high or (high_open and x == high)))
        ):
            x = None
    if x is None:
        allowed = _range_text(low, high, low_open, high_open, unit)
        raise ValueError(f"{name} must be a {allowed}, got {value!r}")
    return x


def all_finite(array: np.ndarray) -> bool:
    """Whether every entry of the float array ``array`` is finite.

    One dot product in the common case (per-tick vectors of a few hundred entries): ``x . x`` is finite
    exactly when every entry is, unless it overflows, and then the elementwise test decides (NumPy then
    warns of the overflow: entries beyond about 1e154, no physical reading).
    """
    flat = array.reshape(-1)
    return math.isfinite(flat.dot(flat)) or bool(np.isfinite(flat).all())


def integer(name: str, value, *, low: int | None = None, high: int | None = None) -> int:
    """``value`` as an int, or ``ValueError`` naming ``name`` unless it is an integer (no bool) in range."""
    bounds = []
    if low is not None:
        bounds.append(f">= {low}")
    if high is not None:
        bounds.append(f"<= {high}")
    allowed = "an integer" + (" " + " and ".join(bounds) if bounds else "")
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ValueError(f"{name} must be {allowed}, got {value!r}")
    if (low is not None and value < low) or (high is not None and value > high):
        raise ValueError(f"{name} must be {allowed}, got {value!r}")
    return int(value)


def vector(name: str, value, sizes: int | tuple[int, ...], *, unit: str = "") -> np.ndarray:
    """``value`` as a finite float vector of one of the ``sizes``, or ``ValueError`` naming ``name``."""
    sizes = (sizes,) if isinstance(sizes, int) else tuple(sizes)
    what = " or ".join(str(s) for s in sizes) + f" finite numbers{f' [{unit}]' if unit else ''}"
    if isinstance(value, str | bytes):
        raise ValueError(f"{name} must be {what}, got the string {value!r}")
    try:
        array = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be {what}, got {value!r}") from None
    if array.ndim != 1 or array.size not in sizes:
        raise ValueError(f"{name} must be {what}, got {value!r} (shape {array.shape})")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be {what}, got {value!r} (NaN or inf)")
    return array


def array(name: str, value, shape: int | tuple[int, ...] | None = None) -> np.ndarray:
    """``value`` as a finite float array (a copy) of exactly ``shape``, or ``ValueError`` naming ``name``.

    Args:
        name: How the user spells the argument (e.g. ``"q_hat"``).
        value: The value given.
        shape: The shape (an int ``n`` is ``(n,)``); ``None``: any 1-D shape.
    """
    if type(shape) is int:  # the common case first: this runs on every sensor reading
        shape = (shape,)
    elif isinstance(shape, numbers.Integral):
        shape = (int(shape),)
    elif shape is not None:
        shape = tuple(int(n) for n in shape)
    try:
        out = np.array(value, dtype=float)
    except (TypeError, ValueError):
        text = "a 1-D shape" if shape is None else str(shape)
        raise ValueError(f"{name} must be a numeric array of shape {text}, got {value!r}") from None
    if (shape is None and out.ndim != 1) or (shape is not None and out.shape != shape):
        text = "a 1-D shape" if shape is None else str(shape)
        raise ValueError(f"{name} must have shape {text}, got {out.shape}")
    if not all_finite(out):
        raise ValueError(f"{name} must be finite ({name} contains NaN or inf: {out})")
    return out


def names(name: str, value, *, min_count: int = 0, unique: bool = True) -> tuple[str, ...]:
    """A sequence of strings (not a lone string), or ``ValueError`` naming ``name``."""
    if isinstance(value, str):
        raise ValueError(
            f"{name} must be a list of names, got the string {value!r} (write [{value!r}] for one name)"
        )
    try:
        items = tuple(value)
    except TypeError:
        raise ValueError(f"{name} must be a list of names, got {value!r}") from None
    if bad := [item for item in items if not isinstance(item, str)]:
        raise ValueError(f"{name} must hold names (strings), got {bad!r} in {value!r}")
    if len(items) < min_count:
        raise ValueError(f"{name} must hold at least {min_count} name(s), got {list(items)}")
    if unique and len(set(items)) != len(items):
        repeated = sorted({item for item in items if items.count(item) > 1})
        raise ValueError(f"{name} names {repeated} more than once: {list(items)}")
    return items


def _range_text(low, high, low_open, high_open, unit) -> str:
    unit = f" [{unit}]" if unit else ""
    if low is not None and high is not None:
        left, right = "(" if low_open else "[", ")" if high_open else "]"
        return f"finite number in {left}{low:g}, {high:g}{right}{unit}"
    if low is not None:
        return f"finite number {'>' if low_open else '>='} {low:g}{unit}"
    if high is not None:
        return f"finite number {'<' if high_open else '<='} {high:g}{unit}"
    return f"finite number{unit}"


#: Physical bounds of commands: far beyond any legged robot (the fastest run at about 4-6 m/s and turn at
#: about 5 rad/s); a command above them is a typo or a unit error, refused before any work.
MAX_BASE_SPEED = 10.0  # [m/s]
MAX_YAW_RATE = 10.0  # [rad/s]
MAX_EE_SPEED = 10.0  # [m/s]


def command_velocity(name: str, linear=None, yaw_rate=None, ee_velocity=None) -> None:
    """Refuse a base or end-effector velocity command beyond :data:`MAX_BASE_SPEED`, :data:`MAX_YAW_RATE`,
    :data:`MAX_EE_SPEED` with a ``ValueError`` that names ``name``, the value and the limit."""
    if linear is not None:
        speed = float(np.linalg.norm(np.asarray(linear, dtype=float)))
        if not speed <= MAX_BASE_SPEED:
            raise ValueError(
                f"{name}: base speed {speed:.4g} m/s is beyond the physical limit of {MAX_BASE_SPEED:g} m/s "
                "(no legged robot walks or runs faster; the fastest reach about 4-6 m/s): give a speed "
                f"in m/s under {MAX_BASE_SPEED:g}"
            )
    if yaw_rate is not None and not abs(float(yaw_rate)) <= MAX_YAW_RATE:
        raise ValueError(
            f"{name}: yaw rate {float(yaw_rate):.4g} rad/s is beyond the physical limit of {MAX_YAW_RATE:g} "
            "rad/s: give a yaw rate in rad/s (not deg/s) under that"
        )
    if ee_velocity is not None:
        speed = float(np.max(np.linalg.norm(np.asarray(ee_velocity, dtype=float).reshape(3, -1), axis=0)))
        if not speed <= MAX_EE_SPEED:
            raise ValueError(
                f"{name}: end-effector speed {speed:.4g} m/s is beyond the physical limit of "
                f"{MAX_EE_SPEED:g} m/s: give a speed in m/s under that"
            )


def gait_velocities(name: str, gait) -> None:
    """Refuse a gait schedule whose segment velocities (``trot@1e6:4``) exceed the limits of
    :func:`command_velocity`; the message names the segment."""
    for j, velocity in enumerate(getattr(gait, "velocities", ()) or ()):
        if velocity is not None:
            where = f"{name} segment {j} ({gait.gaits[j].name}@{velocity[0]:g})"
            command_velocity(where, linear=(velocity[0], velocity[1], 0.0), yaw_rate=velocity[2])
