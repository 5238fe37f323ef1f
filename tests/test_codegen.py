"""Generated NLP functions: exact derivatives, node-independent code size, compiled solve, cache."""

import os
import signal
import subprocess
import sys
import time

import casadi as ca
import numpy as np
import pinocchio as pin
import pytest

from wbmpc.control.mpc import MPCConfig, SolverSettings, WholeBodyMPC
from wbmpc.model.robot import (
    B1_Z1_EE_FRAME,
    B1_Z1_LOCKED_JOINTS,
    UNITREE_FOOT_FRAMES,
    example_robot_data_dir,
    load_b1,
    load_b1_z1,
    load_robot,
)
from wbmpc.ocp import OCP, OCPSettings
from wbmpc.ocp.gait import make_gait
from wbmpc.solver import codegen

FLAGS = ("-O0",)  # quick to compile in CI; the benchmark uses the default -O1
SMALL = OCPSettings(n_nodes=3, n_tau_nodes=1)


@pytest.fixture(scope="module")
def small_ocp():
    return OCP(load_b1(), OCPSettings(n_nodes=3, n_tau_nodes=1))


def test_generated_functions_equal_casadi_derivatives():
    """Each assembled function equals what CasADi derives from the monolithic symbolic NLP."""
    ocp = OCP(load_b1_z1(), OCPSettings(n_nodes=5, n_tau_nodes=2))
    functions = {f.name(): f for f in codegen.nlp_functions(ocp)}
    x, p = ocp.nlp["x"], ocp.nlp["p"]
    lam_f, lam_g = ca.SX.sym("lam_f"), ca.SX.sym("lam_g", ocp.n_constraints)
    lagrangian = lam_f * ocp.nlp["f"] + ca.dot(lam_g, ocp.nlp["g"])
    reference = ca.Function(
        "reference",
        [x, p, lam_f, lam_g],
        [
            ocp.nlp["f"],
            ocp.nlp["g"],
            ca.gradient(ocp.nlp["f"], x),
            ca.jacobian(ocp.nlp["g"], x),
            ca.gradient(lagrangian, x),
            ca.hessian(lagrangian, x)[0],
            ca.gradient(lagrangian, p),
        ],
    )
    rng = np.random.default_rng(0)
    xv = 0.05 * rng.normal(size=ocp.n_variables)
    pv = ocp.params.pack(
        {
            name: rng.uniform(0.01, 0.1, size=shape)
            if name in ("dt_min", "dt_max")
            else rng.normal(size=shape)
            for name, (_, shape) in ocp.params.blocks.items()
        }
    )
    pv[ocp.params.blocks["q_hat"][0] + 3 : ocp.params.blocks["q_hat"][0] + 7] = [0, 0, 0, 1]
    lf, lg = 0.7, rng.normal(size=ocp.n_constraints)
    f, g, grad_f, jac_g, grad_l, hess_l, grad_p = (np.array(v) for v in reference(xv, pv, lf, lg))

    def close(a, b):
        np.testing.assert_allclose(np.array(a), b, atol=1e-9 * max(1.0, np.abs(b).max()))

    close(functions["nlp_f"](xv, pv), f)
    close(functions["nlp_g"](xv, pv), g)
    close(functions["nlp_grad_f"](xv, pv), grad_f)
    close(ca.densify(functions["nlp_jac_g"](xv, pv)[1]), jac_g)
    gx, hx = functions["nlp_hess_l"](xv, pv, lf, lg)
    close(gx, grad_l)
    close(ca.densify(hx), hess_l)
    close(functions["nlp_grad"](xv, pv, lf, lg)[3], grad_p)


def test_stage_code_is_not_repeated_per_node(tmp_path):
    robot = load_b1()
    sizes = []
    for n_nodes in (4, 12):
        generator = ca.CodeGenerator(f"nlp_{n_nodes}.c")
        for function in codegen.nlp_functions(OCP(robot, OCPSettings(n_nodes=n_nodes, n_tau_nodes=2))):
            generator.add(function)
        generator.generate(str(tmp_path) + "/")
        sizes.append((tmp_path / f"nlp_{n_nodes}.c").stat().st_size)
    # Only per-node calls and sparsity patterns grow (~40 kB/node); a stage's code (~1.5 MB) is not copied.
    per_node = (sizes[1] - sizes[0]) / 8
    assert per_node < 0.02 * sizes[0], sizes


def _solve_in_process_and_compiled(robot, cache, monkeypatch):
    """The same stand solve in process and with the compiled library of ``cache``."""
    monkeypatch.setenv("WBMPC_CACHE_DIR", str(cache))
    plans = []
    for compiled in (False, True):
        config = MPCConfig(gait=make_gait("stand"), dt_max=0.02)
        mpc = WholeBodyMPC(robot, SMALL, config, SolverSettings(compiled=compiled, compile_flags=FLAGS))
        mpc.verbose = False
        plans.append(mpc.solve(robot.q_nominal, np.zeros(robot.nv)))
    in_process, compiled = plans
    assert in_process.success and compiled.success
    assert compiled.iterations == in_process.iterations
    np.testing.assert_allclose(compiled.w, in_process.w, atol=1e-8)
    return mpc


def test_compiled_solver_matches_in_process(shared_cache, monkeypatch):
    mpc = _solve_in_process_and_compiled(load_b1(), shared_cache, monkeypatch)
    stats = mpc._solver(cold=True).stats()
    assert list(stats["nu"]) == mpc.ocp.stage_sizes()["nu"]  # Fatrop found the stages in the library too


def test_cache_reuses_rebuilds_on_change_and_survives_truncation(small_ocp, tmp_path):
    first = codegen.build(small_ocp, FLAGS, directory=tmp_path, progress=False)
    assert first.rebuilt and first.library.is_file()
    again = codegen.build(small_ocp, FLAGS, directory=tmp_path, progress=False)
    assert not again.rebuilt and again.library == first.library
    # A truncated library (e.g. a killed copy) is detected by its checksum and rebuilt.
    data = first.library.read_bytes()
    first.library.write_bytes(data[: len(data) // 2])
    repaired = codegen.build(small_ocp, FLAGS, directory=tmp_path, progress=False)
    assert repaired.rebuilt and repaired.library.read_bytes() != data[: len(data) // 2]
    ca.external("nlp_hess_l", str(repaired.library))
    # Anything that changes the generated code changes the key.
    key_flags, _ = codegen.cache_key(small_ocp, ("-O2",))
    key_nodes, _ = codegen.cache_key(OCP(load_b1(), OCPSettings(n_nodes=4, n_tau_nodes=1)), FLAGS)
    assert len({first.key, key_flags, key_nodes}) == 3


def test_compiled_needs_fatrop():
    with pytest.raises(ValueError, match="compiled needs solver='fatrop'"):
        SolverSettings(solver="ipopt", compiled=True)


# --- the cache key covers the numeric model -----------------------------------------------------------------
def _move_frame(robot, name, offset):
    frame = robot.model.frames[robot.model.getFrameId(name)]
    frame.placement = pin.SE3(frame.placement.rotation, frame.placement.translation + np.asarray(offset))


def _edit_inertia(robot, joint, mass=0.0, lever=(0.0, 0.0, 0.0), scale=1.0):
    j = robot.model.getJointId(joint)
    old = robot.model.inertias[j]
    robot.model.inertias[j] = pin.Inertia(old.mass + mass, old.lever + np.asarray(lever), scale * old.inertia)


def _move_joint(robot, joint, offset):
    j = robot.model.getJointId(joint)
    old = robot.model.jointPlacements[j]
    robot.model.jointPlacements[j] = pin.SE3(old.rotation, old.translation + np.asarray(offset))


def _rotate_joint(robot, joint, axis, angle):
    """Turn a joint's placement in its parent by ``angle`` [rad] about ``axis``, its origin unmoved."""
    j = robot.model.getJointId(joint)
    old = robot.model.jointPlacements[j]
    turn = pin.AngleAxis(angle, np.asarray(axis, dtype=float)).matrix()
    robot.model.jointPlacements[j] = pin.SE3(old.rotation @ turn, old.translation)


def _rotate_frame(robot, name, axis, angle):
    """Turn a frame's placement by ``angle`` [rad] about ``axis``, its origin unmoved."""
    frame = robot.model.frames[robot.model.getFrameId(name)]
    turn = pin.AngleAxis(angle, np.asarray(axis, dtype=float)).matrix()
    frame.placement = pin.SE3(frame.placement.rotation @ turn, frame.placement.translation)


def _set_gravity(robot, g):
    robot.model.gravity = pin.Motion(np.array([0.0, 0.0, -g]), np.zeros(3))


def _b1_z1_locked_at(joint5):
    """B1 + Z1 with the locked ``joint5`` held at ``joint5`` [rad] (the SRDF poses all hold it at 0)."""
    robots = example_robot_data_dir()
    urdf = robots / "b1_description/urdf/b1-z1.urdf"
    full = pin.buildModelFromUrdf(str(urdf), pin.JointModelFreeFlyer())
    pin.loadReferenceConfigurations(full, str(robots / "b1_description/srdf/b1-z1.srdf"), False)
    q = full.referenceConfigurations["standing_with_arm_up"].copy()
    q[full.joints[full.getJointId("joint5")].idx_q] = joint5
    return load_robot(
        urdf,
        foot_frames=UNITREE_FOOT_FRAMES,
        ee_frame=B1_Z1_EE_FRAME,
        locked_joints=B1_Z1_LOCKED_JOINTS,
        q_reference=q,
        extra_frames={B1_Z1_EE_FRAME: ("gripperMover", (0.05, 0.0, 0.0))},
    )


def _scale_limit(robot, limits, joint, factor):
    """Scale one joint's entry of ``model.<limits>`` (e.g. ``effortLimit``)."""
    joint_model = robot.model.joints[robot.model.getJointId(joint)]
    values = getattr(robot.model, limits).copy()
    values[joint_model.idx_q if "Position" in limits else joint_model.idx_v] *= factor
    setattr(robot.model, limits, values)


# (loader, change of the loaded robot, description entries that must report it)
MODEL_CHANGES = {
    "gravity": (load_b1, lambda r: _set_gravity(r, 9.0), {"gravity", "model.digests.gravity"}),
    "link_mass": (
        load_b1,
        lambda r: _edit_inertia(r, "FL_calf_joint", mass=0.1),
        {"mass", "model.items.inertias.FL_calf_joint"},
    ),
    "link_rotational_inertia": (
        load_b1,
        lambda r: _edit_inertia(r, "FL_calf_joint", scale=1.1),
        {"model.items.inertias.FL_calf_joint"},
    ),
    "link_com": (
        load_b1,
        lambda r: _edit_inertia(r, "RR_thigh_joint", lever=(0.01, 0.0, 0.0)),
        {"model.items.inertias.RR_thigh_joint"},
    ),
    "joint_placement": (
        load_b1,
        lambda r: _move_joint(r, "FR_thigh_joint", (0.0, 0.005, 0.0)),
        {"model.items.joints.FR_thigh_joint"},
    ),
    "foot_frame": (
        load_b1,
        lambda r: _move_frame(r, "FL_foot", (0.0, 0.0, -0.01)),
        {"model.items.frames.FL_foot"},
    ),
    "gripper_center": (
        load_b1_z1,
        lambda r: _move_frame(r, "gripper_center", (0.03, 0.0, 0.0)),
        {"model.items.frames.gripper_center"},
    ),
    "position_limit": (
        load_b1,
        lambda r: _scale_limit(r, "upperPositionLimit", "FL_thigh_joint", 0.9),
        {"model.items.limits.FL_thigh_joint"},
    ),
    "velocity_limit": (
        load_b1,
        lambda r: _scale_limit(r, "velocityLimit", "RL_calf_joint", 0.5),
        {"model.items.limits.RL_calf_joint"},
    ),
    "torque_limit": (
        load_b1,
        lambda r: _scale_limit(r, "effortLimit", "RL_calf_joint", 0.5),
        {"model.items.limits.RL_calf_joint"},
    ),
    "foot_radius": (load_b1, lambda r: setattr(r, "foot_radius", 0.05), {"foot_radius"}),
    # A calibration's rotor inertia: RNEA, CRBA and ABA add it, so the generated code changes.
    "armature": (
        load_b1,
        lambda r: r.model.armature.__setitem__(r.joint_index_v("FL_calf_joint"), 0.04),
        {"model.items.armature.FL_calf_joint"},
    ),
    # Rotations alone (the origins stay): the placement's rotation is part of the generated kinematics.
    "joint_rotation": (
        load_b1,
        lambda r: _rotate_joint(r, "FR_thigh_joint", (1.0, 0.0, 0.0), 0.02),
        {"model.items.joints.FR_thigh_joint"},
    ),
    "frame_rotation": (
        load_b1_z1,
        lambda r: _rotate_frame(r, "gripper_center", (0.0, 0.0, 1.0), 0.02),
        {"model.items.frames.gripper_center"},
    ),
    # Changes far below any rounding a careless fingerprint might do (a few significant digits).
    "tiny_mass": (
        load_b1,
        lambda r: _edit_inertia(r, "FL_calf_joint", mass=1e-6),
        {"mass", "model.items.inertias.FL_calf_joint"},
    ),
    "tiny_rotational_inertia": (
        load_b1,
        lambda r: _edit_inertia(r, "RL_thigh_joint", scale=1.0 + 1e-6),
        {"model.items.inertias.RL_thigh_joint"},
    ),
    "lower_position_limit": (
        load_b1,
        lambda r: _scale_limit(r, "lowerPositionLimit", "RR_hip_joint", 0.9),
        {"model.items.limits.RR_hip_joint"},
    ),
    "tiny_joint_offset": (
        load_b1,
        lambda r: _move_joint(r, "RR_calf_joint", (0.0, 0.0, 1e-7)),
        {"model.items.joints.RR_calf_joint"},
    ),
}


@pytest.mark.parametrize("change", list(MODEL_CHANGES))
def test_cache_key_changes_with_the_numeric_model(change):
    loader, edit, expected = MODEL_CHANGES[change]
    key, before = codegen.cache_key(OCP(loader(), SMALL), FLAGS)
    robot = loader()
    edit(robot)
    changed_key, after = codegen.cache_key(OCP(robot, SMALL), FLAGS)
    assert changed_key != key
    changes = codegen.describe_changes(before, after)
    assert expected <= set(changes), changes  # the record says what changed ...
    # ... and only that: an item whose digest changed with it would mean items that share numbers.
    items = {c for c in changes if c.startswith("model.items.")}
    assert items == {e for e in expected if e.startswith("model.items.")}, changes
    assert all(c.split(".")[0] in {"gravity", "mass", "foot_radius", "model"} for c in changes), changes
    # ... and the same change made again gives the same key (the fingerprint is canonical).
    again = loader()
    edit(again)
    assert codegen.cache_key(OCP(again, SMALL), FLAGS)[0] == changed_key


def test_canonical_numbers_and_digests():
    """The fingerprint's text of a float: 12 significant digits (reloading noise is no change), no negative
    zero; digests independent of the order a dict was built in; a 16-hex-digit key."""
    assert codegen._number(-0.0) == codegen._number(0.0) == "0"
    assert codegen._number(1.0) == "1" and codegen._number(-2.5) == "-2.5"
    assert codegen._number(0.1 + 0.2) == "0.3" and codegen._number(1.0 + 1e-10) == "1.0000000001"
    assert codegen._digest({"a": 1, "b": [2.0]}, 16) == codegen._digest({"b": [2.0], "a": 1}, 16)
    key, description = codegen.cache_key(OCP(load_b1(), SMALL), FLAGS)
    assert len(key) == 16 and int(key, 16) >= 0
    assert len(description["model"]["digests"]["joints"]) == 12


def _hinge_model(axis=(1.0, 0.0, 0.0), tip=0.5, gravity_angular=(0.0, 0.0, 0.0)):
    """One unaligned revolute joint with a body, a ``tip`` BODY frame and a ``tip`` OP_FRAME (Pinocchio
    keeps frames of one name apart by their type)."""
    model = pin.Model()
    axis = np.asarray(axis, dtype=float)
    j = model.addJoint(
        0, pin.JointModelRevoluteUnaligned(axis / np.linalg.norm(axis)), pin.SE3.Identity(), "hinge"
    )
    model.appendBodyToJoint(j, pin.Inertia.FromSphere(1.0, 0.1), pin.SE3.Identity())
    body = pin.SE3(np.eye(3), np.array([0.0, 0.0, tip]))
    model.addFrame(pin.Frame("tip", j, body, pin.FrameType.BODY))
    model.addFrame(pin.Frame("tip", j, pin.SE3(np.eye(3), np.array([0.0, 0.0, 0.7])), pin.FrameType.OP_FRAME))
    model.gravity = pin.Motion(np.array([0.0, 0.0, -9.81]), np.asarray(gravity_angular, dtype=float))
    return model


def test_the_fingerprint_covers_joint_axes_repeated_frame_names_and_angular_gravity():
    """Numbers a B1 never exercises: the axis of an unaligned joint, a frame whose name another frame
    shares, the angular part of the gravity Motion; each changes the fingerprint, the same model does not."""
    fingerprint = codegen.model_fingerprint
    base = fingerprint(_hinge_model())
    assert fingerprint(_hinge_model()) == base
    assert len(base["frames"]) == 3  # universe and both frames named tip, kept apart
    for changed in (
        _hinge_model(axis=(1.0, 0.01, 0.0)),
        _hinge_model(tip=0.51),
        _hinge_model(gravity_angular=(0.0, 0.0, 0.1)),
    ):
        assert codegen._digest(fingerprint(changed), 16) != codegen._digest(base, 16)


def test_the_urdf_text_is_part_of_the_key(tmp_path):
    """A URDF copy with one comment more: the same numeric model, another file, so another key (the record
    names the file hash only); a robot whose URDF is gone still has a key."""
    robots = example_robot_data_dir()
    urdf = tmp_path / "b1.urdf"
    urdf.write_text((robots / "b1_description/urdf/b1.urdf").read_text() + "\n<!-- a comment -->\n")
    srdf = robots / "b1_description/srdf/b1.srdf"
    copy = load_robot(
        urdf, srdf, foot_frames=UNITREE_FOOT_FRAMES, reference_pose="standing", name="Unitree B1"
    )
    key, before = codegen.cache_key(OCP(load_b1(), SMALL), FLAGS)
    copy_key, after = codegen.cache_key(OCP(copy, SMALL), FLAGS)
    assert copy_key != key and codegen.describe_changes(before, after) == ["urdf_sha256"]
    urdf.unlink()
    gone_key, gone = codegen.cache_key(OCP(copy, SMALL), FLAGS)
    assert gone["urdf_sha256"] is None and gone_key not in (key, copy_key)


def test_cache_key_changes_with_a_locked_joint_value():
    key, before = codegen.cache_key(OCP(_b1_z1_locked_at(0.0), SMALL), FLAGS)
    changed_key, after = codegen.cache_key(OCP(_b1_z1_locked_at(0.3), SMALL), FLAGS)
    assert changed_key != key
    changes = set(codegen.describe_changes(before, after))
    # The locked body now hangs differently from joint4: its inertia and the gripper frame moved.
    assert {
        "locked_joints.joint5",
        "model.items.inertias.joint4",
        "model.items.frames.gripper_center",
    } <= changes


def test_cache_key_changes_with_the_ocp_settings():
    key, _ = codegen.cache_key(OCP(load_b1(), SMALL), FLAGS)
    settings = OCPSettings(n_nodes=3, n_tau_nodes=2)
    assert codegen.cache_key(OCP(load_b1(), settings), FLAGS)[0] != key


def test_reloading_the_same_robot_gives_the_same_key():
    for loader in (load_b1, load_b1_z1):
        first, description = codegen.cache_key(OCP(loader(), SMALL), FLAGS)
        second, again = codegen.cache_key(OCP(loader(), SMALL), FLAGS)
        assert first == second and codegen.describe_changes(description, again) == []


@pytest.mark.parametrize(
    ("loader", "edit"),
    [
        (load_b1, lambda r: _set_gravity(r, 9.0)),
        (load_b1_z1, lambda r: _move_frame(r, "gripper_center", (0.03, 0.0, 0.02))),
    ],
    ids=["gravity", "gripper_center"],
)
def test_compiled_solver_matches_in_process_after_a_model_change(loader, edit, shared_cache, monkeypatch):
    """With the original model's library in the cache, the changed model gets its own library."""
    original = codegen.build(OCP(loader(), SMALL), FLAGS, directory=shared_cache, progress=False)
    robot = loader()
    edit(robot)
    mpc = _solve_in_process_and_compiled(robot, shared_cache, monkeypatch)
    assert mpc.compiled_nlp.key != original.key and mpc.compiled_nlp.rebuilt


# --- temporary folders of killed builds -------------------------------------------------------------------
_BUILD_SCRIPT = """
import sys
from wbmpc.solver import codegen
from wbmpc.ocp import OCP, OCPSettings
from wbmpc.model.robot import load_b1
ocp = OCP(load_b1(), OCPSettings(n_nodes=3, n_tau_nodes=1))
codegen.build(ocp, ("-O0",), directory=sys.argv[1], progress=False)
"""


def _temporaries(folder):
    return sorted(p for p in folder.iterdir() if p.is_dir()) if folder.is_dir() else []


def test_killed_build_leaves_no_stale_temporary(small_ocp, tmp_path):
    key, _ = codegen.cache_key(small_ocp, FLAGS)
    folder = tmp_path / key
    # A build in another process, killed while it works in its temporary folder.
    builder = subprocess.Popen([sys.executable, "-c", _BUILD_SCRIPT, str(tmp_path)], start_new_session=True)
    try:
        deadline = time.monotonic() + 120.0
        while not _temporaries(folder):
            assert builder.poll() is None and time.monotonic() < deadline, "the build never started"
            time.sleep(0.05)
        live = _temporaries(folder)
        # While it runs, nobody else may remove its temporary folder.
        assert codegen.remove_stale_builds(tmp_path) == []
        assert _temporaries(folder) == live
    finally:
        os.killpg(builder.pid, signal.SIGKILL)  # the builder and its gcc, if any
        builder.wait()
    assert _temporaries(folder) == live  # killed: the folder stays behind
    # Leftovers of another key, one from an older wbmpc (tempfile's default name), are swept as well.
    other = tmp_path / "0123456789abcdef"
    (other / ".build-1-x").mkdir(parents=True)
    (other / "tmpabc123").mkdir()
    (other / ".lock").touch()
    built = codegen.build(small_ocp, FLAGS, directory=tmp_path, progress=False)
    assert built.rebuilt and built.key == key
    assert _temporaries(folder) == [] and _temporaries(other) == []
    ca.external("nlp_hess_l", str(built.library))
