"""Analysis of a run log that came from a robot: what the hardware did differently.

Every function takes a columnar :class:`~wbmpc.io.logs.RunLog`, typically read from a ROS 2 bag with
:func:`wbmpc.io.rosbag.read_bag`, and uses only what a robot records: joint states (``q``, ``v``, applied
torques ``tau``), the base state of the odometry, the scheduled contacts and the MPC's solve diagnostics.
None of the analyses needs the simulator's contact forces or the emulated robot's profile (the notebook
``05_hardware_log_analysis`` uses them only to check the results).

* :func:`solve_time_jitter`: solve times against the real-time budget (12.5 ms at 80 Hz), histogram data.
* :func:`gait_phase`, :func:`phase_profile`, :func:`align_by_phase`: a joint signal averaged over gait
  cycles and compared with a nominal simulation at the same commands.
* :func:`detect_touchdowns`: touchdown instants from the jump of a calf's joint velocity, against the
  schedule (a late contact shows as a late spike).
* :func:`foot_forces_from_torques`, :func:`identify_com_offset`: foot forces from the leg torques through the
  leg Jacobians, their centre of pressure against the model's centre of mass: the base's CoM offset.
* :func:`shift_base_com`: the model with that offset, for an MPC re-run; :func:`lean` measures the lean
  (pitch, rear-leg share) before and after.
* :func:`record_emulated_run`, :func:`write_robot_bag`: a stand-then-trot run on the emulated robot and its
  bag with a robot's topics only (how ``data/hardware/emulated_b1_stand_trot`` was made).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pinocchio as pin

from wbmpc.model.base_com import base_com_link, shift_base_com
from wbmpc.model.robot import heading

__all__ = [
    "BUDGET_S",
    "EMULATED_TORQUE_FRACTION",
    "ROBOT_TOPICS",
    "ComIdentification",
    "PhaseAlignment",
    "PhaseProfile",
    "SolveJitter",
    "Touchdowns",
    "align_by_phase",
    "base_com_link",
    "detect_touchdowns",
    "downsample",
    "emulated_mpc",
    "foot_forces_from_torques",
    "gait_phase",
    "identify_com_offset",
    "joint_signal",
    "lean",
    "phase_profile",
    "record_emulated_run",
    "shift_base_com",
    "solve_time_jitter",
    "standing_mask",
    "write_robot_bag",
]

BUDGET_S = 0.0125  # one MPC period at 80 Hz [s]


# ------------------------------------------------------------------------------------------------ jitter
@dataclass
class SolveJitter:
    """Solve times of a run against a real-time budget.

    Attributes:
        solve_ms: Solve times [ms] (the cold first solve left out unless asked for).
        edges_ms: Histogram bin edges [ms]; counts: solves per bin.
        budget_ms: The budget [ms].
        fraction_over: Share of the solves longer than the budget.
        median_ms, p95_ms, max_ms: Statistics [ms].
        period_ms: Intervals between consecutive solve starts [ms] (the loop's actual period).
    """

    solve_ms: np.ndarray
    edges_ms: np.ndarray
    counts: np.ndarray
    budget_ms: float
    fraction_over: float
    median_ms: float
    p95_ms: float
    max_ms: float
    period_ms: np.ndarray

    def summary(self) -> dict:
        """Scalars as a JSON-ready dict."""
        return {
            "solves": int(self.solve_ms.size),
            "budget_ms": self.budget_ms,
            "fraction_over_budget": self.fraction_over,
            "median_ms": self.median_ms,
            "p95_ms": self.p95_ms,
            "max_ms": self.max_ms,
            "period_median_ms": float(np.median(self.period_ms)) if self.period_ms.size else None,
        }


def solve_time_jitter(log, budget: float = BUDGET_S, bin_ms: float | None = None, skip_cold: bool = True):
    """Solve-time distribution and the share of solves over the budget.

    Args:
        log: Run log with the solve columns ``solve_time`` [s] and ``solve_t`` [s] (``/mpc/diagnostics``).
        budget: Real-time budget [s] (one MPC period, 12.5 ms at 80 Hz).
        bin_ms: Histogram bin width [ms]; ``None``: a tenth of the budget, widened to at most 60 bins.
        skip_cold: Leave out the first (cold-started) solve.

    Returns:
        :class:`SolveJitter`.
    """
    times = 1e3 * np.asarray(log["solve_time"], dtype=float)
    stamps = 1e3 * np.asarray(log["solve_t"], dtype=float)
    if skip_cold and times.size > 1:
        times = times[1:]
    if times.size == 0:
        raise ValueError("the log has no solves (no /mpc/diagnostics messages)")
    budget_ms = 1e3 * float(budget)
    top = max(float(times.max()), budget_ms)
    width = bin_ms or max(budget_ms / 10.0, top / 60.0)
    edges = np.arange(0.0, top + width, width)
    counts, edges = np.histogram(times, bins=edges)
    return SolveJitter(
        solve_ms=times,
        edges_ms=edges,
        counts=counts,
        budget_ms=budget_ms,
        fraction_over=float(np.mean(times > budget_ms)),
        median_ms=float(np.median(times)),
        p95_ms=float(np.percentile(times, 95)),
        max_ms=float(times.max()),
        period_ms=np.diff(stamps),
    )


# ------------------------------------------------------------------------------------------- gait phase
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


# --------------------------------------------------------------------------------------------- touchdown
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


# ---------------------------------------------------------------------------------------- CoM from torques
def standing_mask(
    log,
    t_min: float = 0.3,
    t_max: float | None = None,
    max_speed: float = 0.05,
    max_joint_speed: float | None = 0.03,
) -> np.ndarray:
    """Samples of quiet standing.

    Every foot scheduled in stance, ``t`` in ``[t_min, t_max]`` [s], base speed below ``max_speed`` [m/s]
    (odometry: ``v_meas``, else ``v``) and every joint slower than ``max_joint_speed`` [rad/s] (``v``, the
    encoders). The last one matters: a joint that moves carries its motor's friction torque, which the
    logged command does not contain (1 N m on a calf is ~3 N at the foot); still joints carry none on
    average.
    """
    t = np.asarray(log["t"], float)
    contact = np.asarray(log["contact"], bool)
    v = np.asarray(log["v_meas"] if "v_meas" in log.signals else log["v"], float)
    mask = contact.all(axis=1) & (t >= t_min) & (np.linalg.norm(v[:, :3], axis=1) < max_speed)
    if max_joint_speed is not None:
        mask &= np.abs(np.asarray(log["v"], float)[:, 6:]).max(axis=1) < max_joint_speed
    if t_max is not None:
        mask &= t <= t_max
    return mask


def _legs(robot) -> list[tuple[int, np.ndarray]]:
    """Per foot: its frame id and the velocity indices of the joints between the base and the foot."""
    model = robot.model
    out = []
    for name in robot.foot_frames:
        fid = robot.frame_id(name)
        joints = [j for j in model.supports[model.frames[fid].parentJoint] if j > 1]  # skip universe, base
        out.append((fid, np.array([model.joints[j].idx_v for j in joints])))
    return out


def foot_forces_from_torques(robot, q: np.ndarray, tau: np.ndarray, v=None, a=None) -> np.ndarray:
    """Ground forces on the feet [N] (T, n_feet, 3), world axes, from the leg joint torques.

    The leg rows of the equations of motion, ``tau_leg = rnea_leg(q, v, a) - J_leg^T F`` (with ``v = a = 0``:
    ``tau_leg = g_leg(q) - J_leg^T F``), solved for the force ``F`` at the foot's contact point (the bottom
    of the foot sphere) through the 3 x 3 Jacobian of the leg's joints. A leg's rows involve only the links
    below its hip, so the base's mass distribution does not enter.

    Args:
        robot: The robot model (:class:`~wbmpc.model.robot.Robot`).
        q: Configurations (T, nq); tau: joint torques (T, nj) [N m].
        v, a: Optional velocities and accelerations (T, nv) for the dynamic terms.
    """
    model, data = robot.model, robot.model.createData()
    q, tau = np.atleast_2d(q), np.atleast_2d(tau)
    legs = _legs(robot)
    lever = pin.skew(np.array([0.0, 0.0, robot.foot_radius]))  # contact point = frame - r e_z
    zero = np.zeros(model.nv)
    forces = np.zeros((len(q), len(legs), 3))
    for k in range(len(q)):
        vk = zero if v is None else v[k]
        ak = zero if a is None else a[k]
        h = pin.rnea(model, data, q[k], vk, ak)
        pin.computeJointJacobians(model, data, q[k])
        pin.updateFramePlacements(model, data)
        for i, (fid, idx) in enumerate(legs):
            J = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
            Jc = J[:3] + lever @ J[3:]
            forces[k, i] = np.linalg.solve(Jc[:, idx].T, h[idx] - tau[k, idx - 6])
    return forces


@dataclass
class ComIdentification:
    """The base's centre-of-mass offset identified from a standing log.

    Attributes:
        offset: Shift [m] (3,) of the base link's CoM in the base frame (x forward) that explains the centre
            of pressure, in the convention of :attr:`wbmpc.sim.hardware.HardwareProfile.base_com_offset`
            (the heaviest rigidly attached link, mass ``link_mass``, moves). ``z`` is 0: statics on flat
            ground cannot see a vertical shift.
        body_offset: The same as a shift of the whole rigid base body's CoM (mass ``body_mass``) [m].
        com_shift: Whole-robot CoM minus the model's [m] (3,), heading frame (z = 0).
        cop: Centre of pressure minus the model's CoM [m] per sample (n, 2), heading frame.
        foot_forces: Estimated foot forces [N] (n, n_feet, 3), world axes.
        rear_share: Share of the vertical force on the rear feet.
        front_force_ratio: ``1 - rear_share``: the force targets' front share for the MPC.
        samples: Samples used; window_s: their time span [s].
        link_mass: Mass of the moved link [kg]; body_mass: of the rigid base body in the model [kg].
    """

    offset: np.ndarray
    body_offset: np.ndarray
    com_shift: np.ndarray
    cop: np.ndarray
    foot_forces: np.ndarray
    rear_share: float
    front_force_ratio: float
    samples: int
    window_s: tuple[float, float]
    link_mass: float
    body_mass: float

    def summary(self) -> dict:
        return {
            "offset_m": self.offset.tolist(),
            "body_offset_m": self.body_offset.tolist(),
            "com_shift_m": self.com_shift.tolist(),
            "cop_std_m": self.cop.std(axis=0).tolist(),
            "rear_share": self.rear_share,
            "front_force_ratio": self.front_force_ratio,
            "samples": self.samples,
            "window_s": list(self.window_s),
        }


def identify_com_offset(
    log, robot, mask: np.ndarray | None = None, dynamic: bool = True, rear: tuple[int, ...] = (2, 3)
) -> ComIdentification:
    """The base's centre-of-mass offset from the leg torques of a standing robot.

    Foot forces come from the torques (:func:`foot_forces_from_torques`). In static balance on the ground
    the moments about the whole robot's CoM ``c`` vanish: with contact points ``p_i`` and forces ``F_i``,
    ``c_x = (sum x_i F_zi - sum (z_i - c_z) F_xi) / sum F_zi`` (and ``y`` alike), the centre of pressure
    corrected for the horizontal forces. Its difference to the model's CoM at the same configuration is the
    CoM shift; the base link (mass ``m_b`` of a robot of mass ``M``) moved by ``M / m_b`` times it.

    Args:
        log: Run log with ``t``, ``q`` (base pose from odometry or ground truth), ``v``, ``tau``, ``contact``.
        robot: The nominal model.
        mask: Samples to use (T,); ``None``: :func:`standing_mask`.
        dynamic: Include the legs' velocity and acceleration terms (acceleration from finite differences).
        rear: Indices of the rear feet.

    Returns:
        :class:`ComIdentification`.
    """
    t = np.asarray(log["t"], float)
    mask = standing_mask(log) if mask is None else np.asarray(mask, bool)
    if mask.sum() < 10:
        raise ValueError(f"only {int(mask.sum())} standing samples: need a log with quiet standing")
    q, tau = np.asarray(log["q"], float)[mask], np.asarray(log["tau"], float)[mask]
    v = a = None
    if dynamic:
        v_all = np.asarray(log["v"], float)
        a = np.gradient(v_all, t, axis=0)[mask]
        v = v_all[mask]
    forces = foot_forces_from_torques(robot, q, tau, v, a)
    model, data = robot.model, robot.model.createData()
    r = robot.foot_radius
    ids = [robot.frame_id(f) for f in robot.foot_frames]
    cop = np.zeros((len(q), 2))
    for k in range(len(q)):
        c = pin.centerOfMass(model, data, q[k])
        pin.framesForwardKinematics(model, data, q[k])
        p = np.array([data.oMf[i].translation - [0.0, 0.0, r] for i in ids])
        F = forces[k]
        fz = F[:, 2].sum()
        cx = (np.dot(p[:, 0], F[:, 2]) - np.dot(p[:, 2] - c[2], F[:, 0])) / fz
        cy = (np.dot(p[:, 1], F[:, 2]) - np.dot(p[:, 2] - c[2], F[:, 1])) / fz
        yaw = heading(q[k])
        R = np.array([[np.cos(yaw), np.sin(yaw)], [-np.sin(yaw), np.cos(yaw)]])  # world -> heading
        cop[k] = R @ (np.array([cx, cy]) - c[:2])
    shift = np.r_[cop.mean(axis=0), 0.0]
    _, link_mass = base_com_link(robot)
    body_mass = float(model.inertias[1].mass)
    share = float(forces[:, list(rear), 2].sum() / forces[:, :, 2].sum())
    return ComIdentification(
        offset=robot.mass / link_mass * shift,
        body_offset=robot.mass / body_mass * shift,
        com_shift=shift,
        cop=cop,
        foot_forces=forces,
        rear_share=share,
        front_force_ratio=1.0 - share,
        samples=int(mask.sum()),
        window_s=(float(t[mask][0]), float(t[mask][-1])),
        link_mass=link_mass,
        body_mass=body_mass,
    )


# ------------------------------------------------------------------------------------------------- lean
def lean(
    log, mask: np.ndarray | None = None, robot=None, rear: tuple[int, ...] = (2, 3), samples: int = 400
) -> dict:
    """How much a run leans: base pitch and the rear feet's share of the vertical force.

    Args:
        log: Run log (``q``; ``plan_forces`` and ``solve_t`` for the planned share; ``tau`` with ``robot``).
        mask: Samples to use (T,); ``None``: every sample.
        robot: The model, to estimate the forces from the leg torques (:func:`foot_forces_from_torques`,
            static terms) on up to ``samples`` evenly spread samples; ``None``: skipped.
        rear: Indices of the rear feet.

    Returns:
        ``pitch_mean_rad``, ``pitch_std_rad`` (positive: nose down), ``rear_share_torques`` (from the leg
        torques, ``None`` without ``robot``), ``rear_share_measured`` (``foot_forces``, a simulator's, if
        logged), ``rear_share_planned`` (the MPC's first-stage forces of the solves in the same time span).
    """
    t = np.asarray(log["t"], float)
    mask = np.ones(t.shape, bool) if mask is None else np.asarray(mask, bool)
    q = np.asarray(log["q"], float)[mask]
    rot = [pin.Quaternion(qk[3:7]).normalized().toRotationMatrix() for qk in q]
    pitch = np.array([pin.rpy.matrixToRpy(R)[1] for R in rot])
    out = {"pitch_mean_rad": float(pitch.mean()), "pitch_std_rad": float(pitch.std())}

    def share(fz):
        return float(fz[:, list(rear)].sum() / fz[:, :4].sum()) if fz.size else None

    out["rear_share_torques"] = None
    if robot is not None:
        pick = np.linspace(0, len(q) - 1, min(samples, len(q))).astype(int)
        tau = np.asarray(log["tau"], float)[mask][pick]
        out["rear_share_torques"] = share(foot_forces_from_torques(robot, q[pick], tau)[:, :, 2])
    forces = log.signals.get("foot_forces")
    out["rear_share_measured"] = (
        share(np.asarray(forces, float)[mask][:, :, 2]) if forces is not None else None
    )
    out["rear_share_planned"] = None
    if "plan_forces" in log.solves and len(log["plan_forces"]):
        st = np.asarray(log["solve_t"], float)
        span = (st >= t[mask][0]) & (st <= t[mask][-1])
        out["rear_share_planned"] = share(np.asarray(log["plan_forces"], float)[span][:, :4, 2])
    return out


# ------------------------------------------------------------------------------------------- recording
#: Share of the torque limits the MPC plans with on the emulated robot: the drives add their damping on top
#: and clip at the limit (at 1.0 the rear calves were clipped for a few steps at 0.5 m/s).
EMULATED_TORQUE_FRACTION = 0.9


def emulated_mpc(robot, gait, nodes: int = 15, compiled: bool = True, front_force_ratio=None):
    """The MPC the emulated-robot runs use: ``robot``'s model, the gait (schedule), ``nodes`` nodes, torque
    limits at :data:`EMULATED_TORQUE_FRACTION` (:class:`~wbmpc.ocp.OCPSettings`), compiled Fatrop or
    in-process."""
    from wbmpc.control.mpc import MPCConfig, WholeBodyMPC
    from wbmpc.ocp import OCPSettings

    config = MPCConfig(gait=gait, compiled=compiled, front_force_ratio=front_force_ratio)
    settings = OCPSettings(n_nodes=nodes, torque_limit_fraction=EMULATED_TORQUE_FRACTION)
    mpc = WholeBodyMPC(robot, settings, config)
    mpc.verbose = False
    return mpc


def record_emulated_run(
    stand: float = 2.0,
    trot: float = 10.0,
    speed: float = 0.2,
    nodes: int = 15,
    compiled: bool = True,
    profile=None,
    robot=None,
    mpc_robot=None,
    front_force_ratio: float | None = None,
    progress: bool = False,
    gait: str | None = None,
    mpc=None,
    **overrides,
):
    """A run of the MPC on the emulated robot (:func:`wbmpc.sim.presets.hardware_config`): stand, then trot.

    The computation delay is the measured one (each whole solve call's wall time on this machine) unless
    ``delay`` is overridden; the arm holds still in the heading frame (``arm_reference=None`` with
    ``ee_velocity_frame="heading"``).

    Args:
        stand, trot: Durations [s] of the standing and trotting segments (gait schedule
            ``stand:S,trot@speed:T``); ignored with ``gait``.
        speed: Forward speed command of the trot [m/s] (the stand segment stands still).
        nodes: MPC nodes; compiled: compiled Fatrop (cached) or in-process.
        profile: The emulated robot (:class:`~wbmpc.sim.hardware.HardwareProfile`; default: its defaults).
        robot: The robot (default :func:`~wbmpc.model.robot.load_b1_z1`); mpc_robot: the model the MPC uses
            (default: ``robot``; e.g. :func:`shift_base_com` of it, or a calibrated one).
        front_force_ratio: Front share of the MPC's force targets (``None``: the MPC robot's).
        progress: Progress bar.
        gait: A gait schedule instead (:func:`wbmpc.ocp.gait.parse_gait_schedule`, e.g.
            ``"stand:2,trot@0.2:10,trot@0.5:5"``); the run lasts its duration.
        mpc: An MPC to run (e.g. with an observer attached), its gait replaced by the schedule; ``None``
            builds one for ``mpc_robot`` with ``nodes``, ``compiled`` and ``front_force_ratio``.
        **overrides: :class:`~wbmpc.sim.closed_loop.ClosedLoopConfig` fields (``delay``, ``kp``, ...).

    Returns:
        ``(result, mpc)``: the :class:`~wbmpc.sim.closed_loop.ClosedLoopResult` and the MPC.
    """
    from wbmpc.model.robot import load_b1_z1
    from wbmpc.ocp.gait import parse_gait_schedule
    from wbmpc.sim.closed_loop import run_closed_loop
    from wbmpc.sim.presets import hardware_config

    robot = robot or load_b1_z1()
    spec = gait or (f"stand:{stand:g},trot@{speed:g}:{trot:g}" if trot > 0 else "stand")
    schedule = parse_gait_schedule(spec)
    duration = schedule.duration if gait else stand + trot
    if mpc is None:
        mpc = emulated_mpc(mpc_robot or robot, schedule, nodes, compiled, front_force_ratio)
    else:
        mpc.config = replace(mpc.config, gait=schedule)
    options = {"arm_reference": None, "ee_velocity_frame": "heading"} | overrides
    run = hardware_config(profile, duration=duration, **options)
    return run_closed_loop(mpc, run, progress=progress), mpc


#: Topics a robot records (no simulator truth: no ground-truth odometry, no foot force sensors) and no arm
#: topics (the arm holds still in these runs): about 0.65 MB per second at 250 Hz in MCAP.
ROBOT_TOPICS = {
    "joint_states_measured": None,
    "joint_feedforward": None,
    "ground_truth": None,
    "foot_forces": None,
    "ee_position": None,
    "ee_reference": None,
    "ee_force": None,
    "ee_force_cmd": None,
    "extra_prefix": None,
}


def downsample(log, factor: int):
    """The log with every ``factor``-th signal row (solves unchanged): a lower recording rate."""
    from wbmpc.io.logs import RunLog

    if int(factor) < 1:
        raise ValueError(f"factor must be an integer >= 1, got {factor!r}")
    signals = {k: np.asarray(v)[:: int(factor)] for k, v in log.signals.items()}
    return RunLog(signals=signals, solves=dict(log.solves), meta=dict(log.meta))


def write_robot_bag(log, path, robot, factor: int = 2, storage: str = "mcap"):
    """Record a run as a robot's bag: :data:`ROBOT_TOPICS`, signals at 500 / ``factor`` Hz.

    Returns:
        ``(path, topic_map)``: the bag folder and the :class:`~wbmpc.io.rosbag.TopicMap` to read it with.
    """
    from wbmpc.io.rosbag import TopicMap, write_bag

    topic_map = TopicMap(**ROBOT_TOPICS)
    return write_bag(
        downsample(log, factor), path, robot=robot, storage=storage, topic_map=topic_map
    ), topic_map
