"""Meshcat visualisation: visual model consistency, mesh decimation, and a headless viewer round trip.

The viewer tests start meshcat's zmq server in a subprocess (it needs no display or browser). They are
skipped, with the reason, only if that server cannot start on the machine.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from conftest import fake_plan

from wbmpc.model.robot import load_b1_z1, load_robot
from wbmpc.viz import (
    CAMERA_DIRECTION,
    CAMERA_FOV,
    Viewer,
    ViewerUnavailableError,
    camera_for_motion,
    resolve_mesh_path,
    robot_radius,
    simplify_mesh,
    vertex_normals,
    visual_model,
)
from wbmpc.viz import viewer as viz

DATA = Path(__file__).parent / "data" / "quadruped_arm"


@pytest.fixture(scope="module")
def robot():
    return load_b1_z1()


@pytest.fixture(scope="module")
def viewer(robot):
    try:
        v = Viewer(robot)
    except ViewerUnavailableError as exc:
        pytest.skip(f"meshcat's zmq server cannot start on this machine: {exc}")
    yield v
    v.close()


@pytest.fixture(scope="module")
def plan(robot):
    return fake_plan(robot, t0=0.0, ee_force_z=-20.0)


def _frame_placements(model, q, names):
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    return {name: data.oMf[model.getFrameId(name)].homogeneous.copy() for name in names}


def test_visual_model_matches_robot_model(robot):
    model, geometry = visual_model(robot)
    assert model.nq == robot.model.nq and model.nv == robot.model.nv
    assert list(model.names) == list(robot.model.names)
    assert geometry.ngeoms > 0
    assert any(g.meshPath.endswith(".dae") for g in geometry.geometryObjects)
    frames = robot.contact_frames  # the four feet and the end effector
    assert robot.ee_frame in frames
    rng = np.random.default_rng(1)
    q_random = pin.randomConfiguration(robot.model)
    q_random[:3] = rng.uniform(-1, 1, 3)
    for q in (robot.q_nominal, q_random):
        expected = _frame_placements(robot.model, q, frames)
        got = _frame_placements(model, q, frames)
        for name in frames:
            np.testing.assert_allclose(got[name], expected[name], atol=1e-12, err_msg=name)


def test_visual_model_falls_back_to_primitives(robot, monkeypatch):
    # Another package folder (a new cache entry) and mesh references that lead nowhere.
    monkeypatch.setattr("wbmpc.viz.geometry.default_package_dirs", lambda: ("/nonexistent/mesh/dir",))
    monkeypatch.setattr(
        "wbmpc.viz.geometry.resolve_mesh_path", lambda filename, *args: "/nonexistent/mesh/dir/x.dae"
    )
    with pytest.warns(UserWarning, match="primitive shapes"):
        model, geometry = visual_model(robot)
    assert model.nq == robot.model.nq
    assert geometry.ngeoms > 0
    assert not any(g.meshPath.endswith(".dae") for g in geometry.geometryObjects)


def test_simplify_mesh_keeps_the_shape():
    # A unit square split into 2 * 50 * 50 triangles.
    n = 51
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    vertices = np.column_stack([x.ravel(), y.ravel(), np.zeros(n * n)])
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    v, f = simplify_mesh(vertices, faces, cell=0.1)
    assert 0 < len(f) < len(faces) / 10
    assert f.min() >= 0 and f.max() < len(v)
    assert np.all((v >= -1e-12) & (v <= 1 + 1e-12))
    assert v[:, 0].max() - v[:, 0].min() > 0.9  # still spans the square
    normals = vertex_normals(v, f)
    np.testing.assert_allclose(np.abs(normals[:, 2]), 1.0, atol=1e-12)


def test_arrow_transform_points_along_the_vector():
    origin, vector = np.array([0.1, 0.2, 0.3]), np.array([0.3, -0.1, 0.5])
    T = viz._arrow_transform(origin, vector)
    tip = T @ np.array([0.0, 1.0, 0.0, 1.0])  # the unit arrow's tip
    np.testing.assert_allclose(tip[:3], origin + vector, atol=1e-12)


def test_unreachable_server_raises_a_clear_error(robot):
    with pytest.raises(ViewerUnavailableError, match="no meshcat server"):
        Viewer(robot, zmq_url="tcp://127.0.0.1:9", timeout=0.5)


def test_viewer_round_trip(viewer, robot, plan, tmp_path):
    assert viewer.url.startswith("http")
    q = robot.q_nominal
    viewer.display(q)
    forces = np.zeros((len(robot.contact_frames), 3))
    forces[:4, 2] = robot.mass * robot.gravity / 4
    forces[4] = [0.0, 0.0, -20.0]
    viewer.draw_forces(q, forces, contact=np.array([True, False, True, True]))
    assert {"forces/FL_foot", "forces/gripper_center"} <= viewer._arrows
    line = np.column_stack([np.linspace(0, 1, 5), np.zeros(5), np.full(5, 0.1)])
    viewer.draw_path("test_path", line, "#ff7f0e")
    paths = viewer.show_plan(plan)
    assert paths["feet"].shape == (15, 4, 3) and paths["ee"].shape == (15, 3)
    np.testing.assert_allclose(paths["base"][:, 0], plan.q[:, 0])
    anim = viewer.animation(plan.q, plan.node_times, forces=plan.forces, contact=plan.contact.T)
    assert len(anim.clips) > len(viewer.geometry.geometryObjects)  # the bodies plus the force arrows
    path = viewer.export_html(tmp_path / "out" / "replay.html")
    assert path.is_file()
    assert path.stat().st_size > 10_000
    assert "meshcat" in path.read_text(encoding="utf-8").lower()


def test_play_and_clear(viewer, robot):
    qs = np.tile(robot.q_nominal, (3, 1))
    qs[:, 2] += [0.0, 0.01, 0.02]
    viewer.play(qs, dt=0.0)
    viewer.clear("paths")
    viewer.clear()
    assert not viewer._arrows and not viewer._ghosts


def test_animation_rejects_bad_times(viewer, robot):
    qs = np.tile(robot.q_nominal, (3, 1))
    with pytest.raises(ValueError, match="increasing"):
        viewer.animation(qs, np.array([0.0, 0.2, 0.1]))
    with pytest.raises(ValueError, match="must match"):
        viewer.animation(qs, np.array([0.0, 0.1]))


# --- meshes referenced relative to the URDF ------------------------------------------------------------
def test_meshes_relative_to_the_urdf_are_found(recwarn):
    """The test robot's base is "../meshes/cube.stl" and its legs "meshes/cube.obj" (12-triangle cubes)."""
    robot = load_robot(
        DATA / "urdf" / "quadruped_arm.urdf",
        DATA / "srdf" / "quadruped_arm.srdf",
        foot_frames=("FL_foot", "FR_foot", "RL_foot", "RR_foot"),
        ee_frame="ee",
    )
    model, geometry = visual_model(robot)
    assert not [w for w in recwarn if "primitive shapes" in str(w.message)]
    meshes = {g.name: g for g in geometry.geometryObjects if g.meshPath.endswith((".stl", ".obj"))}
    assert meshes["base_0"].meshPath == str((DATA / "meshes" / "cube.stl").resolve())
    assert meshes["FL_leg_0"].meshPath == str((DATA / "urdf" / "meshes" / "cube.obj").resolve())
    assert len(meshes) == 5 and all(g.geometry.num_tris == 12 for g in meshes.values())
    base = meshes["base_0"].geometry  # scaled by the URDF's scale="0.6 0.3 0.15"
    np.testing.assert_allclose(np.ptp(np.asarray(base.vertices()), axis=0), [0.6, 0.3, 0.15], atol=1e-9)


def test_resolve_mesh_path(tmp_path):
    description = tmp_path / "my_robot_description"
    (description / "urdf").mkdir(parents=True)
    (description / "meshes").mkdir()
    mesh = description / "meshes" / "body.stl"
    mesh.write_text("solid empty\nendsolid empty\n")
    urdf = description / "urdf" / "robot.urdf"
    expected = str(mesh.resolve())
    assert resolve_mesh_path("../meshes/body.stl", urdf) == expected
    assert resolve_mesh_path(f"file://{mesh}", urdf) == expected
    # package:// against an ancestor named like the package, or a folder holding the package
    assert resolve_mesh_path("package://my_robot_description/meshes/body.stl", urdf) == expected
    assert resolve_mesh_path(
        "package://my_robot_description/meshes/body.stl", "/elsewhere/r.urdf", [tmp_path]
    ) == (expected)
    assert resolve_mesh_path("package://other/meshes/body.stl", urdf) == "package://other/meshes/body.stl"


# --- replay framing ------------------------------------------------------------------------------------
def test_camera_is_set_from_the_motion_bounds():
    base = np.array([[0.0, 0.0, 0.5], [1.0, 0.2, 0.5], [0.4, -0.2, 0.6]])
    target, position = camera_for_motion(base, robot_radius=0.8)
    np.testing.assert_allclose(target, [0.5, 0.0, 0.55])  # centre of the base box
    direction = np.asarray(CAMERA_DIRECTION) / np.linalg.norm(CAMERA_DIRECTION)
    np.testing.assert_allclose((position - target) / np.linalg.norm(position - target), direction)
    # The sphere holding the motion (half the box diagonal + the robot radius) fills the vertical view.
    radius = np.linalg.norm([1.0, 0.4, 0.1]) / 2 + 0.8
    assert np.linalg.norm(position - target) == pytest.approx(radius / np.sin(np.radians(CAMERA_FOV / 2)))
    distances = []
    for length in (0.0, 1.0, 3.0):
        line = np.column_stack([np.linspace(0.0, length, 5), np.zeros(5), np.full(5, 0.5)])
        target, position = camera_for_motion(line, robot_radius=0.8)
        np.testing.assert_allclose(target, [length / 2, 0.0, 0.5])
        distances.append(np.linalg.norm(position - target))
    assert distances[0] < distances[1] < distances[2]


def test_replay_frames_the_motion(viewer, robot, tmp_path):
    """The nominal pose carried 1 m forward in 2 s: the camera looks at the middle of the path."""
    times = np.linspace(0.0, 2.0, 11)
    qs = np.tile(robot.q_nominal, (len(times), 1))
    qs[:, 0] += np.linspace(0.0, 1.0, len(times))
    viewer.animation(qs, times)
    np.testing.assert_allclose(viewer.camera_target, [robot.q_nominal[0] + 0.5, *robot.q_nominal[1:3]])
    expected = camera_for_motion(qs[:, :3], robot_radius(viewer.model, viewer.geometry, robot.q_nominal))
    np.testing.assert_allclose(viewer.camera_position, expected[1])
    long_distance = np.linalg.norm(viewer.camera_position - viewer.camera_target)
    viewer.animation(qs[:2], times[:2])  # 0.1 m: a closer camera
    assert np.linalg.norm(viewer.camera_position - viewer.camera_target) < long_distance
    assert viewer.export_html(tmp_path / "replay.html").stat().st_size > 10_000


def test_robot_radius_holds_the_robot(robot):
    model, geometry = visual_model(robot)
    radius = robot_radius(model, geometry, robot.q_nominal)
    data = model.createData()
    pin.framesForwardKinematics(model, data, robot.q_nominal)
    reach = max(
        np.linalg.norm(data.oMf[robot.frame_id(f)].translation - robot.q_nominal[:3])
        for f in robot.contact_frames
    )
    assert reach < radius < 2.0


# --- a closed viewer, the notebook view -----------------------------------------------------------------
def test_notebook_view_has_the_live_scene_and_a_snapshot(viewer):
    page = viewer.notebook_view(height=300).data
    assert f'src="{viewer.url}"' in page and "wbmpc-live-scene" in page
    # The static page inline (srcdoc: Chromium refuses data: URLs past 2 MiB), and a picture of the scene,
    # which JupyterLab keeps in an untrusted notebook where it drops every iframe.
    assert 'class="wbmpc-static-scene"' in page and "srcdoc=" in page and "data:text/html" not in page
    assert '<img class="wbmpc-scene-picture" src="data:image/png;base64,' in page
    assert len(viewer.notebook_view(snapshot=False).data) < 1000


def test_a_closed_viewer_says_so(robot, plan):
    try:
        closed = Viewer(robot)
    except ViewerUnavailableError as exc:
        pytest.skip(f"meshcat's zmq server cannot start on this machine: {exc}")
    closed.close()
    closed.close()  # twice is fine
    assert closed.closed
    for call in (lambda: closed.show_plan(plan), lambda: closed.display(robot.q_nominal), closed.static_html):
        with pytest.raises(ViewerUnavailableError, match=r"closed \(Viewer.close\(\)"):
            call()


# --- the re-solve panel -----------------------------------------------------------------------------------
class _FakeMPC:
    """Solves instantly: a fake plan whose base velocity is the commanded one."""

    def __init__(self, robot):
        from types import SimpleNamespace

        self.robot, self.config, self.resets, self.calls = robot, SimpleNamespace(Q=None, R=None), 0, []

    def reset(self):
        self.resets += 1

    def solve(self, q, v, t, commands):
        from types import SimpleNamespace

        self.calls.append(commands)
        plan = fake_plan(self.robot)
        velocities = np.zeros((len(plan.q), self.robot.nv))
        velocities[:, 0] = commands.base_linear_velocity[0]
        return SimpleNamespace(**vars(plan), v=velocities)


def test_resolve_panel_solves_on_release_and_says_what_changed(robot):
    from wbmpc.control.mpc import Commands, default_weights
    from wbmpc.viz.widgets import ReSolvePanel

    mpc = _FakeMPC(robot)
    panel = ReSolvePanel(
        mpc, robot, Commands(base_linear_velocity=np.array([0.2, 0.0, 0.0])), default_weights(robot)
    )
    assert panel.sliders["speed"].value == pytest.approx(0.2) and not panel.sliders["speed"].continuous_update
    panel.resolve(cold=True)
    assert panel.solves == 1 and mpc.resets == 1 and panel.plot.value[:8] == b"\x89PNG\r\n\x1a\n"
    assert "No 3-D view" in panel.status.value
    panel.sliders["speed"].value = 0.35  # a release: no event loop here, so it solves at once, warm
    assert panel.solves == 2 and mpc.resets == 1
    assert mpc.calls[-1].base_linear_velocity[0] == pytest.approx(0.35)
    assert "v_x: 0.2 → 0.35 m/s" in panel.status.value and "warm start" in panel.status.value
    panel.sliders["q_height"].value = 10.0**4
    assert mpc.config.Q[2] == pytest.approx(1e4) and "Q height" in panel.status.value


def test_resolve_panel_says_why_the_3d_view_did_not_follow(robot):
    from wbmpc.control.mpc import Commands, default_weights
    from wbmpc.viz.widgets import ReSolvePanel

    class Closed:
        def show_plan(self, plan):
            raise ViewerUnavailableError("this viewer was closed (Viewer.close() stopped its meshcat server)")

    panel = ReSolvePanel(_FakeMPC(robot), robot, Commands(), default_weights(robot), viewer=Closed())
    panel.resolve()
    assert "3-D view not updated" in panel.status.value and "Viewer.close()" in panel.status.value


# --- known-harmless native output ---------------------------------------------------------------------------
def test_line_filter_drops_only_the_known_harmless_lines():
    from wbmpc.viz.quiet import LineFilter

    f = LineFilter()
    header = b"b3Warning[examples/Importers/ImportURDFDemo/BulletUrdfImporter.cpp,467]:\n"
    base = b"Bad inertia tensor properties, setting inertia to zero for link: base\n"
    trunk = b"Bad inertia tensor properties, setting inertia to zero for link: trunk\n"
    assert f.feed(b"pybullet build time: Jan 29 2025 23:17:20\n") == []
    assert f.feed(header) == [] and f.feed(base) == []
    assert f.feed(header) == [] and f.feed(trunk) == [header, trunk]  # another link: kept
    assert f.feed(header) == [] and f.feed(b"some other warning\n") == [header, b"some other warning\n"]
    assert f.feed(b"ordinary line\n") == [b"ordinary line\n"]
    assert f.feed(header) == [] and f.flush() == [header]
    assert f.dropped == 3


def test_quiet_known_native_output_in_a_child_process():
    import subprocess
    import sys

    code = (
        "import os\n"
        "from wbmpc.viz.quiet import quiet_known_native_output\n"
        "quiet_known_native_output()\n"
        "os.write(2, b'pybullet build time: now\\n')\n"
        "os.write(1, b'b3Warning[x.cpp,1]:\\n')\n"
        "os.write(1, b'Bad inertia tensor properties, setting inertia to zero for link: base\\n')\n"
        "os.write(2, b'a real warning\\n')\n"
        "os.write(1, b'kept\\n')\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=60, check=True)
    assert done.stdout == b"kept\n"
    assert done.stderr == b"a real warning\n"
