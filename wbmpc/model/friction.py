"""Joint friction of geared motors: a smoothed Coulomb term plus a viscous term, per joint.

.. math::  \\tau_f(\\dot q) = c \\tanh(\\dot q / v_s) + b \\dot q

with ``c`` the Coulomb friction [N m], ``b`` the viscous friction [N m s/rad] and ``v_s`` the joint rate
[rad/s] over which the Coulomb term rises (``tanh`` smoothing; it reaches 76 % of ``c`` at ``v_s``). The
torque opposes the motion: the motor must add ``tau_f`` to move the joint at ``qdot``. This is the model
the emulated robot applies (:mod:`wbmpc.sim.pybullet_plant`), the one
:mod:`wbmpc.estimation.identification` fits to a log and the one the low-level controller's friction
feed-forward (:class:`wbmpc.control.low_level.LowLevelController`) compensates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["JointFriction"]


@dataclass(frozen=True)
class JointFriction:
    """Per-joint friction parameters in the robot's joint order (``q[7:]``, ``v[6:]``).

    Attributes:
        coulomb: Coulomb friction ``c`` [N m] (nj,), >= 0.
        viscous: Viscous friction ``b`` [N m s/rad] (nj,), >= 0.
        velocity: Smoothing joint rate ``v_s`` [rad/s] of the Coulomb term, > 0.

    Raises:
        ValueError: if ``coulomb`` and ``viscous`` are not 1-D arrays of one length with finite values
            >= 0, or ``velocity`` is not a finite number > 0.
    """

    coulomb: np.ndarray
    viscous: np.ndarray
    velocity: float = 0.05

    def __post_init__(self):
        arrays = {}
        for name in ("coulomb", "viscous"):
            try:
                value = np.array(getattr(self, name), dtype=float)
            except (TypeError, ValueError):
                raise ValueError(
                    f"JointFriction.{name} must be numbers [N m, N m s/rad], got {getattr(self, name)!r}"
                ) from None
            if value.ndim != 1 or not np.all(np.isfinite(value)) or np.any(value < 0):
                raise ValueError(
                    f"JointFriction.{name} must be a 1-D array of finite values >= 0, got {value}"
                )
            value.setflags(write=False)
            arrays[name] = value
        if arrays["coulomb"].shape != arrays["viscous"].shape:
            raise ValueError(
                f"JointFriction.coulomb has {arrays['coulomb'].size} joints, viscous "
                f"{arrays['viscous'].size}: give one value per joint in both"
            )
        try:
            velocity = float(self.velocity)
        except (TypeError, ValueError):
            raise ValueError(
                f"JointFriction.velocity must be a number [rad/s], got {self.velocity!r}"
            ) from None
        if not (np.isfinite(velocity) and velocity > 0):
            raise ValueError(f"JointFriction.velocity must be finite and > 0 [rad/s], got {self.velocity!r}")
        object.__setattr__(self, "coulomb", arrays["coulomb"])
        object.__setattr__(self, "viscous", arrays["viscous"])
        object.__setattr__(self, "velocity", velocity)

    @property
    def nj(self) -> int:
        """Number of joints."""
        return self.coulomb.size

    def torque(self, qdot: np.ndarray) -> np.ndarray:
        """Friction torque ``c tanh(qdot / v_s) + b qdot`` [N m] at joint rates ``qdot`` [rad/s] (..., nj).

        Raises:
            ValueError: if the last axis of ``qdot`` is not ``nj`` long.
        """
        qdot = np.asarray(qdot, dtype=float)
        if qdot.shape[-1:] != (self.nj,):
            raise ValueError(
                f"joint rates must have {self.nj} values on their last axis, got shape {qdot.shape}"
            )
        return self.coulomb * np.tanh(qdot / self.velocity) + self.viscous * qdot
