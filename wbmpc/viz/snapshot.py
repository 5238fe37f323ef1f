"""A static snapshot of a meshcat scene that a saved notebook can show without its kernel.

:meth:`wbmpc.viz.Viewer.notebook_view` puts the scene's self-contained page
(:meth:`~wbmpc.viz.Viewer.static_html`, several MB: the meshes and meshcat's library) in an
``<iframe src="data:text/html;base64,...">``. Chromium does not load a URL longer than
:data:`CHROMIUM_MAX_URL` (2 MiB): such a frame stays ``about:blank#blocked``, so a reopened notebook shows
no robot in Chrome. :func:`snapshot_iframe` passes the page in the frame's ``srcdoc`` attribute instead,
which has no such limit; :func:`notebook_view` is ``Viewer.notebook_view`` with it.

Either frame is HTML: JupyterLab drops iframes from the outputs of a notebook it does not trust (one saved
on another machine or by ``nbclient``), so there neither shows. An ``<img>`` does: :func:`scene_png` draws
the robot as the viewer last placed it, seen from its camera (matplotlib, coarser meshes, flat shading), and
:func:`notebook_view` puts that picture between the live view and the folded snapshot.
"""

from __future__ import annotations

import base64
import html
import io

import numpy as np

from wbmpc.viz.camera import CAMERA_FOV
from wbmpc.viz.meshes import decimated_mesh

__all__ = ["CHROMIUM_MAX_URL", "PICTURE_MESH_RESOLUTION", "notebook_view", "scene_png", "snapshot_iframe"]

PICTURE_MESH_RESOLUTION = 0.015  # [m] vertex-clustering cell of the meshes drawn by scene_png

CHROMIUM_MAX_URL = 2 * 1024 * 1024  # characters; Chromium's url::kMaxURLChars


def snapshot_iframe(page: str, height: int = 400, css_class: str = "wbmpc-static-scene") -> str:
    """An ``<iframe>`` showing the HTML ``page`` from its ``srcdoc`` attribute (any size, no server).

    Args:
        page: A self-contained HTML page (e.g. :meth:`wbmpc.viz.Viewer.static_html`).
        height: Height of the frame [px].
        css_class: The frame's class.
    """
    return (
        f'<iframe class="{html.escape(css_class)}" srcdoc="{html.escape(page, quote=True)}" width="100%" '
        f'height="{int(height)}" style="border: 0"></iframe>'
    )


def scene_png(
    viewer, width: int = 720, height: int = 405, resolution: float = PICTURE_MESH_RESOLUTION
) -> bytes:
    """A picture (PNG) of the robot as ``viewer`` last placed it, seen from the viewer's camera.

    Every visual mesh (decimated on a ``resolution`` grid) is projected through the camera at
    :attr:`~wbmpc.viz.Viewer.camera_position` looking at :attr:`~wbmpc.viz.Viewer.camera_target` (z up,
    meshcat's vertical field of view), its triangles drawn far to near and shaded by how squarely they face
    the camera; the ground is a 0.5 m grid. Overlays (plans, forces, ghosts) are not drawn.

    Args:
        viewer: A :class:`wbmpc.viz.Viewer` (its last :meth:`~wbmpc.viz.Viewer.display` or animation frame).
        width, height: Size of the picture [px].
        resolution: Mesh decimation cell [m].
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import LineCollection, PolyCollection
    from matplotlib.figure import Figure

    eye = np.asarray(viewer.camera_position, dtype=float)
    target = np.asarray(viewer.camera_target, dtype=float)
    forward = target - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    focal = 1.0 / np.tan(np.radians(CAMERA_FOV) / 2)

    def project(points):  # (..., 3) world -> (..., 2) screen ([-aspect, aspect] x [-1, 1]), depth
        d = points - eye
        depth = d @ forward
        safe = np.where(depth > 1e-3, depth, np.nan)
        return np.stack([focal * (d @ right) / safe, focal * (d @ up) / safe], axis=-1), depth

    triangles, shades = [], []
    for obj, placement in zip(viewer.geometry.geometryObjects, viewer.viz.visual_data.oMg, strict=True):
        mesh = decimated_mesh(obj, resolution)
        if mesh is None:
            continue
        vertices, faces, _ = mesh
        world = (
            vertices * np.asarray(obj.meshScale, dtype=float)
        ) @ placement.rotation.T + placement.translation
        corners = world[faces]  # (m, 3, 3)
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        norm = np.linalg.norm(normals, axis=1)
        keep = norm > 0
        light = np.abs((normals[keep] / norm[keep, None]) @ forward)  # double-sided headlight
        rgb = np.clip(np.asarray(obj.meshColor, dtype=float)[:3], 0.0, 1.0)
        triangles.append(corners[keep])
        shades.append((0.35 + 0.65 * light)[:, None] * rgb)
    aspect = width / height
    fig = Figure(figsize=(width / 100, height / 100), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_axis_off()
    ax.set_xlim(-aspect, aspect)
    ax.set_ylim(-1, 1)
    sky = np.linspace(0.62, 0.95, 64)[:, None, None] * np.ones((1, 2, 3))  # grey at the top to white
    ax.imshow(sky, extent=(-aspect, aspect, -1, 1), aspect="auto", origin="upper", zorder=0)
    ticks = np.arange(-3.0, 3.01, 0.5)
    lines = [np.array([[target[0] + a, target[1] + t, 0.0], [target[0] + b, target[1] + t, 0.0]])
             for t in ticks for a, b in ((-3.0, 3.0),)]  # fmt: skip
    lines += [
        np.array([[target[0] + t, target[1] - 3.0, 0.0], [target[0] + t, target[1] + 3.0, 0.0]])
        for t in ticks
    ]
    segments = []
    for line in lines:  # clipped to the points in front of the camera
        samples = line[0] + np.linspace(0.0, 1.0, 60)[:, None] * (line[1] - line[0])
        screen, depth = project(samples)
        segments.append(screen[depth > 0.05])
    ax.add_collection(
        LineCollection([s for s in segments if len(s) > 1], colors="0.55", linewidths=0.6, zorder=1)
    )
    if triangles:
        corners, colors = np.concatenate(triangles), np.concatenate(shades)
        screen, depth = project(corners)
        order = np.argsort(-depth.mean(axis=1))  # far first
        order = order[np.isfinite(screen[order]).all(axis=(1, 2))]
        ax.add_collection(
            PolyCollection(screen[order], facecolors=colors[order], edgecolors=colors[order], linewidths=0.3,
                           zorder=2)
        )  # fmt: skip
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=100)
    return buffer.getvalue()


def notebook_view(viewer, height: int = 400, snapshot: bool = True):
    """The live scene of ``viewer`` for a notebook cell, with a static snapshot that Chromium loads.

    The same view as :meth:`wbmpc.viz.Viewer.notebook_view` (the live IFrame on the meshcat server, the folded
    snapshot under it), the snapshot given by :func:`snapshot_iframe`, and between them a picture of the scene
    (:func:`scene_png`), which a notebook JupyterLab does not trust still shows. Make it the cell's last
    expression.

    Args:
        viewer: An open :class:`wbmpc.viz.Viewer`.
        height: Height of each view [px].
        snapshot: Add the static snapshot and the picture.

    Returns:
        An :class:`IPython.display.HTML` object.
    """
    from IPython.display import HTML

    size = f'width="100%" height="{int(height)}" style="border: 0"'
    parts = [f'<iframe class="wbmpc-live-scene" src="{html.escape(viewer.url)}" {size}></iframe>']
    if snapshot:
        png = base64.b64encode(scene_png(viewer)).decode("ascii")
        parts.append(
            f'<img class="wbmpc-scene-picture" src="data:image/png;base64,{png}" '
            'alt="the robot when the cell ran" style="max-width: 100%">'
        )
        parts.append(
            "<details><summary>static snapshot of this scene (saved with the notebook, opens without the "
            f"kernel)</summary>{snapshot_iframe(viewer.static_html(), height)}</details>"
        )
    return HTML(f'<div class="wbmpc-scene">{"".join(parts)}</div>')
