"""Framing a motion: the camera target and position that keep the whole motion in view.

The camera looks at the centre of the box swept by the base and stands back far enough for the whole
motion (:func:`camera_for_motion`, with the robot's size from :func:`robot_radius`).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

CAMERA_DIRECTION = (1.3, -1.6, 0.9)  # from the target towards the camera: front right, above
CAMERA_FOV = 75.0  # [deg] meshcat's vertical field of view


def camera_for_motion(
    base_positions: np.ndarray,
    robot_radius: float,
    direction=CAMERA_DIRECTION,
    fov: float = CAMERA_FOV,
) -> tuple[np.ndarray, np.ndarray]:
    """Camera target and position that keep a whole motion in view.

    The target is the centre of the axis-aligned box swept by the base. The motion fits in a sphere about
    the target whose radius is half the box diagonal plus ``robot_radius``; the camera stands on
    ``direction`` from the target at the distance where that sphere fills the vertical field of view.

    Args:
        base_positions: Base positions [m], (n, 3) (or (3,) for one pose).
        robot_radius: Radius [m] of a sphere about the base that holds the robot.
        direction: Direction from the target to the camera (world axes, z up); its length is ignored.
        fov: Vertical field of view [deg] (the smaller one of a landscape window).

    Returns:
        The target and the camera position [m], each (3,).
    """
    points = np.asarray(base_positions, dtype=float).reshape(-1, 3)
    lower, upper = points.min(axis=0), points.max(axis=0)
    target = (lower + upper) / 2
    radius = np.linalg.norm(upper - lower) / 2 + float(robot_radius)
    distance = radius / np.sin(np.radians(fov) / 2)
    direction = np.asarray(direction, dtype=float)
    return target, target + distance * direction / np.linalg.norm(direction)


def robot_radius(model: pin.Model, geometry: pin.GeometryModel, q: np.ndarray) -> float:
    """Radius [m] of a sphere about the base that holds every visual geometry at configuration ``q``.

    Each geometry counts as the sphere about its local bounding box (meshes are scaled on loading).
    """
    data, geometry_data = model.createData(), geometry.createData()
    pin.forwardKinematics(model, data, q)
    pin.updateGeometryPlacements(model, data, geometry, geometry_data)
    base = np.asarray(q[:3], dtype=float)
    radius = 0.0
    for obj, placement in zip(geometry.geometryObjects, geometry_data.oMg, strict=True):
        shape = obj.geometry
        shape.computeLocalAABB()
        centre = placement.act(np.asarray(shape.aabb_center, dtype=float))
        radius = max(radius, float(np.linalg.norm(centre - base) + shape.aabb_radius))
    return radius
