"""ROS 2 message types of the bags: the standard ones used and wbmpc's own (``wbmpc_msgs``), the
``rosbags`` type store that knows them, and the conversions between message fields and arrays."""

from __future__ import annotations

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


def _quat(q) -> list[float]:
    return [q.x, q.y, q.z, q.w]


def _vec(v) -> list[float]:
    return [v.x, v.y, v.z]
