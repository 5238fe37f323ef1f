"""Disturbances of a closed-loop run: base velocity kicks and pushes on the base or the end effector."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wbmpc import checks


@dataclass(frozen=True)
class Kick:
    """An impulsive push: the base velocity jumps by ``delta_v`` at ``time``.

    Attributes:
        time: When [s].
        delta_v: World-frame base linear velocity change [m/s] (3,), or linear and angular (6,).
    """

    time: float
    delta_v: tuple[float, ...]

    def __post_init__(self):
        checks.number("Kick.time", self.time, low=0.0, unit="s")
        checks.vector("Kick.delta_v", self.delta_v, (3, 6), unit="m/s, rad/s")


@dataclass(frozen=True)
class Push:
    """A constant force held over ``[start, start + duration)``.

    Attributes:
        start: Start time [s].
        duration: Duration [s].
        force: World force [N] (3,) (for ``target="base"`` also a (6,) wrench, torque [N m] last).
        target: ``"base"`` (at the base origin) or ``"ee"`` (at the end-effector frame origin).
    """

    start: float
    duration: float
    force: tuple[float, ...]
    target: str = "base"

    def __post_init__(self):
        checks.number("Push.start", self.start, low=0.0, unit="s")
        checks.number("Push.duration", self.duration, low=0.0, low_open=True, unit="s")
        if self.target not in ("base", "ee"):
            raise ValueError(f"Push.target must be 'base' or 'ee', got {self.target!r}")
        checks.vector("Push.force", self.force, (3, 6) if self.target == "base" else 3, unit="N")

    def active(self, t: float) -> bool:
        return self.start <= t < self.start + self.duration

    def wrench(self) -> np.ndarray:
        f = np.asarray(self.force, dtype=float)
        return f if f.size == 6 else np.concatenate([f, np.zeros(3)])


Disturbance = Kick | Push
