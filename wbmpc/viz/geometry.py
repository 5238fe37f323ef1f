"""The robot's visual geometry for the viewer.

:func:`visual_model` rebuilds the robot's visual geometry with the same locked joints as
:attr:`wbmpc.model.robot.Robot.model` (meshes resolved as the PyBullet plant resolves them; primitive shapes
if they cannot be loaded).
"""

from __future__ import annotations

import copy
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from functools import lru_cache
from pathlib import Path

import numpy as np
import pinocchio as pin

from wbmpc.model.robot import Robot, RobotModelError
from wbmpc.model.urdf import default_package_dirs, resolve_mesh_path


def visual_model(robot: Robot) -> tuple[pin.Model, pin.GeometryModel]:
    """The robot's visual geometry on a kinematic model with the same locked joints as ``robot.model``.

    The full model and its visual geometry are read from ``robot.urdf_path`` (mesh references resolve as
    in :func:`resolve_mesh_path`, the rule the PyBullet plant uses too), then reduced with the locked joints
    at their ``robot.locked_joints`` angles. Frames that ``robot.model`` has but the
    URDF does not (the end-effector tool point) are copied over. A visual mesh whose file is missing is
    replaced by primitive shapes (the link's collision shapes, else sticks to its child joints, else a
    small sphere), mesh by mesh: every link keeps a visual, the others keep their meshes, and one warning
    names every missing file.

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


_STAND_IN_RADIUS = 0.015  # [m] of the sticks and spheres that stand in for a link without a primitive shape


def _urdf_with_stand_ins(
    urdf: str, package_dirs: Sequence[str], every_mesh: bool = False
) -> tuple[str, list[str]]:
    """URDF text with every mesh ``filename`` made absolute by :func:`resolve_mesh_path`, each visual mesh
    whose file is missing (every visual mesh with ``every_mesh``) replaced by primitive shapes, and the
    mesh references replaced (in file order, once each).

    A replaced visual shows the link's primitive collision shapes (boxes, cylinders, spheres) if it has
    any, else a stick from the link's origin to each child joint, else a small sphere: every link that had
    a visual keeps one.
    """
    root = ET.parse(urdf).getroot()
    children: dict[str, list[np.ndarray]] = {}
    for joint in root.iter("joint"):
        parent, origin = joint.find("parent"), joint.find("origin")
        xyz = np.zeros(3) if origin is None else np.array(origin.get("xyz", "0 0 0").split(), dtype=float)
        if parent is not None:
            children.setdefault(parent.get("link"), []).append(xyz)
    missing = []
    for link in root.iter("link"):
        replaced = False
        for visual in link.findall("visual"):
            mesh = visual.find("geometry/mesh")
            if mesh is None:
                continue
            filename = mesh.get("filename", "")
            resolved = resolve_mesh_path(filename, urdf, package_dirs)
            if every_mesh or not Path(resolved).is_file():
                missing.append(filename)
                link.remove(visual)
                if not replaced:
                    for stand_in in _stand_ins(link, visual, children.get(link.get("name"), [])):
                        link.append(stand_in)
                    replaced = True
            else:
                mesh.set("filename", resolved)
        for collision in link.findall("collision"):
            mesh = collision.find("geometry/mesh")
            if mesh is not None:  # the visual model has no use for collisions: a missing file must not fail
                link.remove(collision)
    return ET.tostring(root, encoding="unicode"), list(dict.fromkeys(missing))


def _stand_ins(link: ET.Element, visual: ET.Element, child_origins: Sequence[np.ndarray]) -> list[ET.Element]:
    """Visual elements of primitive shapes for ``link`` (see :func:`_urdf_with_stand_ins`)."""
    shapes = []
    for collision in link.findall("collision"):
        geometry = collision.find("geometry")
        if geometry is not None and any(
            geometry.find(tag) is not None for tag in ("box", "cylinder", "sphere")
        ):
            stand_in = copy.deepcopy(collision)
            stand_in.tag = "visual"
            stand_in.attrib.pop("name", None)
            shapes.append(stand_in)
    if shapes:
        return shapes
    for offset in child_origins:
        length = float(np.linalg.norm(offset))
        if length < 1e-3:
            continue
        rotation = pin.Quaternion.FromTwoVectors(
            np.array([0.0, 0.0, 1.0]), offset / length
        ).toRotationMatrix()
        rpy = " ".join(f"{x:.9g}" for x in pin.rpy.matrixToRpy(rotation))
        xyz = " ".join(f"{x:.9g}" for x in offset / 2)
        shapes.append(
            ET.fromstring(
                f'<visual><origin xyz="{xyz}" rpy="{rpy}"/><geometry><cylinder radius="{_STAND_IN_RADIUS}" '
                f'length="{length:.9g}"/></geometry></visual>'
            )
        )
    if shapes:
        return shapes
    origin = visual.find("origin")
    sphere = ET.fromstring(
        f'<visual><geometry><sphere radius="{_STAND_IN_RADIUS * 1.5}"/></geometry></visual>'
    )
    if origin is not None:
        sphere.insert(0, copy.deepcopy(origin))
    return [sphere]


@lru_cache(maxsize=4)
def _full_visual_model(urdf: str, package_dirs: tuple[str, ...]) -> tuple[pin.Model, pin.GeometryModel]:
    """Full model and visual geometry of a URDF (cached: loading the B1 + Z1 meshes takes seconds).

    A visual mesh whose file is missing is replaced by primitive shapes, mesh by mesh, and every missing
    file is named in one warning; if a mesh on disk cannot be read, every mesh is replaced.
    """
    full = pin.buildModelFromUrdf(urdf, pin.JointModelFreeFlyer())
    loader = _mesh_loader()
    kwargs = {"package_dirs": list(package_dirs)} | ({"mesh_loader": loader} if loader else {})
    text, missing = _urdf_with_stand_ins(urdf, package_dirs)
    if missing:
        warnings.warn(
            f"{urdf}: {len(missing)} visual mesh file{'s' if len(missing) > 1 else ''} not found, shown as "
            f"primitive shapes (the link's collision shapes, or sticks to its child joints): "
            f"{', '.join(missing)}",
            stacklevel=3,
        )
    try:
        geom = pin.buildGeomFromUrdfString(full, text, pin.GeometryType.VISUAL, **kwargs)
    except (ValueError, RuntimeError, OSError) as exc:
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        warnings.warn(
            f"could not load the visual meshes of {urdf} ({reason}); showing primitive shapes instead",
            stacklevel=3,
        )
        text, _ = _urdf_with_stand_ins(urdf, package_dirs, every_mesh=True)
        geom = pin.buildGeomFromUrdfString(full, text, pin.GeometryType.VISUAL)
    return full, geom


def _mesh_loader():
    """A caching mesh loader with cheap (OBB) bounding volumes, or ``None`` for Pinocchio's default."""
    try:
        import coal

        return coal.CachedMeshLoader(coal.NODE_TYPE.BV_OBB)
    except (ImportError, AttributeError, TypeError):
        return None
