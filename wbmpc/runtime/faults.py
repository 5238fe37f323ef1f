"""Faults injected into a runtime run, each one of the things that go wrong on a robot.

:class:`Faults` says what goes wrong and when (seconds on the run's clock); :class:`FaultyRobot` wraps the
controller's :class:`~wbmpc.runtime.robot.Robot` and does it to the observations: loses them, repeats
them, delivers them out of order, puts NaN in a sensor field. The MPC worker's faults (killed with SIGKILL,
a stalled solver) and the robot's restart are carried out by :func:`wbmpc.runtime.run.run_runtime`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from wbmpc.runtime.robot import MotorCommand, Observation

__all__ = ["FaultyRobot", "Faults"]


@dataclass(frozen=True)
class Faults:
    """What goes wrong in a run (``None``: not this fault). Times [s] on the run's clock.

    Attributes:
        kill_worker_at: The MPC worker is killed (SIGKILL).
        stall_at, stall_for: The solver stalls once for ``stall_for`` seconds.
        lose: ``(start, end)``: every observation in between is lost.
        duplicate_at: From this time on, each observation arrives twice (for 0.1 s).
        reorder_at: Two observations arrive swapped.
        nan_at: One observation carries NaN in a joint velocity.
        restart_robot_at: The emulated robot's process is killed and a new one started.
    """

    kill_worker_at: float | None = None
    stall_at: float | None = None
    stall_for: float = 0.3
    lose: tuple[float, float] | None = None
    duplicate_at: float | None = None
    reorder_at: float | None = None
    nan_at: float | None = None
    restart_robot_at: float | None = None

    def __post_init__(self):
        for name in (
            "kill_worker_at",
            "stall_at",
            "duplicate_at",
            "reorder_at",
            "nan_at",
            "restart_robot_at",
        ):
            value = getattr(self, name)
            if value is not None and not (np.isfinite(value) and value >= 0):
                raise ValueError(f"Faults.{name} must be a time >= 0 [s] or None, got {value!r}")
        if self.lose is not None and not (len(self.lose) == 2 and 0 <= self.lose[0] < self.lose[1]):
            raise ValueError(f"Faults.lose must be (start, end) with 0 <= start < end [s], got {self.lose!r}")
        if not (np.isfinite(self.stall_for) and self.stall_for > 0):
            raise ValueError(f"Faults.stall_for must be > 0 [s], got {self.stall_for!r}")

    @property
    def observation_faults(self) -> bool:
        return any(x is not None for x in (self.lose, self.duplicate_at, self.reorder_at, self.nan_at))


class FaultyRobot:
    """A robot whose observations suffer :class:`Faults` (the commands pass unchanged).

    Args:
        robot: The robot wrapped.
        faults: What goes wrong.
        clock: ``clock() -> t`` [s], the run's clock.

    Attributes:
        injected: Observations lost, duplicated, reordered and poisoned.
    """

    def __init__(self, robot, faults: Faults, clock):
        self.robot, self.faults, self.clock = robot, faults, clock
        self.joint_names = robot.joint_names
        self.injected = {"lost": 0, "duplicated": 0, "reordered": 0, "nan": 0}
        self._repeat: Observation | None = None
        self._held: Observation | None = None
        self._done: set[str] = set()

    def read(self) -> Observation | None:
        f, t = self.faults, self.clock()
        if self._repeat is not None:  # the second copy of a duplicated message
            observation, self._repeat = self._repeat, None
            self.injected["duplicated"] += 1
            return observation
        observation = self.robot.read()
        if observation is None:
            return None
        if f.lose is not None and f.lose[0] <= t < f.lose[1]:
            self.injected["lost"] += 1
            return None
        if f.duplicate_at is not None and f.duplicate_at <= t < f.duplicate_at + 0.1:
            self._repeat = observation
        if f.reorder_at is not None and t >= f.reorder_at and "reorder" not in self._done:
            if self._held is None:  # keep this one back: the next one overtakes it
                self._held = observation
                return None
            self._done.add("reorder")
            self._repeat, observation = self._held, observation  # newer first, then the older
            self.injected["reordered"] += 1
            self.injected["duplicated"] -= 1  # the held message is delivered late, not twice
        if f.nan_at is not None and t >= f.nan_at and "nan" not in self._done:
            self._done.add("nan")
            dq = observation.dq.copy()
            dq[0] = np.nan
            observation = replace(observation, dq=dq)
            self.injected["nan"] += 1
        return observation

    def write(self, command: MotorCommand) -> None:
        self.robot.write(command)

    def close(self) -> None:
        self.robot.close()
