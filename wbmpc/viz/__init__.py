"""Visualisation: the meshcat viewer and HTML replays, matplotlib figures.

:mod:`~wbmpc.viz.viewer` (the :class:`Viewer`: scene, overlays, replays, HTML export),
:mod:`~wbmpc.viz.geometry` (the robot's visual model), :mod:`~wbmpc.viz.meshes` (decimated meshes),
:mod:`~wbmpc.viz.camera` (framing a motion), :mod:`~wbmpc.viz.plots` (matplotlib figures). The names of the
former module ``wbmpc.viz`` are re-exported here.
"""

from wbmpc.model.urdf import resolve_mesh_path
from wbmpc.viz.camera import CAMERA_DIRECTION, CAMERA_FOV, camera_for_motion, robot_radius
from wbmpc.viz.geometry import visual_model
from wbmpc.viz.meshes import (
    _MESH_CACHE,
    DEFAULT_MESH_RESOLUTION,
    GHOST_MESH_RESOLUTION,
    simplify_mesh,
    vertex_normals,
)
from wbmpc.viz.viewer import (
    ARM_FORCE_COLOR,
    BASE_PATH_COLOR,
    FOOT_FORCE_COLOR,
    GHOST_COLOR,
    Viewer,
    ViewerUnavailableError,
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
