"""Meshcat visualisation: the robot, contact forces, predicted foot and end-effector paths, replays.

:class:`Viewer` wraps Pinocchio's ``MeshcatVisualizer`` on a meshcat server that it starts itself (a zmq
subprocess; it runs headless, a browser is only needed to look)::

    viewer = Viewer(robot)
    viewer.show_plan(plan)                          # robot at node 0, force arrows, predicted paths
    viewer.animation(log["q"], log["t"])            # a replay, played by the browser
    viewer.export_html("data/output/replay.html")   # self-contained file, opens without a server

The robot's visual geometry comes from :mod:`wbmpc.viz.geometry` (:func:`~wbmpc.viz.geometry.visual_model`),
its meshes decimated by :mod:`wbmpc.viz.meshes`. A replay frames itself: the camera looks at the centre of
the box swept by the base and stands back far enough for the whole motion
(:func:`~wbmpc.viz.camera.camera_for_motion`).
"""

from __future__ import annotations

import io
import math
import time
from contextlib import redirect_stdout
from pathlib import Path

import meshcat
import meshcat.geometry as mg
import numpy as np
import pinocchio as pin
import zmq
from meshcat.animation import Animation

from wbmpc.model.robot import Robot
from wbmpc.viz.camera import CAMERA_DIRECTION, camera_for_motion, robot_radius
from wbmpc.viz.geometry import visual_model
from wbmpc.viz.meshes import DEFAULT_MESH_RESOLUTION, GHOST_MESH_RESOLUTION, _RobotVisualizer
from wbmpc.viz.plots import EE_COLOR, FOOT_COLORS

FOOT_FORCE_COLOR = 0xD62728  # red
ARM_FORCE_COLOR = 0x1F5FD0  # blue
BASE_PATH_COLOR = 0x555555
GHOST_COLOR = (0.55, 0.6, 0.7, 0.3)  # translucent grey-blue (RGBA)


class ViewerUnavailableError(RuntimeError):
    """Raised when no meshcat server can be started or reached."""


# --- the viewer ------------------------------------------------------------------------------------------
class Viewer:
    """A meshcat scene of the robot, its contact forces and MPC plans.

    Args:
        robot: The robot.
        zmq_url: Address of a running ``meshcat-server`` (e.g. ``tcp://127.0.0.1:6000``); ``None`` starts
            a private server in a subprocess (stopped by :meth:`close` or at interpreter exit).
        mesh_resolution: Cell size [m] of the decimated meshes; ``None`` sends the original mesh files.
        timeout: Time [s] to wait for an existing server given by ``zmq_url`` to answer.

    Raises:
        ViewerUnavailableError: the meshcat server cannot be started or reached.
    """

    def __init__(
        self,
        robot: Robot,
        zmq_url: str | None = None,
        mesh_resolution: float | None = DEFAULT_MESH_RESOLUTION,
        timeout: float = 10.0,
    ):
        self.robot = robot
        self.model, self.geometry = visual_model(robot)
        self.data = self.model.createData()
        self.mesh_resolution = mesh_resolution
        self.meshcat = _start_meshcat(zmq_url, timeout)
        self._owns_server = zmq_url is None
        self._closed = False
        self.viz = self._load_robot("robot")
        self._ghosts: dict[int, _RobotVisualizer] = {}
        self._arrows: set[str] = set()
        self._robot_radius = robot_radius(self.model, self.geometry, robot.q_nominal)
        self.camera_target = np.zeros(3)
        self.camera_position = np.zeros(3)
        self.frame_motion(robot.q_nominal[None, :3])
        self.display(robot.q_nominal)

    @property
    def closed(self) -> bool:
        """True once :meth:`close` ran: the scene can no longer be changed (create a new :class:`Viewer`)."""
        return self._closed

    def _check_open(self) -> None:
        if self._closed:
            raise ViewerUnavailableError(
                "this viewer was closed (Viewer.close() stopped its meshcat server), so the 3-D view cannot "
                "change any more; create a new one with Viewer(robot)"
            )

    def _load_robot(self, root: str, color=None, resolution: float | None = None) -> _RobotVisualizer:
        viz = _RobotVisualizer(self.model, self.geometry, resolution or self.mesh_resolution)
        viz.initViewer(viewer=self.meshcat)
        viz.loadViewerModel(rootNodeName=root, visual_color=color)
        return viz

    # --- basics ------------------------------------------------------------------------------------------
    @property
    def url(self) -> str:
        """Web address of the scene (open it in a browser)."""
        return self.meshcat.url()

    def jupyter_cell(self, height: int = 400):
        """An IFrame of the live scene for a notebook cell (make it the cell's last expression)."""
        return self.meshcat.jupyter_cell(height=height)

    def notebook_view(self, height: int = 400, snapshot: bool = True):
        """The live scene for a notebook cell, with a picture and a static snapshot saved with the notebook.

        The live view is an IFrame on the meshcat server: it follows every later change of the scene
        (re-solves, replays) but shows nothing once the kernel is gone. Under it are a picture of the scene
        as it is now (an ``<img>``, which JupyterLab keeps in an untrusted notebook) and, folded, the scene
        as a self-contained page (:meth:`static_html` in ``srcdoc``, which Chromium loads where a data: URL
        of this size is refused), so a saved and reopened notebook still shows the robot
        (:func:`wbmpc.viz.snapshot.notebook_view`). Make it the cell's last expression.

        Args:
            height: Height of each view [px].
            snapshot: Add the picture and the static snapshot.

        Returns:
            An :class:`IPython.display.HTML` object.
        """
        from wbmpc.viz import snapshot as snapshots

        self._check_open()
        return snapshots.notebook_view(self, height, snapshot)

    def static_html(self) -> str:
        """The current scene (with its animation, if any) as a self-contained HTML page."""
        self._check_open()
        return self.meshcat.static_html()

    def set_camera(self, position=CAMERA_DIRECTION, target=(0.0, 0.0, 0.0)) -> None:
        """Place the camera at ``position`` [m] looking at ``target`` [m] (world axes, z up).

        Meshcat's camera always looks at (and orbits about) the origin of its scene: translating
        ``/Cameras/default``, as meshcat's readme suggests, moves the camera but it still looks at the
        origin. So the drawn world (the robot and overlays under ``/meshcat``, the grid and the axes) is
        shifted by ``-target`` instead; the picture is that of the world seen from ``position``. Both points
        are kept in :attr:`camera_position` and :attr:`camera_target`, and in an exported HTML file.
        """
        target = np.asarray(target, dtype=float)
        position = np.asarray(position, dtype=float)
        shift = pin.SE3(np.eye(3), -target).homogeneous
        for node in ("/meshcat", "/Grid", "/Axes"):
            self.meshcat[node].set_transform(shift)
        # The camera object lives in meshcat's y-up frame: world (x, y, z) is (x, z, -y) there.
        x, y, z = (float(c) for c in position - target)
        self.meshcat["/Cameras/default/rotated/<object>"].set_property("position", [x, z, -y])
        self.camera_target, self.camera_position = target.copy(), position.copy()

    def frame_motion(self, base_positions: np.ndarray) -> None:
        """Point the camera so that the robot stays in view while its base visits ``base_positions``.

        Args:
            base_positions: Base positions [m], (n, 3); see :func:`camera_for_motion`.
        """
        target, position = camera_for_motion(base_positions, self._robot_radius)
        self.set_camera(position, target)

    def display(self, q: np.ndarray) -> None:
        """Place the robot at configuration ``q`` (nq,)."""
        self._check_open()
        q = np.asarray(q, dtype=float)
        self.viz.display(q)
        pin.framesForwardKinematics(self.model, self.data, q)

    def play(self, qs: np.ndarray, dt: float) -> None:
        """Show configurations ``qs`` (n, nq) one after the other, ``dt`` [s] apart (blocks meanwhile)."""
        for q in qs:
            start = time.perf_counter()
            self.display(q)
            time.sleep(max(0.0, dt - (time.perf_counter() - start)))

    def clear(self, name: str | None = None) -> None:
        """Delete drawn overlays: one node (``"plan"``, ``"forces"``, ``"paths/ee"``...) or all of them."""
        self._check_open()
        names = [name] if name is not None else ["forces", "paths", "plan", "ghosts"]
        for node in names:
            self.meshcat[node].delete()
        self._arrows = {a for a in self._arrows if not any(a == n or a.startswith(n + "/") for n in names)}
        if name is None or name == "ghosts":
            self._ghosts.clear()

    def close(self) -> None:
        """Stop the meshcat server this viewer started (a no-op for an external server).

        Later changes of the scene raise :class:`ViewerUnavailableError` saying so.
        """
        if self._closed:
            return
        self._closed = True
        window = self.meshcat.window
        window.zmq_socket.close(linger=0)
        proc = getattr(window, "server_proc", None)
        if self._owns_server and proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()

    def __enter__(self) -> Viewer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # --- overlays ----------------------------------------------------------------------------------------
    def contact_positions(self, q: np.ndarray) -> np.ndarray:
        """World positions [m] of the contact frames (feet, then the end effector), (n_c, 3)."""
        pin.framesForwardKinematics(self.model, self.data, np.asarray(q, dtype=float))
        frames = self.robot.contact_frames
        return np.array([self.data.oMf[self.model.getFrameId(f)].translation for f in frames])

    def draw_forces(
        self,
        q: np.ndarray,
        forces: np.ndarray,
        contact: np.ndarray | None = None,
        foot_scale: float = 1e-3,
        arm_scale: float = 2e-3,
        name: str = "forces",
    ) -> None:
        """Arrows for the contact forces acting on the robot at the contact frames.

        Args:
            q: Configuration (nq,) that places the contact frames.
            forces: Forces [N], world axes, one row per contact frame (feet, then the end effector).
            contact: Contact flags of the feet; a swing foot gets no arrow. ``None``: all in contact.
            foot_scale: Arrow length per newton [m/N] for the feet (red).
            arm_scale: Arrow length per newton [m/N] for the end effector (blue).
            name: Scene node holding the arrows.
        """
        forces = np.asarray(forces, dtype=float).reshape(-1, 3)
        positions = self.contact_positions(q)
        for i, force in enumerate(forces[: len(positions)]):
            foot = i < self.robot.n_feet
            if foot and contact is not None and not bool(np.asarray(contact)[i]):
                force = np.zeros(3)
            path = f"{name}/{self.robot.contact_frames[i]}"
            self._ensure_arrow(path, FOOT_FORCE_COLOR if foot else ARM_FORCE_COLOR)
            scale = foot_scale if foot else arm_scale
            self.meshcat[path].set_transform(_arrow_transform(positions[i], scale * force))

    def draw_path(
        self,
        name: str,
        points: np.ndarray,
        color: int | str = 0x1F77B4,
        markers: bool = True,
        marker_size: float = 0.012,
    ) -> None:
        """A polyline through ``points`` (n, 3) [m], with a dot at every point if ``markers``.

        The node is ``paths/<name>`` unless ``name`` already contains a ``/``.
        """
        points = np.asarray(points, dtype=np.float32).reshape(-1, 3)
        color = _color_int(color)
        node = self.meshcat[name if "/" in name else f"paths/{name}"]
        node["line"].set_object(mg.Line(mg.PointsGeometry(points.T), mg.LineBasicMaterial(color=color)))
        if markers:
            rgb = np.array([(color >> 16) & 255, (color >> 8) & 255, color & 255], dtype=np.float32) / 255
            colors = np.tile(rgb[:, None], (1, len(points)))
            node["nodes"].set_object(
                mg.Points(mg.PointsGeometry(points.T, color=colors), mg.PointsMaterial(size=marker_size))
            )

    def show_plan(self, plan, ghost_nodes=(-1,), foot_scale: float = 1e-3, arm_scale: float = 2e-3) -> dict:
        """Show an MPC plan: the robot at node 0 with its force arrows, the predicted foot, end-effector and
        base paths (a dot per node) and translucent ghosts of the robot at ``ghost_nodes``.

        Args:
            plan: A :class:`wbmpc.control.mpc.MPCSolution`.
            ghost_nodes: Node indices shown as translucent robots (each costs one more copy of the meshes).
            foot_scale, arm_scale: Arrow lengths per newton [m/N].

        Returns:
            The predicted positions [m]: ``feet`` (N, n_feet, 3), ``ee`` (N, 3) or ``None``, ``base`` (N, 3).
        """
        self._check_open()
        q_nodes = np.asarray(plan.q)
        paths = self.predicted_paths(q_nodes)
        self.display(q_nodes[0])
        for i, foot in enumerate(self.robot.foot_frames):
            self.draw_path(f"plan/{foot}", paths["feet"][:, i], FOOT_COLORS[i % len(FOOT_COLORS)])
        if paths["ee"] is not None:
            self.draw_path("plan/ee", paths["ee"], EE_COLOR)
        self.draw_path("plan/base", paths["base"], BASE_PATH_COLOR)
        contact = np.asarray(plan.contact)[:, 0] if np.size(plan.contact) else None
        self.draw_forces(q_nodes[0], np.asarray(plan.forces)[0], contact, foot_scale, arm_scale)
        for k in ghost_nodes:
            k = int(k) % len(q_nodes)
            if k not in self._ghosts:
                # Translucent ghosts need little detail: coarser meshes keep the scene light.
                coarse = max(self.mesh_resolution, GHOST_MESH_RESOLUTION) if self.mesh_resolution else None
                self._ghosts[k] = self._load_robot(f"ghosts/node{k}", list(GHOST_COLOR), coarse)
            self._ghosts[k].display(q_nodes[k])
        return paths

    def predicted_paths(self, qs: np.ndarray) -> dict:
        """World positions [m] of the feet (n, n_feet, 3), end effector (n, 3) or ``None``, base (n, 3)."""
        ids = [self.model.getFrameId(f) for f in self.robot.foot_frames]
        ee = self.model.getFrameId(self.robot.ee_frame) if self.robot.has_arm else None
        feet, ee_path = [], []
        for q in np.asarray(qs, dtype=float):
            pin.framesForwardKinematics(self.model, self.data, q)
            feet.append([self.data.oMf[i].translation.copy() for i in ids])
            if ee is not None:
                ee_path.append(self.data.oMf[ee].translation.copy())
        return {
            "feet": np.array(feet),
            "ee": np.array(ee_path) if ee is not None else None,
            "base": np.asarray(qs)[:, :3].copy(),
        }

    # --- replays -----------------------------------------------------------------------------------------
    def animation(
        self,
        qs: np.ndarray,
        times: np.ndarray,
        forces: np.ndarray | None = None,
        contact: np.ndarray | None = None,
        fps: float = 30.0,
        play: bool = True,
        repetitions: float = math.inf,
        foot_scale: float = 1e-3,
        arm_scale: float = 2e-3,
        frame_camera: bool = True,
    ) -> Animation:
        """Send a replay to the scene (the browser plays it; :meth:`export_html` keeps it).

        Configurations are interpolated on the Lie group at ``fps`` frames per second of simulated time.
        The robot is shown at the first configuration and, with ``frame_camera``, the camera is set from the
        bounds of the base trajectory (:meth:`frame_motion`) so the whole motion is in view.

        Args:
            qs: Configurations (n, nq).
            times: Their times [s] (n,), increasing.
            forces: Contact forces [N], world, (n, n_c, 3) or per interval (n-1, n_c, 3) (held piecewise
                constant, like MPC stage forces); ``None`` draws no arrows.
            contact: Foot contact flags (n or n-1, n_feet); ``None``: arrows wherever the force is nonzero.
            fps: Frames per second of the replay (real-time playback).
            play: Start playing at once.
            repetitions: Number of times the replay plays; ``math.inf`` (the default) loops until paused.
                Meshcat's "Animations" panel has play/pause/reset and a time slider to scrub through it.
            foot_scale, arm_scale: Arrow lengths per newton [m/N].
            frame_camera: Set the camera from the motion's bounds.

        Returns:
            The meshcat animation (already sent).
        """
        self._check_open()
        qs = np.asarray(qs, dtype=float)
        times = np.asarray(times, dtype=float)
        if qs.ndim != 2 or len(qs) != len(times) or len(qs) < 1:
            raise ValueError(f"qs (n, nq) and times (n,) must match, got {qs.shape} and {times.shape}")
        if len(times) > 1 and np.any(np.diff(times) <= 0):
            raise ValueError("times must be strictly increasing")
        if frame_camera:
            self.frame_motion(qs[:, :3])
        self.display(qs[0])  # the scene as the replay opens
        frame_times = times[0] + np.arange(int(np.floor((times[-1] - times[0]) * fps + 1e-9)) + 1) / fps
        anim = Animation(default_framerate=fps)
        geometry_data = self.viz.visual_data
        visual = pin.GeometryType.VISUAL
        nodes = [self.viz.getViewerNodeName(g, visual) for g in self.geometry.geometryObjects]
        for frame, t in enumerate(frame_times):
            k = int(np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 1))
            if k + 1 < len(times):
                alpha = (t - times[k]) / (times[k + 1] - times[k])
                q = pin.interpolate(self.model, qs[k], qs[k + 1], alpha)
            else:
                q = qs[k]
            pin.forwardKinematics(self.model, self.viz.data, q)
            pin.updateGeometryPlacements(self.model, self.viz.data, self.geometry, geometry_data)
            with anim.at_frame(self.meshcat, frame) as f:
                for node, placement in zip(nodes, geometry_data.oMg, strict=True):
                    f[node].set_transform(placement.homogeneous)
                if forces is not None:
                    c = None if contact is None else np.asarray(contact)[min(k, len(contact) - 1)]
                    f_k = np.asarray(forces)[min(k, len(forces) - 1)]
                    self._animate_forces(f, q, f_k, c, foot_scale, arm_scale)
        self.meshcat.set_animation(anim, play=play, repetitions=repetitions)
        return anim

    def _animate_forces(self, frame, q, forces, contact, foot_scale, arm_scale) -> None:
        positions = self.contact_positions(q)
        for i, force in enumerate(np.asarray(forces, dtype=float).reshape(-1, 3)[: len(positions)]):
            foot = i < self.robot.n_feet
            if foot and contact is not None and not bool(contact[i]):
                force = np.zeros(3)
            path = f"forces/{self.robot.contact_frames[i]}"
            self._ensure_arrow(path, FOOT_FORCE_COLOR if foot else ARM_FORCE_COLOR)
            R, length = _arrow_pose((foot_scale if foot else arm_scale) * force)
            # Animation tracks carry position and rotation; the arrow length is a scale track.
            frame[path].set_transform(pin.SE3(R, positions[i]).homogeneous)
            frame[path].set_property("scale", "vector3", [1.0, length, 1.0])

    def export_html(self, path: str | Path) -> Path:
        """Write the current scene (with its animation, if any) as a self-contained HTML file.

        The file embeds the meshcat viewer and every object, so it opens in a browser without a server.

        Returns:
            The path written.
        """
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(self.static_html(), encoding="utf-8")
        return path

    # --- helpers -----------------------------------------------------------------------------------------
    def _ensure_arrow(self, path: str, color: int) -> None:
        """Create an arrow of unit length along its local y axis (shaft + cone head), once."""
        if path in self._arrows:
            return
        node = self.meshcat[path]
        material = mg.MeshLambertMaterial(color=color)
        head = 0.15  # head length as a fraction of the arrow
        node["shaft"].set_object(mg.Cylinder(1.0 - head, radius=0.008), material)
        node["shaft"].set_transform(pin.SE3(np.eye(3), np.array([0.0, (1.0 - head) / 2, 0.0])).homogeneous)
        node["head"].set_object(mg.Cylinder(head, radiusTop=0.0, radiusBottom=0.02), material)
        node["head"].set_transform(pin.SE3(np.eye(3), np.array([0.0, 1.0 - head / 2, 0.0])).homogeneous)
        self._arrows.add(path)


def _arrow_pose(vector: np.ndarray, min_length: float = 1e-4) -> tuple[np.ndarray, float]:
    """Rotation taking the y axis to ``vector`` and the arrow length [m] (at least ``min_length``)."""
    length = float(np.linalg.norm(vector))
    direction = vector / length if length > 1e-9 else np.array([0.0, 0.0, 1.0])
    R = pin.Quaternion.FromTwoVectors(np.array([0.0, 1.0, 0.0]), direction).toRotationMatrix()
    return R, max(length, min_length)


def _arrow_transform(origin: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """Homogeneous transform taking the unit y-axis arrow to ``origin -> origin + vector`` (scaled in y)."""
    R, length = _arrow_pose(np.asarray(vector, dtype=float))
    T = np.eye(4)
    T[:3, :3] = R @ np.diag([1.0, length, 1.0])
    T[:3, 3] = origin
    return T


def _start_meshcat(zmq_url: str | None, timeout: float) -> meshcat.Visualizer:
    """A meshcat client on a new server subprocess (``zmq_url=None``) or on a running server."""
    if zmq_url is not None:
        _probe_server(zmq_url, timeout)
    try:
        with redirect_stdout(io.StringIO()):  # meshcat prints the URL; Viewer.url has it
            return meshcat.Visualizer(zmq_url=zmq_url)
    except (RuntimeError, OSError, zmq.ZMQError) as exc:
        raise ViewerUnavailableError(
            f"could not start meshcat's zmq server ({exc}). Start one in a terminal with `meshcat-server` "
            "and pass its zmq address, e.g. Viewer(robot, zmq_url='tcp://127.0.0.1:6000')"
        ) from exc


def _probe_server(zmq_url: str, timeout: float) -> None:
    """Raise :class:`ViewerUnavailableError` unless a meshcat server answers at ``zmq_url``."""
    socket = zmq.Context.instance().socket(zmq.REQ)
    socket.setsockopt(zmq.LINGER, 0)
    socket.setsockopt(zmq.RCVTIMEO, int(1000 * timeout))
    try:
        socket.connect(zmq_url)
        socket.send(b"url")
        socket.recv()
    except zmq.ZMQError as exc:
        raise ViewerUnavailableError(
            f"no meshcat server answered at {zmq_url} within {timeout} s ({exc})"
        ) from exc
    finally:
        socket.close()


def _color_int(color: int | str) -> int:
    """``0xRRGGBB`` from an int or a ``"#rrggbb"`` string."""
    if isinstance(color, str):
        return int(color.lstrip("#"), 16)
    return int(color)
