"""A lab's own robot, end to end: a generated third-party-like quadruped with an arm whose URDF has the
defects new users meet (links without ``<inertial>``, an inertia tensor that breaks the triangle inequality,
meshes that are not on disk).

Checked: one pass lists every defect; each suggested fix loads (and the triangle fix is the smallest change
to within 10 %); the loader only warns for what only PyBullet would change, the PyBullet side refuses it; the
demo command line runs the robot on the rigid plant as it is and on the PyBullet plant once fixed (short
quick-mode runs), with a clear exit 2 for bad paths and frames before any work; the viewer falls back mesh
by mesh and keeps every link; frame and joint errors name the model alike; a custom gait runs in the MPC.

The robot, ``labdog``: a 16 kg quadruped (hip, thigh and calf joints per leg) with a 3-joint arm ending in a
``gripper`` link, as a lab would receive it from a CAD export:

* links without ``<inertial>``: the root link ``base_link`` (a dummy fixed to the ``trunk``, as in the
  Unitree descriptions), the ``imu_link``, the ``gripper`` and the four feet;
* ``arm_link2``'s tensor breaks the triangle inequality (a wrong product of inertia ``iyz``);
* visual meshes that are not on disk (``package://labdog_description/meshes/...`` and relative paths),
  and one collision mesh; the feet have collision spheres and (missing) visual meshes.
"""

from __future__ import annotations

import re
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from wbmpc.model.errors import RobotModelError, RobotModelWarning
from wbmpc.model.inertials import (
    _inertia_defect,
    _parse_inertial,
    apply_fixes,
    check_for_pybullet,
    inertial_problems,
)
from wbmpc.model.robot import find_contact_frames, load_robot
from wbmpc.model.urdf import preprocess_urdf
from wbmpc.ocp.gait import Gait, GaitSample, GaitSchedule, make_gait

LEGS = {"FL": (0.19, 0.05), "FR": (0.19, -0.05), "RL": (-0.19, 0.05), "RR": (-0.19, -0.05)}
FEET = tuple(f"{leg}_foot" for leg in LEGS)
EE = "gripper"
MISSING_VISUAL_LINKS = ("base_link", "trunk", "arm_link1", "arm_link2", "arm_link3", *FEET) + tuple(
    f"{leg}_{part}" for leg in LEGS for part in ("hip", "thigh", "calf")
)
NO_INERTIAL = ("base_link", "imu_link", "gripper", *FEET)
TRIANGLE_LINK = "arm_link2"


def _inertial(mass, ixx, iyy, izz, xyz="0 0 0", iyz=0.0) -> str:
    return (
        f'<inertial><origin xyz="{xyz}" rpy="0 0 0"/><mass value="{mass}"/>'
        f'<inertia ixx="{ixx}" ixy="0" ixz="0" iyy="{iyy}" iyz="{iyz}" izz="{izz}"/></inertial>'
    )


def _visual(mesh: str, xyz="0 0 0") -> str:
    return f'<visual><origin xyz="{xyz}" rpy="0 0 0"/><geometry><mesh filename="{mesh}"/></geometry></visual>'


def _joint(name, kind, parent, child, xyz, axis="0 1 0", lower=-1.0, upper=1.0, effort=30.0) -> str:
    limit = (
        f'<limit lower="{lower}" upper="{upper}" effort="{effort}" velocity="20"/>' if kind != "fixed" else ""
    )
    axis_xml = f'<axis xyz="{axis}"/>' if kind != "fixed" else ""
    return (
        f'<joint name="{name}" type="{kind}"><origin xyz="{xyz}" rpy="0 0 0"/><parent link="{parent}"/>'
        f'<child link="{child}"/>{axis_xml}{limit}</joint>'
    )


def urdf_text() -> str:
    package = "package://labdog_description/meshes"
    parts = [
        '<?xml version="1.0"?>',
        "<!-- labdog: exported from CAD by a lab; its meshes were not shipped -->",
        '<robot name="labdog">',
        f'<link name="base_link">{_visual(f"{package}/base.dae")}</link>',
        _joint("floating_base_fixed", "fixed", "base_link", "trunk", "0 0 0"),
        f'<link name="trunk">{_inertial(10.0, 0.0453, 0.1453, 0.1667)}'
        f"{_visual('../meshes/trunk.stl')}"
        '<collision><geometry><box size="0.4 0.2 0.12"/></geometry></collision></link>',
        _joint("imu_fixed", "fixed", "trunk", "imu_link", "0 0 0.02"),
        '<link name="imu_link"/>',
    ]
    for leg, (x, y) in LEGS.items():
        side = 1.0 if y > 0 else -1.0
        parts += [
            _joint(
                f"{leg}_hip_joint", "revolute", "trunk", f"{leg}_hip", f"{x} {y} 0", "1 0 0", -0.8, 0.8, 25
            ),
            f'<link name="{leg}_hip">{_inertial(0.6, 0.0004, 0.0006, 0.0005)}'
            f"{_visual(f'{package}/hip.dae')}</link>",
            _joint(
                f"{leg}_thigh_joint",
                "revolute",
                f"{leg}_hip",
                f"{leg}_thigh",
                f"0 {side * 0.08} 0",
                "0 1 0",
                -1.5,
                3.0,
                25,
            ),  # fmt: skip
            f'<link name="{leg}_thigh">{_inertial(0.9, 0.004, 0.004, 0.0006, "0 0 -0.03")}'
            f"{_visual(f'{package}/thigh.dae')}</link>",
            _joint(
                f"{leg}_calf_joint",
                "revolute",
                f"{leg}_thigh",
                f"{leg}_calf",
                "0 0 -0.2",
                "0 1 0",
                -2.7,
                -0.6,
                35,
            ),  # fmt: skip
            f'<link name="{leg}_calf">{_inertial(0.2, 0.0009, 0.0009, 0.00005, "0 0 -0.1")}'
            f"{_visual('meshes/calf.stl')}</link>",
            _joint(f"{leg}_foot_fixed", "fixed", f"{leg}_calf", f"{leg}_foot", "0 0 -0.2"),
            f'<link name="{leg}_foot">{_visual("meshes/foot.stl")}'
            '<collision><geometry><sphere radius="0.02"/></geometry></collision></link>',
        ]
    parts += [
        _joint("arm_joint1", "revolute", "trunk", "arm_link1", "0.1 0 0.06", "0 0 1", -2.6, 2.6, 20),
        f'<link name="arm_link1">{_inertial(0.5, 0.0005, 0.0005, 0.0004, "0 0 0.03")}'
        f"{_visual(f'{package}/arm1.dae')}"
        f'<collision><geometry><mesh filename="{package}/arm1_collision.stl"/></geometry></collision>'
        "</link>",
        _joint("arm_joint2", "revolute", "arm_link1", "arm_link2", "0 0 0.06", "0 1 0", -2.8, 0.5, 20),
        # A CAD export with a wrong product of inertia: principal moments 0.0004, 0.0011, 0.0029 kg m^2
        f'<link name="{TRIANGLE_LINK}">{_inertial(0.4, 0.0004, 0.002, 0.002, "0.12 0 0", iyz=0.0009)}'
        f"{_visual(f'{package}/arm2.dae')}</link>",
        _joint("arm_joint3", "revolute", "arm_link2", "arm_link3", "0.25 0 0", "0 1 0", -0.5, 2.8, 15),
        f'<link name="arm_link3">{_inertial(0.3, 0.0001, 0.0008, 0.0008, "0.1 0 0")}'
        f"{_visual(f'{package}/arm3.dae')}</link>",
        _joint("gripper_fixed", "fixed", "arm_link3", EE, "0.2 0 0"),
        f'<link name="{EE}"/>',
        "</robot>",
    ]
    return "\n".join(parts)


def srdf_text() -> str:
    legs = "".join(
        f'<joint name="{leg}_hip_joint" value="0"/><joint name="{leg}_thigh_joint" value="0.8"/>'
        f'<joint name="{leg}_calf_joint" value="-1.5"/>'
        for leg in LEGS
    )
    return (
        '<?xml version="1.0"?><robot name="labdog">'
        '<group name="whole_body"><joint name="root_joint"/></group>'
        f'<group_state name="stand" group="whole_body"><joint name="root_joint" value="0 0 0.3 0 0 0 1"/>'
        f'{legs}<joint name="arm_joint1" value="0"/><joint name="arm_joint2" value="-0.8"/>'
        '<joint name="arm_joint3" value="1.2"/></group_state></robot>'
    )


def write_robot(folder: Path, urdf: str | None = None, stem: str = "labdog") -> tuple[Path, Path]:
    """Write ``urdf/<stem>.urdf`` (``urdf`` text, default :func:`urdf_text`) and ``srdf/<stem>.srdf``."""
    paths = folder / "urdf" / f"{stem}.urdf", folder / "srdf" / f"{stem}.srdf"
    for path, text in zip(paths, (urdf or urdf_text(), srdf_text()), strict=True):
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return paths


@pytest.fixture(scope="module")
def labdog(tmp_path_factory) -> tuple[Path, Path]:
    return write_robot(tmp_path_factory.mktemp("labdog"))


@pytest.fixture(scope="module")
def fixed_labdog(tmp_path_factory, labdog) -> tuple[Path, Path]:
    """labdog with the first suggested fix of every problem applied (another file stem: ``labdog_fixed``)."""
    fixes = [problem.fixes[0] for problem in inertial_problems(labdog[0])]
    return write_robot(
        tmp_path_factory.mktemp("fixed"), apply_fixes(labdog[0].read_text(), fixes), "labdog_fixed"
    )


def _load(urdf: Path, srdf: Path, **kwargs):
    return load_robot(urdf, srdf, foot_frames=FEET, ee_frame=EE, **kwargs)


def _load_cleanly(urdf: Path, srdf: Path):
    """Load with every RobotModelWarning an error (a fixed URDF must have none)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", RobotModelWarning)
        return _load(urdf, srdf)


# --- one pass, every defect ----------------------------------------------------------------------------
def test_one_pass_lists_every_defect_of_every_link(labdog):
    """Eight defects of two classes (missing inertials, a triangle-inequality break) in one message: the
    loader used to report the missing inertials first and the tensor only after they were fixed."""
    with pytest.warns(RobotModelWarning) as caught:
        robot = _load(*labdog)
    messages = [str(w.message) for w in caught if issubclass(w.category, RobotModelWarning)]
    assert len(messages) == 1 and messages[0].startswith(f"{labdog[0]}: 8 problems")
    assert {p.link for p in robot.inertial_problems} == {*NO_INERTIAL, TRIANGLE_LINK}
    for link in NO_INERTIAL:
        assert f"link {link!r} has no <inertial>" in messages[0]
    assert (
        f"link {TRIANGLE_LINK!r} has inertia" in messages[0]
        and "break the triangle inequality" in messages[0]
    )
    with pytest.raises(RobotModelError) as error:
        check_for_pybullet(labdog[0])
    assert str(error.value).startswith(f"{labdog[0]}: 8 problems")
    assert all(p.pybullet_only for p in robot.inertial_problems)


def test_errors_and_pybullet_defects_come_in_the_same_pass(tmp_path):
    """A malformed inertial (nobody can load it) does not hide the PyBullet-only defects of other links."""
    text = urdf_text().replace('<mass value="0.9"/>', '<mass value="heavy"/>', 1)
    urdf, srdf = write_robot(tmp_path, text)
    with pytest.raises(RobotModelError) as error:
        _load(urdf, srdf)
    message = str(error.value)
    assert message.startswith(f"{urdf}: 9 problems")
    assert "link 'FL_thigh' has a malformed <inertial> (mass='heavy' is not a number)" in message
    assert all(f"link {link!r}" in message for link in (*NO_INERTIAL, TRIANGLE_LINK))


# --- advice that leads somewhere -----------------------------------------------------------------------
def test_the_triangle_fix_is_the_smallest_change_of_one_entry(labdog):
    """arm_link2: ixx = 0.0004, iyy = izz = 0.002, iyz = 0.0009 (principal moments 0.0004, 0.0011, 0.0029).
    Exactly valid at ixx >= 0.0018 or |iyz| <= 0.0002; the advice is that plus a margin, rounded."""
    (problem,) = [p for p in inertial_problems(labdog[0]) if p.link == TRIANGLE_LINK]
    texts = [fix.text for fix in problem.fixes]
    assert texts == ["bring |iyz| under 0.00019 (iyz=0.00019)", "raise ixx by 0.0015 (to 0.0019)"]
    assert (
        "raise ixx by 0.0015 (to 0.0019), or" in problem.message
        or ", or raise ixx by 0.0015" in problem.message
    )
    written = _parse_inertial(_link(labdog[0], TRIANGLE_LINK).find("inertial")).inertia
    index = {"ixx": (0, 0), "iyz": (1, 2)}
    for fix in problem.fixes:
        ((key, value),) = fix.values
        i, j = index[key]
        changed = written.copy()
        changed[i, j] = changed[j, i] = float(value)
        assert _inertia_defect(changed) is None, fix.text
        shy = written.copy()  # 90 % of the suggested change: still invalid (the change is not oversized)
        shy[i, j] = shy[j, i] = written[i, j] + 0.9 * (float(value) - written[i, j])
        assert _inertia_defect(shy) is not None, fix.text


def test_each_suggestion_loads(labdog, tmp_path):
    """Every alternative fix of every problem, with the first fix of each other problem, gives a URDF with
    no problem left that loads without a warning; each fix is in the message as the user reads it."""
    problems = inertial_problems(labdog[0])
    for problem in problems:
        assert problem.fixes, problem.message
        for fix in problem.fixes:
            assert fix.text in problem.message
            if fix.inertial is not None:  # the XML to paste is in the message verbatim
                assert fix.inertial in problem.message
    for k, problem in enumerate(problems):
        for fix in problem.fixes:
            others = [p.fixes[0] for p in problems if p is not problem]
            urdf, srdf = write_robot(
                tmp_path / f"{k}_{len(fix.text)}", apply_fixes(labdog[0].read_text(), [*others, fix])
            )
            assert inertial_problems(urdf) == [], fix.text
            assert _load_cleanly(urdf, srdf).nv == 21
            check_for_pybullet(urdf)


def test_a_moving_body_without_mass_is_an_error_with_fixes_that_load(tmp_path):
    """FL_calf without its inertial: the calf and its foot (no inertial either) are a massless moving body,
    singular for Pinocchio too, so the loader raises; the estimates it suggests load."""
    text = re.sub(r'(<link name="FL_calf">)<inertial>.*?</inertial>', r"\1", urdf_text())
    urdf, srdf = write_robot(tmp_path / "broken", text)
    problems = inertial_problems(urdf)
    with pytest.raises(
        RobotModelError, match=r"the body moved by joint 'FL_calf_joint' \(links FL_calf, FL_foot\)"
    ):
        _load(urdf, srdf, inertia_checks="ignore")
    calf = next(p for p in problems if p.link == "FL_calf" and p.pybullet_only)
    assert "a 0.1 kg, 5 cm cube" in calf.fixes[0].text  # no collision shape to estimate from
    foot = next(p for p in problems if p.link == "FL_foot")
    assert "a solid sphere of water's density" in foot.fixes[0].text  # from its 2 cm collision sphere
    fixed, _ = write_robot(tmp_path / "fixed", apply_fixes(text, [p.fixes[0] for p in problems if p.fixes]))
    assert inertial_problems(fixed) == []


def test_the_root_link_is_not_advised_a_zero_mass(labdog, tmp_path):
    """The zero inertial the loader suggested for every link was then refused for the root link."""
    (root,) = [p for p in inertial_problems(labdog[0]) if p.link == "base_link"]
    masses = [float(re.search(r'<mass value="([^"]+)"', fix.inertial).group(1)) for fix in root.fixes]
    assert masses and all(m > 0 for m in masses)
    zero = '<inertial><mass value="0"/><inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial>'
    text = labdog[0].read_text().replace('<link name="base_link">', f'<link name="base_link">{zero}')
    urdf, _ = write_robot(tmp_path, text)
    assert any("root link 'base_link' has zero mass" in p.message for p in inertial_problems(urdf))


# --- the checks where PyBullet consumes the data ------------------------------------------------------
def test_planning_and_the_rigid_plant_need_no_edit(labdog):
    """The loader warns and returns the robot (Pinocchio's model is as written); the PyBullet side refuses
    with the same list; ``inertia_checks`` makes the loader strict or silent."""
    with pytest.warns(RobotModelWarning, match="the MPC and the rigid plant use the model as written"):
        robot = _load(*labdog)
    assert robot.mass == pytest.approx(18.0)  # massless links massless, as Pinocchio reads them
    with pytest.raises(RobotModelError, match=r"8 problems[\s\S]*the rigid plant \(ContactPlant"):
        preprocess_urdf(labdog[0])
    with pytest.raises(RobotModelError, match="8 problems"):
        _load(*labdog, inertia_checks="error")
    with warnings.catch_warnings():
        warnings.simplefilter("error", RobotModelWarning)
        assert len(_load(*labdog, inertia_checks="ignore").inertial_problems) == 8


def test_the_pybullet_plant_refuses_what_the_loader_warned_about(labdog, fixed_labdog):
    """The check lives where PyBullet consumes the URDF; once fixed, the plant loads it (the missing
    collision mesh named, left out)."""
    from wbmpc.sim.pybullet_plant import PyBulletPlant

    robot = _load(*labdog, inertia_checks="ignore")
    with pytest.raises(RobotModelError, match=r"8 problems[\s\S]*raise ixx by 0\.0015"):
        PyBulletPlant(robot)
    fixed = _load_cleanly(*fixed_labdog)
    with pytest.warns(UserWarning, match="arm1_collision.stl"), PyBulletPlant(fixed) as plant:
        state = plant.reset(fixed.q_nominal, np.zeros(fixed.nv))
    np.testing.assert_allclose(state.q, fixed.q_nominal, atol=1e-9)


# --- frames and names ------------------------------------------------------------------------------------
def test_feet_and_end_effector_are_found(labdog, tmp_path):
    assert find_contact_frames(*labdog) == (FEET, EE)
    # ANYmal-style names (LF/RF/LH/RH, upper case), declared as SRDF end effectors, in another order.
    names = {
        "FL_foot": "LF_FOOT",
        "FR_foot": "RF_FOOT",
        "RL_foot": "LH_FOOT",
        "RR_foot": "RH_FOOT",
        EE: "tool0",
    }
    text = urdf_text()
    for old, new in names.items():
        text = text.replace(f'"{old}"', f'"{new}"')
    urdf, srdf = write_robot(tmp_path, text)
    srdf.write_text(
        srdf.read_text().replace(
            "</robot>",
            "".join(
                f'<end_effector name="{n}" parent_link="{n}" group="g"/>'
                for n in ("RH_FOOT", "LF_FOOT", "LH_FOOT", "RF_FOOT")
            )
            + "</robot>",
        )
    )
    assert find_contact_frames(urdf, srdf) == (("LF_FOOT", "RF_FOOT", "LH_FOOT", "RH_FOOT"), "tool0")


def test_frame_and_joint_errors_name_the_model_alike(fixed_labdog):
    """Both name the model by the file's stem (the joint error used to give the URDF's robot name)."""
    urdf, srdf = fixed_labdog
    with pytest.raises(RobotModelError, match="unknown frame 'FL_toe' in model 'labdog_fixed'"):
        load_robot(urdf, srdf, foot_frames=("FL_toe", *FEET[1:]), ee_frame=EE)
    with pytest.raises(RobotModelError, match="unknown joint 'arm_joint9'; joints of 'labdog_fixed'"):
        load_robot(urdf, srdf, foot_frames=FEET, ee_frame=EE, locked_joints=("arm_joint9",))


def _link(urdf: Path, name: str):
    import xml.etree.ElementTree as ET

    return next(link for link in ET.parse(urdf).getroot().iter("link") if link.get("name") == name)


# --- the demo command line --------------------------------------------------------------------------------
QUICK_RUN = ["--gait", "stand:0.1,trot:0.2", "--nodes", "6", "--duration", "0.3", "--quiet"]


def _demo(argv, tmp_path, capsys):
    from wbmpc.studies import demo

    summary = demo.main([*argv, *QUICK_RUN, "--output", str(tmp_path)])
    return summary, capsys.readouterr()


def test_cli_runs_the_robot_as_it_is_on_the_rigid_plant_with_its_replay(labdog, tmp_path, capsys):
    """``--urdf/--srdf`` alone (feet and gripper found from the names), the defective URDF as it is: a note,
    then a run that stands; the replay is written with every link (no "replay skipped")."""
    from wbmpc.studies import demo

    summary, out = _demo(["--urdf", str(labdog[0]), "--srdf", str(labdog[1])], tmp_path, capsys)
    assert summary["robot"] == "labdog" and summary["gait"] == "stand:0.1+trot:0.2"
    assert not summary["fell"] and demo.exit_status(summary) == 0
    assert "note:" in out.err and "8 problems" in out.err and "replay skipped" not in out.err
    assert (tmp_path / "replay.html").stat().st_size > 0


def test_cli_refuses_the_defects_on_pybullet_then_runs_the_fixed_robot(
    labdog, fixed_labdog, tmp_path, capsys
):
    from wbmpc.studies import demo

    with pytest.raises(SystemExit) as exit_info:
        demo.main(["--urdf", str(labdog[0]), "--srdf", str(labdog[1]), "--plant", "pybullet", *QUICK_RUN])
    out = capsys.readouterr()
    assert exit_info.value.code == 2 and "OCP built" not in out.out
    assert "--plant pybullet:" in out.err and "8 problems" in out.err and "--plant rigid" in out.err
    argv = [
        "--urdf",
        str(fixed_labdog[0]),
        "--srdf",
        str(fixed_labdog[1]),
        "--plant",
        "pybullet",
        "--no-replay",
    ]
    summary, out = _demo(argv, tmp_path, capsys)
    assert summary["robot"] == "labdog_fixed" and not summary["fell"] and demo.exit_status(summary) == 0
    assert "note:" not in out.err


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--urdf", "{missing}"], "--urdf {missing}: no such file"),
        (["--urdf", "{urdf}"], "give its --srdf too"),
        (["--urdf", "{urdf}", "--srdf", "{missing}"], "--srdf {missing}: no such file"),
        (["--urdf", "{folder}", "--srdf", "{srdf}"], "a folder, not a file"),
        (["--srdf", "{srdf}"], "--srdf describes a robot of your own: give its --urdf too"),
        (["--robot", "b1", "--urdf", "{urdf}", "--srdf", "{srdf}"], "give one of them"),
        (["--urdf", "{urdf}", "--srdf", "{srdf}", "--feet", "FL_foot,FR_foot"], "--feet must be four"),
        (
            ["--urdf", "{urdf}", "--srdf", "{srdf}", "--feet", "FL_toe,FR_foot,RL_foot,RR_foot"],
            "unknown frame 'FL_toe' in model 'labdog' (did you mean",
        ),
        (["--urdf", "{urdf}", "--srdf", "{srdf}", "--ee", "hand"], "unknown frame 'hand' in model 'labdog'"),
        (["--urdf", "{urdf}", "--srdf", "{srdf}", "--lock", "arm_joint9"], "unknown joint 'arm_joint9'"),
        (["--urdf", "{urdf}", "--srdf", "{srdf}", "--pose", "sit"], "SRDF pose 'sit' not found"),
        (["--urdf", "{renamed}", "--srdf", "{srdf}"], "give --feet FL,FR,RL,RR"),
        (["--urdf", "{no_ee}", "--srdf", "{srdf}"], "give --ee FRAME"),
    ],
    ids=[
        "missing-urdf", "no-srdf", "missing-srdf", "folder", "srdf-alone", "both-robots", "three-feet",
        "unknown-foot", "unknown-ee", "unknown-lock", "unknown-pose", "feet-not-found", "ee-not-found",
    ],
)  # fmt: skip
def test_cli_bad_paths_and_frames_exit_2_before_any_work(labdog, tmp_path, capsys, argv, message):
    from wbmpc.studies import demo

    renamed = tmp_path / "renamed.urdf"
    renamed.write_text(re.sub(r"(F|R)(L|R)_foot", r"\1\2_end", labdog[0].read_text()))
    no_ee = tmp_path / "no_ee.urdf"
    no_ee.write_text(labdog[0].read_text().replace(f'"{EE}"', '"arm_flange"'))
    paths = {
        "urdf": labdog[0], "srdf": labdog[1], "missing": tmp_path / "nope.urdf", "folder": tmp_path,
        "renamed": renamed, "no_ee": no_ee,
    }  # fmt: skip
    argv = [arg.format(**paths) for arg in argv]
    with pytest.raises(SystemExit) as exit_info:
        demo.main([*argv, *QUICK_RUN, "--no-replay", "--output", str(tmp_path / "out")])
    out = capsys.readouterr()
    assert exit_info.value.code == 2 and "OCP built" not in out.out
    assert message.format(**paths) in out.err


# --- the viewer ---------------------------------------------------------------------------------------------
def test_viewer_falls_back_mesh_by_mesh_and_keeps_every_link(tmp_path):
    """One mesh on disk (the trunk's) stays a mesh; each missing one becomes primitive shapes (the feet
    their spheres, the legs sticks), every link keeps a visual, one warning names each missing file once."""
    from wbmpc.viz import visual_model

    urdf, srdf = write_robot(tmp_path)
    (tmp_path / "meshes").mkdir()
    shutil.copy(
        Path(__file__).parent / "data" / "quadruped_arm" / "meshes" / "cube.stl",
        tmp_path / "meshes" / "trunk.stl",
    )
    robot = _load(urdf, srdf, inertia_checks="ignore")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model, geometry = visual_model(robot)
    texts = [str(w.message) for w in caught]
    assert len(texts) == 1 and "visual mesh files not found" in texts[0]
    assert "Traceback" not in texts[0] and "could not be found" not in texts[0]  # no C++ message
    missing = re.findall(r'<visual>.*?<mesh filename="([^"]+)"', urdf.read_text())
    missing = [name for name in dict.fromkeys(missing) if name != "../meshes/trunk.stl"]
    assert f"{len(missing)} visual mesh files" in texts[0]
    for name in missing:
        assert texts[0].count(name) == 1, name
    shown = {}
    for g in geometry.geometryObjects:
        shown.setdefault(model.frames[g.parentFrame].name, []).append(type(g.geometry).__name__)
    assert set(MISSING_VISUAL_LINKS) <= set(shown)
    assert shown["trunk"] == ["BVHModelOBBRSS"] or "BVH" in shown["trunk"][0]
    assert all(shown[foot] == ["Sphere"] for foot in FEET)
    assert shown["FL_thigh"] == ["Cylinder"]


def test_replay_animates_every_link(labdog):
    from wbmpc.viz import Viewer, ViewerUnavailableError

    robot = _load(*labdog, inertia_checks="ignore")
    try:
        viewer = Viewer(robot)
    except ViewerUnavailableError as exc:
        pytest.skip(f"meshcat's zmq server cannot start on this machine: {exc}")
    with viewer:
        qs = np.repeat(robot.q_nominal[None], 3, axis=0)
        animation = viewer.animation(qs, np.array([0.0, 0.1, 0.2]), play=False)
        animated = {path.lower() for path in animation.clips}  # "/meshcat/robot/<link>_0"
    for link in MISSING_VISUAL_LINKS:
        assert any(path.endswith(f"/{link}_0") for path in animated), link


# --- custom gaits ----------------------------------------------------------------------------------------
class _HeldUp(Gait):
    """FL held up at mid-swing, the other feet as the walk the gait is made from (a three-legged walk)."""

    def sample_ticks(self, ticks):
        base = super().sample_ticks(ticks)
        contact = base.contact.copy()
        contact[0] = False
        phase = np.where(contact, 0.0, base.swing_phase)
        phase[0] = 0.5
        return GaitSample(contact, phase)  # n_contacts and swing_duration left out: filled in


def test_a_custom_gait_runs_in_schedules_and_the_mpc(fixed_labdog):
    """Subclassing Gait used to fail (GaitSample wanted swing_duration); the documented hook is
    sample_ticks, and the MPC plans FL in the air."""
    from wbmpc.control.mpc import MPCConfig, WholeBodyMPC
    from wbmpc.ocp import OCPSettings

    gait = _HeldUp("held_up", 0.8, 0.25, (0.0, 0.5, 0.75, 0.25))
    sample = gait.sample(np.linspace(0.0, 0.8, 9))
    assert not sample.contact[0].any() and np.all(sample.swing_duration[0] == pytest.approx(0.2))
    np.testing.assert_array_equal(sample.n_contacts, sample.contact.sum(axis=0))
    schedule = GaitSchedule([(make_gait("stand"), 0.4), (gait, 1.0)])
    assert schedule.sample(np.array([0.2])).contact[:, 0].all() and not schedule.contact(0.6)[0]
    robot = _load_cleanly(*fixed_labdog)
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=6), MPCConfig(gait=gait))
    plan = mpc.solve(robot.q_nominal, np.zeros(robot.nv), t=0.0)
    assert plan.success and not np.asarray(plan.contact)[0].any()


def test_overriding_sample_instead_of_sample_ticks_says_what_to_do():
    with pytest.raises(TypeError, match=r"override sample_ticks\(self, ticks\) instead"):

        class _Timed(Gait):
            def sample(self, times):
                return super().sample(times)
