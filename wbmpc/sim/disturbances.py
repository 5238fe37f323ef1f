"""Disturbances of a closed-loop run: base velocity kicks and pushes on the base or the end effector."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


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
        dv = np.asarray(self.delta_v, dtype=float)
        if dv.shape not in ((3,), (6,)) or not np.all(np.isfinite(dv)):
            raise ValueError(f"Kick.delta_v must be 3 or 6 finite numbers [m/s, rad/s], got {self.delta_v!r}")


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
        if self.target not in ("base", "ee"):
            raise ValueError(f"Push.target must be 'base' or 'ee', got {self.target!r}")
        f = np.asarray(self.force, dtype=float)
        sizes = ((3,), (6,)) if self.target == "base" else ((3,),)
        if f.shape not in sizes or not np.all(np.isfinite(f)):
            raise ValueError(
                f"Push.force must be {' or '.join(str(s[0]) for s in sizes)} finite numbers [N], "
                f"got {self.force!r}"
            )
        if not self.duration > 0:
            raise ValueError(f"Push.duration must be > 0 [s], got {self.duration}")

    def active(self, t: float) -> bool:
        return self.start <= t < self.start + self.duration

    def wrench(self) -> np.ndarray:
        f = np.asarray(self.force, dtype=float)
        return f if f.size == 6 else np.concatenate([f, np.zeros(3)])


Disturbance = Kick | Push
