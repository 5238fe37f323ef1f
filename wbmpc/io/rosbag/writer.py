"""Writing a run log as a ROS 2 bag (sqlite3 or MCAP), no ROS install: :func:`write_bag`."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np

from wbmpc.io.logs import RunLog, json_default
from wbmpc.io.rosbag.messages import (
    _ARRAY,
    _DIAG,
    _FEET,
    _IMU,
    _JOINT_STATE,
    _NS,
    _ODOM,
    _PLAN,
    _POINT,
    _STRING,
    _TWIST,
    _WRENCH,
    BAG_FORMAT_VERSION,
    _Msgs,
    _rosbags,
    make_typestore,
)
from wbmpc.io.rosbag.topic_map import TopicMap, _as_topic_map


# -------------------------------------------------------------------------------------------------- write
def write_bag(
    log: RunLog,
    path: str | Path,
    robot=None,
    storage: str = "sqlite3",
    topic_map: TopicMap | dict | str | Path | None = None,
    start_time_ns: int = 0,
    version: int | None = None,
) -> Path:
    """Record a run's log as a ROS 2 bag (see the module docstring for topics and fields).

    Args:
        log: The run's columnar log (``result.run_log()`` or :func:`~wbmpc.io.logs.load_log`).
        path: Bag folder to create (must not exist).
        robot: The :class:`~wbmpc.model.robot.Robot` (joint names, gravity); ``None``: the topic map's
            ``joint_names``, else the names recorded in ``log.meta["joint_names"]``, else the first robot of
            :data:`wbmpc.model.robot.ROBOTS` whose joint count fits the log.
        storage: ``"sqlite3"`` or ``"mcap"``.
        topic_map: A :class:`TopicMap`, a dict of its fields, or a JSON path/string; ``None``: the defaults.
        start_time_ns: Stamp [ns] of ``t = 0`` (0: simulated time; e.g. ``time.time_ns()`` for wall time).
        version: rosbag2 metadata version (8 or 9; ``None``: the newest ``rosbags`` writes).

    Returns:
        The bag folder.

    Raises:
        ValueError: Unknown storage, no joint names, a log without ``t`` or joint columns.
        FileExistsError: ``path`` exists.
    """
    rb = _rosbags()
    tm = _as_topic_map(topic_map)
    plugins = {"sqlite3": rb.rosbag2.StoragePlugin.SQLITE3, "mcap": rb.rosbag2.StoragePlugin.MCAP}
    if storage not in plugins:
        raise ValueError(f"unknown storage {storage!r}; available: {sorted(plugins)}")
    log.validate()
    if "t" not in log.signals or "q" not in log.signals and "q_meas" not in log.signals:
        raise ValueError("the log needs the signal columns 't' and 'q' (or 'q_meas') to make a bag")
    path = Path(path)
    if path.exists():
        raise FileExistsError(f"{path} exists; a rosbag2 writer creates a new folder")
    nj = (log.signals["q"] if "q" in log.signals else log.signals["q_meas"]).shape[1] - 7
    joint_names = _joint_names_for_write(log, robot, tm, nj)
    gravity = robot.gravity if robot is not None else 9.81
    store = make_typestore()
    m = _Msgs(store)

    t = np.asarray(log.signals["t"], dtype=float)
    stamps = start_time_ns + np.round(t * _NS).astype(np.int64)
    channels: list[tuple[str, str, list]] = []  # (topic, type, [(ns, msg), ...])
    used: set[str] = {"t"}

    def add(topic, msgtype, msgs):
        if topic:
            channels.append((topic, msgtype, msgs))

    sig = log.signals
    if "q" in sig and "v" in sig:
        add(
            tm.joint_states,
            _JOINT_STATE,
            _joint_states(m, stamps, joint_names, sig["q"], sig["v"], sig.get("tau")),
        )
        add(tm.ground_truth, _ODOM, _odometry(m, stamps, tm, sig["q"], sig["v"]))
        used |= {"q", "v", "tau"}
    if "q_meas" in sig and "v_meas" in sig:
        hardware = "q" not in sig or "v" not in sig  # then the measurement is the joint state
        tau = sig.get("tau") if hardware else None
        measured = _joint_states(m, stamps, joint_names, sig["q_meas"], sig["v_meas"], tau)
        add(tm.joint_states if hardware else tm.joint_states_measured, _JOINT_STATE, measured)
        used.add("tau" if hardware else "q_meas")
        add(tm.odometry, _ODOM, _odometry(m, stamps, tm, sig["q_meas"], sig["v_meas"]))
        used |= {"q_meas", "v_meas"}
    if "tau_ff" in sig:
        empty = np.zeros((len(t), 0))
        add(
            tm.joint_feedforward,
            _JOINT_STATE,
            _joint_states(m, stamps, joint_names, empty, empty, sig["tau_ff"]),
        )
        used.add("tau_ff")
    imu = _imu_columns(log, t, gravity)
    if imu is not None:
        add(tm.imu, _IMU, _imu(m, stamps, tm.imu_frame, *imu))
        used |= {"imu_orientation", "imu_gyro", "imu_accelerometer"}
    if "foot_forces" in sig and tm.foot_forces:
        for i, topic in enumerate(tm.foot_topics()):
            add(
                topic,
                _WRENCH,
                [
                    (ns, m.wrench(ns, tm.world_frame, f))
                    for ns, f in zip(stamps, sig["foot_forces"][:, i], strict=True)
                ],
            )
        used.add("foot_forces")
    if any(k in sig for k in ("contact", "contact_sim", "foot_height")):
        add(tm.feet_contact, _FEET, _feet(m, stamps, tm, sig))
        used |= {"contact", "contact_sim", "foot_height"}
    for key, topic in (("ee_position", tm.ee_position), ("ee_reference", tm.ee_reference)):
        if key in sig:
            msgs = [
                (ns, m.point_stamped(ns, tm.world_frame, p)) for ns, p in zip(stamps, sig[key], strict=True)
            ]
            add(topic, _POINT, msgs)
            used.add(key)
    for key, topic in (("ee_force_sim", tm.ee_force), ("ee_force_cmd", tm.ee_force_cmd)):
        if key in sig:
            add(
                topic,
                _WRENCH,
                [(ns, m.wrench(ns, tm.world_frame, f)) for ns, f in zip(stamps, sig[key], strict=True)],
            )
            used.add(key)
    if "base_velocity_cmd" in sig:
        cmd = sig["base_velocity_cmd"]
        msgs = [(ns, m.twist_stamped(ns, tm.heading_frame, u)) for ns, u in zip(stamps, cmd, strict=True)]
        add(tm.base_velocity_cmd, _TWIST, msgs)
        used.add("base_velocity_cmd")

    solves, solve_used = log.solves, {"solve_t"}
    if solves and "solve_t" in solves:
        solve_stamps = start_time_ns + np.round(np.asarray(solves["solve_t"], float) * _NS).astype(np.int64)
        if tm.diagnostics:
            add(tm.diagnostics, _DIAG, _diagnostics(m, solve_stamps, start_time_ns, tm, solves))
            solve_used |= {
                "apply_t",
                "solve_time",
                "iterations",
                "success",
                "fallback",
                "hold",
                "violation",
                "status",
                "reason",
            }
        if tm.plan_preview and any(k in solves for k in ("plan_q", "plan_v", "plan_tau", "plan_forces")):
            add(tm.plan_preview, _PLAN, _plan_preview(m, solve_stamps, tm, solves))
            solve_used |= {"plan_q", "plan_v", "plan_tau", "plan_forces", "plan_contact"}
    else:
        solve_stamps = None

    # Any other numeric column: a generic array topic.
    if tm.extra_prefix is not None:
        for table, columns, done, st in (
            ("signals", sig, used, stamps),
            ("solves", solves, solve_used, solve_stamps),
        ):
            for name, column in columns.items():
                if name in done or st is None:
                    continue
                column = np.asarray(column)
                if column.dtype.kind not in "biuf":
                    warnings.warn(
                        f"rosbag: {table} column {name!r} ({column.dtype}) is not numeric; not written",
                        stacklevel=2,
                    )
                    continue
                add(f"{tm.extra_prefix}/{table}/{name}", _ARRAY, _arrays(m, st, tm, column))

    meta = {
        "wbmpc_bag_version": BAG_FORMAT_VERSION,
        "log_meta": log.meta,
        "joint_names": joint_names,
        "foot_names": list(tm.foot_names),
        "start_time_ns": int(start_time_ns),
        "frames": {k: getattr(tm, k) for k in ("world_frame", "base_frame", "imu_frame", "heading_frame")},
        "topic_map": tm.to_dict(),
    }
    if tm.meta:
        string = m.types[_STRING](data=json.dumps(meta, default=json_default))
        first = int(stamps[0]) if len(stamps) else int(start_time_ns)
        channels.append((tm.meta, _STRING, [(first, string)]))

    # Write time-ordered (stable: channel order within one stamp).
    writer_cls = rb.rosbag2.Writer
    writer = writer_cls(path, version=version or writer_cls.VERSION_LATEST, storage_plugin=plugins[storage])
    entries = []
    with writer:
        for index, (topic, msgtype, msgs) in enumerate(channels):
            conn = writer.add_connection(topic, msgtype, typestore=store)
            entries += [(int(ns), index, conn, msg) for ns, msg in msgs]
        entries.sort(key=lambda e: (e[0], e[1]))
        for ns, _, conn, msg in entries:
            writer.write(conn, ns, store.serialize_cdr(msg, conn.msgtype))
    return path


def _joint_names_for_write(log: RunLog, robot, tm: TopicMap, nj: int) -> list[str]:
    if robot is not None:
        names = list(robot.joint_names)
    elif tm.joint_names is not None:
        names = list(tm.joint_names)
    elif log.meta.get("joint_names") is not None:
        names = list(log.meta["joint_names"])
    else:
        names = _guess_robot_joint_names(nj)
    if len(names) != nj:
        raise ValueError(f"{len(names)} joint names {names} for a log with {nj} joints")
    return names


def _guess_robot_joint_names(nj: int) -> list[str]:
    from wbmpc.model.robot import ROBOTS

    for loader in ROBOTS.values():
        robot = loader()
        if robot.nj == nj:
            return list(robot.joint_names)
    raise ValueError(
        f"no joint names for a log with {nj} joints: pass robot=, TopicMap.joint_names or meta['joint_names']"
    )


def _joint_states(m: _Msgs, stamps, names, q, v, tau):
    cls = m.types[_JOINT_STATE]
    q, v = np.asarray(q, float), np.asarray(v, float)
    pos = q[:, 7:] if q.shape[1] else q
    vel = v[:, 6:] if v.shape[1] else v
    empty = np.zeros(0)
    out = []
    for k, ns in enumerate(stamps):
        out.append(
            (
                ns,
                cls(
                    header=m.header(ns, ""),
                    name=list(names),
                    position=pos[k].copy() if pos.shape[1] else empty,
                    velocity=vel[k].copy() if vel.shape[1] else empty,
                    effort=np.asarray(tau[k], float).copy() if tau is not None else empty,
                ),
            )
        )
    return out


def _odometry(m: _Msgs, stamps, tm: TopicMap, q, v):
    cls = m.types[_ODOM]
    cov = np.zeros(36)
    out = []
    for ns, qk, vk in zip(stamps, q, v, strict=True):
        pose = m.Pose(
            position=m.Point(x=float(qk[0]), y=float(qk[1]), z=float(qk[2])), orientation=m.quat(qk[3:7])
        )
        twist = m.Twist(linear=m.vec(vk[:3]), angular=m.vec(vk[3:6]))
        out.append(
            (
                ns,
                cls(
                    header=m.header(ns, tm.world_frame),
                    child_frame_id=tm.base_frame,
                    pose=m.PoseCov(pose=pose, covariance=cov),
                    twist=m.TwistCov(twist=twist, covariance=cov),
                ),
            )
        )
    return out


def _imu_columns(log: RunLog, t: np.ndarray, gravity: float):
    """IMU orientation (T, 4) (or None), gyro (T, 3), accelerometer (T, 3): the log's columns or from q, v."""
    sig = log.signals
    if "imu_gyro" in sig and "imu_accelerometer" in sig:
        return sig.get("imu_orientation"), np.asarray(sig["imu_gyro"]), np.asarray(sig["imu_accelerometer"])
    if "q" not in sig or "v" not in sig or len(t) == 0:
        return None
    from wbmpc.estimation import synthesize_imu

    q, v = np.asarray(sig["q"], float), np.asarray(sig["v"], float)
    period = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    gyro, acc = np.zeros((len(t), 3)), np.zeros((len(t), 3))
    for k in range(len(t)):
        prev = max(k - 1, 0)  # first sample: zero acceleration
        dt = t[k] - t[prev] if k else period
        reading = synthesize_imu(q[k], v[k], q[prev], v[prev], dt, gravity=gravity)
        gyro[k], acc[k] = reading.gyro, reading.accelerometer
    return q[:, 3:7], gyro, acc


def _imu(m: _Msgs, stamps, frame, orientation, gyro, acc):
    cls = m.types[_IMU]
    cov = np.zeros(9)
    no_orientation = np.zeros(9)
    no_orientation[0] = -1.0  # REP 145: orientation not provided
    out = []
    for k, ns in enumerate(stamps):
        quat = orientation[k] if orientation is not None else (0.0, 0.0, 0.0, 1.0)
        have = orientation is not None and np.all(np.isfinite(orientation[k]))
        out.append(
            (
                ns,
                cls(
                    header=m.header(ns, frame),
                    orientation=m.quat(quat if have else (0, 0, 0, 1)),
                    orientation_covariance=cov if have else no_orientation,
                    angular_velocity=m.vec(gyro[k]),
                    angular_velocity_covariance=cov,
                    linear_acceleration=m.vec(acc[k]),
                    linear_acceleration_covariance=cov,
                ),
            )
        )
    return out


def _feet(m: _Msgs, stamps, tm: TopicMap, sig):
    cls = m.types[_FEET]
    empty_b, empty_f = np.zeros(0, bool), np.zeros(0)
    plan, touch, height = sig.get("contact"), sig.get("contact_sim"), sig.get("foot_height")
    out = []
    for k, ns in enumerate(stamps):
        out.append(
            (
                ns,
                cls(
                    header=m.header(ns, tm.world_frame),
                    foot_names=list(tm.foot_names),
                    contact_plan=np.asarray(plan[k], bool).copy() if plan is not None else empty_b,
                    contact_sim=np.asarray(touch[k], bool).copy() if touch is not None else empty_b,
                    foot_height=np.asarray(height[k], float).copy() if height is not None else empty_f,
                ),
            )
        )
    return out


def _diagnostics(m: _Msgs, stamps, start_ns: int, tm: TopicMap, s):
    cls = m.types[_DIAG]
    n = len(stamps)

    def col(name, default):
        return np.asarray(s[name]) if name in s else np.full(n, default)

    apply_t = col("apply_t", np.nan)
    solve_time, iterations, violation = (
        col("solve_time", np.nan),
        col("iterations", -1),
        col("violation", np.nan),
    )
    success, fallback, hold, status, reason = (
        col("success", False),
        col("fallback", False),
        col("hold", False),
        col("status", ""),
        col("reason", ""),
    )
    out = []
    for k, ns in enumerate(stamps):
        applied = start_ns + round(float(apply_t[k]) * _NS) if np.isfinite(apply_t[k]) else ns
        out.append(
            (
                ns,
                cls(
                    header=m.header(ns, tm.world_frame),
                    apply_stamp=m.time(applied),
                    solve_time=float(solve_time[k]),
                    iterations=int(iterations[k]),
                    success=bool(success[k]),
                    fallback=bool(fallback[k]),
                    hold=bool(hold[k]),
                    constraint_violation=float(violation[k]),
                    status=str(status[k]),
                    reason=str(reason[k]),
                ),
            )
        )
    return out


def _plan_preview(m: _Msgs, stamps, tm: TopicMap, s):
    cls = m.types[_PLAN]

    def flat(name, k, dtype=float):
        return np.asarray(s[name][k], dtype).ravel().copy() if name in s else np.zeros(0, dtype)

    n_nodes = (
        np.asarray(s["plan_q"]).shape[1]
        if "plan_q" in s
        else (np.asarray(s["plan_v"]).shape[1] if "plan_v" in s else 0)
    )
    out = []
    for k, ns in enumerate(stamps):
        out.append(
            (
                ns,
                cls(
                    header=m.header(ns, tm.world_frame),
                    n_nodes=int(n_nodes),
                    q=flat("plan_q", k),
                    v=flat("plan_v", k),
                    tau=flat("plan_tau", k),
                    forces=flat("plan_forces", k),
                    contact=flat("plan_contact", k, bool),
                ),
            )
        )
    return out


def _arrays(m: _Msgs, stamps, tm: TopicMap, column: np.ndarray):
    cls = m.types[_ARRAY]
    shape = np.asarray(column.shape[1:], dtype=np.uint32)
    return [
        (
            ns,
            cls(
                header=m.header(ns, tm.world_frame),
                dtype=str(column.dtype),
                shape=shape.copy(),
                data=np.asarray(row, float).ravel().copy(),
            ),
        )
        for ns, row in zip(stamps, column, strict=True)
    ]
