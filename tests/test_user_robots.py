"""Robots that are not the default: a small quadruped with an arm from ``tests/data/quadruped_arm``.

Covers the mass and inertia checks of the loader (each against what PyBullet does with such a link,
measured in DIRECT mode), the default pose taken in the SRDF's order, and the plant loading the same masses.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from wbmpc.model.errors import RobotModelWarning
from wbmpc.model.inertials import check_for_pybullet
from wbmpc.model.robot import RobotModelError, load_robot

DATA = Path(__file__).parent / "data" / "quadruped_arm"
URDF = DATA / "urdf" / "quadruped_arm.urdf"
SRDF = DATA / "srdf" / "quadruped_arm.srdf"
FEET = ("FL_foot", "FR_foot", "RL_foot", "RR_foot")
BOX_INERTIA = {"ixx": "0.01", "ixy": "0", "ixz": "0", "iyy": "0.02", "iyz": "0", "izz": "0.025"}


def _load(urdf: Path = URDF, srdf: Path | None = SRDF, **kwargs):
    return load_robot(urdf, srdf, foot_frames=FEET, ee_frame="ee", **kwargs)


def _edited_urdf(tmp_path: Path, edits: dict[str, dict | None]) -> Path:
    """A copy of the test URDF (next to it, so relative meshes still resolve) with link inertials edited.

    ``edits`` maps a link name to ``None`` (remove its ``<inertial>``) or to ``{"mass": value, "<attribute>":
    value}`` (set the mass and ``<inertia>`` attributes; a value of ``None`` deletes that attribute).
    """
    root = ET.parse(URDF).getroot()
    for link in root.iter("link"):
        edit = edits.get(link.get("name"), "keep")
        if edit == "keep":
            continue
        inertial = link.find("inertial")
        if edit is None:
            link.remove(inertial)
            continue
        for key, value in edit.items():
            element, attribute = (
                (inertial.find("mass"), "value") if key == "mass" else (inertial.find("inertia"), key)
            )
            if value is None:
                del element.attrib[attribute]
            else:
                element.set(attribute, str(value))
    path = tmp_path / "urdf" / "robot.urdf"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(ET.tostring(root, encoding="unicode"))
    return path


# --- the test robot ------------------------------------------------------------------------------------
def test_third_party_robot_loads():
    robot = _load()
    assert (robot.nq, robot.nv) == (13, 12)
    assert robot.arm_joint_names == ["arm_joint1", "arm_joint2"]
    assert robot.foot_radius == pytest.approx(0.02)
    assert robot.mass == pytest.approx(12 + 4 * 1.05 + 1 + 0.5)
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, robot.q_nominal)
    heights = [data.oMf[robot.frame_id(f)].translation[2] for f in FEET]
    np.testing.assert_allclose(heights, robot.foot_radius, atol=1e-12)


def test_default_pose_is_the_first_whole_robot_pose_in_file_order():
    """The SRDF lists arm_tucked (arm only), stand, crouch: "stand" is the default, not "arm_tucked" (the
    file's first, but it does not place the base) nor "crouch" (the first whole-robot pose by name)."""
    robot = _load()
    assert robot.default_pose == "stand"
    assert list(robot.reference_poses) == ["stand", "crouch", "arm_tucked"]
    assert robot.q_nominal[-1] == pytest.approx(-0.5)  # arm_joint2 in "stand"
    assert _load(reference_pose="crouch").default_pose == "crouch"


def test_default_pose_without_a_base_entry_is_the_first_in_the_file(tmp_path):
    srdf = tmp_path / "poses.srdf"
    srdf.write_text(
        '<robot name="quadruped_arm">'
        '<group_state name="zeta" group="legs"><joint name="FL_hip_joint" value="0.1"/></group_state>'
        '<group_state name="alpha" group="legs"><joint name="FL_hip_joint" value="0.2"/></group_state>'
        "</robot>"
    )
    robot = _load(srdf=srdf)
    assert robot.default_pose == "zeta"
    assert robot.q_nominal[robot.joint_index_v("FL_hip_joint") + 1] == pytest.approx(0.1)


# --- mass and inertia checks ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("edits", "message"),
    [
        (
            {"imu": None},
            r"link 'imu' has no <inertial>: Pinocchio makes it massless, but PyBullet gives it a mass of "
            "1 kg",
        ),
        ({"FL_leg": None}, r"link 'FL_leg' has no <inertial>"),
        (
            {"arm_link2": {"ixx": 0.001, "iyy": 0.001, "izz": 0.01}},
            r"link 'arm_link2' has inertia \(ixx=0.001, .*break the triangle inequality "
            r"0.001 \+ 0.001 >= 0.01, so PyBullet replaces it with zero",
        ),
        ({"FR_leg": {"ixx": -0.01}}, r"link 'FR_leg' has inertia .* are not all positive"),
        (
            {"base": {"mass": 0, **dict.fromkeys(("ixx", "iyy", "izz"), 0)}},
            r"root link 'base' has zero mass: PyBullet would weld it",
        ),
        ({"RL_leg": {"izz": None}}, r"link 'RL_leg' has a malformed <inertial> \(<inertia> lacks izz\)"),
        (
            {"RL_leg": {"mass": "heavy"}},
            r"link 'RL_leg' has a malformed <inertial> \(mass='heavy' is not a number\)",
        ),
        ({"RL_leg": {"mass": "nan"}}, r"mass='nan' is not finite"),
        ({"RR_leg": {"mass": -1}}, r"link 'RR_leg' has a negative mass \(-1 kg\)"),
        (
            {
                "FL_leg": {"mass": 0, **dict.fromkeys(("ixx", "iyy", "izz"), 0)},
                "FL_foot": {"mass": 0, "ixx": 0, "iyy": 0, "izz": 0},
            },
            r"the body moved by joint 'FL_hip_joint' \(links FL_leg, FL_foot\) has mass 0 kg "
            r".* needs a positive mass",
        ),
        ({"imu": None, "FL_leg": None}, r"2 problems with link masses or inertias"),
    ],
    ids=[
        "missing-fixed",
        "missing-moving",
        "triangle",
        "negative-moment",
        "massless-root",
        "malformed",
        "not-a-number",
        "nan",
        "negative-mass",
        "massless-body",
        "all-listed",
    ],
)
def test_unusable_inertials_are_named(tmp_path, edits, message, request):
    """Problems only PyBullet has (missing inertial, a tensor it zeroes) are a warning of the loader and an
    error of the PyBullet side; the others (a model nobody can use) an error of the loader."""
    urdf = _edited_urdf(tmp_path, edits)
    if request.node.callspec.id in PYBULLET_ONLY:
        with pytest.warns(RobotModelWarning, match=message):
            assert _load(urdf).inertial_problems
        with pytest.raises(RobotModelError, match=message):
            check_for_pybullet(urdf)
        with pytest.raises(RobotModelError, match=message):
            _load(urdf, inertia_checks="error")
    else:
        with pytest.raises(RobotModelError, match=message):
            _load(urdf)


# The cases only PyBullet refuses (the loader warns).
PYBULLET_ONLY = {"missing-fixed", "missing-moving", "triangle", "all-listed"}


def test_error_says_how_to_fix_a_missing_inertial(tmp_path):
    with pytest.raises(RobotModelError) as error:
        check_for_pybullet(_edited_urdf(tmp_path, {"imu": None}))
    text = str(error.value)
    assert text.startswith(f"{tmp_path / 'urdf' / 'robot.urdf'}: 1 problem")
    assert '<inertial><mass value="0"/><inertia ixx="0"' in text


@pytest.mark.parametrize(
    "edits",
    [
        # A massless moving link is fine when a link fixed to it carries the mass (one rigid body).
        {"FL_leg": {"mass": 0, "ixx": 0, "iyy": 0, "izz": 0}, "FL_foot": {"mass": 1, **BOX_INERTIA}},
        # A placeholder tensor (like the B1's root link) on a much larger rigid body is negligible.
        {"imu": {"mass": 1e-6, **dict.fromkeys(("ixx", "ixy", "ixz", "iyy", "iyz", "izz"), 1e-6)}},
        # A point mass on a fixed link (zero tensor): PyBullet keeps it as written.
        {"FL_foot": {"mass": 0.05, "ixx": 0, "iyy": 0, "izz": 0}},
    ],
    ids=["massless-link-with-fixed-mass", "negligible-placeholder", "point-mass-on-fixed-link"],
)
def test_sound_inertials_are_accepted(tmp_path, edits):
    assert _load(_edited_urdf(tmp_path, edits)).nv == 12


def test_locked_joints_merge_rigid_bodies(tmp_path):
    """A massless leaf on a moving joint is singular, but fine once that joint is locked."""
    urdf = _edited_urdf(tmp_path, {"arm_link2": {"mass": 0, "ixx": 0, "iyy": 0, "izz": 0}})
    with pytest.raises(RobotModelError, match="the body moved by joint 'arm_joint2'"):
        _load(urdf)
    robot = _load(urdf, locked_joints=("arm_joint2",))
    assert robot.nv == 11 and robot.locked_joints["arm_joint2"] == pytest.approx(-0.5)


# --- what PyBullet does, measured (the reasons for the checks) ----------------------------------------
BOX = '<inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/>'


def _pybullet(
    tmp_path: Path, child: str, root: str = f'<inertial><mass value="5"/>{BOX}</inertial>', joint="fixed"
):
    """Mass [kg] and principal inertia [kg m^2] PyBullet gives a child link with ``child`` as its inertial,
    and whether the root stays put under gravity (a fixed base), as the plant loads URDFs."""
    import pybullet as p  # pinned in environment.txt: a broken install fails, never skips

    urdf = tmp_path / "probe.urdf"
    urdf.write_text(
        f'<robot name="probe"><link name="root">{root}'
        '<collision><geometry><box size="0.2 0.2 0.2"/></geometry></collision></link>'
        f'<joint name="j" type="{joint}"><parent link="root"/><child link="child"/><axis xyz="0 0 1"/>'
        '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint>'
        f'<link name="child">{child}</link></robot>'
    )
    client = p.connect(p.DIRECT)
    try:
        p.setGravity(0, 0, -9.81, physicsClientId=client)
        body = p.loadURDF(str(urdf), [0, 0, 1], flags=p.URDF_USE_INERTIA_FROM_FILE, physicsClientId=client)
        mass, _, inertia = p.getDynamicsInfo(body, 0, physicsClientId=client)[:3]
        for _ in range(24):
            p.stepSimulation(physicsClientId=client)
        fixed = p.getBasePositionAndOrientation(body, physicsClientId=client)[0][2] == 1.0
        return mass, tuple(inertia), fixed
    finally:
        p.disconnect(client)


@pytest.mark.parametrize("joint", ["fixed", "revolute"])
def test_pybullet_gives_a_link_without_inertial_one_kilogram(tmp_path, joint):
    assert _pybullet(tmp_path, "", joint=joint) == (1.0, (1.0, 1.0, 1.0), False)


def test_pybullet_zeroes_an_inertia_that_breaks_the_triangle_inequality(tmp_path):
    bad = (
        '<inertial><mass value="1"/>'
        '<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.05"/></inertial>'
    )
    assert _pybullet(tmp_path, bad, joint="revolute")[:2] == (1.0, (0.0, 0.0, 0.0))


def test_pybullet_welds_a_massless_root_to_the_world(tmp_path):
    zero = '<inertial><mass value="0"/><inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial>'
    heavy_child = f'<inertial><mass value="5"/>{BOX}</inertial>'
    assert _pybullet(tmp_path, heavy_child, root=zero)[2]


def test_plant_loads_the_masses_of_the_model(tmp_path):
    """The URDF the plant gives PyBullet has, link by link, the mass of the checked model."""
    import pybullet as p  # pinned in environment.txt: a broken install fails, never skips

    from wbmpc.model.urdf import preprocess_urdf

    robot = _load(locked_joints=("arm_joint2",))
    urdf = tmp_path / "plant.urdf"
    urdf.write_text(preprocess_urdf(robot.urdf_path, robot.locked_joints))
    client = p.connect(p.DIRECT)
    try:
        body = p.loadURDF(str(urdf), flags=p.URDF_USE_INERTIA_FROM_FILE, physicsClientId=client)
        links = range(-1, p.getNumJoints(body, physicsClientId=client))
        mass = sum(p.getDynamicsInfo(body, link, physicsClientId=client)[0] for link in links)
    finally:
        p.disconnect(client)
    assert mass == pytest.approx(robot.mass, rel=1e-12)
