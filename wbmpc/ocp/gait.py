"""Gait schedules, swing-foot vertical velocity reference and nominal contact-force distribution.

Foot order everywhere in wbmpc is the Pinocchio leg order FOOT_NAMES = ("FL", "FR", "RL", "RR"):
front-left, front-right, rear-left, rear-right. Arrays indexed by foot have that order on axis 0.

A gait is periodic with period P [s]. Foot i swings while its local phase
    phi_i(t) = (t / P - offset_i) mod 1
is below the swing fraction sigma; its swing phase (fraction of the swing elapsed) is then phi_i / sigma.

Contact schedules are evaluated in integer ticks of the plant step (``SCHEDULE_TICK`` = 0.5 ms by
default), never in floating-point phases: a time t [s] becomes the tick k = round(t / tick), the period,
offsets and swing duration are whole numbers of ticks, and the phase is an integer modulo. A contact switch
is therefore one exact tick: the MPC's node 0 (sampled at the measurement time), the low level and the
plant (sampled at its own steps) can never put it on different sides of an MPC tick, which floating-point
``mod(t / P - offset, 1)`` did whenever a switch fell on a tick.

:class:`GaitSchedule` strings gaits together in time (stand, then trot, then stand); a single
:class:`Gait` is a one-segment schedule. Both offer the same ``sample`` / ``contact`` / ``swing_phase``.
A schedule's segments also carry their base velocity commands (:meth:`GaitSchedule.velocity_at`): a stand
segment stands still unless told otherwise, e.g. ``"stand:2,trot@0.5:4,trot@0.3/0/0.3:4"``.

Custom gaits: a :class:`Gait` with its own ``swing_fraction`` and ``offsets`` covers any periodic gait in
which each foot swings once per cycle (``Gait("gallop", 0.6, 0.3, (0.0, 0.1, 0.5, 0.6))``). For any other
contact pattern, subclass :class:`Gait` and override :meth:`Gait.sample_ticks`, returning
``GaitSample(contact, swing_phase)`` (``n_contacts`` and ``swing_duration`` may be left out: they are
filled in, the swing duration as ``swing_fraction * period``); the MPC, schedules, the plant and the low
level then use it. Override ``sample_ticks``, not ``sample`` (schedules sample in integer ticks)::

    class ThreeLegged(Gait):  # FL held up at mid-swing, the other feet as the walk it is made from
        def sample_ticks(self, ticks):
            base = super().sample_ticks(ticks)
            contact = base.contact.copy()
            contact[0] = False
            phase = np.where(contact, 0.0, base.swing_phase)
            phase[0] = 0.5
            return GaitSample(contact, phase)
"""

from __future__ import annotations

import bisect
import functools
import math
from dataclasses import dataclass
from typing import NamedTuple

import casadi as ca
import numpy as np

from wbmpc import checks

SCHEDULE_TICK = 5e-4  # [s] resolution of every contact schedule: the default plant step


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
    n_contacts (n,) int, swing_duration (4, n) [s] of the swing in progress (0 for stance feet).

    A custom gait's :meth:`Gait.sample_ticks` may leave ``n_contacts`` and ``swing_duration`` out
    (``None``): the gait fills them in (the swing duration as its ``swing_fraction * period``)."""

    contact: np.ndarray
    swing_phase: np.ndarray
    n_contacts: np.ndarray | None = None
    swing_duration: np.ndarray | None = None


def to_ticks(times, tick: float = SCHEDULE_TICK) -> np.ndarray:
    """Times [s] (1-D array) as the nearest integer ticks of ``tick`` [s] (int64)."""
    times = np.asarray(times, dtype=float)
    if times.ndim != 1 or not checks.all_finite(times):
        raise ValueError(f"times must be a finite 1-D array [s], got shape {times.shape}")
    return np.rint(times / tick).astype(np.int64)


def _whole_ticks(name: str, seconds: float, tick: float) -> int:
    """``seconds`` as a whole number of ticks, or ValueError naming the nearest valid value."""
    n = round(seconds / tick)
    if abs(n * tick - seconds) > 1e-9 * max(1.0, abs(seconds)):
        raise ValueError(
            f"{name} = {seconds} s is not a multiple of the schedule tick {tick * 1e3:g} ms "
            f"(the plant step); use e.g. {max(n, 1) * tick:.6g} s"
        )
    return n


@dataclass(frozen=True)
class Gait:
    """Periodic gait.

    Attributes:
        name: Gait name.
        period: Cycle duration P [s], > 0.
        swing_fraction: Swing duration / period, in [0, 1) (0: the feet never swing).
        offsets: Per-foot phase in [0, 1) of the cycle at which the swing starts, FOOT_NAMES order.
        tick: Schedule resolution [s] (the plant step); the period must be a whole number of ticks, the
            offsets and the swing duration are rounded to whole ticks.
    """

    name: str
    period: float
    swing_fraction: float
    offsets: tuple[float, float, float, float]
    tick: float = SCHEDULE_TICK

    def __post_init__(self):
        _finite("period", self.period, positive=True)
        _finite("tick", self.tick, positive=True)
        if not 0.0 <= _finite("swing_fraction", self.swing_fraction) < 1.0:
            raise ValueError(f"swing_fraction must be in [0, 1), got {self.swing_fraction}")
        try:
            offsets = np.asarray(self.offsets, dtype=float)
        except (TypeError, ValueError):
            raise ValueError(f"offsets must be 4 phases in [0, 1), got {self.offsets!r}") from None
        if offsets.shape != (4,) or not np.all((offsets >= 0.0) & (offsets < 1.0)):
            raise ValueError(f"offsets must be 4 phases in [0, 1), got {self.offsets!r}")
        object.__setattr__(self, "offsets", tuple(float(o) for o in offsets))
        period_ticks = _whole_ticks("period", self.period, self.tick)
        object.__setattr__(self, "_period_ticks", period_ticks)
        object.__setattr__(self, "_swing_ticks", round(self.swing_fraction * period_ticks))
        object.__setattr__(
            self, "_offset_ticks", np.rint(offsets * period_ticks).astype(np.int64) % period_ticks
        )
        object.__setattr__(self, "_offset_column", self._offset_ticks[:, None])

    def __init_subclass__(cls, **kwargs):
        """A subclass's ``sample_ticks`` (a custom contact pattern) is checked and completed: its samples
        get ``n_contacts`` and ``swing_duration`` if it left them out."""
        super().__init_subclass__(**kwargs)
        if "sample" in cls.__dict__ and "sample_ticks" not in cls.__dict__:
            raise TypeError(
                f"{cls.__name__} overrides Gait.sample: override sample_ticks(self, ticks) instead (integer "
                "ticks of self.tick, time = ticks * self.tick), which the MPC, gait schedules, the plant and "
                "the low level all use; return GaitSample(contact, swing_phase)"
            )
        custom = cls.__dict__.get("sample_ticks")
        if custom is None or getattr(custom, "_completes", False):
            return

        @functools.wraps(custom)
        def sample_ticks(self, ticks):
            ticks = np.asarray(ticks, dtype=np.int64)
            return self._completed(custom(self, ticks), ticks.size)

        sample_ticks._completes = True
        cls.sample_ticks = sample_ticks

    def _completed(self, sample, n: int) -> GaitSample:
        """A custom gait's sample checked (shapes, phases in [0, 1]) and completed."""
        who = f"{type(self).__name__}.sample_ticks"
        if not isinstance(sample, GaitSample):
            raise TypeError(
                f"{who} must return a GaitSample(contact, swing_phase), got {type(sample).__name__}"
            )
        contact = np.asarray(sample.contact, dtype=bool)
        phase = np.asarray(sample.swing_phase, dtype=float)
        for label, array in (("contact", contact), ("swing_phase", phase)):
            if array.shape != (4, n):
                raise ValueError(f"{who}: {label} must have shape (4, {n}) (feet x times), got {array.shape}")
        if not np.all((phase >= 0.0) & (phase <= 1.0)):
            raise ValueError(f"{who}: swing_phase must be in [0, 1] (the elapsed fraction of the swing)")
        n_contacts = contact.sum(axis=0) if sample.n_contacts is None else np.asarray(sample.n_contacts)
        if sample.swing_duration is None:
            if np.any(~contact) and self.swing_duration <= 0.0:
                raise ValueError(
                    f"{who}: feet swing but swing_fraction is 0, so no swing duration is known: give the "
                    "gait a swing_fraction > 0 (swing duration = swing_fraction * period) or return "
                    "swing_duration (4, n) [s]"
                )
            duration = np.where(contact, 0.0, self.swing_duration)
        else:
            duration = np.asarray(sample.swing_duration, dtype=float)
        return GaitSample(contact, phase, n_contacts, duration)

    @property
    def swing_duration(self) -> float:
        """Swing duration T = swing_fraction * period [s] (in whole ticks)."""
        return self._swing_ticks * self.tick

    @property
    def n_stance_nominal(self) -> int:
        """Average number of stance feet, 4 (1 - swing_fraction) rounded (trot 2, walk 3, stand 4)."""
        return round(4 * (1.0 - self.swing_fraction))

    def sample(self, times) -> GaitSample:
        """Contact flags and swing phases of the 4 feet at each of the given times [s] (1-D array)."""
        return self.sample_ticks(to_ticks(times, self.tick))

    def sample_ticks(self, ticks) -> GaitSample:
        """:meth:`sample` at integer ticks (time = tick * self.tick, the cycle starting at tick 0)."""
        local = np.mod(np.asarray(ticks, dtype=np.int64)[None, :] - self._offset_column, self._period_ticks)
        swing = local < self._swing_ticks  # always False for swing_fraction 0
        phase = np.where(swing, local / max(self._swing_ticks, 1), 0.0)
        contact = ~swing
        duration = np.where(swing, self.swing_duration, 0.0)
        return GaitSample(contact, phase, contact.sum(axis=0), duration)

    def mid_swing(self, tick: int) -> bool:
        """Whether a foot is in the air both just before and at ``tick`` (a schedule may not switch there)."""
        swing = ~self.sample_ticks(np.array([tick - 1, tick])).contact
        return bool(np.any(swing[:, 0] & swing[:, 1]))

    def contact(self, t: float) -> np.ndarray:
        """Contact flags (4,) bool at time t [s], True = stance."""
        return self.sample(np.array([_finite("t", t)])).contact[:, 0]

    def velocity_at(self, t: float) -> tuple[float, float, float] | None:
        """Base velocity command of this gait (as :meth:`GaitSchedule.velocity_at`): zero for a gait whose
        feet never swing (stand), ``None`` (the run's command) otherwise."""
        _finite("t", t)
        return (0.0, 0.0, 0.0) if self.swing_fraction == 0.0 else None

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


def make_gait(name: str, period: float = 0.8, tick: float = SCHEDULE_TICK) -> Gait:
    """Gait `name` in ("trot", "walk", "stand", "pace", "bound") with cycle period [s] (a whole number of
    schedule ticks [s])."""
    if name not in _GAITS:
        raise ValueError(f"name: unknown gait {name!r}, known gaits: {sorted(_GAITS)}")
    swing_fraction, offsets = _GAITS[name]
    return Gait(name, _finite("period", period, positive=True), swing_fraction, offsets, tick)


class GaitSchedule:
    """Gaits strung together in time: e.g. stand 2 s, trot 6 s, stand (the last gait goes on).

    Segment j runs its gait from its start tick, its cycle restarting there (a trot after a stand lifts its
    first pair at the switch); a segment of the same gait as the one before (a change of speed) continues
    its cycle. A switch never cuts a swing: a segment whose nominal end falls while a foot
    is in the air (in swing just before and at that tick) is extended to the next tick where no foot is,
    and :attr:`notes` says so. The MPC samples the schedule on its stage times, so its preview sees the
    coming gait before the switch.

    Each segment may carry its base velocity command ``(vx [m/s], vy [m/s], yaw rate [rad/s])`` in the
    heading frame (:meth:`velocity_at`): a stand segment without one stands still (zero), a walking segment
    without one takes the run's command.

    Args:
        segments: ``(gait, duration [s])`` pairs or ``(gait, duration [s], velocity)`` triples; the last
            duration only counts for :attr:`duration`.
        tick: Schedule resolution [s] (the plant step); every gait must share it.

    Raises:
        ValueError: an empty schedule, a segment that is not ``(Gait, duration[, velocity])``, a duration
            that is not > 0, a velocity that is not 3 finite numbers, gaits of another tick.
    """

    def __init__(self, segments, tick: float = SCHEDULE_TICK):
        segments = list(segments)
        if not segments:
            raise ValueError("GaitSchedule needs at least one (gait, duration) segment")
        self.tick = _finite("tick", tick, positive=True)
        starts, origins, notes, gaits, durations, velocities = [0], [0], [], [], [], []
        for j, segment in enumerate(segments):
            try:
                gait, duration, *rest = segment
            except (TypeError, ValueError) as err:
                raise ValueError(f"segment {j} must be a (gait, duration) pair, got {segment!r}") from err
            if len(rest) > 1:
                raise ValueError(
                    f"segment {j} must be (gait, duration) or (gait, duration, velocity), got {segment!r}"
                )
            velocities.append(_segment_velocity(j, rest[0]) if rest and rest[0] is not None else None)
            if not isinstance(gait, Gait):
                raise ValueError(f"segment {j}: {gait!r} is not a Gait (see wbmpc.ocp.gait.make_gait)")
            if abs(gait.tick - self.tick) > 1e-15:
                raise ValueError(
                    f"segment {j}: gait tick {gait.tick} s differs from the schedule's {self.tick} s"
                )
            duration = _finite(f"segment {j} ({gait.name}) duration", duration, positive=True)
            if j > 0:
                # Each segment's gait cycle starts at its own start, or goes on from its predecessor's when
                # the gait is the same (a change of speed must not lift the pair that just landed).
                origins.append(origins[-1] if gait == gaits[-1] else starts[-1])
            gaits.append(gait)
            durations.append(duration)
            if j == len(segments) - 1:
                break
            nominal = starts[-1] + max(1, round(duration / self.tick))
            end = nominal
            next_gait = segments[j + 1][0] if isinstance(segments[j + 1], tuple | list) else None
            while (
                next_gait != gait and gait.mid_swing(end - origins[-1]) and end - nominal < gait._period_ticks
            ):
                end += 1
            if end != nominal:
                notes.append(
                    f"{gait.name} segment {j} extended by {(end - nominal) * self.tick:.4g} s to "
                    f"t = {end * self.tick:.4g} s so that no swing is cut by the switch to "
                    f"{segments[j + 1][0].name}"
                )
            starts.append(end)
        self.gaits = tuple(gaits)
        self.velocities = tuple(velocities)
        self.start_ticks = np.asarray(starts, dtype=np.int64)
        self.cycle_origins = np.asarray(origins, dtype=np.int64)  # tick at which each segment's cycle starts
        self.notes = tuple(notes)
        self.duration = float(self.start_ticks[-1] * self.tick + durations[-1])

    @property
    def name(self) -> str:
        """``"stand:2+trot:6+stand:2"`` style (segment durations after any extension)."""
        ends = [*(self.start_ticks[1:] * self.tick), self.duration]
        starts = self.start_ticks * self.tick
        items = zip(self.gaits, self.velocities, starts, ends, strict=True)
        return "+".join(f"{g.name}{_velocity_spec(v)}:{e - s:g}" for g, v, s, e in items)

    @property
    def start_times(self) -> np.ndarray:
        """Start time [s] of each segment."""
        return self.start_ticks * self.tick

    def segment_index(self, times) -> np.ndarray:
        """Index of the segment in force at each time [s]."""
        ticks = to_ticks(times, self.tick)
        return np.clip(np.searchsorted(self.start_ticks, ticks, side="right") - 1, 0, len(self.gaits) - 1)

    def gait_at(self, t: float) -> Gait:
        """The gait in force at time t [s]."""
        return self.gaits[int(self.segment_index(np.array([_finite("t", t)]))[0])]

    def velocity_at(self, t: float) -> tuple[float, float, float] | None:
        """Base velocity command ``(vx [m/s], vy [m/s], yaw rate [rad/s])`` (heading frame) of the segment in
        force at time ``t`` [s]: its own, zero for a stand segment without one, ``None`` (the run's
        command) for a walking segment without one."""
        j = int(self.segment_index(np.array([_finite("t", t)]))[0])
        if self.velocities[j] is not None:
            return self.velocities[j]
        return (0.0, 0.0, 0.0) if self.gaits[j].swing_fraction == 0.0 else None

    def sample(self, times) -> GaitSample:
        """Contact flags, swing phases and swing durations of the 4 feet at the given times [s]."""
        ticks = to_ticks(times, self.tick)
        if ticks.size:  # all in one segment (a window around one time): that gait's sample
            listed = ticks.tolist()
            first, last = self._segment(min(listed)), self._segment(max(listed))
            if first == last:
                return self.gaits[first].sample_ticks(ticks - self.cycle_origins[first])
        index = np.clip(np.searchsorted(self.start_ticks, ticks, side="right") - 1, 0, len(self.gaits) - 1)
        n = ticks.size
        contact, phase, duration = np.ones((4, n), bool), np.zeros((4, n)), np.zeros((4, n))
        for j in np.unique(index):
            cols = index == j
            s = self.gaits[j].sample_ticks(ticks[cols] - self.cycle_origins[j])
            contact[:, cols], phase[:, cols], duration[:, cols] = s.contact, s.swing_phase, s.swing_duration
        return GaitSample(contact, phase, contact.sum(axis=0), duration)

    def _segment(self, tick: int) -> int:
        """Index of the segment in force at an integer tick (:meth:`segment_index` of one tick)."""
        return min(max(bisect.bisect_right(self.start_ticks.tolist(), tick) - 1, 0), len(self.gaits) - 1)

    def contact(self, t: float) -> np.ndarray:
        """Contact flags (4,) bool at time t [s], True = stance."""
        return self.sample(np.array([_finite("t", t)])).contact[:, 0]

    def swing_phase(self, t: float) -> np.ndarray:
        """Swing phase (4,) at time t [s], 0 for stance feet."""
        return self.sample(np.array([_finite("t", t)])).swing_phase[:, 0]

    def __repr__(self) -> str:
        return f"GaitSchedule({self.name!r}, tick={self.tick})"


def _segment_velocity(j: int, velocity) -> tuple[float, float, float]:
    try:
        values = tuple(float(x) for x in velocity)
    except (TypeError, ValueError):
        values = ()
    if len(values) != 3 or not all(math.isfinite(x) for x in values):
        raise ValueError(
            f"segment {j} velocity must be 3 finite numbers (vx [m/s], vy [m/s], yaw rate [rad/s]), "
            f"got {velocity!r}"
        )
    return values


def _velocity_spec(velocity) -> str:
    """``"@vx/vy/wz"`` of a segment velocity (shortest form), or "" for none."""
    if velocity is None:
        return ""
    parts = [f"{x:g}" for x in velocity]
    while len(parts) > 1 and velocity[len(parts) - 1] == 0.0:
        parts.pop()
    return "@" + "/".join(parts)


def parse_gait_schedule(spec: str, period: float = 0.8, tick: float = SCHEDULE_TICK) -> GaitSchedule:
    """A schedule from ``"stand:2,trot:6,stand:2"`` (gait names and durations [s]; a lone name such as
    ``"trot"`` is one segment that goes on), every gait with cycle ``period`` [s].

    A segment may name its base velocity command after ``@``: ``trot@0.5:4`` (forward 0.5 m/s),
    ``trot@0.3/0.1:4`` (and 0.1 m/s to the left), ``trot@0/0/0.3:4`` (a 0.3 rad/s yaw rate); heading frame.
    Without one a stand segment stands still and a walking segment takes the run's command.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise ValueError(f"gait schedule must be a string like 'stand:2,trot:6,stand:2', got {spec!r}")
    segments = []
    for item in spec.split(","):
        name, sep, duration = item.strip().partition(":")
        name, at, velocity_spec = name.partition("@")
        velocity = None
        if at:
            try:
                values = [float(x) for x in velocity_spec.split("/")]
            except ValueError:
                values = []
            if not 1 <= len(values) <= 3 or not all(math.isfinite(x) for x in values):
                raise ValueError(
                    f"gait schedule item {item!r}: the velocity after '@' must be vx[/vy[/yaw rate]] "
                    f"(finite numbers, m/s and rad/s), e.g. 'trot@0.5:4', got {velocity_spec!r}"
                )
            velocity = tuple(values + [0.0] * (3 - len(values)))
        if not sep:
            if "," in spec:
                raise ValueError(f"gait schedule item {item!r} needs a duration, e.g. '{name}:2'")
            duration = "inf"
        try:
            seconds = float(duration)
        except ValueError as err:
            raise ValueError(
                f"gait schedule item {item!r}: duration {duration!r} is not a number [s]"
            ) from err
        if seconds == float("inf"):
            seconds = 1e9  # a single gait that goes on
        segments.append((make_gait(name.strip(), period, tick), seconds, velocity))
    return GaitSchedule(segments, tick)


@dataclass(frozen=True)
class SwingParams:
    """Swing-foot reference: apex height [m] in (0, 0.5), lift-off / touch-down vertical velocities [m/s]."""

    height: float = 0.07
    v_liftoff: float = 0.1
    v_touchdown: float = -0.2

    def __post_init__(self):
        if not 0.0 < _finite("SwingParams.height", self.height) < 0.5:
            raise ValueError(f"SwingParams.height must be in (0, 0.5) m, got {self.height}")
        if not 0.0 <= _finite("SwingParams.v_liftoff", self.v_liftoff) <= 2.0:
            raise ValueError(f"SwingParams.v_liftoff must be in [0, 2] m/s (upwards), got {self.v_liftoff}")
        if not -2.0 <= _finite("SwingParams.v_touchdown", self.v_touchdown) <= 0.0:
            raise ValueError(
                f"SwingParams.v_touchdown must be in [-2, 0] m/s (downwards), got {self.v_touchdown}"
            )


def _check_swing(phi, T, h, v_lo, v_td):
    phi = np.asarray(phi, dtype=float)
    if not ((phi >= 0.0) & (phi <= 1.0)).all():
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
