"""Gait schedules, swing-foot vertical velocity reference and nominal contact-force distribution.

Foot order everywhere in wbmpc is the Pinocchio leg order FOOT_NAMES = ("FL", "FR", "RL", "RR"):
front-left, front-right, rear-left, rear-right. Arrays indexed by foot have that order on axis 0.

A gait is periodic with period P [s]. Foot i swings while its local phase
    phi_i(t) = (t / P - offset_i) mod 1
is below the swing fraction sigma; its swing phase (fraction of the swing elapsed) is then phi_i / sigma.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import casadi as ca
import numpy as np

FOOT_NAMES = ("FL", "FR", "RL", "RR")
FRONT = np.array([True, True, False, False])  # FL, FR are the front feet


def _finite(name: str, value, positive: bool = False) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{name} must be a real number, got {value!r}") from err
    if not math.isfinite(value) or (positive and value <= 0.0):
        raise ValueError(f"{name} must be finite{' and > 0' if positive else ''}, got {value}")
    return value


class GaitSample(NamedTuple):
    """Gait sampled at n times: contact (4, n) bool (True = stance), swing_phase (4, n) in [0, 1),
    n_contacts (n,) int."""

    contact: np.ndarray
    swing_phase: np.ndarray
    n_contacts: np.ndarray


@dataclass(frozen=True)
class Gait:
    """Periodic gait.

    Attributes:
        name: Gait name.
        period: Cycle duration P [s], > 0.
        swing_fraction: Swing duration / period, in [0, 1) (0: the feet never swing).
        offsets: Per-foot phase in [0, 1) of the cycle at which the swing starts, FOOT_NAMES order.
    """

    name: str
    period: float
    swing_fraction: float
    offsets: tuple[float, float, float, float]

    def __post_init__(self):
        _finite("period", self.period, positive=True)
        if not 0.0 <= _finite("swing_fraction", self.swing_fraction) < 1.0:
            raise ValueError(f"swing_fraction must be in [0, 1), got {self.swing_fraction}")
        offsets = np.asarray(self.offsets, dtype=float)
        if offsets.shape != (4,) or not np.all((offsets >= 0.0) & (offsets < 1.0)):
            raise ValueError(f"offsets must be 4 phases in [0, 1), got {self.offsets!r}")
        object.__setattr__(self, "offsets", tuple(float(o) for o in offsets))

    @property
    def swing_duration(self) -> float:
        """Swing duration T = swing_fraction * period [s]."""
        return self.swing_fraction * self.period

    @property
    def n_stance_nominal(self) -> int:
        """Average number of stance feet, 4 (1 - swing_fraction) rounded (trot 2, walk 3, stand 4)."""
        return round(4 * (1.0 - self.swing_fraction))

    def sample(self, times) -> GaitSample:
        """Contact flags and swing phases of the 4 feet at each of the given times [s] (1-D array)."""
        times = np.asarray(times, dtype=float)
        if times.ndim != 1 or not np.all(np.isfinite(times)):
            raise ValueError(f"times must be a finite 1-D array [s], got shape {times.shape}")
        local = np.mod(times[None, :] / self.period - np.asarray(self.offsets)[:, None], 1.0)
        swing = local < self.swing_fraction  # always False for swing_fraction 0
        phase = np.zeros_like(local)
        # local < sigma, but the rounded quotient may still hit 1.0: clip to keep the phase in [0, 1).
        phase[swing] = np.minimum(local[swing] / self.swing_fraction, np.nextafter(1.0, 0.0))
        contact = ~swing
        return GaitSample(contact, phase, contact.sum(axis=0))

    def contact(self, t: float) -> np.ndarray:
        """Contact flags (4,) bool at time t [s], True = stance."""
        return self.sample(np.array([_finite("t", t)])).contact[:, 0]

    def swing_phase(self, t: float) -> np.ndarray:
        """Swing phase (4,) at time t [s]: elapsed fraction of the swing in [0, 1), 0 for stance feet."""
        return self.sample(np.array([_finite("t", t)])).swing_phase[:, 0]


_GAITS = {  # name -> (swing_fraction, swing start phase per foot FL, FR, RL, RR)
    "trot": (0.5, (0.0, 0.5, 0.5, 0.0)),  # diagonal pairs FL+RR, FR+RL
    "walk": (0.25, (0.0, 0.5, 0.75, 0.25)),  # FL, RR, FR, RL
    "stand": (0.0, (0.0, 0.0, 0.0, 0.0)),
    "pace": (0.5, (0.0, 0.5, 0.0, 0.5)),  # left pair, right pair
    "bound": (0.5, (0.0, 0.0, 0.5, 0.5)),  # front pair, rear pair
}


def make_gait(name: str, period: float = 0.8) -> Gait:
    """Gait `name` in ("trot", "walk", "stand", "pace", "bound") with cycle period [s]."""
    if name not in _GAITS:
        raise ValueError(f"name: unknown gait {name!r}, known gaits: {sorted(_GAITS)}")
    swing_fraction, offsets = _GAITS[name]
    return Gait(name, _finite("period", period, positive=True), swing_fraction, offsets)


@dataclass(frozen=True)
class SwingParams:
    """Swing-foot reference: apex height [m] in (0, 0.5), lift-off / touch-down vertical velocities [m/s]."""

    height: float = 0.07
    v_liftoff: float = 0.1
    v_touchdown: float = -0.2

    def __post_init__(self):
        if not 0.0 < _finite("height", self.height) < 0.5:
            raise ValueError(f"height must be in (0, 0.5) m, got {self.height}")
        _finite("v_liftoff", self.v_liftoff)
        _finite("v_touchdown", self.v_touchdown)


def _check_swing(phi, T, h, v_lo, v_td):
    phi = np.asarray(phi, dtype=float)
    if not np.all((phi >= 0.0) & (phi <= 1.0)):
        raise ValueError("phi must be in [0, 1]")
    return phi, _finite("T", T, positive=True), _finite("h", h), _finite("v_lo", v_lo), _finite("v_td", v_td)


def swing_height_profile(phi, T: float, h: float, v_lo: float, v_td: float):
    """Swing-foot height z [m] at swing phase phi in [0, 1] (swing duration T [s]).

    Two cubic Hermite pieces in s with half-swing d = T / 2 (tangents wrt s are velocity * d):
        phi < 0.5, s = 2 phi:      z = h (3 s^2 - 2 s^3) + v_lo d (s - 2 s^2 + s^3)   (0, v_lo) -> (h, 0)
        phi >= 0.5, s = 2 phi - 1: z = h (1 - 3 s^2 + 2 s^3) + v_td d (s^3 - s^2)     (h, 0) -> (0, v_td)
    """
    phi, T, h, v_lo, v_td = _check_swing(phi, T, h, v_lo, v_td)
    d = 0.5 * T
    s1, s2 = 2.0 * phi, 2.0 * phi - 1.0
    z1 = h * (3 * s1**2 - 2 * s1**3) + v_lo * d * (s1 - 2 * s1**2 + s1**3)
    z2 = h * (1 - 3 * s2**2 + 2 * s2**3) + v_td * d * (s2**3 - s2**2)
    return np.where(phi < 0.5, z1, z2)


def swing_vertical_velocity(phi, T: float, h: float, v_lo: float, v_td: float):
    """Swing-foot vertical velocity dz/dt [m/s] at swing phase phi in [0, 1] (swing duration T [s]).

    Time derivative (dz/ds) / d of `swing_height_profile`, d = T / 2, same s:
        phi < 0.5:  v_z = v_lo (1 - 4 s + 3 s^2) + (6 h / d)(s - s^2)
        phi >= 0.5: v_z = v_td (3 s^2 - 2 s) - (6 h / d)(s - s^2)
    """
    phi, T, h, v_lo, v_td = _check_swing(phi, T, h, v_lo, v_td)
    return _velocity(phi, T, h, v_lo, v_td, np.where)


def symbolic_swing_vertical_velocity(phi, T, h, v_lo, v_td):
    """CasADi (SX or MX) version of `swing_vertical_velocity`, branch chosen with casadi.if_else."""
    return _velocity(phi, T, h, v_lo, v_td, ca.if_else)


def _velocity(phi, T, h, v_lo, v_td, select):
    d = 0.5 * T
    s1, s2 = 2 * phi, 2 * phi - 1
    v1 = v_lo * (1 - 4 * s1 + 3 * s1**2) + (6 * h / d) * (s1 - s1**2)
    v2 = v_td * (3 * s2**2 - 2 * s2) - (6 * h / d) * (s2 - s2**2)
    return select(phi < 0.5, v1, v2)


def default_force_distribution(contact, mass: float, gravity: float = 9.81, front_ratio: float = 0.5):
    """Nominal vertical contact forces [N] carrying the weight m g over the stance feet.

    With front and rear feet in stance, front_ratio * m g is shared equally by the front stance feet and
    (1 - front_ratio) * m g by the rear ones; if only front (or only rear) feet are in stance they carry
    all of m g. Swing feet get 0, and so does every foot when none is in stance.

    Args:
        contact: Bool array (4,) or (4, n), True = stance, FOOT_NAMES order.
        mass: Total robot mass m [kg], > 0.
        gravity: g [m/s^2], > 0.
        front_ratio: Share of the weight on the front feet, in [0, 1].

    Returns:
        Array with the shape of `contact`; each column sums to m g if any foot is in stance.
    """
    contact = np.asarray(contact)
    if contact.shape[:1] != (4,) or contact.ndim > 2 or not np.all((contact == 0) | (contact == 1)):
        raise ValueError(f"contact must be a bool array of shape (4,) or (4, n), got shape {contact.shape}")
    weight = _finite("mass", mass, positive=True) * _finite("gravity", gravity, positive=True)
    if not 0.0 <= _finite("front_ratio", front_ratio) <= 1.0:
        raise ValueError(f"front_ratio must be in [0, 1], got {front_ratio}")
    c = contact.astype(bool).reshape(4, -1)
    n_front, n_rear = c[FRONT].sum(axis=0), c[~FRONT].sum(axis=0)
    both = (n_front > 0) & (n_rear > 0)
    w_front = np.where(both, front_ratio, (n_front > 0).astype(float)) * weight
    w_rear = np.where(both, 1.0 - front_ratio, (n_rear > 0).astype(float)) * weight
    per_front = w_front / np.maximum(n_front, 1)
    per_rear = w_rear / np.maximum(n_rear, 1)
    forces = c * np.where(FRONT[:, None], per_front[None, :], per_rear[None, :])
    return forces.reshape(contact.shape)
