"""Robot models: the default Unitree B1 + Z1 arm, B1 alone, and any URDF/SRDF pair.

A :class:`Robot` bundles what the MPC needs from a robot description: the reduced Pinocchio model (locked
joints removed), foot frames in a fixed order, the arm end-effector frame, joint limits, the total mass and
named reference configurations with the feet on the ground.

Every description is checked before use: each link's mass and inertia must be ones that PyBullet (the
simulated plant) loads as written, so the plant simulates the robot the MPC models (see
:func:`load_robot`).

Foot order everywhere in wbmpc follows the Pinocchio leg order of the Unitree URDFs:
``FL, FR, RL, RR`` (front-left, front-right, rear-left, rear-right).

Example:
    >>> robot = load_b1_z1()
    >>> robot.model.nv, robot.mass  # 22 DoF, ~61 kg
"""

from __future__ import annotations

import difflib
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from importlib.metadata import PackageNotFoundError, distribution
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pinocchio as pin

from wbmpc import checks
from wbmpc.model.errors import RobotModelError, RobotModelWarning
from wbmpc.model.inertials import InertialProblem, _read, check_inertials, loadable_urdf_text, report

if TYPE_CHECKING:
    from wbmpc.model.calibration import Calibration

FOOT_NAMES = ("FL", "FR", "RL", "RR")
FRONT_FEET = np.array([True, True, False, False])  # FL, FR: the front feet, in FOOT_NAMES order
UNITREE_FOOT_FRAMES = tuple(f"{name}_foot" for name in FOOT_NAMES)
B1_Z1_LOCKED_JOINTS = ("joint5", "joint6", "jointGripper")
B1_Z1_EE_FRAME = "gripper_center"
# Extra arm poses (Z1 joint1..joint4) not in the example-robot-data SRDF; the SRDF's own poses are kept.
B1_Z1_EXTRA_ARM_POSES = {
    "standing_with_arm_forward": {"joint1": 0.0, "joint2": 2.4, "joint3": -0.6, "joint4": -1.4},
}


ROOT_JOINT = "root_joint"  # Pinocchio's name of the free-flyer joint (also used in SRDF group states)


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
        calibration: The calibration applied to the model (:mod:`wbmpc.model.calibration`), ``None``: the
            nominal description. Its joint friction is for the low level (``calibration.joint_friction``).
        inertial_problems: The URDF's link masses and inertias that only PyBullet would change (the loader
            warned about them; the PyBullet plant refuses the URDF), each with its fixes
            (:mod:`wbmpc.model.inertials`).
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
    calibration: Calibration | None = None
    inertial_problems: tuple[InertialProblem, ...] = ()

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
def load_b1_z1(
    reference_pose: str = "standing_with_arm_up", calibration: str | Path | Calibration | None = None
) -> Robot:
    """The default robot: Unitree B1 with the Z1 arm, joint5, joint6 and the gripper locked (22 DoF).

    The locked joints are held at their values in ``reference_pose``. The end effector is a frame
    ``gripper_center`` placed 5 cm ahead of the gripper hinge (the tool centre point between the jaws).
    ``calibration``: a calibration file or :class:`~wbmpc.model.calibration.Calibration` to apply (see
    :func:`load_robot`).
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
        calibration=calibration,
    )


def load_b1(reference_pose: str = "standing", calibration: str | Path | Calibration | None = None) -> Robot:
    """Unitree B1 without an arm (18 DoF); ``calibration`` as in :func:`load_robot`."""
    robots = example_robot_data_dir()
    return load_robot(
        robots / "b1_description/urdf/b1.urdf",
        robots / "b1_description/srdf/b1.srdf",
        foot_frames=UNITREE_FOOT_FRAMES,
        ee_frame=None,
        reference_pose=reference_pose,
        name="Unitree B1",
        calibration=calibration,
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
    calibration: str | Path | Calibration | None = None,
    inertia_checks: str = "warn",
) -> Robot:
    """Build a :class:`Robot` from any URDF (and optional SRDF) with a free-flyer base.

    Args:
        urdf: Path of the URDF file.
        srdf: Path of an SRDF with ``group_state`` poses; optional if ``q_reference`` is given.
        foot_frames: Foot frame names, in the order the MPC uses (FL, FR, RL, RR for a quadruped).
        ee_frame: Arm end-effector frame (may be one of ``extra_frames``), or ``None``.
        locked_joints: Joint names to remove; each is locked at its value in the reference pose.
        reference_pose: SRDF pose used for locking and as the nominal configuration. ``None`` picks, in the
            SRDF's file order, the first ``<group_state>`` that places the floating base (one with a
            ``root_joint`` entry, i.e. a pose of the whole robot), or the file's first ``<group_state>``
            if none does; ``"reference"`` if ``q_reference`` is given.
        q_reference: Full-model configuration (nq of the unreduced model) used instead of an SRDF pose.
        extra_frames: Frames to add, ``{name: (parent_frame, (x, y, z))}``, offset [m] in the parent frame.
        extra_poses: Extra poses as joint-value overrides of the reference pose ``{pose: {joint: rad}}``.
        foot_radius: Foot sphere radius [m]; read from the URDF foot collision spheres when ``None``.
        front_force_ratio: Share of the weight on the front feet in the nominal force split, in (0, 1).
        name: Display name; the URDF file stem by default.
        calibration: A calibration file (``.yaml``, ``.yml``, ``.json``) or
            :class:`~wbmpc.model.calibration.Calibration` to apply (:meth:`~wbmpc.model.calibration.
            Calibration.apply`): the base CoM moved, its front force ratio (replacing
            ``front_force_ratio``), the armature in ``model.armature``; the robot's ``calibration``
            attribute keeps it (its friction is for the low level). Read and checked before the URDF.
        inertia_checks: What to do with link masses or inertias that only PyBullet would change (below):
            ``"warn"`` (default: a :class:`~wbmpc.model.errors.RobotModelWarning`; the MPC, planning and
            the rigid plant use the model as written, the PyBullet plant refuses it), ``"error"`` (raise,
            as for a model nobody can use) or ``"ignore"``. Either way they are kept in
            ``robot.inertial_problems``.

    Returns:
        The robot, with every reference pose shifted vertically so the lowest foot contact point is at z = 0.
        ``reference_poses`` keeps the SRDF's order.

    Raises:
        RobotModelError: missing file, unknown joint/frame/pose, an inconsistent description, or link
            masses or inertias that make the model unusable (a malformed ``<inertial>``, a negative mass,
            a moving body without mass or inertia); every problem of every link is listed in one message,
            each with a fix that loads.
        FileNotFoundError: if ``calibration`` names no file.
        CalibrationError: for a calibration file with a bad field, or joints the robot does not have.

    Mass and inertia checks (:mod:`wbmpc.model.inertials`; all found in one pass, each with concrete fixes).
    PyBullet loads every URDF link as a body of its own, so the PyBullet plant only matches the MPC model if
    each link's ``<inertial>`` is used as written; these are PyBullet-only (see ``inertia_checks``):

    * every link needs an ``<inertial>`` with ``<mass value>`` and the six ``<inertia>`` attributes, all
      finite numbers, mass >= 0. Without one, Pinocchio makes the link massless but PyBullet gives it 1 kg
      and a unit inertia; a massless frame link (on a fixed joint) needs an explicit zero inertial;
    * the root link needs a positive mass of its own: PyBullet welds a root link of zero mass to the world;
    * a non-zero inertia tensor must be positive definite and satisfy the triangle inequalities of its
      principal moments (I1 + I2 >= I3 and permutations), else PyBullet replaces it with zero. A tensor
      at most :data:`wbmpc.model.inertials.NEGLIGIBLE_INERTIA_RATIO` of the rigid body it belongs to (the
      links joined by fixed or locked joints) is accepted as a negligible placeholder.

    Errors for everyone (raised whatever ``inertia_checks``): a malformed ``<inertial>`` or a negative
    mass, and

    * every rigid body that moves (the floating base, and each movable joint's links with the links fixed
      to them) needs a positive mass and a positive-definite rotational inertia, else its dynamics are
      singular.
    """
    for label, path in (("urdf", urdf), ("srdf", srdf)):
        if path is not None and not isinstance(path, str | Path):
            raise RobotModelError(f"{label} must be a file path (str or Path), got {path!r}")
    calibration = _read_calibration(calibration)
    urdf = Path(urdf)
    if not urdf.is_file():
        raise RobotModelError(f"URDF file not found: {urdf}")
    if srdf is not None and not Path(srdf).is_file():
        raise RobotModelError(f"SRDF file not found: {srdf}")
    try:
        foot_frames = checks.names("foot_frames", foot_frames, min_count=1)
        locked_joints = checks.names("locked_joints", locked_joints)
    except ValueError as exc:
        raise RobotModelError(str(exc)) from None
    for label, value in (("ee_frame", ee_frame), ("reference_pose", reference_pose), ("name", name)):
        if value is not None and not isinstance(value, str):
            raise RobotModelError(f"{label} must be a name (str) or None, got {value!r}")
    if ee_frame in foot_frames:
        raise RobotModelError(f"ee_frame {ee_frame!r} is also one of the foot_frames {list(foot_frames)}")
    try:
        checks.number(
            "front_force_ratio", front_force_ratio, low=0.0, high=1.0, low_open=True, high_open=True
        )
        if foot_radius is not None:
            checks.number("foot_radius", foot_radius, low=0.0, high=1.0, unit="m")
    except ValueError as exc:
        raise RobotModelError(str(exc)) from None
    if inertia_checks not in ("warn", "error", "ignore"):
        raise RobotModelError(f"inertia_checks must be 'warn', 'error' or 'ignore', got {inertia_checks!r}")
    urdf_root = _parse_xml(urdf)
    inertials, _ = _read(urdf_root)
    loadable = loadable_urdf_text(urdf_root)  # malformed inertials zeroed: every other problem is found too
    if loadable is None:
        full = pin.buildModelFromUrdf(str(urdf), pin.JointModelFreeFlyer())
    else:
        full = pin.buildModelFromXML(loadable, pin.JointModelFreeFlyer())
    full.name = name or urdf.stem  # the one name of the model in frame and joint errors

    for frame_name, spec in (extra_frames or {}).items():
        try:
            parent, offset = spec
            offset = checks.vector(f"extra_frames[{frame_name!r}] offset", offset, 3, unit="m")
        except (TypeError, ValueError) as exc:
            raise RobotModelError(
                f"extra_frames[{frame_name!r}] must be (parent_frame, (x, y, z)), got {spec!r}: {exc}"
            ) from None
        parent_frame = full.frames[_frame_id(full, parent)]
        placement = parent_frame.placement * pin.SE3(np.eye(3), offset)
        full.addFrame(pin.Frame(frame_name, parent_frame.parentJoint, placement, pin.FrameType.OP_FRAME))

    poses_full = _reference_poses(full, srdf, urdf)
    if q_reference is not None:
        try:
            q_reference = np.asarray(q_reference, dtype=float)
        except (TypeError, ValueError):
            raise RobotModelError(f"q_reference must be {full.nq} numbers, got {q_reference!r}") from None
        if q_reference.shape != (full.nq,):
            raise RobotModelError(f"q_reference must have shape ({full.nq},), got {q_reference.shape}")
        if not np.all(np.isfinite(q_reference)):
            raise RobotModelError(f"q_reference must be finite (no NaN or inf), got {q_reference}")
        if np.linalg.norm(q_reference[3:7]) < 1e-9:
            raise RobotModelError("q_reference[3:7] is the base quaternion (x, y, z, w) and must not be zero")
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
            try:
                value = checks.number(f"extra_poses[{pose_name!r}][{joint!r}]", value, unit="rad")
            except ValueError as exc:
                raise RobotModelError(str(exc)) from None
            q[full.joints[_joint_id(full, joint)].idx_q] = value
        poses_full[pose_name] = q
    for pose_name, q in poses_full.items():
        if not np.all(np.isfinite(q)):
            bad = [
                full.names[j] for j in range(1, full.njoints) if not np.all(np.isfinite(q[full.idx_qs[j]]))
            ]
            raise RobotModelError(f"reference pose {pose_name!r} has NaN or inf values at joints {bad}")

    q_lock = poses_full[reference_pose]
    lock_ids = [_joint_id(full, joint) for joint in locked_joints]
    if srdf is not None and reference_pose != "reference":
        _check_pose_covers_joints(full, srdf, urdf, reference_pose, locked_joints)
    locked = {jn: float(q_lock[full.idx_qs[jid]]) for jn, jid in zip(locked_joints, lock_ids, strict=True)}
    model = pin.buildReducedModel(full, lock_ids, q_lock) if lock_ids else full
    model.name = full.name
    problems = check_inertials(urdf, inertials, model, urdf_root)
    if problems and (inertia_checks == "error" or not all(p.pybullet_only for p in problems)):
        raise RobotModelError(report(urdf, problems))
    if problems and inertia_checks == "warn":
        warnings.warn(report(urdf, problems), RobotModelWarning, stacklevel=2)

    for frame in (*foot_frames, *([ee_frame] if ee_frame else [])):
        _frame_id(model, frame)
    radius = _foot_radius(urdf_root, foot_frames) if foot_radius is None else float(foot_radius)

    keep = [full.getJointId(model.names[j]) for j in range(1, model.njoints)]
    poses = {}
    for pose_name, q_full in poses_full.items():
        q = np.concatenate(
            [q_full[full.joints[j].idx_q : full.joints[j].idx_q + full.joints[j].nq] for j in keep]
        )
        poses[pose_name] = place_feet_on_ground(model, q, foot_frames, radius)

    robot = Robot(
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
        inertial_problems=tuple(problems),
    )
    return robot if calibration is None else calibration.apply(robot)


_LEG_TOKENS = {  # how descriptions name the legs, in FOOT_NAMES order (FL, FR, RL, RR)
    "FL": ("fl", "lf", "front_left", "left_front", "frontleft", "leftfront"),
    "FR": ("fr", "rf", "front_right", "right_front", "frontright", "rightfront"),
    "RL": ("rl", "lh", "hl", "bl", "lb", "rear_left", "left_rear", "back_left", "left_hind", "hind_left"),
    "RR": (
        "rr",
        "rh",
        "hr",
        "br",
        "rb",
        "rear_right",
        "right_rear",
        "back_right",
        "right_hind",
        "hind_right",
    ),
}
_FOOT_WORDS = ("foot", "toe", "feet", "tip")
_EE_NAMES = ("ee", "ee_link", "end_effector", "gripper_center", "gripper", "tool0", "tool", "hand", "tcp")


def find_contact_frames(
    urdf: str | Path, srdf: str | Path | None = None
) -> tuple[tuple[str, ...] | None, str | None]:
    """Foot frames (FL, FR, RL, RR) and the arm's end-effector frame of a description, from its SRDF's
    ``<end_effector>`` entries and the usual link names (``FL_foot``, ``LF_FOOT``, ``front_left_foot``;
    ``gripper``, ``ee_link``, ``tool0``, ``end_effector``...).

    Returns:
        The feet (``None`` unless exactly one candidate was found per leg) and the end effector (``None``
        unless exactly one candidate was found).

    Raises:
        RobotModelError: a file is not valid XML.
    """
    links = [link.get("name") for link in _parse_xml(Path(urdf)).findall("link")]
    declared = []
    if srdf is not None:
        for element in _parse_xml(Path(srdf)).findall("end_effector"):
            declared += [element.get("parent_link"), element.get("name")]
    declared = [name for name in dict.fromkeys(declared) if name in links]

    def leg_of(name: str) -> str | None:
        lower = name.lower().replace("-", "_")
        legs = [leg for leg, tokens in _LEG_TOKENS.items() if any(lower.startswith(t + "_") for t in tokens)]
        return legs[0] if len(legs) == 1 else None

    def feet_among(names) -> tuple[str, ...] | None:
        found: dict[str, list[str]] = {leg: [] for leg in _LEG_TOKENS}
        for name in names:
            leg = leg_of(name)
            if leg is not None and any(word in name.lower() for word in _FOOT_WORDS):
                found[leg].append(name)
        if all(len(names_) == 1 for names_ in found.values()):
            return tuple(found[leg][0] for leg in _LEG_TOKENS)
        return None

    feet = feet_among(declared) or feet_among(links)
    others = [name for name in declared if name not in (feet or ())]
    ee = others[0] if len(others) == 1 else None
    if ee is None:
        named = [name for name in links if name.lower() in _EE_NAMES]
        ranked = sorted(named, key=lambda name: _EE_NAMES.index(name.lower()))
        ee = ranked[0] if ranked else None
    return feet, ee


def _read_calibration(calibration) -> Calibration | None:
    """A :class:`~wbmpc.model.calibration.Calibration` from a path or an instance (``None`` passes)."""
    from wbmpc.model.calibration import Calibration

    if calibration is None or isinstance(calibration, Calibration):
        return calibration
    if not isinstance(calibration, str | Path):
        raise RobotModelError(f"calibration must be a file path or a Calibration, got {calibration!r}")
    return Calibration.load(calibration)


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
    if not isinstance(name, str):
        raise RobotModelError(f"frames are given by name (str), got {name!r}")
    if not model.existFrame(name):
        known = list(dict.fromkeys(frame.name for frame in model.frames))
        close = difflib.get_close_matches(name, known, n=3)
        hint = f" (did you mean {close}?)" if close else ""
        raise RobotModelError(f"unknown frame {name!r} in model {model.name!r}{hint}; frames: {known}")
    return model.getFrameId(name)


def _joint_id(model: pin.Model, name: str) -> int:
    if not isinstance(name, str):
        names = [model.names[i] for i in range(1, model.njoints)]
        raise RobotModelError(
            f"joints are given by name (str), got {name!r}; joints of {model.name!r}: {names}"
        )
    if not model.existJointName(name):
        names = [model.names[i] for i in range(1, model.njoints)]
        raise RobotModelError(f"unknown joint {name!r}; joints of {model.name!r}: {names}")
    return model.getJointId(name)


def _parse_xml(path: Path) -> ET.Element:
    try:
        return ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise RobotModelError(f"{path} is not valid XML: {exc}") from exc


def _reference_poses(model: pin.Model, srdf: str | Path | None, urdf: Path) -> dict[str, np.ndarray]:
    """SRDF poses in the file's order, whole-robot poses (with a ``root_joint`` entry) first.

    Pinocchio stores the poses in a map sorted by name, so the order is read from the XML.

    Raises:
        RobotModelError: the SRDF is not valid XML, or its poses name joints the URDF does not have.
    """
    if srdf is None:
        return {}
    states = _parse_xml(Path(srdf)).findall("group_state")  # before Pinocchio: it cannot name the file
    known = set(model.names)
    unknown = sorted({j.get("name") for s in states for j in s.findall("joint")} - known - {ROOT_JOINT, None})
    if unknown:
        raise RobotModelError(
            f"the SRDF's joints do not match the URDF's: {srdf} sets joints {unknown} that {urdf} does not "
            f"have (an SRDF of another robot?); URDF joints: {list(model.names)[2:]}"
        )
    pin.loadReferenceConfigurations(model, str(srdf), False)
    loaded = {item.key(): np.array(item.data(), dtype=float) for item in model.referenceConfigurations}
    whole = [s.get("name") for s in states if any(j.get("name") == ROOT_JOINT for j in s.findall("joint"))]
    order = list(dict.fromkeys([*whole, *(s.get("name") for s in states), *sorted(loaded)]))
    poses = {}
    for pose_name in order:
        if pose_name in loaded:
            q = loaded[pose_name]
            q[3:7] /= np.linalg.norm(q[3:7])
            poses[pose_name] = q
    return poses


def _check_pose_covers_joints(
    model: pin.Model, srdf: str | Path, urdf: Path, pose: str, locked_joints: Sequence[str]
) -> None:
    """Warn unless the reference pose sets every movable joint the reduced model keeps (else it is 0)."""
    states = [s for s in _parse_xml(Path(srdf)).findall("group_state") if s.get("name") == pose]
    if not states:
        return
    given = {j.get("name") for s in states for j in s.findall("joint")}
    missing = [
        model.names[j]
        for j in range(2, model.njoints)
        if model.names[j] not in given and model.names[j] not in locked_joints and model.joints[j].nq > 0
    ]
    if missing:  # a warning: the official b1-z1.srdf leaves out jointGripper (0 is a fine value there)
        warnings.warn(
            f"the SRDF's joints do not match the URDF's: pose {pose!r} of {srdf} sets no value for the "
            f"{urdf.name} joints {missing}, which are put at 0 (an SRDF of another robot?). Use the SRDF "
            "written for this URDF, add those joints to the pose, or lock them (locked_joints)",
            UserWarning,
            stacklevel=3,
        )


def _foot_radius(urdf_root: ET.Element, foot_frames: Sequence[str]) -> float:
    """Radius of the collision sphere of the foot links, 0 if they have none."""
    links = {link.get("name"): link for link in urdf_root.iter("link")}
    radii = []
    for frame in foot_frames:
        link = links.get(frame)
        sphere = link.find("collision/geometry/sphere") if link is not None else None
        radii.append(float(sphere.get("radius")) if sphere is not None else 0.0)
    return float(min(radii))


# --- mass and inertia checks -----------------------------------------------------------------------------
def heading(q: np.ndarray) -> float:
    """Yaw angle [rad] of the base (rotation about world z of its x axis)."""
    R = pin.Quaternion(q[3:7]).normalized().toRotationMatrix()
    return float(np.arctan2(R[1, 0], R[0, 0]))
