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

from wbmpc.io.rosbag.cli import main
from wbmpc.io.rosbag.messages import BAG_FORMAT_VERSION, WBMPC_MSGS, make_typestore
from wbmpc.io.rosbag.reader import read_bag
from wbmpc.io.rosbag.topic_map import JointNameError, MissingTopicError, RosbagError, TimeGapError, TopicMap
from wbmpc.io.rosbag.writer import write_bag

__all__ = [
    "main",
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
