"""Decimated meshes for meshcat.

The B1 and Z1 meshes are large (about 100 MB of Collada files, a million triangles). By default the
viewer sends each mesh decimated by vertex clustering on a 5 mm grid (:func:`simplify_mesh`, about 15 % of
the triangles) with vertex normals (:func:`vertex_normals`), which keeps the scene and the exported HTML at a
few MB. ``mesh_resolution=None`` sends the original files.
"""

from __future__ import annotations

import meshcat.geometry as mg
import numpy as np
import pinocchio as pin
from pinocchio.visualize import MeshcatVisualizer

DEFAULT_MESH_RESOLUTION = 0.005  # [m] vertex-clustering cell of the decimated meshes
GHOST_MESH_RESOLUTION = 0.012  # [m] the same for the translucent ghosts


def simplify_mesh(vertices: np.ndarray, faces: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Decimate a triangle mesh by vertex clustering: one vertex per occupied cubic cell.

    Vertices in the same ``cell``-sized grid cell merge into their mean; triangles that collapse (two
    corners in one cell) and duplicates are dropped. The shape is kept to about ``cell``.

    Args:
        vertices: (n, 3) vertex positions [m].
        faces: (m, 3) vertex indices of the triangles.
        cell: Grid cell size [m].

    Returns:
        The decimated vertices (n', 3) and faces (m', 3).
    """
    vertices = np.asarray(vertices, dtype=float)
    faces = np.asarray(faces, dtype=np.int64)
    if len(vertices) == 0 or len(faces) == 0:
        return vertices.reshape(-1, 3), faces.reshape(-1, 3)
    _, cluster = np.unique(np.floor(vertices / cell).astype(np.int64), axis=0, return_inverse=True)
    cluster = cluster.ravel()
    counts = np.bincount(cluster)
    merged = np.zeros((counts.size, 3))
    np.add.at(merged, cluster, vertices)
    merged /= counts[:, None]
    f = cluster[faces]
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    _, first = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
    f = f[np.sort(first)]
    used = np.unique(f)
    remap = np.full(counts.size, -1, dtype=np.int64)
    remap[used] = np.arange(used.size)
    return merged[used], remap[f]


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit vertex normals (n, 3): the area-weighted sum of the adjacent face normals."""
    v = np.asarray(vertices, dtype=float)
    f = np.asarray(faces, dtype=np.int64)
    face_normals = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # |n| = 2 x area
    normals = np.zeros_like(v)
    for corner in range(3):
        np.add.at(normals, f[:, corner], face_normals)
    norm = np.linalg.norm(normals, axis=1, keepdims=True)
    return normals / np.where(norm > 0, norm, 1.0)


class _IndexedMeshGeometry(mg.Geometry):
    """A triangle mesh with vertex normals (meshcat's TriangularMeshGeometry sends none)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray):
        super().__init__()
        self.vertices = np.asarray(vertices, dtype=np.float32)
        self.faces = np.asarray(faces, dtype=np.uint32)
        self.normals = np.asarray(normals, dtype=np.float32)

    def lower(self, object_data):
        return {
            "uuid": self.uuid,
            "type": "BufferGeometry",
            "data": {
                "attributes": {
                    "position": mg.pack_numpy_array(self.vertices.T),
                    "normal": mg.pack_numpy_array(self.normals.T),
                },
                "index": mg.pack_numpy_array(self.faces.T),
            },
        }


_MESH_CACHE: dict[tuple, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}


def decimated_mesh(geometry_object: pin.GeometryObject, cell: float):
    """Decimated (vertices, faces, normals) of a mesh geometry object, or ``None`` if it is not a mesh.

    Args:
        geometry_object: A Pinocchio visual geometry object (its mesh file and scale).
        cell: Vertex-clustering cell [m] (:func:`simplify_mesh`). Cached per file, scale and cell.
    """
    geometry = geometry_object.geometry
    if not (hasattr(geometry, "vertices") and hasattr(geometry, "tri_indices")):
        return None
    scale = np.asarray(geometry_object.meshScale, dtype=float)
    key = (geometry_object.meshPath, tuple(scale), cell)
    if key not in _MESH_CACHE:
        tri = geometry.tri_indices
        faces = np.array([(t[0], t[1], t[2]) for t in map(tri, range(geometry.num_tris))], dtype=np.int64)
        # The loader applied meshScale to the vertices; Pinocchio applies it again in the transforms.
        vertices = np.asarray(geometry.vertices(), dtype=float) / np.where(scale != 0, scale, 1.0)
        vertices, faces = simplify_mesh(vertices, faces, cell)
        _MESH_CACHE[key] = (vertices, faces, vertex_normals(vertices, faces))
    return _MESH_CACHE[key]


class _RobotVisualizer(MeshcatVisualizer):
    """Pinocchio's meshcat visualizer, sending decimated meshes when a resolution is given."""

    def __init__(self, model, geometry, mesh_resolution: float | None):
        super().__init__(model, None, geometry)
        self.mesh_resolution = mesh_resolution

    def loadViewerGeometryObject(self, geometry_object, geometry_type, color=None):
        mesh = decimated_mesh(geometry_object, self.mesh_resolution) if self.mesh_resolution else None
        if mesh is None:
            return super().loadViewerGeometryObject(geometry_object, geometry_type, color)
        rgba = np.asarray(geometry_object.meshColor if color is None else color, dtype=float)
        material = mg.MeshPhongMaterial(color=_rgb_int(rgba[:3]), opacity=float(rgba[3]))
        node = self.viewer[self.getViewerNodeName(geometry_object, geometry_type)]
        node.set_object(mg.Mesh(_IndexedMeshGeometry(*mesh), material))


def _rgb_int(rgb) -> int:
    r, g, b = (int(round(255 * float(np.clip(c, 0.0, 1.0)))) for c in rgb[:3])
    return (r << 16) + (g << 8) + b
