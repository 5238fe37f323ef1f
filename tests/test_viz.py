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
