"""Reading a ROS 2 bag into a run log: :func:`read_bag`, the topics aligned on the joint-state stamps."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from wbmpc.io.logs import RunLog
from wbmpc.io.rosbag.messages import _ARRAY, _ns, _quat, _rosbags, _vec, make_typestore
from wbmpc.io.rosbag.topic_map import (
    _TOPIC_FIELDS,
    JointNameError,
    MissingTopicError,
    TimeGapError,
    TopicMap,
    _as_topic_map,
)


# --------------------------------------------------------------------------------------------------- read
def read_bag(
    path: str | Path,
    topic_map: TopicMap | dict | str | Path | None = None,
    robot=None,
) -> RunLog:
    """Import a ROS 2 bag (sqlite3 or MCAP storage) into a columnar :class:`~wbmpc.io.logs.RunLog`.

    Args:
        path: Bag folder (with ``metadata.yaml``) or a single ``.db3``/``.mcap`` file.
        topic_map: A :class:`TopicMap`, a dict of its fields or a JSON path/string; ``None``: the defaults.
        robot: Optional :class:`~wbmpc.model.robot.Robot`: the model's joint order if the topic map has none.

    Returns:
        The log: ``signals`` at the joint-state stamps, ``solves`` one row per diagnostics message; ``meta``
        the recorded one (if the bag has ``/wbmpc/meta``) plus ``joint_names`` and ``rosbag`` (source path,
        topics read, start time, base-state source).

    Raises:
        FileNotFoundError: ``path`` does not exist.
        MissingTopicError: A required topic is not in the bag (the message lists the bag's topics).
        JointNameError: Joint names unknown to the model, or model joints missing from a message.
        TimeGapError: A signal topic has a gap longer than ``max_gap_factor`` median periods.
    """
    rb = _rosbags()
    tm = _as_topic_map(topic_map)
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no ROS 2 bag at {path}")
    store = make_typestore()
    with rb.highlevel.AnyReader([path], default_typestore=store) as reader:
        available = {name: info.msgtype for name, info in reader.topics.items()}
        listing = ", ".join(f"{k} ({v})" for k, v in sorted(available.items()))
        for key in tm.required:
            topics = tm.foot_topics() if key == "foot_forces" else [getattr(tm, key)]
            for topic in topics:
                if topic is None:
                    continue
                if topic not in available:
                    raise MissingTopicError(
                        f"bag {path} has no topic {topic!r} (TopicMap.{key}, required); its topics: {listing}"
                    )
        wanted = {getattr(tm, key) for key in _TOPIC_FIELDS} | set(tm.foot_topics())
        extra = {}
        if tm.extra_prefix:
            for topic in available:
                parts = (
                    topic[len(tm.extra_prefix) + 1 :].split("/")
                    if topic.startswith(tm.extra_prefix + "/")
                    else []
                )
                if len(parts) == 2 and parts[0] in ("signals", "solves") and available[topic] == _ARRAY:
                    extra[topic] = tuple(parts)
        wanted = (wanted | set(extra)) & set(available)
        messages: dict[str, list] = {topic: [] for topic in wanted}
        connections = [c for c in reader.connections if c.topic in wanted]
        for conn, bag_ns, raw in reader.messages(connections=connections):
            msg = reader.deserialize(raw, conn.msgtype)
            header = getattr(msg, "header", None)
            messages[conn.topic].append((_ns(header.stamp) if header is not None else int(bag_ns), msg))
    for topic in messages:
        messages[topic].sort(key=lambda e: e[0])
    return _assemble(path, tm, robot, messages, extra)


def _assemble(path: Path, tm: TopicMap, robot, messages: dict, extra: dict) -> RunLog:
    recorded = {}
    if tm.meta and messages.get(tm.meta):
        recorded = json.loads(messages[tm.meta][0][1].data)
    js = messages.get(tm.joint_states, [])
    if not js:
        raise MissingTopicError(f"bag {path} has no messages on the joint-state topic {tm.joint_states!r}")
    t_ns = np.array([ns for ns, _ in js], dtype=np.int64)
    start_ns = int(recorded.get("start_time_ns", t_ns[0]))
    t = (t_ns - start_ns) * 1e-9
    _check_gaps(tm.joint_states, t, tm.max_gap_factor)

    expected = _expected_joints(tm, robot, recorded, js)
    signals: dict[str, np.ndarray] = {"t": t}

    def stamps_of(topic):
        return (np.array([ns for ns, _ in messages[topic]], dtype=np.int64) - start_ns) * 1e-9

    def aligned(topic, values, kind="float", quat_slice=None):
        """values (N, ...) on ``topic``'s stamps -> (T, ...) on the joint-state stamps."""
        ts = stamps_of(topic)
        _check_gaps(topic, ts, tm.max_gap_factor)
        return _align(ts, np.asarray(values), t, kind, quat_slice, tm.max_gap_factor)

    pos, vel, eff = _joint_arrays(tm.joint_states, js, expected, tm)
    odom = _odometry_arrays(messages[tm.odometry]) if tm.odometry in messages else None
    truth = _odometry_arrays(messages[tm.ground_truth]) if tm.ground_truth in messages else None
    base_source = "ground_truth" if truth is not None else ("odometry" if odom is not None else None)
    base = truth if truth is not None else odom
    base_topic = tm.ground_truth if truth is not None else tm.odometry
    if base is not None:
        qb = aligned(base_topic, base[0], quat_slice=slice(3, 7))
        vb = aligned(base_topic, base[1])
        if pos is not None:
            signals["q"] = np.concatenate([qb, pos], axis=1)
        if vel is not None:
            signals["v"] = np.concatenate([vb, vel], axis=1)
    if eff is not None:
        signals["tau"] = eff
    if odom is not None:
        measured = messages.get(tm.joint_states_measured) if tm.joint_states_measured else None
        if measured:
            pos_m, vel_m, _ = _joint_arrays(tm.joint_states_measured, measured, expected, tm)
            pos_m = aligned(tm.joint_states_measured, pos_m) if pos_m is not None else None
            vel_m = aligned(tm.joint_states_measured, vel_m) if vel_m is not None else None
        else:
            pos_m, vel_m = pos, vel
        qb = aligned(tm.odometry, odom[0], quat_slice=slice(3, 7))
        vb = aligned(tm.odometry, odom[1])
        if pos_m is not None:
            signals["q_meas"] = np.concatenate([qb, pos_m], axis=1)
        if vel_m is not None:
            signals["v_meas"] = np.concatenate([vb, vel_m], axis=1)
    if tm.joint_feedforward and messages.get(tm.joint_feedforward):
        _, _, ff = _joint_arrays(tm.joint_feedforward, messages[tm.joint_feedforward], expected, tm)
        if ff is not None:
            signals["tau_ff"] = aligned(tm.joint_feedforward, ff)
    if tm.imu and messages.get(tm.imu):
        imu = [msg for _, msg in messages[tm.imu]]
        quat = np.array([_quat(x.orientation) for x in imu])
        quat[np.array([x.orientation_covariance[0] == -1.0 for x in imu], bool)] = np.nan
        signals["imu_orientation"] = aligned(tm.imu, quat, quat_slice=slice(0, 4))
        signals["imu_gyro"] = aligned(tm.imu, np.array([_vec(x.angular_velocity) for x in imu]))
        signals["imu_accelerometer"] = aligned(tm.imu, np.array([_vec(x.linear_acceleration) for x in imu]))
    feet = tm.foot_topics()
    if feet and all(messages.get(topic) for topic in feet):
        forces = [
            aligned(topic, np.array([_vec(x.wrench.force) for _, x in messages[topic]])) for topic in feet
        ]
        signals["foot_forces"] = np.stack(forces, axis=1)
    if tm.feet_contact and messages.get(tm.feet_contact):
        msgs = [x for _, x in messages[tm.feet_contact]]
        for column, attr, kind in (
            ("contact", "contact_plan", "flag"),
            ("contact_sim", "contact_sim", "flag"),
            ("foot_height", "foot_height", "float"),
        ):
            if all(len(getattr(x, attr)) for x in msgs):
                values = np.array([getattr(x, attr) for x in msgs])
                signals[column] = aligned(tm.feet_contact, values, kind)
    for column, topic in (("ee_position", tm.ee_position), ("ee_reference", tm.ee_reference)):
        if topic and messages.get(topic):
            signals[column] = aligned(topic, np.array([_vec(x.point) for _, x in messages[topic]]))
    for column, topic in (("ee_force_sim", tm.ee_force), ("ee_force_cmd", tm.ee_force_cmd)):
        if topic and messages.get(topic):
            signals[column] = aligned(topic, np.array([_vec(x.wrench.force) for _, x in messages[topic]]))
    if tm.base_velocity_cmd and messages.get(tm.base_velocity_cmd):
        values = np.array([_vec(x.twist.linear) for _, x in messages[tm.base_velocity_cmd]])
        signals["base_velocity_cmd"] = aligned(tm.base_velocity_cmd, values)

    solves = _solves(tm, messages, start_ns)
    for topic, (table, name) in sorted(extra.items()):
        rows = [x for _, x in messages[topic]]
        dtype = np.dtype(rows[0].dtype)
        values = np.array([x.data.reshape(tuple(int(s) for s in x.shape)) for x in rows])
        if table == "signals":
            kind = "float" if dtype.kind == "f" else "flag"
            signals[name] = aligned(topic, values, kind).astype(dtype)
        elif "solve_t" in solves:
            index = _hold_index(stamps_of(topic), solves["solve_t"])
            solves[name] = values[index].astype(dtype)

    meta = dict(recorded.get("log_meta", {}))
    meta["joint_names"] = list(expected)
    meta["rosbag"] = {
        "path": str(path),
        "topics": sorted(messages),
        "start_time_ns": start_ns,
        "base_state_source": base_source,
        "topic_map": tm.to_dict(),
    }
    log = RunLog(signals=signals, solves=solves, meta=meta)
    log.validate()
    return log


def _expected_joints(tm: TopicMap, robot, recorded: dict, js: list) -> list[str]:
    if tm.joint_names is not None:
        return list(tm.joint_names)
    if robot is not None:
        return list(robot.joint_names)
    if recorded.get("joint_names"):
        return list(recorded["joint_names"])
    names = [tm.joint_name_map.get(n, n) for n in js[0][1].name]
    return [n for n in names if n not in tm.ignore_joints]


def _joint_arrays(topic: str, msgs: list, expected: Sequence[str], tm: TopicMap):
    """(position, velocity, effort), each (N, nj) in the model order or ``None`` if the messages have none."""
    expected = list(expected)
    index_of = {n: i for i, n in enumerate(expected)}
    orders: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}
    n = len(msgs)
    out = {k: np.full((n, len(expected)), np.nan) for k in ("position", "velocity", "effort")}
    present = {k: False for k in out}
    for k, (ns, msg) in enumerate(msgs):
        key = tuple(msg.name)
        if key not in orders:
            names = [tm.joint_name_map.get(x, x) for x in msg.name]
            keep = [i for i, x in enumerate(names) if x not in tm.ignore_joints]
            kept = [names[i] for i in keep]
            unknown = [x for x in kept if x not in index_of]
            missing = [x for x in expected if x not in kept]
            if unknown or missing:
                problem = f"unknown joint names {unknown}" if unknown else ""
                problem += ("; " if unknown and missing else "") + (
                    f"missing joints {missing}" if missing else ""
                )
                raise JointNameError(
                    f"topic {topic!r} at stamp {ns * 1e-9:.6f} s: {problem}; "
                    f"expected (model order): {expected} "
                    "(set TopicMap.joint_names, joint_name_map or ignore_joints)"
                )
            orders[key] = (np.array(keep, int), np.array([index_of[x] for x in kept], int))
        src, dst = orders[key]
        for name in out:
            values = np.asarray(getattr(msg, name), float)
            if values.size:
                out[name][k, dst] = values[src]
                present[name] = True
    return tuple(out[k] if present[k] else None for k in ("position", "velocity", "effort"))


def _odometry_arrays(msgs: list) -> tuple[np.ndarray, np.ndarray]:
    """Base ``q`` part (N, 7) (position, quaternion xyzw) and ``v`` part (N, 6) (twist, child frame)."""
    q = np.array([_vec(x.pose.pose.position) + _quat(x.pose.pose.orientation) for _, x in msgs])
    v = np.array([_vec(x.twist.twist.linear) + _vec(x.twist.twist.angular) for _, x in msgs])
    return q.reshape(-1, 7), v.reshape(-1, 6)


def _solves(tm: TopicMap, messages: dict, start_ns: int) -> dict[str, np.ndarray]:
    solves: dict[str, np.ndarray] = {}
    diag = messages.get(tm.diagnostics) if tm.diagnostics else None
    plan = messages.get(tm.plan_preview) if tm.plan_preview else None
    if diag:
        msgs = [x for _, x in diag]
        solves["solve_t"] = (np.array([ns for ns, _ in diag], np.int64) - start_ns) * 1e-9
        solves["apply_t"] = (np.array([_ns(x.apply_stamp) for x in msgs], np.int64) - start_ns) * 1e-9
        solves["solve_time"] = np.array([x.solve_time for x in msgs], float)
        solves["iterations"] = np.array([x.iterations for x in msgs], np.int64)
        solves["success"] = np.array([x.success for x in msgs], bool)
        solves["fallback"] = np.array([x.fallback for x in msgs], bool)
        solves["violation"] = np.array([x.constraint_violation for x in msgs], float)
        solves["status"] = np.asarray([x.status for x in msgs], dtype=str)
        solves["reason"] = np.asarray([x.reason for x in msgs], dtype=str)
        solves["hold"] = np.array([x.hold for x in msgs], bool)
    if plan:
        plan_t = (np.array([ns for ns, _ in plan], np.int64) - start_ns) * 1e-9
        if "solve_t" not in solves:
            solves["solve_t"] = plan_t
        index = _hold_index(plan_t, solves["solve_t"])
        msgs = [plan[i][1] for i in index]
        n_nodes = max(int(msgs[0].n_nodes), 1)
        for column, attr, width, dtype in (
            ("plan_q", "q", n_nodes, float),
            ("plan_v", "v", n_nodes, float),
            ("plan_tau", "tau", None, float),
            ("plan_forces", "forces", -3, float),
            ("plan_contact", "contact", None, bool),
        ):
            if not all(len(getattr(x, attr)) for x in msgs):
                continue
            values = np.array([getattr(x, attr) for x in msgs], dtype)
            if width is not None and width > 0:
                values = values.reshape(len(msgs), width, -1)
            elif width == -3:
                values = values.reshape(len(msgs), -1, 3)
            solves[column] = values
    return solves


# ----------------------------------------------------------------------------------------- time alignment
def _check_gaps(topic: str, t: np.ndarray, factor: float) -> None:
    """Raise :class:`TimeGapError` if a step of ``t`` [s] exceeds ``factor`` median steps."""
    if len(t) < 3:
        return
    dt = np.diff(t)
    median = float(np.median(dt))
    if median <= 0:
        return
    k = int(np.argmax(dt))
    if dt[k] > factor * median:
        raise TimeGapError(
            f"topic {topic!r}: gap of {dt[k]:.4f} s between t={t[k]:.4f} s and t={t[k + 1]:.4f} s, more than "
            f"{factor:g} x its median period {median * 1e3:.3g} ms (TopicMap.max_gap_factor)"
        )


def _hold_index(t_src: np.ndarray, t_ref: np.ndarray) -> np.ndarray:
    """Index of the latest ``t_src`` sample at or before each ``t_ref`` (the first one before it starts)."""
    tol = 1e-9  # stamps are whole nanoseconds
    return np.clip(np.searchsorted(t_src, t_ref + tol, side="right") - 1, 0, len(t_src) - 1)


def _align(t_src, values, t_ref, kind: str, quat_slice: slice | None, factor: float) -> np.ndarray:
    """Resample ``values`` (N, ...) at ``t_src`` [s] onto ``t_ref`` [s] (T,).

    Equal stamps: unchanged. ``"float"``: linear interpolation, NaN more than a gap threshold outside the
    source span; the quaternion columns ``quat_slice`` are made sign-continuous first, normalised after.
    ``"flag"`` (and integer) values: the previous sample held.
    """
    if len(t_src) == len(t_ref) and np.all(np.abs(t_src - t_ref) < 0.5e-9):
        return values
    if len(t_src) == 0:
        return np.full((len(t_ref),) + values.shape[1:], np.nan)
    if kind != "float" or values.dtype.kind in "biu":
        return values[_hold_index(t_src, t_ref)]
    flat = values.reshape(len(values), -1).astype(float)
    if quat_slice is not None:
        quat = flat[:, quat_slice]
        flips = np.concatenate([[1.0], np.sign(np.sum(quat[1:] * quat[:-1], axis=1))])
        flips[flips == 0] = 1.0
        flat[:, quat_slice] = quat * np.cumprod(flips)[:, None]
    out = np.column_stack([np.interp(t_ref, t_src, flat[:, j]) for j in range(flat.shape[1])])
    period = float(np.median(np.diff(t_src))) if len(t_src) > 1 else 0.0
    tol = factor * period
    out[(t_ref < t_src[0] - tol) | (t_ref > t_src[-1] + tol)] = np.nan
    if quat_slice is not None:
        quat = out[:, quat_slice]
        out[:, quat_slice] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    return out.reshape((len(t_ref),) + values.shape[1:])
