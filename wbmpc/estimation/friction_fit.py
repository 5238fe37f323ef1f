"""The result of a joint friction identification (:mod:`wbmpc.estimation.identification`): per joint group
its Coulomb and viscous friction and armature, how well the log determines them, and the motor model's
torque that reaches the links.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from wbmpc.model.friction import JointFriction

__all__ = ["PARAMETERS", "UNITS", "FrictionIdentification", "GroupFit", "log_column"]

PARAMETERS = ("coulomb", "viscous", "armature")
UNITS = {"coulomb": "N m", "viscous": "N m s/rad", "armature": "kg m^2"}


@dataclass
class GroupFit:
    """The fit of one joint group.

    Attributes:
        name: Group name; joints: its joints.
        coulomb: Coulomb friction [N m]; viscous: viscous friction [N m s/rad]; armature: [kg m^2]
            (0 for a parameter that is not identified).
        std: Standard error of each parameter (``PARAMETERS`` order; NaN when not fitted).
        identified: Per parameter, whether the log identifies it; reasons: why not, per parameter.
        delay: Command delay [s] used (fitted or given).
        rms_before: RMS [N m] of the torque-tracking error ``tau_cmd(t - d) - (M a + h)`` on the samples
            used; rms_after: of the fit's residual.
        samples: Samples used (all joints of the group); rejected: candidate samples removed as outliers.
        velocity_rms: RMS joint rate [rad/s] on the samples used; moving_share: share of them faster than
            2 ``friction_velocity``; acceleration_rms: RMS joint acceleration [rad/s^2].
    """

    name: str
    joints: tuple[str, ...]
    coulomb: float = 0.0
    viscous: float = 0.0
    armature: float = 0.0
    std: tuple[float, float, float] = (math.nan, math.nan, math.nan)
    identified: dict[str, bool] = field(default_factory=lambda: dict.fromkeys(PARAMETERS, False))
    reasons: dict[str, str] = field(default_factory=dict)
    delay: float = 0.0
    rms_before: float = math.nan
    rms_after: float = math.nan
    samples: int = 0
    rejected: int = 0
    velocity_rms: float = math.nan
    moving_share: float = math.nan
    acceleration_rms: float = math.nan

    def summary(self) -> dict:
        """JSON-ready values."""
        return {
            "joints": list(self.joints),
            **{p: float(getattr(self, p)) for p in PARAMETERS},
            "std": dict(zip(PARAMETERS, map(float, self.std), strict=True)),
            "identified": dict(self.identified),
            "reasons": dict(self.reasons),
            "delay_s": self.delay,
            "rms_before_nm": self.rms_before,
            "rms_after_nm": self.rms_after,
            "samples": self.samples,
            "rejected": self.rejected,
            "velocity_rms_radps": self.velocity_rms,
            "moving_share": self.moving_share,
            "acceleration_rms_radps2": self.acceleration_rms,
        }


@dataclass
class FrictionIdentification:
    """Friction and armature of every joint group of a robot, identified from one log.

    Attributes:
        groups: ``{group name: GroupFit}``.
        joint_names: The robot's actuated joints (model order).
        friction_velocity: Smoothing rate ``v_s`` [rad/s] of the Coulomb features.
        base: Source of the base accelerations used (``"imu"``, ``"odometry"`` or ``"log"``).
        sample_period: Log sample period [s]; window: span [s] of the Savitzky-Golay smoothing (0: none).
    """

    groups: dict[str, GroupFit]
    joint_names: list[str]
    friction_velocity: float
    base: str
    sample_period: float
    window: float

    def per_joint(self, parameter: str) -> dict[str, float]:
        """``{joint: value}`` of one parameter (``"coulomb"``, ``"viscous"``, ``"armature"``) for every
        grouped joint (0 where the log does not identify it).

        Raises:
            ValueError: for another parameter name.
        """
        if parameter not in PARAMETERS:
            raise ValueError(f"parameter must be one of {PARAMETERS}, got {parameter!r}")
        return {j: float(getattr(g, parameter)) for g in self.groups.values() for j in g.joints}

    def applied_torque(self, log) -> np.ndarray:
        """The torque that reaches the links [N m] (T, nj) according to the identified motor model.

        Per grouped joint: the logged command ``tau`` as it arrives ``delay`` later (linear interpolation),
        minus the identified friction at the logged joint rate and the armature times the joint
        acceleration (``np.gradient`` of the rates); parameters not identified count as 0 and joints in no
        group keep the command. Analyses that solve the equations of motion for the contact forces (e.g.
        :func:`wbmpc.analysis.identify_com_offset`) then see the rigid-body torques: a
        standing B1 creeps at up to 0.03 rad/s, where its 1 N m Coulomb friction is still ~0.5 N m.

        Raises:
            ValueError: if the log's ``tau`` or ``v`` do not fit the identified robot's joints.
        """
        t = np.asarray(log["t"], dtype=float)
        nj = len(self.joint_names)
        tau = log_column(log, "tau", (nj,), t.size)
        rates = log_column(log, "v", (nj + 6,), t.size)[:, 6:]
        acceleration = np.gradient(rates, t, axis=0)
        out = tau.copy()
        index = {name: i for i, name in enumerate(self.joint_names)}
        for fit in self.groups.values():
            friction = JointFriction([fit.coulomb], [fit.viscous], self.friction_velocity)
            for joint in fit.joints:
                k = index[joint]
                out[:, k] = np.interp(t - fit.delay, t, tau[:, k])
                out[:, k] -= friction.torque(rates[:, k : k + 1])[:, 0] + fit.armature * acceleration[:, k]
        return out

    def summary(self) -> dict:
        """JSON-ready values (written to a calibration file's ``identification`` field)."""
        return {
            "method": "wbmpc.estimation.identification.identify_joint_friction",
            "friction_velocity_radps": self.friction_velocity,
            "base_acceleration": self.base,
            "sample_period_s": self.sample_period,
            "window_s": self.window,
            "groups": {name: g.summary() for name, g in self.groups.items()},
        }

    def table(self) -> str:
        """A text table: per group the three parameters (``-`` where not identified), delay, fit quality."""
        head = (
            f"{'group':<12}{'joints':>7}{'Coulomb':>10}{'viscous':>11}{'armature':>10}{'delay':>8}"
            f"{'rms':>7}{'fit':>7}{'samples':>9}"
        )
        units = (
            f"{'':<12}{'':>7}{'[N m]':>10}{'[N m s/r]':>11}{'[kg m2]':>10}{'[ms]':>8}{'[N m]':>7}{'[N m]':>7}"
        )
        rows = [head, units]
        for g in self.groups.values():
            cells = []
            for p, width, fmt in (("coulomb", 10, ".3f"), ("viscous", 11, ".3f"), ("armature", 10, ".4f")):
                cells.append(f"{getattr(g, p):>{width}{fmt}}" if g.identified[p] else f"{'-':>{width}}")
            fitted = any(g.identified.values())
            delay = f"{1e3 * g.delay:>8.2f}" if fitted else f"{'-':>8}"
            rms = "".join(
                f"{x:>7.2f}" if math.isfinite(x) else f"{'-':>7}" for x in (g.rms_before, g.rms_after)
            )
            rows.append(f"{g.name:<12}{len(g.joints):>7}{''.join(cells)}{delay}{rms}{g.samples:>9}")
            if len(g.reasons) == len(PARAMETERS) and len(set(g.reasons.values())) == 1:
                rows.append(f"{'':<12}not identified: {next(iter(g.reasons.values()))}")
                continue
            for p, reason in g.reasons.items():
                rows.append(f"{'':<12}{p} not identified: {reason}")
        return "\n".join(rows)


def log_column(log, name: str, shape_tail: tuple[int, ...] | None, rows: int | None = None) -> np.ndarray:
    """A log column as floats, its shape checked: ``(rows, *shape_tail)``.

    Raises:
        ValueError: naming the column if it is missing or has another shape.
    """
    try:
        value = np.asarray(log[name], dtype=float)
    except KeyError:
        raise ValueError(f"the log has no {name!r} column, which the identification needs") from None
    if shape_tail is not None and value.shape[1:] != shape_tail:
        raise ValueError(
            f"log column {name!r} has shape {value.shape}, expected (T, {', '.join(map(str, shape_tail))})"
        )
    if rows is not None and value.shape[0] != rows:
        raise ValueError(f"log column {name!r} has {value.shape[0]} rows, 't' has {rows}")
    return value
