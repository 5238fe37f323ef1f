"""Where each column of a run log lives in a bag: :class:`TopicMap` (editable, JSON), and the errors of
reading a bag that does not match it."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

from wbmpc import checks


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
