"""The robot's visual geometry for the viewer.

:func:`visual_model` rebuilds the robot's visual geometry with the same locked joints as
:attr:`wbmpc.model.robot.Robot.model` (meshes resolved as the PyBullet plant resolves them; primitive shapes
if they cannot be loaded).
"""

from __future__ import annotations

import warnings
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from functools import lru_cache

import numpy as np
import pinocchio as pin

from wbmpc.model.robot import Robot, RobotModelError
from wbmpc.model.urdf import default_package_dirs, resolve_mesh_path


def visual_model(robot: Robot) -> tuple[pin.Model, pin.GeometryModel]:
    """The robot's visual geometry on a kinematic model with the same locked joints as ``robot.model``.

    The full model and its visual geometry are read from ``robot.urdf_path`` (mesh references resolve as
    in :func:`resolve_mesh_path`, the rule the PyBullet plant uses too), then reduced with the locked joints
    at their ``robot.locked_joints`` angles. Frames that ``robot.model`` has but the
    URDF does not (the end-effector tool point) are copied over. If the meshes cannot be loaded, each mesh
    is replaced by the link's primitive collision shapes and a warning is issued: the viewer still works.

    Args:
        robot: The robot.

    Returns:
        The reduced model (same joints, configuration layout and frame placements as ``robot.model``) and its
        visual geometry model.

    Raises:
        RobotModelError: if the reduced model does not match ``robot.model`` (nq or joint names).
    """
    full, geom = _full_visual_model(str(robot.urdf_path), default_package_dirs())
    lock_ids = [full.getJointId(name) for name in robot.locked_joints]
    if lock_ids:
        q_ref = pin.neutral(full)
        for name, angle in robot.locked_joints.items():
            joint = full.joints[full.getJointId(name)]
            if joint.nq == 1:
                q_ref[joint.idx_q] = angle
            elif joint.nq == 2:  # continuous joint: (cos, sin)
                q_ref[joint.idx_q : joint.idx_q + 2] = np.cos(angle), np.sin(angle)
        model, geoms = pin.buildReducedModel(full, [geom], lock_ids, q_ref)
        geom = geoms[0]
    else:
        model, geom = full.copy(), geom.copy()
    if model.nq != robot.model.nq or list(model.names) != list(robot.model.names):
        raise RobotModelError(
            f"visual model does not match robot.model: nq {model.nq} vs {robot.model.nq}, "
            f"joints {list(model.names)} vs {list(robot.model.names)}"
        )
    for frame in robot.model.frames:
        if model.existFrame(frame.name):
            continue
        parent_frame = robot.model.frames[frame.parentFrame].name
        model.addFrame(
            pin.Frame(
                frame.name,
                frame.parentJoint,  # same joint order (checked above)
                model.getFrameId(parent_frame) if model.existFrame(parent_frame) else 0,
                frame.placement,
                frame.type,
            )
        )
    model.name = robot.model.name
    return model, geom


def _urdf_with_resolved_meshes(urdf: str, package_dirs: Sequence[str]) -> str:
    """URDF text with every mesh ``filename`` made absolute by :func:`resolve_mesh_path`."""
    root = ET.parse(urdf).getroot()
    for mesh in root.iter("mesh"):
        mesh.set("filename", resolve_mesh_path(mesh.get("filename", ""), urdf, package_dirs))
    return ET.tostring(root, encoding="unicode")


@lru_cache(maxsize=4)
def _full_visual_model(urdf: str, package_dirs: tuple[str, ...]) -> tuple[pin.Model, pin.GeometryModel]:
    """Full model and visual geometry of a URDF (cached: loading the B1 + Z1 meshes takes seconds)."""
    full = pin.buildModelFromUrdf(urdf, pin.JointModelFreeFlyer())
    try:
        loader = _mesh_loader()
        kwargs = {"package_dirs": list(package_dirs)} | ({"mesh_loader": loader} if loader else {})
        text = _urdf_with_resolved_meshes(urdf, package_dirs)
        geom = pin.buildGeomFromUrdfString(full, text, pin.GeometryType.VISUAL, **kwargs)
    except (ValueError, RuntimeError, OSError) as exc:
        warnings.warn(
            f"could not load the visual meshes of {urdf} ({exc}); showing primitive shapes instead",
            stacklevel=3,
        )
        geom = pin.buildGeomFromUrdfString(full, _urdf_without_meshes(urdf), pin.GeometryType.VISUAL)
    return full, geom


def _mesh_loader():
    """A caching mesh loader with cheap (OBB) bounding volumes, or ``None`` for Pinocchio's default."""
    try:
        import coal

        return coal.CachedMeshLoader(coal.NODE_TYPE.BV_OBB)
    except (ImportError, AttributeError, TypeError):
        return None


def _urdf_without_meshes(urdf: str) -> str:
    """URDF text where every mesh visual is replaced by the link's primitive collision shapes."""
    root = ET.parse(urdf).getroot()
    for link in root.iter("link"):
        elements = link.findall("visual") + link.findall("collision")
        meshes = [e for e in elements if e.find("geometry/mesh") is not None]
        for element in meshes:
            link.remove(element)
        if any(e.tag == "visual" for e in meshes):
            for collision in link.findall("collision"):
                stand_in = ET.fromstring(ET.tostring(collision))
                stand_in.tag = "visual"
                link.append(stand_in)
    return ET.tostring(root, encoding="unicode")
