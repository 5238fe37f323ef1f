"""Solver status names, physical prechecks and the once-per-reason failure reporter."""

import numpy as np
import pinocchio as pin
import pytest

from wbmpc.control import prechecks as diag
from wbmpc.control.mpc import Commands, MPCConfig, WholeBodyMPC
from wbmpc.model.robot import load_b1, load_b1_z1
from wbmpc.ocp import OCPSettings
from wbmpc.ocp.gait import make_gait
from wbmpc.sim.failure_reporter import FailureReporter
from wbmpc.solver import statuses


@pytest.fixture(scope="module")
def robot():
    return load_b1_z1()


@pytest.fixture(scope="module")
def b1():
    return load_b1()


def codes(findings):
    return [f.code for f in findings]


# --- end-effector force -----------------------------------------------------------------------------------
def rnea_hold_torque(robot, q, force_world):
    """Joint torques holding the robot still with ``force_world`` [N] applied on the end effector.

    Independent of the module: RNEA at v = a = 0 with the force as an external spatial force on the parent
    joint of the end-effector frame (Pinocchio wants fext in each joint's local frame).
    """
    model, data = robot.model, robot.model.createData()
    pin.framesForwardKinematics(model, data, q)
    fid = model.getFrameId(robot.ee_frame)
    joint = model.frames[fid].parentJoint
    p = data.oMf[fid].translation
    f_world = pin.Force(force_world, np.cross(p, force_world))  # about the world origin
    fext = [pin.Force.Zero() for _ in range(model.njoints)]
    fext[joint] = data.oMi[joint].actInv(f_world)
    zero = np.zeros(model.nv)
    return pin.rnea(model, data, q, zero, zero, fext)


def test_100_newton_down_is_flagged_at_joint3_with_the_rnea_torque(robot):
    q = robot.q_nominal
    force = np.array([0.0, 0.0, -100.0])  # the environment pushes the gripper down (a 10 kg load)
    findings = diag.ee_force_feasibility(robot, q, force)
    over = [f for f in findings if f.code == "ee_force_exceeds_torque_limit"]
    assert [f.data["joint"] for f in over] == ["joint3"]
    assert over[0].severity == "error"
    expected = rnea_hold_torque(robot, q, force)[robot.joint_index_v("joint3")]
    assert abs(expected) == pytest.approx(56.8, abs=0.5)
    assert over[0].data["needed"] == pytest.approx(expected, rel=0.02)
    assert over[0].data["limit"] == pytest.approx(30.0)
    assert "joint3" in over[0].message and "56.8" in over[0].message and "30.0" in over[0].message


def test_arm_hold_torques_match_rnea_for_any_force(robot):
    q = robot.q_nominal
    force = np.array([12.0, -7.0, 25.0])
    tau, names, _ = diag.arm_hold_torques(robot, q, force)
    expected = rnea_hold_torque(robot, q, force)
    idx = [robot.joint_index_v(n) for n in names]
    np.testing.assert_allclose(tau, expected[idx], atol=1e-9)


def test_small_force_is_not_flagged(robot):
    assert diag.ee_force_feasibility(robot, robot.q_nominal, [0.0, 0.0, -10.0]) == []


def test_upward_force_above_the_weight_is_flagged(robot):
    weight = robot.mass * robot.gravity
    findings = diag.ee_force_feasibility(robot, robot.q_nominal, [0.0, 0.0, weight + 50.0])
    assert "ee_force_lifts_robot" in codes(findings)


def test_horizontal_force_beyond_friction_is_flagged_only_with_mu(b1):
    force = [0.7 * b1.mass * b1.gravity + 10.0, 0.0, 0.0]
    assert diag.ee_force_feasibility(b1, b1.q_nominal, force) == []
    assert codes(diag.ee_force_feasibility(b1, b1.q_nominal, force, mu=0.7)) == ["ee_force_exceeds_friction"]


# --- speed, joint state, arm commands -----------------------------------------------------------------
def test_trot_speed_check(robot):
    trot = make_gait("trot", 0.8)
    fast = diag.speed_feasibility(robot, trot, [2.0, 0.0, 0.0], np.zeros(3))
    assert codes(fast) == ["speed_beyond_gait"]
    assert fast[0].data["stride"] == pytest.approx(2.0 * 0.4)  # v * stance duration
    assert diag.speed_feasibility(robot, trot, [0.2, 0.0, 0.0], np.zeros(3)) == []
    # Far beyond the kinematic reach: an error, not a warning.
    assert diag.speed_feasibility(robot, trot, [4.0, 0.0, 0.0], np.zeros(3))[0].severity == "error"


def test_stand_with_a_speed_can_only_lean(robot):
    stand = make_gait("stand")
    assert codes(diag.speed_feasibility(robot, stand, [0.3, 0.0, 0.0], np.zeros(3))) == [
        "speed_without_stepping"
    ]
    assert diag.speed_feasibility(robot, stand, np.zeros(3), np.zeros(3)) == []


def test_leg_reach_of_the_b1(robot):
    reach = diag.leg_reach(robot)
    # Thigh and calf 0.35 m each, knee bent at least 0.6 rad, thigh joint ~0.49 m above the foot.
    d_max = 0.35 * np.sqrt(2.0 + 2.0 * np.cos(0.6))
    assert reach["reach"] == pytest.approx(np.sqrt(d_max**2 - reach["hip_height"] ** 2), rel=1e-3)
    assert reach["leg_length"] == pytest.approx(0.7)


def test_joint_outside_limits_is_named(robot):
    q = robot.q_nominal
    q[7 + robot.joint_names.index("joint3")] = 0.5  # limit [-2.88, 0]
    v = np.zeros(robot.nv)
    v[robot.joint_index_v("FL_calf_joint")] = 30.0  # limit 15.55 rad/s
    findings = diag.joint_state_limits(robot, q, v)
    assert codes(findings) == ["joint_position_limit", "joint_velocity_limit"]
    assert "joint3" in findings[0].message and "0.500" in findings[0].message
    assert "FL_calf_joint" in findings[1].message
    assert diag.joint_state_limits(robot, robot.q_nominal, np.zeros(robot.nv)) == []


def test_arm_commands_on_b1_without_arm(b1, robot):
    commands = Commands(ee_velocity=np.array([0.1, 0.0, 0.0]))
    findings = diag.arm_commands_without_arm(b1, commands)
    assert codes(findings) == ["arm_command_without_arm"] and "ee_velocity" in findings[0].message
    assert diag.arm_commands_without_arm(b1, Commands()) == []
    assert diag.arm_commands_without_arm(robot, commands) == []


def test_run_prechecks_collects_everything(robot):
    q, v = robot.q_nominal, np.zeros(robot.nv)
    commands = Commands(base_linear_velocity=np.array([2.0, 0, 0]), ee_force=np.array([0, 0, -100.0]))
    findings = diag.run_prechecks(robot, q, v, commands, make_gait("trot"))
    assert {"ee_force_exceeds_torque_limit", "speed_beyond_gait"} <= set(codes(findings))
    assert findings[0].severity == "error"  # errors first
    assert diag.run_prechecks(robot, q, v, Commands(), make_gait("trot")) == []


# --- solver status ---------------------------------------------------------------------------------------
def test_fatrop_status_of_a_real_success_and_a_real_max_iter_failure(robot):
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=5), MPCConfig(gait=make_gait("stand")))
    mpc.verbose = False
    plan = mpc.solve(robot.q_nominal, np.zeros(robot.nv))
    assert plan.success
    args = mpc.last_inputs

    solver = mpc.make_solver("diag_ok", cold=True)
    solver(**args)
    assert statuses.solver_status("fatrop", solver.stats()) == statuses.FATROP_FLAGS[0]
    assert statuses.solver_status("fatrop", solver.stats())[0] == "success"

    capped = mpc.make_solver("diag_capped", cold=True, max_iter=1)
    capped(**args)
    stats = capped.stats()
    assert not stats["success"]
    name, reason = statuses.solver_status("fatrop", stats)
    assert name == "max_iter_exceeded" and not name.isdigit()
    assert "iteration" in reason


def test_status_tables_and_unknown_codes():
    assert (
        statuses.solver_status("ipopt", {"return_status": "Maximum_Iterations_Exceeded"})[0]
        == "max_iter_exceeded"
    )
    invalid = statuses.solver_status("ipopt", {"return_status": "Invalid_Number_Detected"})
    assert invalid[0] == "invalid_number"
    assert statuses.solver_status("ipopt", {"return_status": "Solve_Succeeded"})[0] == "success"
    assert statuses.solver_status("ipopt", {"return_status": "Brand_New"})[0] == "ipopt_status_Brand_New"
    assert (
        statuses.solver_status("fatrop", {"return_status": 1, "fatrop": {"return_flag": 4}})[0]
        == "line_search_failed"
    )
    assert (
        statuses.solver_status("fatrop", {"return_status": 1, "fatrop": {"return_flag": 42}})[0]
        == "fatrop_status_42"
    )
    assert statuses.solver_status("fatrop", {"return_status": 1})[0] == "fatrop_failed"
    assert (
        statuses.solver_status("fatrop", {"return_status": -1, "fatrop": {"return_flag": 6}})[0]
        == "solver_exception"
    )


def test_exception_status():
    nan = RuntimeError("Error in Function::call for 'solver' [FatropInterface]: nlp_g failed: NaN detected")
    assert statuses.exception_status(nan)[0] == "nan_in_evaluation"
    assert statuses.exception_status(RuntimeError("something else"))[0] == "solver_exception"


# --- reporter -------------------------------------------------------------------------------------------
def test_reporter_prints_once_per_reason_and_counts(capsys, robot):
    reporter = FailureReporter()
    assert reporter.report(0.10, "max_iter_exceeded", "Fatrop reached its iteration cap.")
    assert not reporter.report(0.12, "max_iter_exceeded", "Fatrop reached its iteration cap.")
    assert not reporter.report(0.14, "success")
    assert reporter.report(0.30, "line_search_failed", "no step")
    reporter.report(0.32, "max_iter_exceeded")
    findings = diag.ee_force_feasibility(robot, robot.q_nominal, [0.0, 0.0, -100.0])
    assert reporter.report_findings(0.0, findings) == 2
    assert reporter.report_findings(0.5, findings) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 4
    assert "t=0.100" in lines[0] and "max_iter_exceeded" in lines[0]
    assert "line_search_failed" in lines[1]
    summary = reporter.summary()
    assert summary["failures"] == 4
    assert summary["failure_reasons"] == {"max_iter_exceeded": 3, "line_search_failed": 1}
    assert summary["findings"] == {"ee_force_exceeds_torque_limit": 2, "ee_force_near_torque_limit": 2}
    assert summary["first_time"]["max_iter_exceeded"] == pytest.approx(0.10)
