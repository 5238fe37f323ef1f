"""ROS 2 bags (wbmpc.io.rosbag, pure-Python ``rosbags``): run -> bag -> log, topic maps, import errors."""

import json
from pathlib import Path

import numpy as np
import pytest

# rosbags is pinned in environment.txt: a broken install must fail here, not skip the file.
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Writer

from wbmpc.control.mpc import MPCConfig, WholeBodyMPC
from wbmpc.io.logs import RunLog, load_log, save_log
from wbmpc.io.rosbag import (
    JointNameError,
    MissingTopicError,
    TimeGapError,
    TopicMap,
    main,
    make_typestore,
    read_bag,
    write_bag,
)
from wbmpc.model.robot import load_b1_z1
from wbmpc.ocp import OCPSettings
from wbmpc.ocp.gait import make_gait
from wbmpc.sim.closed_loop import ClosedLoopConfig, run_closed_loop
from wbmpc.sim.loop_config import CommandSchedule


@pytest.fixture(scope="module")
def robot():
    return load_b1_z1()


@pytest.fixture(scope="module")
def run_log(robot):
    """A short real closed loop (0.3 s standing: 150 low-level samples, 24 solves)."""
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=6), MPCConfig(gait=make_gait("stand"), dt_max=0.04))
    result = run_closed_loop(
        mpc, ClosedLoopConfig(duration=0.3, commands=CommandSchedule(arm_reference=None)), progress=False
    )
    return result.run_log()


def bag_topics(path) -> dict[str, str]:
    with AnyReader([Path(path)]) as reader:
        return {name: info.msgtype for name, info in reader.topics.items()}


def assert_columns_equal(original: RunLog, back: RunLog) -> None:
    """Every column the two logs share is equal (times to the nanosecond stamps, the rest exactly)."""
    for table in ("signals", "solves"):
        a, b = getattr(original, table), getattr(back, table)
        assert set(a) <= set(b), (table, sorted(set(a) - set(b)))
        for name in a:
            x, y = np.asarray(a[name]), np.asarray(b[name])
            assert x.shape == y.shape and x.dtype == y.dtype, (name, x.shape, y.shape, x.dtype, y.dtype)
            if name in ("t", "solve_t", "apply_t"):
                np.testing.assert_allclose(y, x, rtol=0, atol=1e-9, err_msg=name)
            else:
                np.testing.assert_array_equal(y, x, err_msg=name)


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_round_trip_run_bag_log(run_log, robot, tmp_path, storage):
    path = write_bag(run_log, tmp_path / "bag", robot=robot, storage=storage)
    suffix = {"sqlite3": ".db3", "mcap": ".mcap"}[storage]
    assert (path / "metadata.yaml").exists() and any(p.suffix == suffix for p in path.iterdir())
    topics = bag_topics(path)
    assert topics["/joint_states"] == "sensor_msgs/msg/JointState"
    assert topics["/imu"] == "sensor_msgs/msg/Imu"
    assert topics["/odom"] == "nav_msgs/msg/Odometry"
    assert topics["/feet/RL/force"] == "geometry_msgs/msg/WrenchStamped"
    assert topics["/mpc/diagnostics"] == "wbmpc_msgs/msg/SolveDiagnostics"
    assert topics["/mpc/plan_preview"] == "wbmpc_msgs/msg/PlanPreview"
    assert topics["/wbmpc/solves/ee_command"] == "wbmpc_msgs/msg/ArrayStamped"

    back = read_bag(path)
    assert_columns_equal(run_log, back)
    assert back.meta["joint_names"] == robot.joint_names
    assert back.meta["summary"]["mpc_solves"] == len(run_log.solves["solve_t"])
    assert back.meta["rosbag"]["base_state_source"] == "ground_truth"
    # The synthesised IMU: orientation = the true base orientation, gravity read at rest.
    np.testing.assert_allclose(back["imu_orientation"], run_log["q"][:, 3:7], atol=1e-12)
    np.testing.assert_allclose(back["imu_gyro"], run_log["v"][:, 3:6], atol=1e-12)
    np.testing.assert_allclose(back["imu_accelerometer"][0], [0.0, 0.0, robot.gravity], atol=1e-9)
    # A written bag is re-read through a saved .npz without losing columns.
    assert_columns_equal(run_log, load_log(save_log(back, tmp_path / "back.npz")))


def test_topic_map_from_json_renames_topics_and_permutes_joints(run_log, robot, tmp_path):
    names = robot.joint_names
    lab = {
        "joint_states": "/b1/joint_states",
        "imu": "/b1/imu/data",
        "odometry": "/b1/odom",
        "ground_truth": None,
        "foot_forces": "/b1/{foot}_foot/grf",
        "diagnostics": "/b1/mpc/diagnostics",
        "world_frame": "odom",
        "base_frame": "trunk",
    }
    (tmp_path / "write.json").write_text(json.dumps(lab))
    write_map = TopicMap.from_json(tmp_path / "write.json")
    assert TopicMap.from_json(write_map.to_json()) == write_map
    path = write_bag(run_log, tmp_path / "bag", robot=robot, topic_map=write_map)
    topics = bag_topics(path)
    assert {"/b1/joint_states", "/b1/imu/data", "/b1/odom", "/b1/FL_foot/grf"} <= set(topics)
    assert not {"/joint_states", "/imu", "/odom", "/ground_truth/odom"} & set(topics)

    # The lab's model names the joints differently and orders them in reverse.
    rename = {name: f"lab_{name}" for name in names}
    perm = np.arange(len(names))[::-1]
    read_map = dict(lab, joint_name_map=rename, joint_names=[rename[names[i]] for i in perm])
    (tmp_path / "read.json").write_text(json.dumps(read_map))
    back = read_bag(path, topic_map=tmp_path / "read.json")
    assert back.meta["joint_names"] == read_map["joint_names"]
    assert back.meta["rosbag"]["base_state_source"] == "odometry"  # no ground truth: q's base from odometry
    for column, offset in (("q", 7), ("v", 6), ("q_meas", 7), ("v_meas", 6), ("tau", 0), ("tau_ff", 0)):
        source = "q_meas" if column == "q" else "v_meas" if column == "v" else column
        np.testing.assert_array_equal(back[column][:, :offset], run_log[source][:, :offset])
        np.testing.assert_array_equal(back[column][:, offset:], run_log[column][:, offset:][:, perm])
    np.testing.assert_array_equal(back["foot_forces"], run_log["foot_forces"])
    with pytest.raises(ValueError, match="unknown TopicMap keys \\['joint_state'\\]"):
        TopicMap.from_dict({"joint_state": "/x"})


def test_missing_topic_lists_the_bag_topics(run_log, robot, tmp_path):
    path = write_bag(run_log, tmp_path / "bag", robot=robot)
    with pytest.raises(MissingTopicError, match=r"no topic '/imu/data' \(TopicMap.imu, required\)") as info:
        read_bag(path, topic_map={"imu": "/imu/data"})
    assert "/joint_states (sensor_msgs/msg/JointState)" in str(info.value)
    assert "/imu (sensor_msgs/msg/Imu)" in str(info.value)
    # Optional topics that are absent are skipped.
    back = read_bag(path, topic_map={"ee_position": "/not/there"})
    assert "ee_position" not in back.signals


def test_unknown_joint_names_are_listed(run_log, robot, tmp_path):
    path = write_bag(run_log, tmp_path / "bag", robot=robot, storage="mcap")
    expected = ["FL_hip"] + robot.joint_names[1:]
    with pytest.raises(JointNameError) as info:
        read_bag(path, topic_map={"joint_names": expected})
    message = str(info.value)
    assert f"unknown joint names ['{robot.joint_names[0]}']" in message
    assert "missing joints ['FL_hip']" in message and "'/joint_states' at stamp 0.000000 s" in message
    assert str(expected) in message
    # A joint the model does not have can be dropped instead.
    back = read_bag(
        path, topic_map={"joint_names": robot.joint_names[1:], "ignore_joints": [robot.joint_names[0]]}
    )
    np.testing.assert_array_equal(back["q"][:, 7:], run_log["q"][:, 8:])


def test_time_gap_is_reported_with_place_and_length(run_log, robot, tmp_path):
    keep = np.r_[0:60, 80 : len(run_log["t"])]  # 20 samples (40 ms) lost after t = 0.118 s
    gappy = RunLog({k: v[keep] for k, v in run_log.signals.items()}, run_log.solves, run_log.meta)
    path = write_bag(gappy, tmp_path / "bag", robot=robot)
    with pytest.raises(
        TimeGapError, match=r"'/joint_states': gap of 0.0420 s between t=0.1180 s and t=0.1600 s"
    ):
        read_bag(path)
    back = read_bag(path, topic_map={"max_gap_factor": 50.0})  # a looser threshold accepts it
    np.testing.assert_allclose(back["t"], gappy["t"], atol=1e-9)


def test_lab_bag_at_other_rates_is_resampled_to_joint_states(robot, tmp_path):
    """A bag as a robot records it: no wbmpc meta, an extra gripper joint in a different order, IMU at 1 kHz
    and odometry at 250 Hz with offset stamps, a wall-clock start."""
    store = make_typestore()
    types = store.types
    Time, Header = types["builtin_interfaces/msg/Time"], types["std_msgs/msg/Header"]
    Vector3, Quaternion = types["geometry_msgs/msg/Vector3"], types["geometry_msgs/msg/Quaternion"]
    geo = {k: types[f"geometry_msgs/msg/{k}"] for k in ("Point", "Pose", "Twist")}
    start = 1_700_000_000 * 10**9
    names = robot.joint_names

    def header(t):
        ns = start + round(t * 1e9)
        return Header(stamp=Time(sec=ns // 10**9, nanosec=ns % 10**9), frame_id="")

    def yaw_quat(t):
        return np.array([0.0, 0.0, np.sin(0.25 * t), np.cos(0.25 * t)])  # yaw = 0.5 t

    t_js, t_imu, t_odom = np.arange(100) * 0.002, np.arange(200) * 0.001, 0.0015 + np.arange(50) * 0.004
    order = list(reversed(names)) + ["gripper"]
    path = tmp_path / "lab_bag"
    with Writer(path, version=Writer.VERSION_LATEST) as writer:
        c_js = writer.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=store)
        c_imu = writer.add_connection("/imu", "sensor_msgs/msg/Imu", typestore=store)
        c_odom = writer.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=store)
        entries = []
        for t in t_js:
            position = np.array([np.sin(t + names.index(n)) for n in order[:-1]] + [0.3])
            js = types["sensor_msgs/msg/JointState"](
                header=header(t),
                name=order,
                position=position,
                velocity=np.zeros(len(order)),
                effort=np.zeros(0),
            )
            entries.append((t, c_js, js))
        cov = np.zeros(9)
        for t in t_imu:
            q = yaw_quat(t)
            imu = types["sensor_msgs/msg/Imu"](
                header=header(t),
                orientation=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]),
                orientation_covariance=cov,
                angular_velocity=Vector3(x=0.0, y=0.0, z=0.5),
                angular_velocity_covariance=cov,
                linear_acceleration=Vector3(x=t, y=0.0, z=9.81),
                linear_acceleration_covariance=cov,
            )
            entries.append((t, c_imu, imu))
        cov36 = np.zeros(36)
        for t in t_odom:
            q = yaw_quat(t)
            pose = geo["Pose"](
                position=geo["Point"](x=0.1 * t, y=0.0, z=0.5),
                orientation=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]),
            )
            twist = geo["Twist"](linear=Vector3(x=0.1, y=0.0, z=0.0), angular=Vector3(x=0.0, y=0.0, z=0.5))
            odom = types["nav_msgs/msg/Odometry"](
                header=header(t),
                child_frame_id="base",
                pose=types["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov36),
                twist=types["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=cov36),
            )
            entries.append((t, c_odom, odom))
        for t, conn, msg in sorted(entries, key=lambda e: e[0]):
            writer.write(conn, start + round(t * 1e9), store.serialize_cdr(msg, conn.msgtype))

    with pytest.raises(JointNameError, match=r"unknown joint names \['gripper'\]"):
        read_bag(path, robot=robot)
    log = read_bag(path, robot=robot, topic_map={"ignore_joints": ["gripper"]})
    assert (
        log.meta["rosbag"]["start_time_ns"] == start and log.meta["rosbag"]["base_state_source"] == "odometry"
    )
    np.testing.assert_allclose(log["t"], t_js, atol=1e-9)
    expected_q = np.array([[np.sin(t + i) for i in range(len(names))] for t in t_js])
    np.testing.assert_allclose(log["q_meas"][:, 7:], expected_q, atol=1e-12)
    np.testing.assert_array_equal(log["q"], log["q_meas"])
    assert "tau" not in log.signals  # the bag has no efforts
    # IMU at 1 kHz: every other sample; odometry at 250 Hz: interpolated, outside its span held at the edge.
    np.testing.assert_allclose(log["imu_accelerometer"][:, 0], t_js, atol=1e-12)
    np.testing.assert_allclose(log["imu_orientation"], np.array([yaw_quat(t) for t in t_js]), atol=1e-12)
    inside = (t_js >= t_odom[0]) & (t_js <= t_odom[-1])
    np.testing.assert_allclose(log["q_meas"][inside, 0], 0.1 * t_js[inside], atol=1e-12)
    np.testing.assert_allclose(log["q_meas"][[0, -1], 0], 0.1 * t_odom[[0, -1]], atol=1e-12)
    quat = log["q_meas"][:, 3:7]
    np.testing.assert_allclose(np.linalg.norm(quat, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(quat[inside], np.array([yaw_quat(t) for t in t_js[inside]]), atol=1e-6)
    assert log.solves == {}


def test_cli_export_import_and_topic_map(run_log, robot, tmp_path, capsys):
    log_path = save_log(
        RunLog(run_log.signals, run_log.solves, dict(run_log.meta, joint_names=robot.joint_names)),
        tmp_path / "run.npz",
    )
    assert main(["export", str(log_path), str(tmp_path / "bag"), "--storage", "mcap"]) == 0
    assert main(["import", str(tmp_path / "bag"), str(tmp_path / "back.npz")]) == 0
    assert_columns_equal(run_log, load_log(tmp_path / "back.npz"))
    assert main(["export", str(log_path), str(tmp_path / "bag")]) == 1
    assert "exists" in capsys.readouterr().err
    assert main(["topic-map", str(tmp_path / "map.json")]) == 0
    assert TopicMap.from_json(tmp_path / "map.json") == TopicMap()
