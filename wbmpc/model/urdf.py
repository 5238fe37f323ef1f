"""URDF handling shared by the plants and the viewer: where a mesh reference points, the URDF PyBullet loads
(locked joints made fixed, absolute mesh paths, no visuals), a base CoM moved in the URDF text.

What :func:`preprocess_urdf` does for PyBullet (the plant loads a temporary copy; the original is untouched):

* ``<visual>`` elements are dropped: DIRECT mode never renders, and parsing the Collada visual meshes took
  ~5 s per load. Collision meshes (the Z1 gripper STLs) keep their geometry; ``package://`` URIs are
  rewritten to absolute paths (``example-robot-data`` is located through its installed distribution, other
  packages by searching the folders above the URDF).
* Locked joints (``robot.locked_joints``, e.g. ``joint5, joint6, jointGripper``) are rewritten as *fixed*
  joints whose origin includes the rotation by the locked angle. This is exactly what Pinocchio's
  ``buildReducedModel`` does, so the two models have the same rigid bodies; a stiff position motor or a
  fixed constraint would instead add compliance, drift and solver load.
"""

from __future__ import annotations

import re
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import pinocchio as pin

from wbmpc.model.inertials import check_for_pybullet
from wbmpc.model.robot import RobotModelError, example_robot_data_dir

__all__ = ["default_package_dirs", "offset_base_com", "preprocess_urdf", "resolve_mesh_path"]


def default_package_dirs() -> tuple[str, ...]:
    """Folders against which ``package://`` mesh URIs resolve."""
    try:
        robots = example_robot_data_dir()
    except RobotModelError:
        return ()
    # URIs "package://example-robot-data/robots/..." need the share folder, "package://b1_description/..."
    # the robots folder.
    return (str(robots.parent.parent), str(robots))


def resolve_mesh_path(
    filename: str, urdf_path: str | Path, package_dirs: Sequence[str | Path] | None = None
) -> str:
    """Absolute path of a mesh reference of a URDF (the one rule of the PyBullet plant and the viewer).

    * ``package://<package>/<rest>``: the first existing file among ``<dir>/<package>/<rest>`` for each of
      ``package_dirs`` (default :func:`default_package_dirs`: the example-robot-data folders),
      ``<ancestor>/<package>/<rest>`` for each folder above the URDF, and ``<ancestor>/<rest>`` for a
      folder above the URDF named ``<package>``;
    * ``file://<path>`` and plain paths: relative ones are relative to the URDF's folder (``meshes/x.stl``,
      ``../meshes/x.dae``).

    Args:
        filename: The ``filename`` attribute of a ``<mesh>``.
        urdf_path: The URDF file.
        package_dirs: Folders that hold packages, searched first (``None``: :func:`default_package_dirs`).

    Returns:
        The absolute path, or ``filename`` unchanged if a ``package://`` URI matches no file.
    """
    if package_dirs is None:
        package_dirs = default_package_dirs()
    urdf_dir = Path(urdf_path).resolve().parent
    match = re.match(r"package://([^/]+)/(.*)", filename)
    if match:
        package, rest = match.groups()
        candidates = [Path(d) / package / rest for d in package_dirs]
        ancestors = [urdf_dir, *urdf_dir.parents]
        candidates += [folder / package / rest for folder in ancestors]
        candidates += [folder / rest for folder in ancestors if folder.name == package]
        return next((str(c.resolve()) for c in candidates if c.is_file()), filename)
    path = Path(filename.removeprefix("file://"))
    return str(path if path.is_absolute() else (urdf_dir / path).resolve())


def preprocess_urdf(
    urdf_path: str | Path, locked_joints: Mapping[str, float] | None = None, check_inertials: bool = True
) -> str:
    """URDF text ready for PyBullet: no visuals, absolute mesh paths, locked joints made fixed; a
    collision mesh whose file is missing is dropped (named in one warning).

    Args:
        urdf_path: The original URDF.
        locked_joints: ``{joint name: angle}`` [rad] (or [m] for prismatic joints) to turn into fixed joints
            at that value.
        check_inertials: Refuse link masses and inertias PyBullet would not simulate as written
            (:func:`wbmpc.model.inertials.check_for_pybullet`: the check lives where PyBullet consumes
            them; the robot loader only warns).

    Returns:
        The processed URDF as a string.

    Raises:
        RobotModelError: If a locked joint is missing or not revolute, continuous or prismatic, or (with
            ``check_inertials``) listing every link mass or inertia PyBullet would change, with its fixes.
    """
    urdf_path = Path(urdf_path)
    if check_inertials:
        check_for_pybullet(urdf_path, locked_joints)
    root = ET.fromstring(urdf_path.read_text())
    for link in root.iter("link"):
        for visual in link.findall("visual"):
            link.remove(visual)
    missing = []
    for link in root.iter("link"):
        for collision in link.findall("collision"):
            mesh = collision.find("geometry/mesh")
            if mesh is None:
                continue
            filename = mesh.get("filename", "")
            resolved = resolve_mesh_path(filename, urdf_path)
            if not Path(resolved).is_file():
                missing.append(filename)
                link.remove(collision)
            mesh.set("filename", resolved)
    if missing:
        warnings.warn(
            f"{urdf_path}: collision mesh files not found, those collision shapes are left out of the "
            f"PyBullet plant: {', '.join(dict.fromkeys(missing))}",
            stacklevel=2,
        )
    joints = {joint.get("name"): joint for joint in root.iter("joint") if joint.get("type")}
    for name, value in (locked_joints or {}).items():
        joint = joints.get(name)
        if joint is None:
            raise RobotModelError(f"locked joint {name!r} is not in {urdf_path}")
        kind = joint.get("type")
        if kind not in ("revolute", "continuous", "prismatic"):
            raise RobotModelError(f"locked joint {name!r} has unsupported type {kind!r}")
        origin = joint.find("origin")
        xyz = np.array(origin.get("xyz", "0 0 0").split(), dtype=float) if origin is not None else np.zeros(3)
        rpy = np.array(origin.get("rpy", "0 0 0").split(), dtype=float) if origin is not None else np.zeros(3)
        axis_el = joint.find("axis")
        axis = (
            np.array(axis_el.get("xyz").split(), dtype=float)
            if axis_el is not None
            else np.array([1, 0, 0.0])
        )
        axis = axis / np.linalg.norm(axis)
        placement = pin.SE3(pin.rpy.rpyToMatrix(rpy), xyz)
        if kind == "prismatic":
            motion = pin.SE3(np.eye(3), axis * value)
        else:
            motion = pin.SE3(pin.AngleAxis(value, axis).toRotationMatrix(), np.zeros(3))
        placement = placement * motion
        for tag in ("axis", "limit", "dynamics", "calibration", "safety_controller", "mimic", "origin"):
            for element in joint.findall(tag):
                joint.remove(element)
        joint.set("type", "fixed")
        new_origin = ET.SubElement(joint, "origin")
        new_origin.set("xyz", " ".join(f"{x:.17g}" for x in placement.translation))
        new_origin.set("rpy", " ".join(f"{x:.17g}" for x in pin.rpy.matrixToRpy(placement.rotation)))
    return ET.tostring(root, encoding="unicode")


def offset_base_com(urdf_text: str, offset: np.ndarray) -> str:
    """URDF text with the base's centre of mass moved by ``offset`` [m] (root link frame).

    The mass moved is the heaviest link rigidly attached to the root link (through fixed joints; the B1's
    root ``base`` is a massless dummy on the ``trunk``), so that its inertial origin moves by ``offset``
    expressed in the root frame.
    """
    root = ET.fromstring(urdf_text)
    links = {link.get("name"): link for link in root.iter("link")}
    children = {child.get("link") for child in root.iter("child")}
    base = next(name for name in links if name not in children)
    # Links rigidly attached to the base, with their rotation relative to it.
    rigid, stack = {base: np.eye(3)}, [base]
    while stack:
        parent = stack.pop()
        for joint in root.iter("joint"):
            if joint.get("type") == "fixed" and joint.find("parent").get("link") == parent:
                origin = joint.find("origin")
                rpy = np.zeros(3) if origin is None else np.array(origin.get("rpy", "0 0 0").split(), float)
                child = joint.find("child").get("link")
                rigid[child] = rigid[parent] @ pin.rpy.rpyToMatrix(rpy)
                stack.append(child)

    def mass(name):
        element = links[name].find("inertial/mass")
        return 0.0 if element is None else float(element.get("value", 0.0))

    heavy = max(rigid, key=mass)
    inertial = links[heavy].find("inertial")
    if inertial is None:
        raise RobotModelError(f"no link rigidly attached to {base!r} has an <inertial> to move")
    origin = inertial.find("origin")
    if origin is None:
        origin = ET.SubElement(inertial, "origin")
    xyz = np.array(origin.get("xyz", "0 0 0").split(), dtype=float)
    origin.set("xyz", " ".join(f"{x:.17g}" for x in xyz + rigid[heavy].T @ np.asarray(offset, float)))
    return ET.tostring(root, encoding="unicode")
