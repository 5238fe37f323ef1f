"""Forward kinematics in CasADi: joint placements, local velocities and accelerations, frames, CoM.

Mirrors ``pinocchio.forwardKinematics``, ``updateFramePlacement``, ``getFrameVelocity`` and
``centerOfMass``. Velocities and accelerations of joint ``i`` are spatial motions ``(linear, angular)``
expressed in the joint frame at its origin (Pinocchio's ``data.v[i]`` and ``data.a[i]``); with an
acceleration given, the root acceleration includes gravity as in RNEA (``data.a[0] = -gravity``).
World placements are computed lazily, only for the joints that need them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca

from wbmpc.cpin.model import JointInfo, SymbolicModel
from wbmpc.cpin.spatial import angle_axis_rotation, axis_rotation, cross, quaternion_to_rotation

LOCAL = "LOCAL"
WORLD = "WORLD"
LOCAL_WORLD_ALIGNED = "LOCAL_WORLD_ALIGNED"


@dataclass
class Motion:
    """A spatial motion (twist or its derivative): linear and angular 3-vectors."""

    linear: ca.SX
    angular: ca.SX

    def vector(self) -> ca.SX:
        return ca.vertcat(self.linear, self.angular)


@dataclass
class SymbolicData:
    """Results of :func:`forward_kinematics` (the symbolic counterpart of part of ``pinocchio.Data``).

    Attributes:
        rotations: ``liMi`` rotations, parent joint frame -> joint frame, per joint index.
        translations: ``liMi`` translations [m].
        v: Joint spatial velocities in the joint frame (``None`` if no velocity was given).
        a: Joint spatial accelerations in the joint frame, gravity included (``None`` if not given).
    """

    model: SymbolicModel
    q: ca.SX
    rotations: list = field(default_factory=list)
    translations: list = field(default_factory=list)
    v: list | None = None
    a: list | None = None
    _world: dict = field(default_factory=dict)

    def placement(self, joint: int) -> tuple[ca.SX, ca.SX]:
        """World rotation and translation ``oMi`` of a joint (memoised)."""
        if joint not in self._world:
            info = self.model.joints[joint]
            if info.parent == 0:
                self._world[joint] = (self.rotations[joint], self.translations[joint])
            else:
                R_parent, p_parent = self.placement(info.parent)
                self._world[joint] = (
                    ca.mtimes(R_parent, self.rotations[joint]),
                    p_parent + ca.mtimes(R_parent, self.translations[joint]),
                )
        return self._world[joint]

    def rotate_to_world(self, joint: int, x: ca.SX) -> ca.SX:
        """``oR_i x`` by applying the chain of local rotations to the vector (cheaper than composing them)."""
        for j in reversed(self.model.support(joint)):
            x = ca.mtimes(self.rotations[j], x)
        return x

    def rotate_to_local(self, joint: int, x: ca.SX) -> ca.SX:
        """``oR_i^T x``, applying the transposed local rotations from the root down."""
        for j in self.model.support(joint):
            x = ca.mtimes(self.rotations[j].T, x)
        return x


def joint_transform(info: JointInfo, q: ca.SX) -> tuple[ca.SX, ca.SX]:
    """Rotation and translation ``liMi`` (parent joint frame -> joint frame) at configuration ``q``."""
    if info.kind == "freeflyer":
        return quaternion_to_rotation(q[3:7]), q[0:3]
    qi = q[info.idx_q]
    R0, p0 = info.placement_rotation, info.placement_translation
    if info.kind == "revolute":
        R_joint = (
            axis_rotation(info.axis, qi)
            if info.axis is not None
            else angle_axis_rotation(info.axis_vector, qi)
        )
        R = R_joint if info.placement_is_identity_rotation else ca.mtimes(R0, R_joint)
        return R, p0
    shift = ca.SX(info.axis_vector.reshape(3, 1)) * qi
    return R0, p0 + ca.mtimes(R0, shift)


def _subspace(info: JointInfo, rate: ca.SX) -> Motion:
    """Joint motion ``S qdot`` in the joint frame for a 1-DoF joint."""
    vec = ca.SX(info.axis_vector.reshape(3, 1)) * rate
    zero = ca.SX.zeros(3, 1)
    return Motion(zero, vec) if info.kind == "revolute" else Motion(vec, zero)


def motion_act_inv(R: ca.SX, p: ca.SX, m: Motion) -> Motion:
    """``M^{-1} m`` for ``M = (R, p)``: ``(R^T (v - p x w), R^T w)``."""
    return Motion(ca.mtimes(R.T, m.linear - cross(p, m.angular)), ca.mtimes(R.T, m.angular))


def motion_cross(a: Motion, b: Motion) -> Motion:
    """Spatial motion cross product ``a x b``."""
    return Motion(cross(a.angular, b.linear) + cross(a.linear, b.angular), cross(a.angular, b.angular))


def forward_kinematics(
    model: SymbolicModel, q: ca.SX, v: ca.SX | None = None, a: ca.SX | None = None
) -> SymbolicData:
    """Joint placements, and local velocities/accelerations when ``v``/``a`` are given.

    Args:
        model: Symbolic model tables.
        q: Configuration (nq,), free-flyer ``[x, y, z, qx, qy, qz, qw]`` first.
        v: Generalised velocity (nv,), base twist in the base frame, or ``None``.
        a: Generalised acceleration (nv,), or ``None``; requires ``v``. Gravity is added at the root.
    """
    if a is not None and v is None:
        raise ValueError("forward_kinematics: an acceleration needs a velocity")
    data = SymbolicData(
        model, q, [None], [None], [None] if v is not None else None, [None] if a is not None else None
    )
    for info in model.joints[1:]:
        R, p = joint_transform(info, q)
        data.rotations.append(R)
        data.translations.append(p)
        if v is None:
            continue
        if info.kind == "freeflyer":
            vi = Motion(v[0:3], v[3:6])
            data.v.append(vi)
            if a is not None:
                # a_0 = -gravity seen from the base; the free-flyer has no bias acceleration.
                data.a.append(Motion(ca.mtimes(R.T, -model.gravity) + a[0:3], a[3:6]))
            continue
        vj = _subspace(info, v[info.idx_v])
        parent_v = data.v[info.parent]
        v_in = motion_act_inv(R, p, parent_v)
        vi = Motion(v_in.linear + vj.linear, v_in.angular + vj.angular)
        data.v.append(vi)
        if a is not None:
            aj = _subspace(info, a[info.idx_v])
            a_in = motion_act_inv(R, p, data.a[info.parent])
            bias = motion_cross(vi, vj)
            data.a.append(
                Motion(a_in.linear + aj.linear + bias.linear, a_in.angular + aj.angular + bias.angular)
            )
    return data


def frame_placement(data: SymbolicData, frame: str) -> tuple[ca.SX, ca.SX]:
    """World rotation and position [m] of a frame (``updateFramePlacement`` then ``data.oMf``)."""
    joint, R_f, p_f = data.model.frame(frame)
    R_i, p_i = data.placement(joint)
    return ca.mtimes(R_i, R_f), p_i + ca.mtimes(R_i, p_f)


def frame_velocity(data: SymbolicData, frame: str, reference: str = LOCAL_WORLD_ALIGNED) -> Motion:
    """Spatial velocity of a frame (``getFrameVelocity``) in ``LOCAL``, ``WORLD`` or ``LOCAL_WORLD_ALIGNED``.

    ``LOCAL_WORLD_ALIGNED``: linear velocity [m/s] of the frame origin and angular velocity [rad/s], both
    in world axes. Requires ``forward_kinematics`` with a velocity.
    """
    if data.v is None:
        raise ValueError("frame_velocity needs forward_kinematics(model, q, v)")
    joint, R_f, p_f = data.model.frame(frame)
    vi = data.v[joint]
    linear_at_frame = vi.linear + cross(vi.angular, p_f)
    if reference == LOCAL:
        return Motion(ca.mtimes(R_f.T, linear_at_frame), ca.mtimes(R_f.T, vi.angular))
    if reference == LOCAL_WORLD_ALIGNED:
        return Motion(data.rotate_to_world(joint, linear_at_frame), data.rotate_to_world(joint, vi.angular))
    if reference == WORLD:
        R_i, p_i = data.placement(joint)
        angular = ca.mtimes(R_i, vi.angular)
        return Motion(ca.mtimes(R_i, vi.linear) + cross(p_i, angular), angular)
    raise ValueError(f"unknown reference frame {reference!r}; use LOCAL, WORLD or LOCAL_WORLD_ALIGNED")


def center_of_mass(data: SymbolicData) -> ca.SX:
    """Centre of mass [m] in the world frame (``pinocchio.centerOfMass``)."""
    model = data.model
    weighted = ca.SX.zeros(3, 1)
    for info in model.joints[1:]:
        if info.mass == 0.0:
            continue
        R_i, p_i = data.placement(info.index)
        weighted += info.mass * (p_i + ca.mtimes(R_i, info.lever))
    return weighted / model.total_mass
