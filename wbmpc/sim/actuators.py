"""Motors between torque commands and a plant's joints: saturation, latency, friction, armature.

:class:`MotorModel` describes the motors (per-joint values, validated); :class:`Actuators` is its state for
one run (the latency's delay line, the rate history of the armature torque, counters);
:class:`ActuatedPlant` puts them in front of any :class:`~wbmpc.sim.plant.Plant` (rigid or PyBullet), so that
the same motor effects apply whichever physics runs behind. What reaches the joints at each plant step:

1. the command clipped to the torque limits (the clips counted per joint);
2. delayed by ``round(latency / dt)`` steps (the first command fills the delay line after a reset);
3. plus the friction torque ``-(c tanh(qdot / v_s) + b qdot)`` (Coulomb ``c`` [N m], viscous ``b``
   [N m s/rad], smoothed over ``v_s`` [rad/s]) and the reflected rotor inertia's ``-I_a qddot``.

PyBullet has no armature (``changeDynamics`` has no such option, its URDF parser ignores it), hence the
torque. ``qddot`` is the mean of the last two finite differences of the joint rates: one-step-old estimates
are unstable once ``I_a`` exceeds a joint's effective link inertia (the B1 calf ~0.04 kg m^2, the Z1 wrist
~0.009); the two-step mean is stable up to twice it, and the error decays within a few steps.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from wbmpc import checks
from wbmpc.sim.plant import Plant, PlantState

__all__ = ["ActuatedPlant", "Actuators", "MotorModel"]


@dataclass(frozen=True)
class MotorModel:
    """The motors' effects the MPC does not model (all zero: ideal torque sources).

    Attributes:
        coulomb: Coulomb friction [N m], scalar or one per joint.
        viscous: Viscous friction [N m s/rad], scalar or one per joint.
        friction_velocity: Joint rate [rad/s] over which the Coulomb friction rises (tanh smoothing).
        armature: Reflected rotor inertia [kg m^2], scalar or one per joint.
        latency: Delay of the torque commands [s] (rounded to whole plant steps).
    """

    coulomb: float | np.ndarray = 0.0
    viscous: float | np.ndarray = 0.0
    friction_velocity: float = 0.02
    armature: float | np.ndarray = 0.0
    latency: float = 0.0

    def __post_init__(self):
        checks.number(
            "MotorModel.friction_velocity", self.friction_velocity, low=0.0, low_open=True, unit="rad/s"
        )
        checks.number("MotorModel.latency", self.latency, low=0.0, unit="s")
        for name in ("coulomb", "viscous", "armature"):  # sizes are checked against the joints in per_joint
            values = np.asarray(getattr(self, name), dtype=float)
            if values.ndim > 1 or not np.all(np.isfinite(values)) or np.any(values < 0):
                raise ValueError(
                    f"MotorModel.{name} must be a scalar or one value per joint, finite and >= 0, "
                    f"got {getattr(self, name)!r}"
                )

    def per_joint(self, nj: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(coulomb, viscous, armature)`` as arrays (nj,); raises ``ValueError`` on a wrong size, a negative
        or non-finite value."""
        return tuple(
            _joint_values(getattr(self, k), nj, f"MotorModel.{k}") for k in ("coulomb", "viscous", "armature")
        )


class Actuators:
    """A :class:`MotorModel` running at a plant's step, with its state and counters.

    Args:
        model: The motors.
        torque_limits: Per-joint torque limits [N m] (nj,) of the saturation.
        dt: Plant step [s].
    """

    def __init__(self, model: MotorModel, torque_limits: np.ndarray, dt: float):
        self.model = model
        self.torque_limits = checks.array("torque_limits", torque_limits, len(np.atleast_1d(torque_limits)))
        nj = len(self.torque_limits)
        self._coulomb, self._viscous, self._armature = model.per_joint(nj)
        self._friction_velocity = float(model.friction_velocity)
        self._dt = checks.number("dt", dt, low=0.0, low_open=True, unit="s")
        self.latency_steps = round(model.latency / self._dt)
        self._has_armature = bool(self._armature.any())
        self._two_dt = 2.0 * self._dt
        self._work = np.empty(nj)  # scratch of torque()
        self._queue: deque[np.ndarray] = deque()  # torque delay line, oldest first
        self._rates: list[np.ndarray] = []  # last three joint rates, for the armature torque
        self.clip_counts = np.zeros(nj, dtype=np.int64)
        self.motor_torque = np.zeros(nj)
        self.friction_torque = np.zeros(nj)

    def reset(self) -> None:
        """Empty the delay line and the rate history, zero the counters."""
        self._queue.clear()
        self._rates.clear()
        self.clip_counts[:] = 0
        self.motor_torque = np.zeros_like(self.motor_torque)
        self.friction_torque = np.zeros_like(self.friction_torque)

    def torque(self, command: np.ndarray, joint_rates: np.ndarray) -> np.ndarray:
        """Joint torques [N m] (nj,) for one plant step from the commanded ones and the current joint rates.

        Raises:
            ValueError: On a wrong shape or a non-finite value in ``command``.
        """
        limits = self.torque_limits
        try:  # the common case first: a valid command within the limits (hence finite)
            tau = np.array(command, dtype=float)
            valid = tau.shape == limits.shape and np.count_nonzero(np.abs(tau) <= limits) == tau.size
        except (TypeError, ValueError):
            valid = False
        if not valid:
            tau = checks.array("tau_joints", command, len(limits))
            clipped = np.abs(tau) > limits
            if clipped.any():
                self.clip_counts += clipped
                tau = np.clip(tau, -limits, limits)
        if self.latency_steps:
            if not self._queue:
                self._queue.extend(tau.copy() for _ in range(self.latency_steps))
            self._queue.append(tau)  # a copy of the command already
            tau = self._queue.popleft()
        self.motor_torque = tau
        qd = joint_rates
        # -(c tanh(qd / v_s) + b qd) - I_a qddot, the operations in that order; buffers: fewer allocations.
        extra, work = qd / self._friction_velocity, self._work
        np.tanh(extra, out=extra)
        np.multiply(self._coulomb, extra, out=extra)
        extra += np.multiply(self._viscous, qd, out=work)
        np.negative(extra, out=extra)
        if self._has_armature:
            history = self._rates
            history.append(qd.copy())
            if len(history) > 3:
                del history[0]
            if len(history) == 3:  # mean acceleration over the last two steps
                np.subtract(history[2], history[0], out=work)
                np.multiply(self._armature, work, out=work)
                extra -= np.divide(work, self._two_dt, out=work)
        self.friction_torque = extra
        return tau + extra


class ActuatedPlant(Plant):
    """Any plant behind motors: :meth:`step` passes the torque commands through :class:`Actuators`.

    Everything else (state, contacts, scene, kicks) is the wrapped plant's. The wrapped plant should not
    clip torques itself (the motors saturate first, then friction adds): build it with its clipping off
    (``PyBulletPlant(..., clip_torques=False)``); :func:`wbmpc.sim.closed_loop.make_plant` does.

    Args:
        plant: The plant.
        actuators: The motors, at the plant's step.
    """

    def __init__(self, plant: Plant, actuators: Actuators):
        self.plant = plant
        self.actuators = actuators

    def __getattr__(self, name: str):
        if name in ("plant", "actuators"):  # not yet set (e.g. while unpickling)
            raise AttributeError(name)
        return getattr(self.plant, name)

    def reset(self, q: np.ndarray, v: np.ndarray, t: float = 0.0) -> PlantState:
        """Reset the plant and the motors' state."""
        state = self.plant.reset(q, v, t)
        self.actuators.reset()
        return state

    def step(self, tau_joints, contact=None, external_wrench=None, ee_force=None) -> PlantState:
        """One plant step with the motors' torques for the commanded ``tau_joints`` [N m] (nj,)."""
        plant = self.plant
        rates = plant.joint_velocities if hasattr(type(plant), "joint_velocities") else plant.state.v[6:]
        tau = self.actuators.torque(tau_joints, rates)
        return self.plant.step(tau, contact, external_wrench=external_wrench, ee_force=ee_force)

    @property
    def torque_clip_counts(self) -> np.ndarray:
        """Per-joint number of steps whose command exceeded the torque limit since :meth:`reset`, (nj,)."""
        return self.actuators.clip_counts.copy()

    @property
    def motor_torque(self) -> np.ndarray:
        """Motor torques [N m] (nj,) of the last step: the clipped command, ``latency`` late."""
        return self.actuators.motor_torque.copy()

    @property
    def friction_torque(self) -> np.ndarray:
        """Motor friction plus armature torques [N m] (nj,) added in the last step."""
        return self.actuators.friction_torque.copy()

    # The Plant protocol's members, forwarded explicitly (Plant defines them, so __getattr__ would not).
    @property
    def model(self):
        return self.plant.model

    @property
    def dt(self) -> float:
        return self.plant.dt

    @property
    def foot_frames(self):
        return self.plant.foot_frames

    def contact_forces(self) -> np.ndarray:
        return self.plant.contact_forces()

    @property
    def foot_positions(self) -> np.ndarray:
        return self.plant.foot_positions

    def foot_contacts(self, scheduled=None) -> np.ndarray:
        return self.plant.foot_contacts(scheduled)

    def ee_contact_force(self) -> np.ndarray:
        return self.plant.ee_contact_force()

    @property
    def body_names(self) -> list[str]:
        return self.plant.body_names

    def body_pose(self, name: str):
        return self.plant.body_pose(name)

    def close(self) -> None:
        self.plant.close()


def _joint_values(x, nj: int, name: str) -> np.ndarray:
    """A per-joint parameter >= 0: scalar or (nj,), as an (nj,) array."""
    arr = np.broadcast_to(np.asarray(x, dtype=float), (nj,)).copy() if np.ndim(x) == 0 else None
    arr = checks.array(name, x, nj) if arr is None else arr
    if not np.isfinite(arr).all() or np.any(arr < 0):
        raise ValueError(f"{name} must be finite and >= 0, got {x!r}")
    return arr
