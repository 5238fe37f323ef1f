"""ROS 2 bags of closed-loop runs without a ROS install, with the pure-Python ``rosbags`` library.

:func:`write_bag` records a columnar :class:`~wbmpc.io.logs.RunLog` (``result.run_log()`` or
:func:`~wbmpc.io.logs.load_log`) as a rosbag2 folder (sqlite3 storage by default, MCAP optional) that ROS 2
tools (``ros2 bag play``, Foxglove, PlotJuggler) open. :func:`read_bag` imports a rosbag2 folder (sqlite3
or MCAP), this module's or a lab's, back into a ``RunLog`` through a :class:`TopicMap` (topic names, joint
order, frame ids; editable as JSON). Command line::

    python -m wbmpc.io.rosbag export LOG.npz BAG_DIR [--storage mcap] [--topic-map MAP.json]
    python -m wbmpc.io.rosbag import BAG_DIR LOG.npz [--topic-map MAP.json]
    python -m wbmpc.io.rosbag topic-map [MAP.json]      # write (or print) the default topic map

Topics (default names; ``T`` rows of ``signals`` at the low-level rate, 500 Hz in simulation; one message
per MPC solve, 80 Hz, for ``solves``). Units SI; ``q``/``v`` follow Pinocchio (``q = [p, quat xyzw,
joints]``, ``v = [base linear, base angular (base axes), joint rates]``):

=============================  ===============================  ====  ========================================
topic (TopicMap field)         type                             rate  fields <- log columns
=============================  ===============================  ====  ========================================
``/joint_states``              sensor_msgs/msg/JointState       500   ``position`` <- ``q[:, 7:]`` [rad],
(``joint_states``)                                                    ``velocity`` <- ``v[:, 6:]`` [rad/s],
                                                                      ``effort`` <- ``tau`` [N m] (true plant
                                                                      state, applied torques); ``name``:
                                                                      joints in model order
``/joint_states/measured``     sensor_msgs/msg/JointState       500   ``q_meas[:, 7:]``, ``v_meas[:, 6:]``
(``joint_states_measured``)                                           (what the controller saw)
``/joint_states/feedforward``  sensor_msgs/msg/JointState       500   ``effort`` <- ``tau_ff`` [N m]
(``joint_feedforward``)                                               (position, velocity empty)
``/imu`` (``imu``)             sensor_msgs/msg/Imu              500   frame ``imu`` (base origin, base axes):
                                                                      ``orientation`` base -> world,
                                                                      ``angular_velocity`` [rad/s],
                                                                      ``linear_acceleration``: specific force
                                                                      ``R^T (a - g)`` [m/s^2] <- ``imu_*``
                                                                      columns, else synthesised from ``q``,
                                                                      ``v`` (``estimation.synthesize_imu``:
                                                                      exact, no noise); none if the log has
                                                                      neither
``/odom`` (``odometry``)       nav_msgs/msg/Odometry            500   frame ``world``, child ``base``:
                                                                      ``pose`` <- ``q_meas[:, :7]``,
                                                                      ``twist`` <- ``v_meas[:, :6]`` (base
                                                                      axes, as REP 105's child frame)
``/ground_truth/odom``         nav_msgs/msg/Odometry            500   the same from ``q``, ``v`` (simulator
(``ground_truth``)                                                    truth)
``/feet/<FL|FR|RL|RR>/force``  geometry_msgs/msg/WrenchStamped  500   frame ``world``: ``force`` <-
(``foot_forces``)                                                     ``foot_forces[:, i]`` [N], torque 0
``/feet/contact``              wbmpc_msgs/msg/FeetContact       500   ``contact`` (schedule), ``contact_sim``,
(``feet_contact``)                                                    ``foot_height`` [m]
``/ee/position``               geometry_msgs/msg/PointStamped   500   ``ee_position`` [m], frame ``world``
``/ee/reference``              geometry_msgs/msg/PointStamped   500   ``ee_reference`` [m] (NaN: none)
``/ee/force``                  geometry_msgs/msg/WrenchStamped  500   ``ee_force_sim`` [N], frame ``world``
``/cmd/base_velocity``         geometry_msgs/msg/TwistStamped   500   ``linear`` <- ``base_velocity_cmd``
(``base_velocity_cmd``)                                               [m/s], frame ``heading``
``/cmd/ee_force``              geometry_msgs/msg/WrenchStamped  500   ``ee_force_cmd`` [N], frame ``world``
``/mpc/diagnostics``           wbmpc_msgs/msg/SolveDiagnostics  80    stamp <- ``solve_t``; ``apply_t``,
(``diagnostics``)                                                     ``solve_time`` [s], ``iterations``,
                                                                      ``success``, ``fallback``, ``hold``,
                                                                      ``violation``, ``status``
``/mpc/plan_preview``          wbmpc_msgs/msg/PlanPreview       80    ``plan_q``, ``plan_v``, ``plan_tau``,
(``plan_preview``)                                                    ``plan_forces``, ``plan_contact``
``/wbmpc/signals/<column>``    wbmpc_msgs/msg/ArrayStamped      500   any other numeric signal column
``/wbmpc/solves/<column>``     wbmpc_msgs/msg/ArrayStamped      80    any other numeric solve column (e.g.
(``extra_prefix``)                                                    ``ee_command``)
``/wbmpc/meta`` (``meta``)     std_msgs/msg/String              once  JSON: the log's ``meta``, joint and foot
                                                                      names, frame ids, start time
=============================  ===============================  ====  ========================================

Every message carries its sample time in ``header.stamp`` (and as the bag timestamp):
``start_time_ns + round(t * 1e9)`` [ns]; the frame ids are those of the :class:`TopicMap`. The custom
messages' definitions are :data:`WBMPC_MSGS` (package ``wbmpc_msgs``; bags embed them, so readers need no
ROS package):

* ``wbmpc_msgs/msg/SolveDiagnostics``: ``std_msgs/Header header`` (stamp: the solve's measurement time),
  ``builtin_interfaces/Time apply_stamp`` (when the plan reached the low level), ``float64 solve_time`` [s],
  ``int32 iterations``, ``bool success``, ``bool fallback``, ``bool hold``, ``float64 constraint_violation``,
  ``string status``, ``string reason``.
* ``wbmpc_msgs/msg/PlanPreview``: ``header``, ``uint32 n_nodes``, ``float64[] q`` (``n_nodes x nq``
  row-major), ``float64[] v`` (``n_nodes x nv``), ``float64[] tau`` (first stage, ``nj``) [N m],
  ``float64[] forces`` (first stage, ``n_contacts x 3``, world) [N], ``bool[] contact`` (first stage, per
  foot).
* ``wbmpc_msgs/msg/FeetContact``: ``header``, ``string[] foot_names``, ``bool[] contact_plan``,
  ``bool[] contact_sim``, ``float64[] foot_height`` [m] (empty arrays: not logged).
* ``wbmpc_msgs/msg/ArrayStamped``: ``header``, ``string dtype`` (NumPy dtype of the column),
  ``uint32[] shape`` (of one row), ``float64[] data`` (the row, row-major).

Import (:func:`read_bag`): every topic of the map that the bag has is read, in ``header.stamp`` order; the
``required`` ones must be there (:class:`MissingTopicError` otherwise). Signal topics are aligned to the
joint-state stamps (``t = stamp - start``, the start from ``/wbmpc/meta`` or the first joint state): equal
stamps are taken as they are, others are interpolated linearly (quaternions normalised, flags held from the
previous sample), NaN more than one gap threshold outside a topic's time span. A gap in a signal topic
longer than ``max_gap_factor`` times its median period raises :class:`TimeGapError`; joint names are
matched by name (``joint_name_map`` renames, ``ignore_joints`` drops), unknown or missing ones raise
:class:`JointNameError`. ``q``/``v`` take the base from ``ground_truth`` if the bag has it, else from
``odometry`` (``meta["rosbag"]["base_state_source"]`` says which); ``q_meas``/``v_meas`` take their
joints from ``joint_states_measured`` if present, else from ``joint_states``. The IMU becomes the columns
``imu_orientation`` (T, 4) (xyzw; NaN if the IMU gives none), ``imu_gyro`` (T, 3) [rad/s] and
``imu_accelerometer`` (T, 3) [m/s^2].

Example:
    >>> write_bag(result.run_log(), "runs/stand_bag", robot=robot)
    >>> log = read_bag("runs/stand_bag")
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np

from wbmpc import checks
from wbmpc.io.logs import RunLog, json_default, load_log, save_log

__all__ = [
    "BAG_FORMAT_VERSION",
    "JointNameError",
    "MissingTopicError",
    "RosbagError",
    "TimeGapError",
    "TopicMap",
    "WBMPC_MSGS",
    "make_typestore",
    "read_bag",
    "write_bag",
]

BAG_FORMAT_VERSION = 1
ROSBAGS_VERSION = "0.11.9"  # the version this module was written and tested with
_NS = 1_000_000_000

WBMPC_MSGS: dict[str, str] = {
    "wbmpc_msgs/msg/SolveDiagnostics": """\
# One MPC solve.
std_msgs/Header header               # stamp: measurement time of the solve; frame_id: world frame
builtin_interfaces/Time apply_stamp  # when the plan reached the low level (later with computation delay)
float64 solve_time                   # wall time of the solve [s]
int32 iterations                     # solver iterations
bool success                         # the solver converged
bool fallback                        # the previous plan was kept (solve failed)
bool hold                            # the static hold was applied (no converged plan existed yet)
float64 constraint_violation         # max constraint violation of the plan
string status                        # named solver status (wbmpc.solver.statuses.solver_status)
string reason                        # why the solve failed (empty on success)
""",
    "wbmpc_msgs/msg/PlanPreview": """\
# The first nodes of one MPC plan; arrays flattened row-major.
std_msgs/Header header  # stamp: measurement time of the solve; frame_id: world frame
uint32 n_nodes          # nodes in q and v
float64[] q             # n_nodes x nq configurations (p [m], quaternion xyzw, joints [rad])
float64[] v             # n_nodes x nv velocities (base axes [m/s], [rad/s]; joints [rad/s])
float64[] tau           # nj joint torques of the first stage [N m]
float64[] forces        # n_contacts x 3 contact forces of the first stage, world axes [N]
bool[] contact          # stance flag per foot on the first stage
""",
    "wbmpc_msgs/msg/FeetContact": """\
# Contact state of the feet (empty arrays: not logged).
std_msgs/Header header
string[] foot_names     # FL, FR, RL, RR
bool[] contact_plan     # stance flags of the gait schedule
bool[] contact_sim      # feet touching the ground in the simulator
float64[] foot_height   # height of each foot sphere's bottom above the ground [m]
""",
    "wbmpc_msgs/msg/ArrayStamped": """\
# One row of a log column without a dedicated message.
std_msgs/Header header
string dtype            # NumPy dtype of the column (float64, bool, int64, ...)
uint32[] shape          # shape of one row
float64[] data          # the row, row-major
""",
}

_JOINT_STATE = "sensor_msgs/msg/JointState"
_IMU = "sensor_msgs/msg/Imu"
_ODOM = "nav_msgs/msg/Odometry"
_WRENCH = "geometry_msgs/msg/WrenchStamped"
_POINT = "geometry_msgs/msg/PointStamped"
_TWIST = "geometry_msgs/msg/TwistStamped"
_STRING = "std_msgs/msg/String"
_DIAG = "wbmpc_msgs/msg/SolveDiagnostics"
_PLAN = "wbmpc_msgs/msg/PlanPreview"
_FEET = "wbmpc_msgs/msg/FeetContact"
_ARRAY = "wbmpc_msgs/msg/ArrayStamped"
# TopicMap fields holding one topic name each (``foot_forces`` is a template, ``extra_prefix`` a prefix).
_TOPIC_FIELDS = (
    "joint_states",
    "joint_states_measured",
    "joint_feedforward",
    "imu",
    "odometry",
    "ground_truth",
    "feet_contact",
    "ee_position",
    "ee_reference",
    "ee_force",
    "base_velocity_cmd",
    "ee_force_cmd",
    "diagnostics",
    "plan_preview",
    "meta",
)


# ------------------------------------------------------------------------------------------------ errors
class RosbagError(ValueError):
    """A bag that cannot be imported with the given topic map."""


class MissingTopicError(RosbagError):
    """A required topic is not in the bag."""


class JointNameError(RosbagError):
    """Joint names of the bag do not match the model's."""


class TimeGapError(RosbagError):
    """A signal topic has a gap in time longer than the topic map allows."""


# ---------------------------------------------------------------------------------------------- topic map
_TOPIC_FIELDS = (
    "joint_states",
    "joint_states_measured",
    "joint_feedforward",
    "imu",
    "odometry",
    "ground_truth",
    "foot_forces",
    "feet_contact",
    "ee_position",
    "ee_reference",
    "ee_force",
    "base_velocity_cmd",
    "ee_force_cmd",
    "diagnostics",
    "plan_preview",
    "meta",
    "extra_prefix",
)


@dataclass
class TopicMap:
    """Topic names, joint order and frame ids of a robot's bags (a lab edits it for its robot).

    Topic fields set to ``None`` (``null`` in JSON) are neither written nor read.

    Attributes:
        joint_states: True joint state and applied torques (``q[:, 7:]``, ``v[:, 6:]``, ``tau``).
        joint_states_measured: Joint state the controller saw (``q_meas``, ``v_meas`` joints).
        joint_feedforward: Feed-forward torques ``tau_ff`` (JointState efforts).
        imu: IMU (sensor_msgs/Imu).
        odometry: Base state the controller used (``q_meas[:, :7]``, ``v_meas[:, :6]``).
        ground_truth: True base state (``q[:, :7]``, ``v[:, :6]``).
        foot_forces: Per-foot force topic, a template with ``{foot}`` (a name of ``foot_names``).
        feet_contact: Contact flags and foot heights (wbmpc_msgs/FeetContact).
        ee_position, ee_reference, ee_force: End-effector position, its reference, measured force.
        base_velocity_cmd, ee_force_cmd: Commands (TwistStamped in the heading frame, WrenchStamped).
        diagnostics: MPC solve diagnostics (wbmpc_msgs/SolveDiagnostics).
        plan_preview: First plan nodes (wbmpc_msgs/PlanPreview).
        meta: The log's metadata as JSON (std_msgs/String).
        extra_prefix: Other numeric columns go to ``<prefix>/signals/<column>``, ``<prefix>/solves/<column>``.
        joint_names: The model's joint order (the columns of ``q[:, 7:]``, ``v[:, 6:]``, ``tau``); ``None``:
            the robot's, else the bag's recorded order.
        joint_name_map: Renames of the bag's joint names to the model's (bag name -> model name).
        ignore_joints: Joint names in the bag to drop (after renaming), e.g. a gripper not in the model.
        foot_names: Feet in the log's order (the ``{foot}`` values).
        world_frame, base_frame, imu_frame, heading_frame: Frame ids [-] written to headers.
        required: TopicMap fields whose topics a bag must have to be imported.
        max_gap_factor: A signal topic gap longer than this many median periods is an error.
    """

    joint_states: str | None = "/joint_states"
    joint_states_measured: str | None = "/joint_states/measured"
    joint_feedforward: str | None = "/joint_states/feedforward"
    imu: str | None = "/imu"
    odometry: str | None = "/odom"
    ground_truth: str | None = "/ground_truth/odom"
    foot_forces: str | None = "/feet/{foot}/force"
    feet_contact: str | None = "/feet/contact"
    ee_position: str | None = "/ee/position"
    ee_reference: str | None = "/ee/reference"
    ee_force: str | None = "/ee/force"
    base_velocity_cmd: str | None = "/cmd/base_velocity"
    ee_force_cmd: str | None = "/cmd/ee_force"
    diagnostics: str | None = "/mpc/diagnostics"
    plan_preview: str | None = "/mpc/plan_preview"
    meta: str | None = "/wbmpc/meta"
    extra_prefix: str | None = "/wbmpc"
    joint_names: list[str] | None = None
    joint_name_map: dict[str, str] = field(default_factory=dict)
    ignore_joints: list[str] = field(default_factory=list)
    foot_names: list[str] = field(default_factory=lambda: ["FL", "FR", "RL", "RR"])
    world_frame: str = "world"
    base_frame: str = "base"
    imu_frame: str = "imu"
    heading_frame: str = "heading"
    required: list[str] = field(default_factory=lambda: ["joint_states", "imu", "odometry"])
    max_gap_factor: float = 5.0

    def __post_init__(self):
        if self.joint_states is None:
            raise ValueError("TopicMap.joint_states cannot be None: joint states give the log's time base")
        for name in _TOPIC_FIELDS:
            topic = getattr(self, name)
            if topic is not None and (
                not isinstance(topic, str) or not topic.startswith("/") or " " in topic
            ):
                raise ValueError(
                    f"TopicMap.{name} must be a topic name starting with '/' (no spaces) or None, "
                    f"got {topic!r}"
                )
        if self.foot_forces is not None and "{foot}" not in self.foot_forces:
            raise ValueError(f"TopicMap.foot_forces must contain '{{foot}}', got {self.foot_forces!r}")
        for name in ("world_frame", "base_frame", "imu_frame", "heading_frame"):
            frame = getattr(self, name)
            if not isinstance(frame, str) or not frame.strip():
                raise ValueError(f"TopicMap.{name} must be a non-empty frame id, got {frame!r}")
        if self.joint_names is not None:
            checks.names("TopicMap.joint_names", self.joint_names, min_count=1)
        checks.names("TopicMap.ignore_joints", self.ignore_joints)
        checks.names("TopicMap.foot_names", self.foot_names, min_count=1)
        if not isinstance(self.joint_name_map, dict) or not all(
            isinstance(k, str) and isinstance(v, str) for k, v in self.joint_name_map.items()
        ):
            raise ValueError(
                f"TopicMap.joint_name_map must map bag joint names to model joint names (str -> str), "
                f"got {self.joint_name_map!r}"
            )
        known = {f.name for f in fields(self)}
        checks.names("TopicMap.required", self.required)
        if bad := [r for r in self.required if r not in known]:
            raise ValueError(f"TopicMap.required names unknown fields {bad}; fields: {sorted(known)}")
        if off := [r for r in self.required if r in known and getattr(self, r) is None]:
            raise ValueError(f"TopicMap.required lists {off}, whose topics are set to None")
        checks.number("TopicMap.max_gap_factor", self.max_gap_factor, low=1.0, low_open=True)

    @classmethod
    def from_dict(cls, data: dict) -> TopicMap:
        """Build from a dict of field values (missing fields keep their defaults).

        Raises:
            ValueError: For unknown keys (listing the known ones).
        """
        known = {f.name for f in fields(cls)}
        if unknown := sorted(set(data) - known):
            raise ValueError(f"unknown TopicMap keys {unknown}; known: {sorted(known)}")
        return cls(**data)

    @classmethod
    def from_json(cls, source: str | Path) -> TopicMap:
        """Load from a JSON file path or a JSON string (an object of field values)."""
        text = str(source)
        if not text.lstrip().startswith("{"):
            text = Path(source).read_text()
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            where = "the JSON string" if text is str(source) else str(source)
            raise ValueError(f"TopicMap JSON: {where} is not valid JSON ({exc})") from None
        if not isinstance(data, dict):
            raise ValueError(f"a TopicMap JSON must be an object, got {type(data).__name__}")
        return cls.from_dict(data)

    def to_dict(self) -> dict:
        return asdict(self)

    def to_json(self, path: str | Path | None = None) -> str:
        """The map as indented JSON; also written to ``path`` if given."""
        text = json.dumps(self.to_dict(), indent=2) + "\n"
        if path is not None:
            Path(path).write_text(text)
        return text

    def foot_topics(self) -> list[str]:
        return [self.foot_forces.format(foot=f) for f in self.foot_names] if self.foot_forces else []


def _as_topic_map(topic_map) -> TopicMap:
    if topic_map is None:
        return TopicMap()
    if isinstance(topic_map, TopicMap):
        return topic_map
    if isinstance(topic_map, dict):
        return TopicMap.from_dict(topic_map)
    return TopicMap.from_json(topic_map)


# ------------------------------------------------------------------------------------------- rosbags glue
def _rosbags():
    try:
        import rosbags.highlevel
        import rosbags.rosbag2
        import rosbags.typesys
    except ImportError as exc:  # not a dependency of wbmpc itself
        raise ImportError(
            f"ROS 2 bags need the 'rosbags' package: pip install rosbags=={ROSBAGS_VERSION}"
        ) from exc
    return rosbags


def make_typestore():
    """The ROS 2 Humble message types plus :data:`WBMPC_MSGS` (a ``rosbags`` ``Typestore``)."""
    typesys = _rosbags().typesys
    store = typesys.get_typestore(typesys.Stores.ROS2_HUMBLE)
    types = {}
    for name, text in WBMPC_MSGS.items():
        types.update(typesys.get_types_from_msg(text, name))
    store.register(types)
    return store


class _Msgs:
    """Constructors of the message classes of a typestore, with stamp helpers."""

    def __init__(self, store):
        self.store = store
        t = store.types
        self.Time, self.Header = t["builtin_interfaces/msg/Time"], t["std_msgs/msg/Header"]
        self.Vector3, self.Point = t["geometry_msgs/msg/Vector3"], t["geometry_msgs/msg/Point"]
        self.Quaternion, self.Pose = t["geometry_msgs/msg/Quaternion"], t["geometry_msgs/msg/Pose"]
        self.Twist, self.Wrench = t["geometry_msgs/msg/Twist"], t["geometry_msgs/msg/Wrench"]
        self.PoseCov = t["geometry_msgs/msg/PoseWithCovariance"]
        self.TwistCov = t["geometry_msgs/msg/TwistWithCovariance"]
        self.types = t

    def time(self, ns: int):
        return self.Time(sec=int(ns // _NS), nanosec=int(ns % _NS))

    def header(self, ns: int, frame: str):
        return self.Header(stamp=self.time(ns), frame_id=frame)

    def vec(self, x):
        return self.Vector3(x=float(x[0]), y=float(x[1]), z=float(x[2]))

    def quat(self, x):
        return self.Quaternion(x=float(x[0]), y=float(x[1]), z=float(x[2]), w=float(x[3]))

    def point_stamped(self, ns: int, frame: str, p):
        point = self.Point(x=float(p[0]), y=float(p[1]), z=float(p[2]))
        return self.types[_POINT](header=self.header(ns, frame), point=point)

    def twist_stamped(self, ns: int, frame: str, linear):
        twist = self.Twist(linear=self.vec(linear), angular=self.vec((0, 0, 0)))
        return self.types[_TWIST](header=self.header(ns, frame), twist=twist)

    def wrench(self, ns: int, frame: str, force):
        return self.types[_WRENCH](
            header=self.header(ns, frame),
            wrench=self.Wrench(force=self.vec(force), torque=self.vec((0, 0, 0))),
        )


def _ns(stamp) -> int:
    return int(stamp.sec) * _NS + int(stamp.nanosec)


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


def _quat(q) -> list[float]:
    return [q.x, q.y, q.z, q.w]


def _vec(v) -> list[float]:
    return [v.x, v.y, v.z]


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


# ---------------------------------------------------------------------------------------------------- CLI
def main(argv: Sequence[str] | None = None) -> int:
    """Command line: ``export LOG.npz BAG_DIR``, ``import BAG_DIR LOG.npz``, ``topic-map [PATH]``."""
    parser = argparse.ArgumentParser(prog="python -m wbmpc.io.rosbag", description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    export = sub.add_parser("export", help="write a run log (.npz) as a ROS 2 bag")
    export.add_argument("log", type=Path)
    export.add_argument("bag", type=Path)
    export.add_argument("--storage", choices=("sqlite3", "mcap"), default="sqlite3")
    export.add_argument("--topic-map", type=Path, help="TopicMap JSON file")
    export.add_argument("--robot", help="robot name of wbmpc.model.robot.ROBOTS giving the joint names")
    imp = sub.add_parser("import", help="read a ROS 2 bag into a run log (.npz)")
    imp.add_argument("bag", type=Path)
    imp.add_argument("log", type=Path)
    imp.add_argument("--topic-map", type=Path, help="TopicMap JSON file")
    imp.add_argument("--robot", help="robot name of wbmpc.model.robot.ROBOTS giving the joint order")
    tmap = sub.add_parser("topic-map", help="write (or print) the default topic map as JSON")
    tmap.add_argument("path", type=Path, nargs="?")
    args = parser.parse_args(argv)

    robot = None
    if getattr(args, "robot", None):
        from wbmpc.model.robot import load

        robot = load(args.robot)
    topic_map = TopicMap.from_json(args.topic_map) if getattr(args, "topic_map", None) else None
    try:
        if args.command == "export":
            out = write_bag(
                load_log(args.log), args.bag, robot=robot, storage=args.storage, topic_map=topic_map
            )
            print(f"wrote {out}")
        elif args.command == "import":
            out = save_log(read_bag(args.bag, topic_map=topic_map, robot=robot), args.log)
            print(f"wrote {out}")
        else:
            text = TopicMap().to_json(args.path)
            print(f"wrote {args.path}" if args.path else text, end="\n" if args.path else "")
    except (ValueError, FileNotFoundError, FileExistsError, ImportError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
