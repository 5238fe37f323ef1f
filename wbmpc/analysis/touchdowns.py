"""Touchdown instants from the jump of a calf's joint velocity, against the schedule (a late contact shows
as a late spike).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wbmpc.analysis.gait_phase import _edges


@dataclass
class Touchdowns:
    """Touchdown instants of one foot found in its calf signal, against the schedule.

    Attributes:
        scheduled: Scheduled touchdown times [s] (n,).
        detected: Detected ones [s] (NaN: no spike found in the window).
        spike: Peak change of the joint acceleration per sample in the window [rad/s^2].
    """

    scheduled: np.ndarray
    detected: np.ndarray
    spike: np.ndarray

    @property
    def mismatch(self) -> np.ndarray:
        """Detected minus scheduled [s] (positive: the contact came late)."""
        return self.detected - self.scheduled

    def summary(self) -> dict:
        m = self.mismatch[np.isfinite(self.mismatch)]
        return {
            "touchdowns": int(self.scheduled.size),
            "detected": int(m.size),
            "mismatch_median_ms": float(1e3 * np.median(m)) if m.size else None,
            "mismatch_mean_ms": float(1e3 * np.mean(m)) if m.size else None,
            "mismatch_max_ms": float(1e3 * np.max(np.abs(m))) if m.size else None,
        }


def detect_touchdowns(
    t: np.ndarray,
    contact: np.ndarray,
    velocity: np.ndarray,
    window: tuple[float, float] = (-0.08, 0.08),
    fraction: float = 0.3,
    min_spike: float = 20.0,
) -> Touchdowns:
    """Touchdowns from the jump of a joint velocity (the calf's) near each scheduled touchdown.

    A foot that lands stops its calf within a few milliseconds: the joint velocity jumps, its acceleration
    spikes, and the acceleration's change per sample ``|a_k - a_{k-1}|`` (``a = dv/dt``) stands far above
    that of the smooth swing. In each window ``[t_td + window[0], t_td + window[1]]`` around a scheduled
    touchdown ``t_td`` (starting no earlier than mid-swing, ending at the next liftoff), the touchdown is the
    first sample whose score reaches ``fraction`` of the window's peak, if the peak acceleration change is at
    least ``min_spike``.

    Args:
        t: Sample times [s] (T,), uniform.
        contact: Scheduled stance flags of this foot (T,).
        velocity: The calf's joint velocity [rad/s] (T,).
        window: Search window around the scheduled touchdown [s].
        fraction: Share of the window's peak score that marks the onset.
        min_spike: Smallest peak change of acceleration per sample [rad/s^2] taken as an impact.

    Returns:
        :class:`Touchdowns` (``spike``: the peak score [rad/s^2]).
    """
    t, v = np.asarray(t, float), np.asarray(velocity, float)
    lift, touch = _edges(contact)
    acc = np.gradient(v, t)
    score = np.abs(np.r_[0.0, np.diff(acc)])
    scheduled, detected, spike = [], [], []
    for k in touch:
        before = lift[lift < k]
        after = lift[lift > k]
        start_t = t[k] + window[0]
        if before.size:
            start_t = max(start_t, 0.5 * (t[before[-1]] + t[k]))
        end_t = t[k] + window[1]
        if after.size:
            end_t = min(end_t, t[after[0]])
        idx = np.flatnonzero((t >= start_t) & (t <= end_t))
        scheduled.append(t[k])
        if idx.size == 0 or score[idx].max() < min_spike:
            detected.append(np.nan)
            spike.append(np.nan)
            continue
        peak = score[idx].max()
        first = idx[np.argmax(score[idx] >= fraction * peak)]
        detected.append(t[first])
        spike.append(peak)
    return Touchdowns(np.array(scheduled), np.array(detected), np.array(spike))


def first_contacts(t, flags, scheduled, window=(-0.15, 0.1)) -> np.ndarray:
    """The first contact of a contact flag near each scheduled touchdown (e.g. the simulator's
    ``contact_sim``, which a robot does not have: a check of :func:`detect_touchdowns`).

    Args:
        t: Sample times [s] (T,).
        flags: Contact flags of one foot (T,).
        scheduled: Scheduled touchdown times [s] (n,).
        window: Search window around each scheduled touchdown [s].

    Returns:
        The first rise of ``flags`` in each window [s] (n,) (NaN: none).
    """
    out = []
    for ts in scheduled:
        idx = np.flatnonzero((t > ts + window[0]) & (t < ts + window[1]))
        rise = np.flatnonzero(np.diff(flags[idx].astype(int)) == 1)
        out.append(t[idx][rise[0] + 1] if rise.size else np.nan)
    return np.array(out)
