"""The protocol every robot implements for the runtime: time-stamped readings in, motor commands out.

A robot, real or emulated, is read and written in its own terms (motor slots, its IMU's quaternion order);
the runtime works in the model's (Pinocchio's joint order, quaternions ``(x, y, z, w)``). The two meet
here:

* :class:`JointMap`: which motor slot drives which model joint (explicit; never assumed from an order);
* :class:`Observation`: one reading of the robot (joint encoders and torques, IMU), model order;
* :class:`MotorCommand`: one command per joint, the law the motor drivers evaluate at their own rate,

  .. math:: \\tau = \\tau_{ff} + k_p (q_{des} - q) + k_d (\\dot q_{des} - \\dot q);

* :class:`Robot`: ``read()`` the newest observation, ``write(command)``, ``close()``.

The IMU quaternion convention of :class:`Observation` is the estimator's ``(x, y, z, w)``, base to world;
the Unitree wire format's ``(w, x, y, z)`` is converted at the message boundary
(:func:`quaternion_wxyz_to_xyzw`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from wbmpc import checks
from wbmpc.estimation import ImuReading, JointReading

__all__ = [
    "NO_ORIENTATION",
    "JointMap",
    "MotorCommand",
    "Observation",
    "Robot",
    "orientation_from_wire",
    "orientation_to_wire",
    "quaternion_wxyz_to_xyzw",
    "quaternion_xyzw_to_wxyz",
]

#: What a wire carries in its quaternion field when the IMU reports no orientation of its own: the zero
#: quaternion (not a rotation, so it cannot be mistaken for one). A wire that put the identity there would
#: tell the estimator, at its orientation output's confidence, that the base is level: on the emulated
#: robot (whose IMU has no orientation output) that held the estimated tilt at zero while the real base
#: leaned, and the trot fell within a second.
NO_ORIENTATION = np.zeros(4)


def orientation_to_wire(orientation) -> np.ndarray:
    """The quaternion ``(x, y, z, w)`` a wire carries for ``orientation`` (``None``:
    :data:`NO_ORIENTATION`)."""
    return NO_ORIENTATION.copy() if orientation is None else np.asarray(orientation, dtype=float)


def orientation_from_wire(quat_xyzw) -> np.ndarray | None:
    """The IMU orientation ``(x, y, z, w)`` a wire carried, or ``None`` for :data:`NO_ORIENTATION` (an
    exactly zero quaternion: no orientation output). A non-finite one is passed on for
    :meth:`Observation.problem` to refuse."""
    quat = np.asarray(quat_xyzw, dtype=float)
    return None if not np.any(quat) else quat


def quaternion_wxyz_to_xyzw(quat) -> np.ndarray:
    """A quaternion from the wire's ``(w, x, y, z)`` to Pinocchio's ``(x, y, z, w)``."""
    w, x, y, z = np.asarray(quat, dtype=float)
    return np.array([x, y, z, w])


def quaternion_xyzw_to_wxyz(quat) -> np.ndarray:
    """A quaternion from Pinocchio's ``(x, y, z, w)`` to the wire's ``(w, x, y, z)``."""
    x, y, z, w = np.asarray(quat, dtype=float)
    return np.array([w, x, y, z])


@dataclass(frozen=True)
class JointMap:
    """Which robot motor slot drives each model joint.

    Args:
        joint_names: The model's actuated joints, in the model's order (``robot.joint_names``).
        slots: For each model joint, the index of its slot on the robot's wire (e.g. one of Unitree's 20
            motor slots), all different.
        n_slots: Slots on the wire (20 for Unitree's ``LowCmd_``).

    Raises:
        ValueError: repeated or out-of-range slots, or as many slots as names not given.
    """

    joint_names: tuple[str, ...]
    slots: tuple[int, ...]
    n_slots: int = 20

    def __post_init__(self):
        object.__setattr__(self, "joint_names", tuple(self.joint_names))
        object.__setattr__(self, "slots", tuple(int(s) for s in self.slots))
        if len(self.slots) != len(self.joint_names):
            raise ValueError(
                f"JointMap needs one slot per joint: {len(self.joint_names)} joints, {len(self.slots)} slots"
            )
        bad = [s for s in self.slots if not 0 <= s < self.n_slots]
        if bad:
            raise ValueError(f"JointMap slots must be in [0, {self.n_slots}), got {bad}")
        if len(set(self.slots)) != len(self.slots):
            repeated = sorted({s for s in self.slots if self.slots.count(s) > 1})
            raise ValueError(f"JointMap slots must be different, slot(s) {repeated} repeated")

    @classmethod
    def in_order(cls, joint_names: Sequence[str], first_slot: int = 0, n_slots: int = 20) -> JointMap:
        """Model joints on consecutive slots from ``first_slot``: a wire laid out in the model's own order
        (the emulated arm's topic). Unitree's legs are not: see :meth:`unitree_legs`."""
        n = len(joint_names)
        return cls(tuple(joint_names), tuple(range(first_slot, first_slot + n)), n_slots)

    @classmethod
    def unitree_legs(cls, joint_names: Sequence[str], n_slots: int = 20) -> JointMap:
        """Unitree's leg slots: FR 0-2, FL 3-5, RR 6-8, RL 9-11 (hip, thigh, calf), found by each joint
        name's leg prefix (``FR_``, ``FL_``, ``RR_``, ``RL_``) and joint kind (``hip``, ``thigh``, ``calf``).

        Raises:
            ValueError: a joint whose name carries no leg prefix and joint kind.
        """
        legs, kinds = ("FR", "FL", "RR", "RL"), ("hip", "thigh", "calf")
        slots = []
        for name in joint_names:
            leg = next((i for i, p in enumerate(legs) if name.startswith(p + "_")), None)
            kind = next((i for i, k in enumerate(kinds) if k in name), None)
            if leg is None or kind is None:
                raise ValueError(
                    f"joint {name!r} names no Unitree leg (FR_, FL_, RR_, RL_) and kind (hip, thigh, calf)"
                )
            slots.append(3 * leg + kind)
        return cls(tuple(joint_names), tuple(slots), n_slots)

    @property
    def nj(self) -> int:
        return len(self.joint_names)

    def to_wire(self, values: np.ndarray, fill: float = 0.0) -> np.ndarray:
        """Model-order values (nj,) on the wire's slots (n_slots,); unused slots hold ``fill``."""
        out = np.full(self.n_slots, fill, dtype=float)
        out[list(self.slots)] = values
        return out

    def from_wire(self, values: np.ndarray) -> np.ndarray:
        """The wire's slot values (n_slots,) in model order (nj,)."""
        return np.asarray(values, dtype=float)[list(self.slots)]


@dataclass
class Observation:
    """One reading of the robot, in model order.

    Attributes:
        stamp: When the robot measured it [s], on the robot's monotonic clock.
        seq: The robot's tick or message counter (increasing; a repeat or a step back is stale).
        q: Joint angles [rad] (nj,); dq: joint rates [rad/s] (nj,), unfiltered; tau: measured joint
            torques [N m] (nj,).
        gyro: IMU angular velocity [rad/s] (3,), base frame; accelerometer: specific force [m/s^2] (3,).
        orientation: IMU orientation, quaternion ``(x, y, z, w)`` base to world (4,), or ``None``.
        foot_force: Foot contact force sensors (n_feet,) [robot units], or ``None``.
    """

    stamp: float
    seq: int
    q: np.ndarray
    dq: np.ndarray
    tau: np.ndarray
    gyro: np.ndarray
    accelerometer: np.ndarray
    orientation: np.ndarray | None = None
    foot_force: np.ndarray | None = None

    def problem(self) -> str:
        """Why this reading must not reach the estimator (a non-finite field, a wrong shape), or ``""``."""
        nj = np.shape(self.q)
        for name in ("q", "dq", "tau", "gyro", "accelerometer", "orientation", "foot_force"):
            value = getattr(self, name)
            if value is None:
                continue
            value = np.asarray(value, dtype=float)
            if name in ("dq", "tau") and value.shape != nj:
                return f"observation {name} has shape {value.shape}, q has {nj}"
            if not np.all(np.isfinite(value)):
                bad = np.flatnonzero(~np.isfinite(value.ravel())).tolist()
                return f"observation {name} is not finite at index {bad}"
        if not np.isfinite(self.stamp):
            return f"observation stamp is not finite ({self.stamp})"
        return ""

    def imu(self) -> ImuReading:
        """The IMU part as the estimator's reading."""
        return ImuReading(self.gyro, self.accelerometer, self.orientation)

    def joints(self) -> JointReading:
        """The encoder part as the estimator's reading."""
        return JointReading(self.q, self.dq)


@dataclass
class MotorCommand:
    """One command per joint (model order, nj each), evaluated by the motor drivers.

    Attributes:
        q: Position setpoints [rad]; dq: rate setpoints [rad/s]; tau: feed-forward torques [N m];
        kp: stiffness [N m/rad]; kd: damping [N m s/rad].
        damping: True for the damping mode (kp = 0, zero feed-forward: the joints are only slowed down).
    """

    q: np.ndarray
    dq: np.ndarray
    tau: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    damping: bool = field(default=False)

    @classmethod
    def damping_mode(cls, nj: int, kd) -> MotorCommand:
        """The safe command when plans stop: ``kp = 0``, ``kd > 0`` (scalar or (nj,)), no feed-forward, zero
        setpoints, so that each drive's law ``tau + kp (q - q_m) + kd (dq - dq_m)`` is ``-kd dq_m``: it only
        takes energy out.

        Raises:
            ValueError: ``nj`` not a positive int, or ``kd`` not finite and > 0 on every joint.
        """
        nj = checks.integer("nj", nj, low=1)
        try:
            gains = np.broadcast_to(np.asarray(kd, dtype=float), (nj,)).copy()
        except (TypeError, ValueError):
            raise ValueError(f"kd must be a damping > 0 [N m s/rad], scalar or ({nj},), got {kd!r}") from None
        if not np.all(np.isfinite(gains)) or np.any(gains <= 0):
            raise ValueError(f"kd must be finite and > 0 on every joint [N m s/rad], got {kd!r}")
        zeros = np.zeros(nj)
        return cls(zeros, zeros.copy(), zeros.copy(), zeros.copy(), gains, damping=True)

    def problem(self, position_limits=None, velocity_limits=None, torque_limits=None) -> str:
        """Why the command must not be written (``""`` if it may): a non-finite value, negative gains, or a
        setpoint outside the given limits (``position_limits`` (2, nj) [rad], the others (nj,) symmetric).
        The damping mode skips the position check (its setpoint is unused: kp = 0)."""
        values = (self.q, self.dq, self.tau, self.kp, self.kd)
        limited = position_limits is not None or velocity_limits is not None or torque_limits is not None
        if not limited and np.isfinite(sum(float(np.sum(v)) for v in values)):
            if float(np.min(self.kp)) >= 0 and float(np.min(self.kd)) >= 0:
                return ""  # the fast path of every tick: finite values sum to a finite number
        for name in ("q", "dq", "tau", "kp", "kd"):
            value = np.asarray(getattr(self, name), dtype=float)
            if not np.all(np.isfinite(value)):
                joints = np.flatnonzero(~np.isfinite(value)).tolist()
                return f"command {name} is not finite at joint(s) {joints}"
        for name in ("kp", "kd"):
            if np.any(np.asarray(getattr(self, name)) < 0):
                return f"command {name} is negative"
        if position_limits is not None and not self.damping:
            low, high = np.asarray(position_limits, dtype=float)
            out = np.flatnonzero((self.q < low - 1e-9) | (self.q > high + 1e-9))
            if out.size:
                return f"command q outside the joint limits at joint(s) {out.tolist()}"
        for name, limits in (("dq", velocity_limits), ("tau", torque_limits)):
            if limits is not None:
                out = np.flatnonzero(np.abs(getattr(self, name)) > np.asarray(limits) * (1 + 1e-9))
                if out.size:
                    return f"command {name} beyond its limit at joint(s) {out.tolist()}"
        return ""


@runtime_checkable
class Robot(Protocol):
    """What the runtime needs of a robot.

    Attributes:
        joint_names: The model joints the robot reads and drives (model order).
    """

    joint_names: tuple[str, ...]
    # A robot may also say how much ``Observation.seq`` advances per reading, as ``seq_step`` (1 if it
    # does not): the controller then knows how many readings an observation superseded.

    def read(self) -> Observation | None:
        """The newest observation since the last call, or ``None`` if none arrived (never blocks long)."""
        ...

    def write(self, command: MotorCommand) -> None:
        """Send one command to every joint."""
        ...

    def close(self) -> None:
        """Release the connection (the robot's drivers keep their last command or time out)."""
        ...
