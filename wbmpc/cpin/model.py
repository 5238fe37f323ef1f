"""A numeric :class:`pinocchio.Model` turned into constant tables for the symbolic algorithms.

Supported joints: a free-flyer root (``JointModelFreeFlyer``, joint 1) and 1-DoF revolute or prismatic
joints, axis-aligned (``RX``, ``RY``, ``RZ``, ``PX``, ...) or not (``RevoluteUnaligned``, ...). That covers
the URDF legged robots this project targets; anything else raises a clear error.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np
import pinocchio as pin

from wbmpc.cpin.spatial import clean_constant

_ALIGNED = {
    "JointModelRX": ("revolute", 0),
    "JointModelRY": ("revolute", 1),
    "JointModelRZ": ("revolute", 2),
    "JointModelPX": ("prismatic", 0),
    "JointModelPY": ("prismatic", 1),
    "JointModelPZ": ("prismatic", 2),
}
_UNALIGNED = {"JointModelRevoluteUnaligned": "revolute", "JointModelPrismaticUnaligned": "prismatic"}


@dataclass(frozen=True)
class JointInfo:
    """Constant description of one joint of the kinematic tree (Pinocchio joint index ``index``)."""

    index: int
    name: str
    parent: int
    kind: str  # "freeflyer", "revolute" or "prismatic"
    axis: int | None  # 0, 1, 2 for axis-aligned joints, None otherwise
    axis_vector: np.ndarray  # unit axis in the joint frame
    idx_q: int
    idx_v: int
    placement_rotation: ca.SX  # parent joint frame -> this joint frame at q = 0 (cleaned constants)
    placement_translation: ca.SX
    placement_is_identity_rotation: bool
    mass: float
    lever: ca.SX  # centre of mass in the joint frame [m]
    rotational_inertia: ca.SX  # inertia about the centre of mass, joint axes [kg m^2]


class SymbolicModel:
    """Constant tables of a Pinocchio model for the CasADi mirror of its algorithms.

    Args:
        model: Numeric Pinocchio model with a free-flyer root joint.

    Attributes:
        armature: ``model.armature`` (nv,) [kg m^2 or kg]: the rotor inertia each degree of freedom adds to
            the diagonal of the joint-space inertia matrix, as Pinocchio's RNEA, CRBA and ABA add it.

    Raises:
        ValueError: if the root is not a free flyer, another joint is attached to the world or a joint
            type is not supported.
    """

    def __init__(self, model: pin.Model):
        self.model = model
        self.nq, self.nv = model.nq, model.nv
        self.gravity = clean_constant(model.gravity.linear.reshape(3, 1))
        self.armature = np.array(model.armature, dtype=float).ravel()
        self.joints: list[JointInfo | None] = [None]
        for j in range(1, model.njoints):
            self.joints.append(self._joint_info(model, j))
        if model.njoints < 2 or self.joints[1].kind != "freeflyer":
            raise ValueError("the symbolic model needs a free-flyer root joint (joint 1)")
        for info in self.joints[2:]:
            if info.parent == 0:  # a second tree: the algorithms start every branch at the free flyer
                raise ValueError(
                    f"joint {info.name!r} is attached to the world: the symbolic model needs a single tree "
                    "under the free-flyer root"
                )
        self.total_mass = float(sum(inertia.mass for inertia in model.inertias))

    @staticmethod
    def _joint_info(model: pin.Model, j: int) -> JointInfo:
        joint = model.joints[j]
        short = joint.shortname()
        placement = model.jointPlacements[j]
        if short == "JointModelFreeFlyer":
            if j != 1 or model.parents[j] != 0:
                raise ValueError(f"free-flyer joint {model.names[j]!r} must be the root joint")
            if not np.allclose(placement.homogeneous, np.eye(4), atol=1e-12):
                # The symbolic algorithms take the base pose from q directly, as URDF free flyers have it.
                raise ValueError(f"free-flyer joint {model.names[j]!r} must have an identity joint placement")
            kind, axis, axis_vector = "freeflyer", None, np.zeros(3)
        elif short in _ALIGNED:
            kind, axis = _ALIGNED[short]
            axis_vector = np.eye(3)[axis]
        elif short in _UNALIGNED:
            kind, axis = _UNALIGNED[short], None
            axis_vector = np.array(joint.extract().axis, dtype=float).ravel()
            axis_vector /= np.linalg.norm(axis_vector)
        else:
            raise ValueError(
                f"joint {model.names[j]!r} has type {short}, which the symbolic model does not support "
                "(free flyer, revolute and prismatic joints only)"
            )
        inertia = model.inertias[j]
        rotation = np.array(placement.rotation)
        return JointInfo(
            index=j,
            name=model.names[j],
            parent=model.parents[j],
            kind=kind,
            axis=axis,
            axis_vector=axis_vector,
            idx_q=joint.idx_q,
            idx_v=joint.idx_v,
            placement_rotation=clean_constant(rotation),
            placement_translation=clean_constant(np.array(placement.translation).reshape(3, 1)),
            placement_is_identity_rotation=bool(np.allclose(rotation, np.eye(3), atol=1e-12)),
            mass=float(inertia.mass),
            lever=clean_constant(np.array(inertia.lever).reshape(3, 1)),
            rotational_inertia=clean_constant(np.array(inertia.inertia)),
        )

    def frame(self, name: str) -> tuple[int, ca.SX, ca.SX]:
        """Parent joint, rotation and translation (constants) of a frame in its parent joint frame.

        Raises:
            ValueError: if the model has no frame of that name.
        """
        if not self.model.existFrame(name):
            raise ValueError(f"unknown frame {name!r} in model {self.model.name!r}")
        frame = self.model.frames[self.model.getFrameId(name)]
        return (
            frame.parentJoint,
            clean_constant(np.array(frame.placement.rotation)),
            clean_constant(np.array(frame.placement.translation).reshape(3, 1)),
        )

    def support(self, joint: int) -> list[int]:
        """Joint indices from the root (joint 1) down to ``joint``, inclusive."""
        path = []
        while joint > 0:
            path.append(joint)
            joint = self.joints[joint].parent
        return path[::-1]
