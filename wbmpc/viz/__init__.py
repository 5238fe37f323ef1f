"""Visualisation: the meshcat viewer and HTML replays, matplotlib figures.

The names of the former module ``wbmpc.viz`` are re-exported here from ``wbmpc.viz.viewer``.
"""

from wbmpc.viz.viewer import (
    _MESH_CACHE,
    ARM_FORCE_COLOR,
    BASE_PATH_COLOR,
    CAMERA_DIRECTION,
    CAMERA_FOV,
    DEFAULT_MESH_RESOLUTION,
    FOOT_FORCE_COLOR,
    GHOST_COLOR,
    GHOST_MESH_RESOLUTION,
    Viewer,
    ViewerUnavailableError,
    camera_for_motion,
    resolve_mesh_path,
    robot_radius,
    simplify_mesh,
    vertex_normals,
    visual_model,
)

__all__ = [
    "ARM_FORCE_COLOR",
    "BASE_PATH_COLOR",
    "CAMERA_DIRECTION",
    "CAMERA_FOV",
    "DEFAULT_MESH_RESOLUTION",
    "FOOT_FORCE_COLOR",
    "GHOST_COLOR",
    "GHOST_MESH_RESOLUTION",
    "Viewer",
    "ViewerUnavailableError",
    "_MESH_CACHE",
    "camera_for_motion",
    "resolve_mesh_path",
    "robot_radius",
    "simplify_mesh",
    "vertex_normals",
    "visual_model",
]
