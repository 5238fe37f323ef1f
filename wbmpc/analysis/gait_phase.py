"""A joint signal averaged over gait cycles and compared with a nominal simulation at the same commands.

:func:`gait_phase` (the phase from the scheduled liftoffs), :func:`phase_profile` (a signal per phase bin),
:func:`align_by_phase` (a robot log against a nominal run), :func:`joint_signal` (one joint's column).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def joint_signal(log, column: str, joint, robot=None) -> np.ndarray:
    """One joint's series (T,) of ``q`` [rad], ``v`` [rad/s] or ``tau``/``tau_ff`` [N m].

    Args:
        log: Run log.
        column: ``"q"``, ``"v"``, ``"q_meas"``, ``"v_meas"``, ``"tau"`` or ``"tau_ff"``.
        joint: Joint name (``log.meta["joint_names"]``, else the robot's) or index among the joints.
        robot: Robot giving the joint names if the log has none.
    """
    names = log.meta.get("joint_names") or (robot.joint_names if robot is not None else None)
    if isinstance(joint, str):
        if names is None or joint not in names:
            raise ValueError(f"unknown joint {joint!r}; joints: {names}")
        joint = list(names).index(joint)
    offset = {"q": 7, "q_meas": 7, "v": 6, "v_meas": 6, "tau": 0, "tau_ff": 0}
    if column not in offset:
        raise ValueError(f"column must be one of {sorted(offset)}, got {column!r}")
    return np.asarray(log[column], dtype=float)[:, offset[column] + int(joint)]


def _edges(flags: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices of liftoffs (True -> False) and touchdowns (False -> True) of a boolean series."""
    f = np.asarray(flags, dtype=bool).astype(np.int8)
    d = np.diff(f)
    return np.flatnonzero(d == -1) + 1, np.flatnonzero(d == 1) + 1


def gait_phase(t: np.ndarray, contact: np.ndarray, foot: int = 0) -> np.ndarray:
    """Gait phase in [0, 1) from the scheduled liftoffs of one foot (NaN outside complete cycles).

    A cycle runs from one liftoff of ``foot`` to the next; the phase grows linearly in time within it.

    Args:
        t: Sample times [s] (T,).
        contact: Scheduled stance flags (T, n_feet) (the log's ``contact`` column).
        foot: Reference foot (0: FL).
    """
    t = np.asarray(t, dtype=float)
    lift, _ = _edges(np.asarray(contact)[:, foot])
    phase = np.full(t.shape, np.nan)
    for a, b in zip(lift[:-1], lift[1:], strict=True):
        phase[a:b] = (t[a:b] - t[a]) / (t[b] - t[a])
    return phase


@dataclass
class PhaseProfile:
    """A signal averaged per gait-phase bin: ``phase`` bin centres [-], ``mean``, ``std``, ``count``."""

    phase: np.ndarray
    mean: np.ndarray
    std: np.ndarray
    count: np.ndarray


def phase_profile(phase: np.ndarray, signal: np.ndarray, bins: int = 50) -> PhaseProfile:
    """Mean and standard deviation of ``signal`` in ``bins`` equal bins of the gait phase (NaN: skipped)."""
    phase, signal = np.asarray(phase, float), np.asarray(signal, float)
    ok = np.isfinite(phase) & np.isfinite(signal)
    k = np.minimum((phase[ok] * bins).astype(int), bins - 1)
    count = np.bincount(k, minlength=bins)
    total = np.bincount(k, signal[ok], minlength=bins)
    square = np.bincount(k, signal[ok] ** 2, minlength=bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = total / count
        std = np.sqrt(np.maximum(square / count - mean**2, 0.0))
    return PhaseProfile((np.arange(bins) + 0.5) / bins, mean, std, count)


@dataclass
class PhaseAlignment:
    """A joint signal of the robot and of a nominal simulation, both averaged by gait phase.

    Attributes:
        robot, nominal: The two :class:`PhaseProfile`.
        rms_difference: RMS of ``robot.mean - nominal.mean`` over the bins (unit of the signal).
        lag_phase: Phase shift [-] (in (-0.5, 0.5]) of the robot's profile that best matches the nominal one
            (circular cross-correlation; positive: the robot's features come later).
        period_s: Gait cycle [s] (median over the robot's cycles); lag_s = lag_phase * period_s.
    """

    robot: PhaseProfile
    nominal: PhaseProfile
    rms_difference: float
    lag_phase: float
    period_s: float

    @property
    def lag_s(self) -> float:
        return self.lag_phase * self.period_s


def align_by_phase(
    log,
    nominal,
    column: str,
    joint,
    robot=None,
    foot: int = 0,
    bins: int = 50,
    t_min: float = 0.0,
    t_min_nominal: float | None = None,
) -> PhaseAlignment:
    """Align one joint signal of a robot log with a nominal simulation by gait phase.

    Args:
        log: The robot's log; nominal: a simulation at the same commands (both with ``t`` and ``contact``).
        column, joint, robot: The signal (see :func:`joint_signal`), e.g. ``"tau"``, ``"RL_calf_joint"``.
        foot: Foot whose liftoff starts a cycle.
        bins: Phase bins.
        t_min: Ignore samples before this time [s] (the first cycles after the gait starts).
        t_min_nominal: The same for the nominal run (``None``: ``t_min``).
    """
    profiles, periods = [], []
    t_mins = (t_min, t_min if t_min_nominal is None else t_min_nominal)
    for run, start in zip((log, nominal), t_mins, strict=True):
        t = np.asarray(run["t"], float)
        phase = gait_phase(t, run["contact"], foot)
        phase[t < start] = np.nan
        if not np.isfinite(phase).any():
            raise ValueError("no complete gait cycle in the log (a stand-only run, or t_min too late)")
        profiles.append(phase_profile(phase, joint_signal(run, column, joint, robot), bins))
        lift, _ = _edges(np.asarray(run["contact"])[:, foot])
        periods.append(np.diff(t[lift]))
    a, b = profiles[0].mean, profiles[1].mean
    ok = np.isfinite(a) & np.isfinite(b)
    a0, b0 = np.where(ok, a - np.nanmean(a), 0.0), np.where(ok, b - np.nanmean(b), 0.0)
    corr = [np.dot(np.roll(a0, -s), b0) for s in range(bins)]
    shift = int(np.argmax(corr))
    lag = shift / bins if shift <= bins // 2 else shift / bins - 1.0
    return PhaseAlignment(
        robot=profiles[0],
        nominal=profiles[1],
        rms_difference=float(np.sqrt(np.mean((a[ok] - b[ok]) ** 2))),
        lag_phase=float(lag),
        period_s=float(np.median(periods[0])),
    )
