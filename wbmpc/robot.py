"""Robot models: the default Unitree B1 + Z1 arm, B1 alone, and any URDF/SRDF pair.

A :class:`Robot` bundles what the MPC needs from a robot description: the reduced Pinocchio model (locked
joints removed), foot frames in a fixed order, the arm end-effector frame, joint limits, the total mass and
named reference configurations with the feet on the ground.

Foot order everywhere in wbmpc follows the Pinocchio leg order of the Unitree URDFs:
``FL, FR, RL, RR`` (front-left, front-right, rear-left, rear-right).

Example:
    >>> robot = load_b1_z1()
    >>> robot.model.nv, robot.mass  # 22 DoF, ~61 kg
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from importlib.metadata import PackageNotFoundError, distribution
from pathlib import Path

import numpy as np
import pinocchio as pin

FOOT_NAMES = ("FL", "FR", "RL", "RR")
UNITREE_FOOT_FRAMES = tuple(f"{name}_foot" for name in FOOT_NAMES)
B1_Z1_LOCKED_JOINTS = ("joint5", "joint6", "jointGripper")
B1_Z1_EE_FRAME = "gripper_center"
# Extra arm poses (Z1 joint1..joint4) not in the example-robot-data SRDF; the SRDF's own poses are kept.
B1_Z1_EXTRA_ARM_POSES = {
    "standing_with_arm_forward": {"joint1": 0.0, "joint2": 2.4, "joint3": -0.6, "joint4": -1.4},
}


class RobotModelError(ValueError):
    """Raised for a robot description that cannot be used (missing file, unknown joint, frame or pose)."""


def example_robot_data_dir() -> Path:
    """Return the ``robots`` folder of the example-robot-data wheel.

    Raises:
        RobotModelError: if the ``example-robot-data`` distribution is not installed.
    """
    try:
        dist = distribution("example-robot-data")
    except PackageNotFoundError as exc:
        raise RobotModelError("the 'example-robot-data' package is not installed (pip install it)") from exc
    return Path(dist.locate_file("cmeel.prefix/share/example-robot-data/robots"))


@dataclass
class Robot:
    """A floating-base legged robot (optionally with an arm) ready for the MPC.

    Attributes:
        name: Human-readable name.
        model: Reduced Pinocchio model, free-flyer root, locked joints removed.
        urdf_path: Path of the URDF the model was built from.
        foot_frames: Foot frame names in wbmpc foot order (FL, FR, RL, RR for quadrupeds).
        ee_frame: Arm end-effector frame name, or ``None`` for a robot without an arm.
        reference_poses: Named configurations (nq,), feet on the ground (contact points at z = 0).
        default_pose: Name of the nominal standing configuration.
        locked_joints: Joint names removed from the model, with the angle [rad] each is locked at.
        foot_radius: Radius [m] of the foot collision spheres; foot frames sit this far above the ground.
        front_force_ratio: Share of the weight carried by the front feet in the nominal force split.
    """

    name: str
    model: pin.Model
    urdf_path: Path
    foot_frames: tuple[str, ...]
    ee_frame: str | None
    reference_poses: dict[str, np.ndarray]
    default_pose: str
    locked_joints: dict[str, float] = field(default_factory=dict)
    foot_radius: float = 0.0
    front_force_ratio: float = 0.5

    # --- sizes -------------------------------------------------------------------------------------------
    @property
    def nq(self) -> int:
        """Configuration size (7 for the free-flyer base + one per revolute joint)."""
        return self.model.nq

    @property
    def nv(self) -> int:
        """Velocity size (6 for the base + one per joint)."""
        return self.model.nv

    @property
    def nj(self) -> int:
        """Number of actuated joints."""
        return self.model.nv - 6

    @property
    def n_feet(self) -> int:
        return len(self.foot_frames)

    @property
    def contact_frames(self) -> tuple[str, ...]:
        """Frames that carry a 3-D force in the MPC: the feet, then the arm end effector if any."""
        return self.foot_frames + ((self.ee_frame,) if self.ee_frame else ())

    @property
    def has_arm(self) -> bool:
        return self.ee_frame is not None

    @property
    def joint_names(self) -> list[str]:
        """Actuated joint names in the order of ``q[7:]`` and ``v[6:]``."""
        return [self.model.names[i] for i in range(2, self.model.njoints)]

    @property
    def arm_joint_names(self) -> list[str]:
        """Actuated joints that do not belong to a leg (the arm), in model order."""
        if not self.has_arm:
            return []
        legs = set()
        for frame in self.foot_frames:
            joint = self.model.frames[self.model.getFrameId(frame)].parentJoint
            while joint > 1:
                legs.add(self.model.names[joint])
                joint = self.model.parents[joint]
        return [name for name in self.joint_names if name not in legs]

    # --- physical data ---------------------------------------------------------------------------------
    @property
    def mass(self) -> float:
        """Total mass [kg] (locked joints keep their bodies' mass)."""
        return float(sum(inertia.mass for inertia in self.model.inertias))

    @property
    def gravity(self) -> float:
        """Gravity magnitude [m/s^2] of the model (Pinocchio: 9.81)."""
        return float(np.linalg.norm(self.model.gravity.linear))

    @property
    def q_nominal(self) -> np.ndarray:
        """Nominal standing configuration (nq,), a copy of ``reference_poses[default_pose]``."""
        return self.reference_poses[self.default_pose].copy()

    @property
    def joint_position_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper joint position limits [rad], each (nj,)."""
        return self.model.lowerPositionLimit[7:].copy(), self.model.upperPositionLimit[7:].copy()

    @property
    def joint_velocity_limits(self) -> np.ndarray:
        """Symmetric joint velocity limits [rad/s], (nj,)."""
        return self.model.velocityLimit[6:].copy()

    @property
    def joint_torque_limits(self) -> np.ndarray:
        """Symmetric joint torque limits [N m], (nj,)."""
        return self.model.effortLimit[6:].copy()

    def pose(self, name: str) -> np.ndarray:
        """Return a copy of the named reference configuration.

        Raises:
            RobotModelError: if no pose has that name.
        """
        if name not in self.reference_poses:
            raise RobotModelError(f"unknown pose {name!r}; known poses: {sorted(self.reference_poses)}")
        return self.reference_poses[name].copy()

    def frame_id(self, name: str) -> int:
        """Return the id of a frame, with a clear error for an unknown name."""
        return _frame_id(self.model, name)

    def joint_index_v(self, name: str) -> int:
        """Index in ``v`` of an actuated joint."""
        if not self.model.existJointName(name):
            raise RobotModelError(f"unknown joint {name!r}; actuated joints: {self.joint_names}")
        return self.model.joints[self.model.getJointId(name)].idx_v

    def summary(self) -> str:
        """One-paragraph description: sizes, mass, frames, locked joints."""
        locked = ", ".join(f"{k}={v:.3f}" for k, v in self.locked_joints.items()) or "none"
        return (
            f"{self.name}: nq={self.nq}, nv={self.nv} ({self.nj} joints), mass={self.mass:.2f} kg, "
            f"feet={list(self.foot_frames)}, end effector={self.ee_frame}, locked: {locked}"
        )


# --- loaders ---------------------------------------------------------------------------------------------
def load_b1_z1(reference_pose: str = "standing_with_arm_up") -> Robot:
    """The default robot: Unitree B1 with the Z1 arm, joint5, joint6 and the gripper locked (22 DoF).

    The locked joints are held at their values in ``reference_pose``. The end effector is a frame
    ``gripper_center`` placed 5 cm ahead of the gripper hinge (the tool centre point between the jaws).
    """
    robots = example_robot_data_dir()
    return load_robot(
        robots / "b1_description/urdf/b1-z1.urdf",
        robots / "b1_description/srdf/b1-z1.srdf",
        foot_frames=UNITREE_FOOT_FRAMES,
        ee_frame=B1_Z1_EE_FRAME,
        locked_joints=B1_Z1_LOCKED_JOINTS,
        reference_pose=reference_pose,
        extra_frames={B1_Z1_EE_FRAME: ("gripperMover", (0.05, 0.0, 0.0))},
        extra_poses=B1_Z1_EXTRA_ARM_POSES,
        name="Unitree B1 + Z1",
    )


def load_b1(reference_pose: str = "standing") -> Robot:
    """Unitree B1 without an arm (18 DoF)."""
    robots = example_robot_data_dir()
    return load_robot(
        robots / "b1_description/urdf/b1.urdf",
        robots / "b1_description/srdf/b1.srdf",
        foot_frames=UNITREE_FOOT_FRAMES,
        ee_frame=None,
        reference_pose=reference_pose,
        name="Unitree B1",
    )


ROBOTS = {"b1_z1": load_b1_z1, "b1": load_b1}


def load(name: str = "b1_z1", **kwargs) -> Robot:
    """Load a built-in robot by name (``b1_z1`` or ``b1``)."""
    if name not in ROBOTS:
        raise RobotModelError(f"unknown robot {name!r}; built-in robots: {sorted(ROBOTS)}")
    return ROBOTS[name](**kwargs)


def load_robot(
    urdf: str | Path,
    srdf: str | Path | None = None,
    *,
    foot_frames: Sequence[str],
    ee_frame: str | None = None,
    locked_joints: Sequence[str] = (),
    reference_pose: str | None = None,
    q_reference: np.ndarray | None = None,
    extra_frames: Mapping[str, tuple[str, Sequence[float]]] | None = None,
    extra_poses: Mapping[str, Mapping[str, float]] | None = None,
    foot_radius: float | None = None,
    front_force_ratio: float = 0.5,
    name: str | None = None,
) -> Robot:
    """Build a :class:`Robot` from any URDF (and optional SRDF) with a free-flyer base.

    Args:
        urdf: Path of the URDF file.
        srdf: Path of an SRDF with ``group_state`` poses; optional if ``q_reference`` is given.
        foot_frames: Foot frame names, in the order the MPC uses (FL, FR, RL, RR for a quadruped).
        ee_frame: Arm end-effector frame (may be one of ``extra_frames``), or ``None``.
        locked_joints: Joint names to remove; each is locked at its value in the reference pose.
        reference_pose: SRDF pose used for locking and as the nominal configuration.
        q_reference: Full-model configuration (nq of the unreduced model) used instead of an SRDF pose.
        extra_frames: Frames to add, ``{name: (parent_frame, (x, y, z))}``, offset [m] in the parent frame.
        extra_poses: Extra poses as joint-value overrides of the reference pose ``{pose: {joint: rad}}``.
        foot_radius: Foot sphere radius [m]; read from the URDF foot collision spheres when ``None``.
        front_force_ratio: Share of the weight on the front feet in the nominal force split, in (0, 1).
        name: Display name; the URDF file stem by default.

    Returns:
        The robot, with every reference pose shifted vertically so the lowest foot contact point is at z = 0.

    Raises:
        RobotModelError: missing file, unknown joint/frame/pose, or an inconsistent description.
    """
    urdf = Path(urdf)
    if not urdf.is_file():
        raise RobotModelError(f"URDF file not found: {urdf}")
    if srdf is not None and not Path(srdf).is_file():
        raise RobotModelError(f"SRDF file not found: {srdf}")
    if not foot_frames:
        raise RobotModelError("foot_frames must name at least one foot frame")
    if not 0.0 < front_force_ratio < 1.0:
        raise RobotModelError(f"front_force_ratio must be in (0, 1), got {front_force_ratio}")
    full = pin.buildModelFromUrdf(str(urdf), pin.JointModelFreeFlyer())

    for frame_name, (parent, offset) in (extra_frames or {}).items():
        parent_frame = full.frames[_frame_id(full, parent)]
        placement = parent_frame.placement * pin.SE3(np.eye(3), np.asarray(offset, dtype=float))
        full.addFrame(pin.Frame(frame_name, parent_frame.parentJoint, placement, pin.FrameType.OP_FRAME))

    poses_full = _reference_poses(full, srdf)
    if q_reference is not None:
        q_reference = np.asarray(q_reference, dtype=float)
        if q_reference.shape != (full.nq,):
            raise RobotModelError(f"q_reference must have shape ({full.nq},), got {q_reference.shape}")
        poses_full["reference"] = q_reference
        reference_pose = reference_pose or "reference"
    if not poses_full:
        raise RobotModelError("no reference pose: give an SRDF with group_state poses or q_reference")
    reference_pose = reference_pose or next(iter(poses_full))
    if reference_pose not in poses_full:
        raise RobotModelError(
            f"SRDF pose {reference_pose!r} not found; available poses: {sorted(poses_full)}"
        )
    for pose_name, overrides in (extra_poses or {}).items():
        q = poses_full[reference_pose].copy()
        for joint, value in overrides.items():
            q[full.joints[_joint_id(full, joint)].idx_q] = value
        poses_full[pose_name] = q

    q_lock = poses_full[reference_pose]
    lock_ids = [_joint_id(full, joint) for joint in locked_joints]
    locked = {jn: float(q_lock[full.idx_qs[jid]]) for jn, jid in zip(locked_joints, lock_ids, strict=True)}
    model = pin.buildReducedModel(full, lock_ids, q_lock) if lock_ids else full
    model.name = name or urdf.stem

    for frame in (*foot_frames, *([ee_frame] if ee_frame else [])):
        _frame_id(model, frame)
    radius = _foot_radius(urdf, model, foot_frames) if foot_radius is None else float(foot_radius)

    keep = [full.getJointId(model.names[j]) for j in range(1, model.njoints)]
    poses = {}
    for pose_name, q_full in poses_full.items():
        q = np.concatenate(
            [q_full[full.joints[j].idx_q : full.joints[j].idx_q + full.joints[j].nq] for j in keep]
        )
        poses[pose_name] = place_feet_on_ground(model, q, foot_frames, radius)

    return Robot(
        name=name or urdf.stem,
        model=model,
        urdf_path=urdf,
        foot_frames=tuple(foot_frames),
        ee_frame=ee_frame,
        reference_poses=poses,
        default_pose=reference_pose,
        locked_joints=locked,
        foot_radius=radius,
        front_force_ratio=front_force_ratio,
    )


def place_feet_on_ground(
    model: pin.Model, q: np.ndarray, foot_frames: Sequence[str], foot_radius: float = 0.0
) -> np.ndarray:
    """Shift the base vertically so the lowest foot contact point (frame z - radius) is at z = 0."""
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    lowest = min(data.oMf[_frame_id(model, f)].translation[2] for f in foot_frames)
    q = q.copy()
    q[2] -= lowest - foot_radius
    return q


# --- helpers ---------------------------------------------------------------------------------------------
def _frame_id(model: pin.Model, name: str) -> int:
    if not model.existFrame(name):
        raise RobotModelError(f"unknown frame {name!r} in model {model.name!r}")
    return model.getFrameId(name)


def _joint_id(model: pin.Model, name: str) -> int:
    if not model.existJointName(name):
        names = [model.names[i] for i in range(1, model.njoints)]
        raise RobotModelError(f"unknown joint {name!r}; joints of {model.name!r}: {names}")
    return model.getJointId(name)


def _reference_poses(model: pin.Model, srdf: str | Path | None) -> dict[str, np.ndarray]:
    if srdf is None:
        return {}
    pin.loadReferenceConfigurations(model, str(srdf), False)
    poses = {}
    for item in model.referenceConfigurations:
        q = np.array(item.data(), dtype=float)
        q[3:7] /= np.linalg.norm(q[3:7])
        poses[item.key()] = q
    return poses


def _foot_radius(urdf: Path, model: pin.Model, foot_frames: Sequence[str]) -> float:
    """Radius of the collision sphere of the foot links, 0 if they have none."""
    import xml.etree.ElementTree as ET

    links = {link.get("name"): link for link in ET.parse(urdf).getroot().iter("link")}
    radii = []
    for frame in foot_frames:
        link = links.get(frame)
        sphere = link.find("collision/geometry/sphere") if link is not None else None
        radii.append(float(sphere.get("radius")) if sphere is not None else 0.0)
    return float(min(radii))
