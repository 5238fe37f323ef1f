"""Cheap physical checks of a solve request before it is solved.

The prechecks (:func:`run_prechecks` and the checks it runs) look at the robot, the measured state, the
commands and the gait with plain NumPy/Pinocchio, in tens of microseconds, and return :class:`Finding`
objects that name the problem and its numbers (e.g. the arm joint that cannot hold the commanded
end-effector force).

Example:
    >>> findings = Prechecks(robot).run(q, v, commands, gait)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from wbmpc.control.findings import Finding, findings_to_dicts, has_errors
from wbmpc.model.robot import Robot, heading
from wbmpc.ocp.gait import Gait

__all__ = ["Finding", "Prechecks", "absurd_measurement", "findings_to_dicts", "has_errors", "run_prechecks"]

# Fraction of a torque limit above which a hold torque is reported as a warning.
TORQUE_WARNING_FRACTION = 0.9
# Static hold torque, as a multiple of the limit, up to which the MPC can still meet the force: the torque
# is that of the current pose held still, and the plan may let the arm give way over its horizon (the B1 +
# Z1 MPC at 15 nodes meets 100 N up, 1.36 x joint3's limit here, and fails at 120 N, 1.68 x). Above it the
# force is reported as an error; between 1 and it as a warning (the arm must move under the force).
TORQUE_YIELD_FACTOR = 1.5


def ee_force_feasibility(
    robot: Robot,
    q: np.ndarray,
    ee_force: np.ndarray,
    mu: float | None = None,
    *,
    info: _RobotInfo | None = None,
) -> list[Finding]:
    """Can the arm hold the commanded end-effector force in the current pose, and can the feet?

    The static arm torques are those of :mod:`wbmpc.model.statics`: ``tau = g(q) - J^T F`` restricted
    to the arm joints, with ``J`` the ``LOCAL_WORLD_ALIGNED`` linear Jacobian of the end-effector frame
    and ``F`` the force the environment applies on the end effector (``Commands.ee_force``, world axes).
    Velocity and acceleration terms are ignored (the arm is assumed slow).

    Args:
        robot: The robot (nothing is checked without an arm; see :func:`arm_commands_without_arm`).
        q: Configuration (nq,).
        ee_force: Force [N] on the end effector, world axes (3,).
        mu: Foot friction coefficient; when given, a horizontal force larger than ``mu`` times the normal
            load on the feet is reported (the feet would slip).

    Returns:
        ``ee_force_exceeds_torque_limit`` (error, one per joint over :data:`TORQUE_YIELD_FACTOR` times its
        limit), ``ee_force_needs_arm_motion`` (warning, over its limit but within that factor),
        ``ee_force_near_torque_limit`` (warning, above 90 % of the limit), ``ee_force_lifts_robot``
        (error, upward force above the weight: the stance feet would have to pull),
        ``ee_force_exceeds_friction`` (error).
    """
    force = np.asarray(ee_force, dtype=float).reshape(3)
    findings: list[Finding] = []
    info = _resolve(robot, info)
    weight = info.weight
    if force[2] > weight:
        findings.append(
            Finding(
                "ee_force_lifts_robot",
                "error",
                f"upward end-effector force {force[2]:.1f} N exceeds the robot's weight {weight:.1f} N: "
                "the stance feet would have to pull on the ground",
                {"force_z": float(force[2]), "weight": float(weight)},
            )
        )
    elif mu is not None:
        normal = weight - force[2]  # what the feet press on the ground with
        horizontal = float(np.hypot(force[0], force[1]))
        if horizontal > mu * normal:
            findings.append(
                Finding(
                    "ee_force_exceeds_friction",
                    "error",
                    f"horizontal end-effector force {horizontal:.1f} N exceeds the feet's friction "
                    f"{mu:.2f} x {normal:.1f} N = {mu * normal:.1f} N: the feet would slip",
                    {"horizontal": horizontal, "normal": float(normal), "mu": float(mu)},
                )
            )
    if not robot.has_arm:
        return findings
    tau, names, limits = arm_hold_torques(robot, q, force, info=info)
    for name, needed, limit in zip(names, tau, limits, strict=True):
        ratio = abs(needed) / limit if limit > 0 else math.inf
        if ratio <= TORQUE_WARNING_FRACTION:
            continue  # the every-tick case: nothing to report
        data = {"joint": name, "needed": float(needed), "limit": float(limit), "force": force.tolist()}
        if ratio > TORQUE_YIELD_FACTOR:
            findings.append(
                Finding(
                    "ee_force_exceeds_torque_limit",
                    "error",
                    f"holding end-effector force {_vec(force)} N needs {abs(needed):.1f} N m at {name}, "
                    f"above its {limit:.1f} N m limit (more than {TORQUE_YIELD_FACTOR:g} x: the arm cannot "
                    "give way enough for the plan to meet it)",
                    data,
                )
            )
        elif ratio > 1.0:
            findings.append(
                Finding(
                    "ee_force_needs_arm_motion",
                    "warning",
                    f"holding end-effector force {_vec(force)} N still here needs {abs(needed):.1f} N m "
                    f"at {name}, above its {limit:.1f} N m limit: the arm has to move under the force (the "
                    "plan can meet it, the hand drifts from its reference)",
                    data,
                )
            )
        else:
            findings.append(
                Finding(
                    "ee_force_near_torque_limit",
                    "warning",
                    f"holding end-effector force {_vec(force)} N needs {abs(needed):.1f} N m at {name}, "
                    f"{100 * ratio:.0f} % of its {limit:.1f} N m limit",
                    data,
                )
            )
    return findings


def arm_hold_torques(
    robot: Robot, q: np.ndarray, ee_force: np.ndarray, *, info: _RobotInfo | None = None
) -> tuple[np.ndarray, list[str], np.ndarray]:
    """Static arm joint torques [N m] holding ``ee_force`` (on the end effector, world axes) and gravity.

    Returns:
        Torques ``g_arm(q) - J_arm^T F`` (n_arm,), the arm joint names and their torque limits [N m].
    """
    info = _resolve(robot, info)
    if info.ee_id is None:
        raise ValueError(f"{robot.name} has no arm")
    q = np.asarray(q, dtype=float)
    idx = info.arm_idx
    J = pin.computeFrameJacobian(info.model, info.data, q, info.ee_id, pin.LOCAL_WORLD_ALIGNED)
    gravity = pin.computeGeneralizedGravity(info.model, info.data, q)
    tau = gravity[idx] - J[:3, idx].T @ np.asarray(ee_force, dtype=float).reshape(3)
    return tau, list(info.arm_names), info.arm_limits.copy()


# Share of the kinematic reach a foot may use on each side of its nominal position before a warning.
STRIDE_COMFORT_FRACTION = 0.5
# Commanded speeds below these are treated as zero [m/s], [rad/s].
SPEED_TOLERANCE = 1e-3


def leg_reach(robot: Robot, q: np.ndarray | None = None, *, info: _RobotInfo | None = None) -> dict:
    """Horizontal reach [m] of the feet about their nominal positions, from the leg kinematics and limits.

    For each foot, the last two joints above it (thigh and calf of a Unitree leg) give the links
    ``l1`` (thigh joint to calf joint) and ``l2`` (calf joint to foot). The knee bend is limited by the calf
    joint range, so the thigh-joint-to-foot distance is at most ``d = |p_calf + R_y(theta) p_foot|`` at the
    least-bent knee angle ``theta`` in the range. Keeping the thigh joint at its height ``h`` above the foot,
    the foot can then be at most ``sqrt(d^2 - h^2)`` from the point below the thigh joint; minus the
    foot's horizontal offset from that point, that is its reach ``R`` about the nominal position. The
    leg is assumed to swing about its y axis (pitch), the same reach is used in every horizontal
    direction.

    Args:
        robot: The robot.
        q: Configuration (nq,); the nominal pose by default.

    Returns:
        ``{"reach": min over feet [m], "per_foot": {foot: reach}, "hip_height": mean h [m],
        "leg_length": mean l1 + l2 [m]}``.
    """
    model, data = robot.model, _resolve(robot, info).data
    q = robot.q_nominal if q is None else np.asarray(q, dtype=float)
    pin.framesForwardKinematics(model, data, q)
    per_foot, heights, lengths = {}, [], []
    for foot in robot.foot_frames:
        frame = model.frames[robot.frame_id(foot)]
        calf = frame.parentJoint
        thigh = model.parents[calf]
        p_calf = model.jointPlacements[calf].translation  # in the thigh joint frame
        p_foot = frame.placement.translation  # in the calf joint frame
        lo, hi = model.lowerPositionLimit[model.idx_qs[calf]], model.upperPositionLimit[model.idx_qs[calf]]
        angles = (
            np.linspace(lo, hi, 61) if np.isfinite(lo) and np.isfinite(hi) else np.linspace(-np.pi, np.pi, 61)
        )
        c, s = np.cos(angles), np.sin(angles)
        # R_y(theta) p_foot for every angle (the calf axis is y on Unitree legs).
        rotated = np.stack(
            [c * p_foot[0] + s * p_foot[2], np.full_like(c, p_foot[1]), -s * p_foot[0] + c * p_foot[2]]
        )
        d_max = float(np.max(np.linalg.norm(p_calf[:, None] + rotated, axis=0)))
        hip = data.oMi[thigh].translation
        foot_pos = data.oMf[robot.frame_id(foot)].translation
        h = float(hip[2] - foot_pos[2])
        offset = float(np.linalg.norm(foot_pos[:2] - hip[:2]))
        per_foot[foot] = max(0.0, math.sqrt(max(d_max**2 - h**2, 0.0)) - offset)
        heights.append(h)
        lengths.append(float(np.linalg.norm(p_calf) + np.linalg.norm(p_foot)))
    return {
        "reach": min(per_foot.values()),
        "per_foot": per_foot,
        "hip_height": float(np.mean(heights)),
        "leg_length": float(np.mean(lengths)),
    }


def speed_feasibility(
    robot: Robot,
    gait: Gait,
    base_linear_velocity: np.ndarray,
    base_angular_velocity: np.ndarray,
    *,
    info: _RobotInfo | None = None,
) -> list[Finding]:
    """Is the commanded base speed within what the gait can produce?

    Rule: a stance foot stays on the ground while the base moves over it, so relative to the base it travels
    a stride ``s = u * T_stance`` with ``u`` the foot's horizontal speed relative to the base
    (``|v_xy + omega_z x p_foot|``, ``p_foot`` its nominal position from the base) and ``T_stance = (1 -
    swing_fraction) * period``. Centred on its nominal position, it spans ``+-s/2``. Error when ``s/2``
    exceeds the kinematic reach ``R`` of :func:`leg_reach` (impossible); warning when ``s/2`` exceeds
    ``STRIDE_COMFORT_FRACTION * R`` (the legs end the stance near full stretch, no margin left for balance).
    For the default B1 (``R`` = 0.46 m) and a 0.8 s trot (0.4 s stance) that is 1.14 m/s (warning) and
    2.29 m/s (error). A gait without swing (``stand``) can only reach a speed by leaning: any speed is a
    warning. Vertical, roll and pitch rates cannot be held at all: warning.

    Args:
        robot: The robot.
        gait: The gait schedule.
        base_linear_velocity: Commanded base velocity [m/s], heading frame (3,).
        base_angular_velocity: Commanded base angular velocity [rad/s], heading frame (3,).

    Returns:
        ``speed_without_stepping`` (warning), ``speed_beyond_gait`` (warning or error),
        ``unsustainable_velocity`` (warning).
    """
    v = np.asarray(base_linear_velocity, dtype=float).reshape(3)
    w = np.asarray(base_angular_velocity, dtype=float).reshape(3)
    findings: list[Finding] = []
    if abs(v[2]) > SPEED_TOLERANCE or np.any(np.abs(w[:2]) > SPEED_TOLERANCE):
        findings.append(
            Finding(
                "unsustainable_velocity",
                "warning",
                f"vertical velocity {v[2]:.2f} m/s or roll/pitch rates {_vec(w[:2])} rad/s cannot be held "
                "by a standing or walking robot",
                {"v_z": float(v[2]), "roll_rate": float(w[0]), "pitch_rate": float(w[1])},
            )
        )
    planar = float(np.hypot(v[0], v[1]))
    if planar <= SPEED_TOLERANCE and abs(w[2]) <= SPEED_TOLERANCE:
        return findings
    if gait.swing_fraction <= 0.0:
        findings.append(
            Finding(
                "speed_without_stepping",
                "warning",
                f"gait {gait.name!r} never lifts a foot: speed {planar:.2f} m/s, yaw rate {w[2]:.2f} rad/s "
                "can only be reached by leaning, not sustained",
                {"gait": gait.name, "speed": planar, "yaw_rate": float(w[2])},
            )
        )
        return findings
    geometry, rel = _nominal_geometry(robot, info)
    reach = geometry["reach"]
    stance = (1.0 - gait.swing_fraction) * gait.period
    # Foot speed relative to the base: v_xy + omega_z x p (p: nominal foot position from the base).
    foot_speed = np.linalg.norm(v[:2][None, :] + w[2] * np.stack([-rel[:, 1], rel[:, 0]], axis=1), axis=1)
    u = float(foot_speed.max())
    half_stride = 0.5 * u * stance
    data_out = {
        "gait": gait.name,
        "speed": planar,
        "yaw_rate": float(w[2]),
        "foot_speed": u,
        "stance_duration": stance,
        "stride": 2.0 * half_stride,
        "reach": reach,
        "max_speed": 2.0 * reach / stance,
        "comfortable_speed": 2.0 * STRIDE_COMFORT_FRACTION * reach / stance,
    }
    if half_stride > reach:
        severity, what = "error", f"beyond the legs' reach of +-{reach:.2f} m"
    elif half_stride > STRIDE_COMFORT_FRACTION * reach:
        severity, what = (
            "warning",
            f"over {100 * STRIDE_COMFORT_FRACTION:.0f} % of the legs' reach of +-{reach:.2f} m",
        )
    else:
        return findings
    findings.append(
        Finding(
            "speed_beyond_gait",
            severity,
            f"{gait.name} with {stance:.2f} s stance at speed {planar:.2f} m/s "
            f"(yaw rate {w[2]:.2f} rad/s) needs a {2 * half_stride:.2f} m stride "
            f"(+-{half_stride:.2f} m about the nominal foot position), {what}; "
            f"max {data_out['max_speed']:.2f} m/s, comfortable {data_out['comfortable_speed']:.2f} m/s",
            data_out,
        )
    )
    return findings


def joint_state_limits(
    robot: Robot, q: np.ndarray, v: np.ndarray, tol: float = 1e-6, *, info: _RobotInfo | None = None
) -> list[Finding]:
    """Joint positions outside their limits and joint speeds above their limits.

    Args:
        robot: The robot.
        q: Configuration (nq,).
        v: Velocity (nv,).
        tol: Allowed excess [rad], [rad/s] (rounding).

    Returns:
        ``state_not_finite``, ``joint_position_limit``, ``joint_velocity_limit`` (errors), each naming
        the joints and their values.
    """
    q = np.asarray(q, dtype=float)
    v = np.asarray(v, dtype=float)
    if not (np.isfinite(q).all() and np.isfinite(v).all()):
        bad = [int(i) for i in np.flatnonzero(~np.isfinite(np.concatenate([q, v])))]
        return [
            Finding("state_not_finite", "error", f"state has NaN or inf at indices {bad}", {"indices": bad})
        ]
    findings: list[Finding] = []
    info = _resolve(robot, info)
    names, lower, upper = info.joint_names, info.lower, info.upper
    qj = q[7:]
    out = np.flatnonzero((qj < lower - tol) | (qj > upper + tol))
    if out.size:
        items = [
            {"joint": names[i], "value": float(qj[i]), "lower": float(lower[i]), "upper": float(upper[i])}
            for i in out
        ]
        text = ", ".join(
            f"{d['joint']} = {d['value']:.3f} rad not in [{d['lower']:.3f}, {d['upper']:.3f}]" for d in items
        )
        findings.append(
            Finding(
                "joint_position_limit", "error", f"joint positions outside limits: {text}", {"joints": items}
            )
        )
    vmax = info.velocity_limits
    vj = v[6:]
    fast = np.flatnonzero(np.abs(vj) > vmax + tol)
    if fast.size:
        items = [{"joint": names[i], "value": float(vj[i]), "limit": float(vmax[i])} for i in fast]
        text = ", ".join(f"{d['joint']} = {d['value']:.2f} rad/s above {d['limit']:.2f}" for d in items)
        findings.append(
            Finding("joint_velocity_limit", "error", f"joint speeds above limits: {text}", {"joints": items})
        )
    return findings


# Bounds beyond which a measured state is not a state of a legged robot but a sensor or estimator fault.
ABSURD_BASE_SPEED = 20.0  # [m/s]: a free fall from 20 m reaches 19.8 m/s
ABSURD_BASE_RATE = 50.0  # [rad/s]: ~8 turns per second
ABSURD_JOINT_SPEED_FACTOR = 5.0  # times the joint's velocity limit
ABSURD_JOINT_EXCESS = 0.5  # [rad] (or m) beyond a joint's position limit
ABSURD_QUATERNION_NORM = 0.1  # |norm - 1| of the measured base quaternion


def absurd_measurement(robot: Robot, q: np.ndarray, v: np.ndarray, *, info: _RobotInfo | None = None):
    """Measured states no robot can be in: a sensor, estimator or unit fault, not a hard problem.

    Checked on the measurement as given (before the MPC normalises its quaternion): a base quaternion whose
    norm is off 1 by more than :data:`ABSURD_QUATERNION_NORM` (a warning, ``non_unit_quaternion``: the MPC
    normalises it, any non-zero quaternion is a rotation), a base speed above
    :data:`ABSURD_BASE_SPEED` or rate above :data:`ABSURD_BASE_RATE`, joint positions more than
    :data:`ABSURD_JOINT_EXCESS` beyond their limits, joint speeds above :data:`ABSURD_JOINT_SPEED_FACTOR`
    times their limits. Non-finite states are the caller's (the MPC refuses them as bad input).

    Returns:
        ``absurd_measurement`` errors (the MPC skips the solve and falls back), one per measurement, each
        naming it, its value and the bound; the ``non_unit_quaternion`` warning.
    """
    q = np.asarray(q, dtype=float)
    v = np.asarray(v, dtype=float)
    if not (np.isfinite(q).all() and np.isfinite(v).all()):
        return []
    info = _resolve(robot, info)
    found = []

    def add(what: str, value: float, bound: str, hint: str, code="absurd_measurement", severity="error"):
        label = "absurd measurement" if severity == "error" else "suspicious measurement"
        found.append(
            Finding(code, severity, f"{label}: {what} = {value:.4g}, {bound}; {hint}", {"measurement": what})
        )
        found[-1].data["value"] = float(value)

    norm = float(np.linalg.norm(q[3:7]))
    if abs(norm - 1.0) > ABSURD_QUATERNION_NORM:  # a warning: a quaternion of any norm is a rotation
        add(
            "|q_hat[3:7]| (base quaternion norm)",
            norm,
            f"a unit quaternion has norm 1 (tolerance {ABSURD_QUATERNION_NORM}; it is normalised)",
            "check the attitude estimate (order x, y, z, w; not Euler angles)",
            code="non_unit_quaternion",
            severity="warning",
        )
    speed = float(np.linalg.norm(v[0:3]))
    if speed > ABSURD_BASE_SPEED:
        add(
            "base speed |v_hat[0:3]| [m/s]",
            speed,
            f"no legged robot moves faster than {ABSURD_BASE_SPEED:g} m/s",
            "check the base velocity estimate and its units (m/s, base frame)",
        )
    rate = float(np.linalg.norm(v[3:6]))
    if rate > ABSURD_BASE_RATE:
        add(
            "base angular speed |v_hat[3:6]| [rad/s]",
            rate,
            f"above {ABSURD_BASE_RATE:g} rad/s",
            "check the gyro and its units (rad/s, not deg/s)",
        )
    qj, names = q[7:], info.joint_names
    excess = np.maximum(info.lower - qj, qj - info.upper)
    for i in np.flatnonzero(excess > ABSURD_JOINT_EXCESS):
        add(
            f"joint position {names[i]} (q_hat[{7 + i}])",
            qj[i],
            f"{excess[i]:.3g} beyond its limits [{info.lower[i]:.3f}, {info.upper[i]:.3f}] "
            f"(more than {ABSURD_JOINT_EXCESS:g})",
            "check the encoder offsets, the joint order and the units (rad, not deg)",
        )
    vj, vmax = v[6:], info.velocity_limits
    bounded = np.isfinite(vmax) & (vmax > 0)
    for i in np.flatnonzero(bounded & (np.abs(vj) > ABSURD_JOINT_SPEED_FACTOR * np.where(bounded, vmax, 0))):
        add(
            f"joint speed {names[i]} (v_hat[{6 + i}]) [rad/s]",
            vj[i],
            f"over {ABSURD_JOINT_SPEED_FACTOR:g} times its limit {vmax[i]:.2f}",
            "check the joint velocity estimate and its units",
        )
    return found


def arm_commands_without_arm(robot: Robot, commands) -> list[Finding]:
    """End-effector velocity or force commands given to a robot without an arm.

    Args:
        robot: The robot.
        commands: A :class:`wbmpc.control.mpc.Commands` (``ee_velocity`` (3,) or (3, N-1), ``ee_force`` (3,)).

    Returns:
        ``arm_command_without_arm`` (error) naming the ignored commands, or nothing.
    """
    if robot.has_arm or commands is None:
        return []
    given = {}
    for name in ("ee_velocity", "ee_force"):
        value = np.asarray(getattr(commands, name, np.zeros(3)), dtype=float)
        if value.size and np.any(value != 0.0):
            given[name] = float(np.max(np.abs(value)))
    if not given:
        return []
    text = ", ".join(f"{k} (max |component| {val:.3g})" for k, val in given.items())
    return [
        Finding(
            "arm_command_without_arm",
            "error",
            f"{robot.name} has no arm, but the commands set {text}",
            {"robot": robot.name, "commands": given},
        )
    ]


# A hand whose commanded world velocity differs from the base's by more than this share of the base's speed
# (and at least HAND_SPEED_TOLERANCE) does not move with the body.
HAND_SPEED_SHARE = 0.25
HAND_SPEED_TOLERANCE = 0.05  # [m/s]


def arm_reach(robot: Robot, *, info: _RobotInfo | None = None) -> dict:
    """The arm's reach [m]: the length of its kinematic chain from the first arm joint to the end effector
    (the sum of the joint-to-joint distances at the nominal pose: the hand cannot get further than this from
    that joint).

    Returns:
        ``{"shoulder_joint": name, "reach": R}``; ``{}`` for a robot without an arm.
    """
    if not robot.has_arm:
        return {}
    info = _resolve(robot, info)
    if info.arm_reach is None:
        model, data = info.model, info.data
        pin.framesForwardKinematics(model, data, robot.q_nominal)
        joints = [model.getJointId(name) for name in info.arm_names]
        points = [data.oMi[j].translation.copy() for j in joints] + [data.oMf[info.ee_id].translation.copy()]
        length = float(sum(np.linalg.norm(b - a) for a, b in zip(points[:-1], points[1:], strict=True)))
        info.arm_reach = {"shoulder_joint": info.arm_names[0], "reach": length, "joint_id": joints[0]}
    return {k: info.arm_reach[k] for k in ("shoulder_joint", "reach")}


def ee_world_hold(robot: Robot, q: np.ndarray, commands, *, info: _RobotInfo | None = None) -> list[Finding]:
    """Does a constant world end-effector velocity command outrun the base? (a hand held still in the world
    while the base walks anchors the robot until the arm's reach runs out).

    Checks the paper's command, one end-effector velocity held over the horizon (``commands.ee_velocity``
    of shape (3,)); per-stage commands (a reference followed in the heading frame) are not checked. The hand
    moves relative to the arm's first joint at ``ee_velocity - (v_base + omega_z x (p_shoulder - p_base))``;
    when that differs from zero by more than :data:`HAND_SPEED_SHARE` of the base's speed, the finding (a
    warning: the arm's posture cost and joint limits resist long before) gives the time and the walked
    distance until the hand leaves the arm's reach (:func:`arm_reach`, an upper bound).

    Args:
        robot: The robot.
        q: Measured configuration (nq,).
        commands: :class:`wbmpc.control.mpc.Commands` (base velocity and yaw rate in the heading frame,
            end-effector velocity in world axes).

    Returns:
        ``[]`` or one ``ee_world_hold_with_walking_base`` warning.
    """
    ee_velocity = np.asarray(getattr(commands, "ee_velocity", np.zeros(3)), dtype=float)
    if not robot.has_arm or ee_velocity.shape != (3,):
        return []
    base = np.asarray(commands.base_linear_velocity, dtype=float)
    yaw_rate = float(np.asarray(commands.base_angular_velocity, dtype=float)[2])
    if np.linalg.norm(base[:2]) < SPEED_TOLERANCE and abs(yaw_rate) < SPEED_TOLERANCE:
        return []
    info = _resolve(robot, info)
    reach = arm_reach(robot, info=info)
    pin.framesForwardKinematics(info.model, info.data, q)
    shoulder = info.data.oMi[info.arm_reach["joint_id"]].translation
    hand = info.data.oMf[info.ee_id].translation
    yaw = heading(q)
    c, s = math.cos(yaw), math.sin(yaw)
    base_world = np.array([c * base[0] - s * base[1], s * base[0] + c * base[1], 0.0])
    lever = shoulder - np.array([q[0], q[1], shoulder[2]])
    shoulder_velocity = base_world + yaw_rate * np.array([-lever[1], lever[0], 0.0])
    relative = ee_velocity - shoulder_velocity
    r0 = hand - shoulder
    a, b = float(relative @ relative), float(r0 @ relative)
    c0 = float(r0 @ r0) - reach["reach"] ** 2
    if math.sqrt(a) < max(HAND_SPEED_TOLERANCE, HAND_SPEED_SHARE * float(np.linalg.norm(shoulder_velocity))):
        return []
    t_out = 0.0 if c0 >= 0 else (-b + math.sqrt(b * b - a * c0)) / a
    walked = float(np.linalg.norm(base_world) * t_out)
    return [
        Finding(
            "ee_world_hold_with_walking_base",
            "warning",
            f"the end-effector velocity command {_vec2(ee_velocity)} m/s (world, held over the horizon) does "
            f"not move with the base commanded at {_vec2(base_world)} m/s and {yaw_rate:.2f} rad/s: the hand "
            f"leaves the arm's reach ({reach['reach']:.2f} m from {reach['shoulder_joint']}) after at most "
            f"{t_out:.1f} s, {walked:.2f} m of walking, and then anchors the robot; to hold it still "
            "relative to the body use the heading frame (CommandSchedule.ee_velocity_frame='heading' or "
            "ArmReference.still()), or give it the base's velocity",
            {
                "ee_velocity": ee_velocity.tolist(),
                "base_velocity_world": base_world.tolist(),
                "yaw_rate": yaw_rate,
                "reach_m": reach["reach"],
                "time_to_reach_limit_s": t_out,
                "distance_m": walked,
            },
        )
    ]


def run_prechecks(
    robot: Robot,
    q: np.ndarray,
    v: np.ndarray,
    commands=None,
    gait: Gait | None = None,
    mu: float | None = None,
    info: _RobotInfo | None = None,
) -> list[Finding]:
    """Run every precheck on a solve request (cheap: well under a millisecond in total).

    Args:
        robot: The robot.
        q: Measured configuration (nq,).
        v: Measured velocity (nv,).
        commands: :class:`wbmpc.control.mpc.Commands`, or ``None`` (no command checks).
        gait: The gait, or ``None`` (no speed check).
        mu: Friction coefficient for the end-effector force check, or ``None``.
        info: The robot's data (:class:`Prechecks` passes its own); ``None``: computed for this call.

    Returns:
        All findings, errors first.
    """
    info = _resolve(robot, info)
    findings = joint_state_limits(robot, q, v, info=info)
    if commands is not None:
        findings += arm_commands_without_arm(robot, commands)
        state_ok = not any(f.code == "state_not_finite" for f in findings)
        ee_force = np.asarray(getattr(commands, "ee_force", np.zeros(3)), dtype=float)
        if state_ok and ee_force.shape == (3,) and np.isfinite(ee_force).all():
            findings += ee_force_feasibility(robot, q, ee_force, mu, info=info)
        if gait is not None:
            findings += speed_feasibility(
                robot, gait, commands.base_linear_velocity, commands.base_angular_velocity, info=info
            )
        if state_ok:
            findings += ee_world_hold(robot, q, commands, info=info)
    return sorted(findings, key=lambda f: f.severity != "error")


# --- helpers --------------------------------------------------------------------------------------------
@dataclass
class _RobotInfo:
    """What the checks need from a robot, computed once per model (the Robot properties walk the model)."""

    model: pin.Model
    data: pin.Data
    weight: float
    joint_names: list[str]
    arm_names: list[str]
    arm_idx: np.ndarray
    arm_limits: np.ndarray
    ee_id: int | None
    lower: np.ndarray
    upper: np.ndarray
    velocity_limits: np.ndarray
    reach: dict | None = None
    foot_offsets: np.ndarray | None = None  # nominal foot positions from the base, x-y (n_feet, 2)
    arm_reach: dict | None = None  # see arm_reach()


class Prechecks:
    """The prechecks of one robot, owning the Pinocchio data and the per-model numbers they use.

    :meth:`of` gives the robot's own (created on first use and kept on the robot, so its lifetime is the
    robot's; rebuilt if ``robot.model`` was replaced); the module's functions use it.

    Args:
        robot: The robot.
    """

    def __init__(self, robot: Robot):
        model = robot.model
        arm_names = list(robot.arm_joint_names)
        arm_idx = np.array([robot.joint_index_v(n) for n in arm_names], dtype=int)
        self.robot = robot
        self.info = _RobotInfo(
            model=model,
            data=model.createData(),
            weight=robot.mass * robot.gravity,
            joint_names=robot.joint_names,
            arm_names=arm_names,
            arm_idx=arm_idx,
            arm_limits=model.effortLimit[arm_idx].copy(),
            ee_id=robot.frame_id(robot.ee_frame) if robot.has_arm else None,
            lower=model.lowerPositionLimit[7:].copy(),
            upper=model.upperPositionLimit[7:].copy(),
            velocity_limits=model.velocityLimit[6:].copy(),
        )

    def run(self, q, v, commands=None, gait: Gait | None = None, mu: float | None = None) -> list[Finding]:
        """:func:`run_prechecks` for this robot, with its own data."""
        return run_prechecks(self.robot, q, v, commands, gait, mu, info=self.info)

    def absurd_measurement(self, q, v) -> list[Finding]:
        """:func:`absurd_measurement` for this robot, with its own data."""
        return absurd_measurement(self.robot, q, v, info=self.info)


def _resolve(robot: Robot, info: _RobotInfo | None) -> _RobotInfo:
    """The given per-robot data, or a new one (a direct call outside a :class:`Prechecks`)."""
    return Prechecks(robot).info if info is None else info


def _nominal_geometry(robot: Robot, info: _RobotInfo | None = None) -> tuple[dict, np.ndarray]:
    """Leg reach and nominal foot offsets from the base, computed once per :class:`Prechecks`."""
    info = _resolve(robot, info)
    if info.reach is None:
        info.reach = leg_reach(robot, info=info)
        q0 = robot.q_nominal
        pin.framesForwardKinematics(info.model, info.data, q0)
        info.foot_offsets = np.array(
            [info.data.oMf[robot.frame_id(f)].translation[:2] - q0[:2] for f in robot.foot_frames]
        )
    return info.reach, info.foot_offsets


def _vec2(x) -> str:
    return "[" + ", ".join(f"{float(c):.2f}" for c in np.ravel(x)) + "]"


def _vec(x) -> str:
    return "[" + ", ".join(f"{float(c):.1f}" for c in np.ravel(x)) + "]"
