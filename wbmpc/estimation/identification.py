"""Motor friction and rotor inertia (armature) of each joint group, identified from a robot's run log.

Method. A joint row of the floating-base equations of motion of a limb that touches nothing (a leg in
swing, the arm without an end-effector force) reads

.. math::  \\tau_{cmd}(t - d) - \\left(M(q)\\,\\dot v + h(q, v)\\right)_j
           = c \\tanh(\\dot q_j / v_s) + b\\,\\dot q_j + I_a\\,\\ddot q_j

with the full rigid-body model's ``M`` and ``h`` (numeric Pinocchio RNEA with the base acceleration, without
armature), the logged command ``tau_cmd`` acting ``d`` seconds late, and the unknown Coulomb friction ``c``
[N m], viscous friction ``b`` [N m s/rad] and armature ``I_a`` [kg m^2] of the joint's motor
(:class:`wbmpc.model.friction.JointFriction`). A limb's rows involve only the links below its first joint,
so the base's mass distribution (the CoM offset) does not enter. Per joint group (the same joint of every
leg, or one arm joint) a least-squares fit over the features ``[tanh(qdot / v_s), qdot, qddot]`` of its
free samples gives ``(c, b, I_a)``.

The equation is taken as a mean over each sample period ``[t_k, t_k+1]``: the acceleration is the finite
difference ``(v_k+1 - v_k) / dt`` of the logged velocities (no differentiation filter, whose lag would
differ from the torque's), ``M`` and ``h`` are evaluated at the period's midpoint, the command is the mean
of its linear interpolation over ``[t_k - d, t_k+1 - d]`` and the Coulomb feature the mean of its values at
both ends. Both sides, the features included, are then smoothed by one Savitzky-Golay filter (cubic,
``window`` seconds): a linear filter applied alike to the equation and to its features leaves the fit
unbiased and removes the noise of the finite differences.

Signals (what a robot records; :data:`wbmpc.analysis.ROBOT_TOPICS`):

* joints: the encoders (``q[:, 7:]``, ``v[:, 6:]``, the joint states);
* base: pose and linear velocity of the state estimator (``q_meas``/``v_meas``, the odometry; the log's
  ``q``/``v`` if it has none); its accelerations from the IMU (``base="imu"``: the specific force
  ``imu_accelerometer`` rotated to the world with the estimated attitude, plus gravity, and the finite
  difference of ``imu_gyro``), from the finite difference of the estimator's base velocity
  (``base="odometry"``, worse: the estimator's velocity lags), or from the log's ``q``/``v`` as they are
  (``base="log"``: the simulator's truth in a simulation log; the odometry in a bag without ground
  truth). The base acceleration matters: a leg's rows carry its mass times it (~1 N m per m/s^2 on a B1
  thigh). No ground-truth signal is needed;
* the joint torque ``tau``: the command sent to the motors (after the controller's clipping), or, when
  the motor drivers close the joint PD loop themselves (Unitree's low-level interface,
  :mod:`wbmpc.sim.motor_drive`), the torque the drivers report.

Assumptions:

* the logged torque reaches the joint ``delay`` seconds after its stamp. A command sent to the motors:
  the transport latency plus half its hold period (a zero-order hold delays a signal by half its period
  on average: with 3 ms latency and a 500 Hz command, 4 ms). A torque reported by the drivers: about 0
  (the latency then delays the setpoints, which the log does not need). ``delay=None`` fits it per group
  (the residual is smallest near the true delay; the viscous term absorbs the rest of an error:
  ~0.2 N m s/rad per ms on the B1's legs);
* the log holds every command (the joint states recorded at the command rate): at half the command rate
  the commands in between are unknown and the armature comes out low (B1 hips and thighs: 15-25 %);
* a torque reported by the drivers is their output at the sample instant, and the drivers update it much
  faster than the log samples it: a driver that holds its torque for ``h`` seconds while closing a
  damping loop ``k_d (qdot_des - qdot)`` changes it within each log period in a way the samples do not
  show, and the armature comes out ``k_d h / 2`` low (0.005 kg m^2 for the emulated robot's 2 kHz
  drivers at k_d = 20 N m s/rad; 0.0005 for a 20 kHz driver); the friction is not affected;
* the IMU sits at the base origin with the base's axes, and ``imu_accelerometer[k]`` is the mean specific
  force over the sample period ending at ``t_k`` (an IMU's delta-velocity output divided by the period,
  as :func:`wbmpc.estimation.synthesize_imu` gives);
* a leg is free while the schedule (``contact`` column) has it in swing, ``swing_margin`` seconds away
  from its liftoff and touchdown; a foot that still touches the ground (late liftoff, early touchdown,
  dragging) shows as a large residual on all joints of its leg and is removed by iterated outlier
  rejection (``outlier_threshold`` robust standard deviations, widened by the filter's half width);
* the arm is free unless the log commands an end-effector force (``ee_force_cmd``);
* the friction smoothing ``v_s`` (``friction_velocity``) is given: it shapes the friction only below
  ~2 v_s (0.1 rad/s), where swinging joints spend little time;
* the friction and armature are those of the motor at the joint (the reflected rotor inertia adds to the
  joint's diagonal of ``M``), identical for the joints of a group.

A parameter is reported as identified when its estimate is >= 0 and its standard error is below
``max_relative_error`` of it (standard errors from the residual, with the sample count reduced by the
filter's width for the correlation it causes). A joint that barely moves (an arm held still) cannot
separate its Coulomb from its viscous term: they are then reported as not identified.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
import pinocchio as pin

from wbmpc.estimation.friction_fit import PARAMETERS, UNITS, FrictionIdentification, GroupFit, log_column
from wbmpc.estimation.signals import dilate, erode, savgol

# FrictionIdentification and GroupFit (wbmpc.estimation.friction_fit) are the results, re-exported here.
__all__ = ["FrictionIdentification", "GroupFit", "default_joint_groups", "identify_joint_friction"]

BASE_SOURCES = ("auto", "imu", "odometry", "log")
_MIN_SAMPLES = 50


# -------------------------------------------------------------------------------------------- groups
def _chains(robot) -> dict[str, list[str]]:
    """Free-limb chains: per foot the joints between the base and the foot, and the arm's joints."""
    model = robot.model
    chains = {}
    for foot in robot.foot_frames:
        joint = model.frames[robot.frame_id(foot)].parentJoint
        names = []
        while joint > 1:
            names.append(model.names[joint])
            joint = model.parents[joint]
        chains[foot] = names[::-1]
    if robot.has_arm:
        chains["arm"] = list(robot.arm_joint_names)
    return chains


def default_joint_groups(robot) -> dict[str, list[str]]:
    """Joint groups of one motor type each: the k-th joint of every leg together, each arm joint alone.

    A leg group is named by what its joints' names share once the foot prefix is removed (the B1's
    ``hip``, ``thigh``, ``calf``), else ``leg_joint<k>``; an arm group by its joint.

    Raises:
        ValueError: if the legs do not all have the same number of joints.
    """
    chains = _chains(robot)
    legs = [chains[f] for f in robot.foot_frames]
    if len({len(leg) for leg in legs}) != 1:
        raise ValueError(
            f"legs of different lengths {[len(leg) for leg in legs]}: give the groups explicitly"
        )
    groups = {}
    for k, joints in enumerate(zip(*legs, strict=True)):
        stems = {name.split("_", 1)[-1].removesuffix("_joint") for name in joints}
        name = stems.pop() if len(stems) == 1 else f"leg_joint{k}"
        groups[name if name not in groups else f"leg_joint{k}"] = list(joints)
    for joint in chains.get("arm", []):
        groups[joint] = [joint]
    return groups


def _check_groups(robot, groups: Mapping[str, Sequence[str]]) -> dict[str, list[str]]:
    if not isinstance(groups, Mapping) or not groups:
        raise ValueError(f"groups must map group names to lists of joint names, got {groups!r}")
    limb = {name for chain in _chains(robot).values() for name in chain}
    seen: dict[str, str] = {}
    out = {}
    for group, joints in groups.items():
        if isinstance(joints, str) or not isinstance(joints, Sequence) or not joints:
            raise ValueError(f"group {group!r} must list joint names, got {joints!r}")
        for joint in joints:
            if joint not in robot.joint_names:
                raise ValueError(f"group {group!r}: unknown joint {joint!r}; joints: {robot.joint_names}")
            if joint not in limb:
                raise ValueError(f"group {group!r}: joint {joint!r} is in no leg and not in the arm")
            if joint in seen:
                raise ValueError(f"joint {joint!r} is in groups {seen[joint]!r} and {group!r}")
            seen[joint] = group
        out[str(group)] = list(joints)
    return out


# ------------------------------------------------------------------------------------------- checks
def _check_options(friction_velocity, delay, delay_range, window, swing_margin, outlier_threshold, base):
    def positive(name, value, allow_zero=False):
        ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
        if not ok or value < 0 or (value == 0 and not allow_zero):
            raise ValueError(f"{name} must be a finite number {'>=' if allow_zero else '>'} 0, got {value!r}")

    positive("friction_velocity", friction_velocity)
    positive("window", window, allow_zero=True)
    positive("swing_margin", swing_margin, allow_zero=True)
    positive("outlier_threshold", outlier_threshold)
    if delay is not None and not (isinstance(delay, int | float) and abs(delay) < 1.0):
        raise ValueError(f"delay must be a finite number of seconds (|delay| < 1 s) or None, got {delay!r}")
    if (
        not isinstance(delay_range, Sequence)
        or len(delay_range) != 2
        or not all(isinstance(x, int | float) and abs(x) < 1.0 for x in delay_range)
        or not delay_range[0] < delay_range[1]
    ):
        raise ValueError(
            f"delay_range must be (low, high) [s] with low < high, |values| < 1 s, got {delay_range!r}"
        )
    if base not in BASE_SOURCES:
        raise ValueError(f"base must be one of {BASE_SOURCES}, got {base!r}")


# ------------------------------------------------------------------------------------ identification
def identify_joint_friction(
    log,
    robot,
    *,
    groups: Mapping[str, Sequence[str]] | None = None,
    friction_velocity: float = 0.05,
    delay: float | None = None,
    delay_range: tuple[float, float] = (-0.004, 0.008),
    window: float = 0.016,
    swing_margin: float = 0.03,
    outlier_threshold: float = 3.5,
    base: str = "auto",
    max_relative_error: float = 0.15,
    min_speed: float | None = None,
    t_min: float = 0.0,
) -> FrictionIdentification:
    """Coulomb and viscous friction and armature per joint group from a log's torque-tracking error.

    The method and its assumptions are in the module doc.

    Args:
        log: :class:`~wbmpc.io.logs.RunLog` (e.g. :func:`wbmpc.io.rosbag.read_bag` of a robot's bag) with
            ``t`` (evenly spaced), ``q``, ``v``, ``tau``, ``contact`` and, for ``base="imu"``,
            ``imu_accelerometer`` and ``imu_gyro``; ``q_meas``/``v_meas`` are used for the base if present.
        robot: The nominal :class:`~wbmpc.model.robot.Robot` (its armature, if any, is left out of the
            model: it is what is identified).
        groups: ``{name: [joint, ...]}`` (``None``: :func:`default_joint_groups`); every joint in a leg or
            the arm, in one group at most.
        friction_velocity: Smoothing rate ``v_s`` [rad/s] of the Coulomb feature ``tanh(qdot / v_s)``.
        delay: Time [s] from a logged torque to the torque at the joint (see the module doc); ``None``:
            fitted per group.
        delay_range: Search range [s] of the fitted delay (0.2 ms grid, then refined to 0.01 ms).
        window: Savitzky-Golay window [s] (cubic; at least 5 samples; 0: no smoothing).
        swing_margin: Samples this close [s] to a scheduled liftoff or touchdown are not used.
        outlier_threshold: Rejection threshold [robust standard deviations] of a limb's residual.
        base: ``"auto"`` (``"imu"`` if the log has IMU columns, else ``"odometry"``), ``"imu"``,
            ``"odometry"`` or ``"log"`` (see the module doc).
        max_relative_error: A parameter is identified if its standard error is below this share of it.
        min_speed: A joint's samples slower than this [rad/s] (over the filter's window) are not used
            (``None``: 2 ``friction_velocity``): a joint that stops sticks, and the friction then holds
            it with whatever torque is needed, not a function of its rate.
        t_min: Ignore samples before this time [s].

    Returns:
        :class:`FrictionIdentification`.

    Raises:
        ValueError: for a missing or misshaped column, unevenly spaced samples, a log shorter than the
            filter, a bad group or option, or ``base="imu"`` on a log without IMU columns.
    """
    _check_options(friction_velocity, delay, delay_range, window, swing_margin, outlier_threshold, base)
    if min_speed is not None and not (isinstance(min_speed, int | float) and 0 <= min_speed < math.inf):
        raise ValueError(f"min_speed must be a finite number >= 0 [rad/s] or None, got {min_speed!r}")
    if not (isinstance(max_relative_error, int | float) and 0 < max_relative_error < math.inf):
        raise ValueError(f"max_relative_error must be a finite number > 0, got {max_relative_error!r}")
    groups = _check_groups(robot, default_joint_groups(robot) if groups is None else groups)
    t = np.asarray(log["t"] if "t" in log.signals else [], dtype=float)
    if t.ndim != 1 or t.size < 3:
        raise ValueError(f"the log needs a time column 't' with samples, got {t.size} samples")
    dt = float(np.median(np.diff(t)))
    if not dt > 0 or np.max(np.abs(np.diff(t) - dt)) > 0.05 * dt:
        raise ValueError(
            f"the log's samples are not evenly spaced (median period {dt:g} s, largest deviation "
            f"{np.max(np.abs(np.diff(t) - dt)):g} s): resample it first"
        )
    half = max(2, round(window / (2 * dt))) if window > 0 else 0
    if t.size < max(4 * half + 2, _MIN_SAMPLES):
        raise ValueError(
            f"the log has {t.size} samples: too short (at least {max(4 * half + 2, _MIN_SAMPLES)} for a "
            f"{2 * half + 1}-sample filter)"
        )
    n, nq, nv, nj = t.size, robot.nq, robot.nv, robot.nj
    q_log, v_log = log_column(log, "q", (nq,), n), log_column(log, "v", (nv,), n)
    tau = log_column(log, "tau", (nj,), n)
    chains = _chains(robot)
    has_imu = "imu_accelerometer" in log.signals and "imu_gyro" in log.signals
    if base == "auto":
        base = "imu" if has_imu else "odometry"
    if base == "imu" and not has_imu:
        raise ValueError("base='imu' needs the log's 'imu_accelerometer' and 'imu_gyro' columns")
    leg_joints = {j for f in robot.foot_frames for j in chains[f]}
    contact = None
    if any(j in leg_joints for js in groups.values() for j in js):
        contact = np.asarray(log["contact"] if "contact" in log.signals else np.zeros((0,)), dtype=bool)
        if contact.shape != (n, robot.n_feet):
            raise ValueError(
                f"the log needs the scheduled contacts 'contact' (T, {robot.n_feet}) to find the legs' swing "
                f"phases, got shape {contact.shape}"
            )

    qm, vm, am = _intervals(log, robot, base, q_log, v_log, dt)
    model = robot.model.copy()
    model.armature[:] = 0.0
    data = model.createData()
    valid = np.isfinite(am).all(axis=1) & np.isfinite(vm).all(axis=1) & (t[:-1] >= t_min)
    rigid = np.full((n - 1, nj), np.nan)
    for k in np.flatnonzero(valid):
        rigid[k] = pin.rnea(model, data, qm[k], vm[k], am[k])[6:]

    def smooth(x: np.ndarray) -> np.ndarray:
        return savgol(x, half, 0, dt) if half else x

    coulomb = np.tanh(v_log[:, 6:] / friction_velocity)
    features = smooth(np.stack([0.5 * (coulomb[1:] + coulomb[:-1]), vm[:, 6:], am[:, 6:]], axis=2))
    slowest = 2 * friction_velocity if min_speed is None else float(min_speed)
    moving = np.abs(v_log[:, 6:]) >= slowest
    moving = np.stack([erode(m[:-1] & m[1:], half) for m in moving.T], axis=1)  # (T - 1, nj)
    free = _free_samples(robot, log, chains, contact, swing_margin, dt)
    candidates = {c: m[:-1] & m[1:] & valid for c, m in free.items()}  # per sample period
    index = {name: i for i, name in enumerate(robot.joint_names)}
    chain_of = {j: c for c, joints in chains.items() for j in joints}
    nodes = np.linspace(0.0, 1.0, 9)

    def target(d: float, cols: list[int]) -> np.ndarray:
        """Mean delayed command minus the rigid-body torque per sample period, smoothed (n - 1, len(cols))."""
        mean = np.mean([[np.interp(t[:-1] + x * dt - d, t, tau[:, c]) for c in cols] for x in nodes], axis=0)
        return smooth(mean.T - rigid[:, cols])

    delays = {g: (0.004 if delay is None else float(delay)) for g in groups}
    use = dict(candidates)
    for round_ in range(2 if delay is None else 1):
        y = {g: target(delays[g], [index[j] for j in js]) for g, js in groups.items()}
        use = _reject_outliers(
            groups, y, features, index, chain_of, candidates, moving, outlier_threshold, half
        )
        if delay is None and round_ == 0:
            for g, joints in groups.items():
                cols = [index[j] for j in joints]
                masks = [use[chain_of[j]] & moving[:, index[j]] for j in joints]
                delays[g] = _best_delay(
                    lambda d, cols=cols, masks=masks: _fit(target(d, cols), features[:, cols], masks)[1],
                    delay_range,
                    delays[g],
                )

    fits = {}
    for g, joints in groups.items():
        cols = [index[j] for j in joints]
        masks = [use[chain_of[j]] & moving[:, index[j]] for j in joints]
        rejected = int(sum(candidates[chain_of[j]].sum() - use[chain_of[j]].sum() for j in joints))
        fits[g] = _group_fit(
            g,
            joints,
            target(delays[g], cols),
            features[:, cols],
            masks,
            delays[g],
            rejected,
            half,
            friction_velocity,
            max_relative_error,
        )
    return FrictionIdentification(
        groups=fits,
        joint_names=list(robot.joint_names),
        friction_velocity=float(friction_velocity),
        base=base,
        sample_period=dt,
        window=2 * half * dt,
    )


def _best_delay(rms, delay_range, default: float) -> float:
    """The delay [s] of least residual ``rms(delay)``: a 0.2 ms grid over the range, then 0.01 ms steps
    around its best point (an armature error of ``k_d`` times the delay error follows a damping loop in
    the motor drive: 0.2 ms is 0.004 kg m^2 at 20 N m s/rad)."""
    coarse = np.arange(delay_range[0], delay_range[1] + 1e-12, 2e-4)
    values = np.array([rms(d) for d in coarse])
    if not np.isfinite(values).any():
        return default
    best = float(coarse[int(np.nanargmin(values))])
    fine = np.arange(best - 2e-4, best + 2e-4 + 1e-12, 1e-5)
    fine = fine[(fine >= delay_range[0]) & (fine <= delay_range[1])]
    values = np.array([rms(d) for d in fine])
    return float(fine[int(np.nanargmin(values))]) if np.isfinite(values).any() else best


def _intervals(log, robot, base, q_log, v_log, dt):
    """Per sample period ``[t_k, t_k+1]``: midpoint configuration (T - 1, nq), mean velocity (T - 1, nv)
    and mean acceleration (T - 1, nv) (Pinocchio conventions: base twist and its derivative in the base
    frame)."""
    q, v = q_log.copy(), v_log.copy()
    if base != "log":
        if "q_meas" in log.signals:
            q[:, :7] = np.asarray(log["q_meas"], dtype=float)[:, :7]
        if "v_meas" in log.signals:
            v[:, :6] = np.asarray(log["v_meas"], dtype=float)[:, :6]
    q[:, 3:7] /= np.linalg.norm(q[:, 3:7], axis=1, keepdims=True)
    qm = q[:-1] + 0.5 * (q[1:] - q[:-1])
    flip = np.sum(q[1:, 3:7] * q[:-1, 3:7], axis=1) < 0  # the same rotation, opposite quaternion sign
    qm[flip, 3:7] = 0.5 * (q[:-1][flip, 3:7] - q[1:][flip, 3:7])
    qm[:, 3:7] /= np.linalg.norm(qm[:, 3:7], axis=1, keepdims=True)
    vm = 0.5 * (v[1:] + v[:-1])
    am = (v[1:] - v[:-1]) / dt
    if base == "imu":
        gyro = np.asarray(log["imu_gyro"], dtype=float)
        specific = np.asarray(log["imu_accelerometer"], dtype=float)
        R = np.array([pin.Quaternion(x).toRotationMatrix() for x in q[:, 3:7]])
        gravity = np.asarray(robot.model.gravity.linear, dtype=float)
        world = np.einsum("kij,kj->ki", R[1:], specific[1:]) + gravity  # mean over the period ending at k+1
        Rm = np.array([pin.Quaternion(x).toRotationMatrix() for x in qm[:, 3:7]])
        vm[:, 3:6] = 0.5 * (gyro[1:] + gyro[:-1])
        am[:, 3:6] = (gyro[1:] - gyro[:-1]) / dt
        # Pinocchio's base acceleration is spatial, base frame: R^T p_ddot - omega x v_linear.
        am[:, :3] = np.einsum("kji,kj->ki", Rm, world) - np.cross(vm[:, 3:6], vm[:, :3])
    return qm, vm, am


def _free_samples(robot, log, chains, contact, margin, dt) -> dict[str, np.ndarray]:
    """Per chain, the samples (T,) where the limb touches nothing (by the schedule and the commands)."""
    steps = round(margin / dt)
    n = np.asarray(log["t"]).size
    out = {}
    for i, foot in enumerate(robot.foot_frames):
        out[foot] = np.ones(n, bool) if contact is None else erode(~contact[:, i], steps)
    if "arm" in chains:
        free = np.ones(n, bool)
        if "ee_force_cmd" in log.signals:
            pushing = np.linalg.norm(np.asarray(log["ee_force_cmd"], dtype=float), axis=1) > 0
            free &= ~dilate(pushing, steps)
        out["arm"] = free
    return out


def _fit(y: np.ndarray, phi: np.ndarray, masks: list[np.ndarray], active=(0, 1, 2)):
    """Least squares over the masked samples of the group's joints: ``(x (3,), rms, A, Y)``."""
    A = np.concatenate([phi[m, i][:, list(active)] for i, m in enumerate(masks)])
    Y = np.concatenate([y[m, i] for i, m in enumerate(masks)])
    ok = np.isfinite(Y) & np.isfinite(A).all(axis=1)
    A, Y = A[ok], Y[ok]
    x = np.zeros(3)
    if Y.size < len(active) + 1:
        return x, math.nan, A, Y
    sol, *_ = np.linalg.lstsq(A, Y, rcond=None)
    x[list(active)] = sol
    return x, float(np.sqrt(np.mean((A @ sol - Y) ** 2))), A, Y


def _reject_outliers(groups, y, features, index, chain_of, candidates, moving, threshold, half, rounds=6):
    """Iterated rejection of the chain samples whose residuals (the RMS over the chain's moving joints,
    each scaled by its group's robust standard deviation) exceed ``threshold``, widened by the filter's
    half width: a foot on the ground loads every joint of its leg."""
    use = {c: m.copy() for c, m in candidates.items()}
    for _ in range(rounds):
        score = {c: np.zeros(m.size) for c, m in candidates.items()}
        count = {c: np.zeros(m.size) for c, m in candidates.items()}
        for g, joints in groups.items():
            cols = [index[j] for j in joints]
            masks = [use[chain_of[j]] & moving[:, index[j]] for j in joints]
            x, _, _, _ = _fit(y[g], features[:, cols], masks)
            residual = y[g] - features[:, cols] @ x  # (T, n_joints)
            pooled = np.concatenate([residual[m, i] for i, m in enumerate(masks)])
            pooled = pooled[np.isfinite(pooled)]
            if pooled.size == 0:
                continue
            sigma = 1.4826 * np.median(np.abs(pooled - np.median(pooled))) or 1e-12
            for i, joint in enumerate(joints):
                counted = moving[:, index[joint]] & np.isfinite(residual[:, i])  # stuck joints: not scored
                score[chain_of[joint]] += np.where(counted, (residual[:, i] / sigma) ** 2, 0.0)
                count[chain_of[joint]] += counted
        new = {}
        for c, m in candidates.items():
            bad = m & (score[c] > threshold**2 * np.maximum(count[c], 1))
            new[c] = m & ~dilate(bad, half)
        if all(np.array_equal(new[c], use[c]) for c in use):
            break
        use = new
    return use


def _group_fit(name, joints, y, phi, masks, delay, rejected, half, v_s, max_rel) -> GroupFit:
    """Fit with the physically admissible parameters (>= 0): a negative estimate's feature is dropped."""
    fit = GroupFit(name=name, joints=tuple(joints), delay=delay, rejected=rejected)
    active = [0, 1, 2]
    x, rms, A, Y = _fit(y, phi, masks, active)
    fit.samples = int(Y.size)
    if Y.size < _MIN_SAMPLES:
        fit.reasons = dict.fromkeys(PARAMETERS, f"only {Y.size} free samples (need {_MIN_SAMPLES})")
        return fit
    dropped = {}
    while any(x[k] < 0 for k in active) and len(active) > 1:
        worst = min(active, key=lambda k: x[k])
        dropped[PARAMETERS[worst]] = f"negative estimate ({x[worst]:.3g} {UNITS[PARAMETERS[worst]]})"
        active.remove(worst)
        x, rms, A, Y = _fit(y, phi, masks, active)
    qd = np.concatenate([phi[m, i, 1] for i, m in enumerate(masks)])
    qdd = np.concatenate([phi[m, i, 2] for i, m in enumerate(masks)])
    fit.velocity_rms = float(np.sqrt(np.nanmean(qd**2)))
    fit.moving_share = float(np.nanmean(np.abs(qd) > 2 * v_s))
    fit.acceleration_rms = float(np.sqrt(np.nanmean(qdd**2)))
    fit.rms_before, fit.rms_after = float(np.sqrt(np.mean(Y**2))), rms
    # Standard errors, with the sample count reduced by the filter width (neighbouring residuals share
    # most of their window, so they are far from independent).
    dof = max(Y.size / (2 * half + 1) - len(active), 1.0)
    sigma2 = float(np.sum((A @ x[active] - Y) ** 2)) / Y.size * (Y.size / dof)
    try:
        cov = sigma2 * np.linalg.inv(A.T @ A)
        std = np.full(3, np.nan)
        std[active] = np.sqrt(np.maximum(np.diag(cov), 0.0))
    except np.linalg.LinAlgError:
        std = np.full(3, np.inf)
    fit.std = tuple(float(s) for s in std)
    reasons = dict(dropped)
    for k, p in enumerate(PARAMETERS):
        if p in reasons:
            continue
        if not std[k] < max_rel * abs(x[k]):
            reasons[p] = (
                f"standard error {std[k]:.2g} {UNITS[p]} is more than {max_rel:.0%} of the estimate "
                f"{x[k]:.3g} (rms rate {fit.velocity_rms:.2f} rad/s, {fit.moving_share:.0%} of the "
                f"samples faster than {2 * v_s:g} rad/s)"
            )
    fit.identified = {p: p not in reasons for p in PARAMETERS}
    fit.reasons = reasons
    for k, p in enumerate(PARAMETERS):
        setattr(fit, p, float(x[k]) if fit.identified[p] else 0.0)
    return fit
