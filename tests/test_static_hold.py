"""The static hold (``WholeBodyMPC.hold_plan``), applied while no solve has converged: the measured pose held
at rest on the scheduled stance feet when they can hold it, on all four feet otherwise.

Every hold is checked against numeric Pinocchio, independently of wbmpc's statics: the generalised gravity
``g(q) = [0; tau] + sum_c J_c^T F_c`` (a balanced base, the torques that hold the joints) and feet that
push (``F_z >= 0``).
"""

import numpy as np
import pinocchio as pin
import pytest

from wbmpc.control.mpc import MPCConfig, SolverSettings, WholeBodyMPC
from wbmpc.model.robot import load_b1_z1
from wbmpc.ocp import OCPSettings
from wbmpc.ocp.gait import Gait, make_gait


@pytest.fixture(scope="module")
def robot():
    return load_b1_z1()


def _failed_first_solve(robot, gait, t):
    """A first solve that cannot converge (one iteration from a cold start): the static hold at ``t``."""
    mpc = WholeBodyMPC(
        robot, OCPSettings(n_nodes=4), MPCConfig(gait=gait, dt_max=0.03), SolverSettings(cold_max_iter=1)
    )
    mpc.verbose = False
    plan = mpc.solve(robot.q_nominal, np.zeros(robot.nv), t=t)
    assert plan.hold and plan.fallback and not plan.success and mpc.previous is None
    return plan


def _equilibrium_residual(robot, q, forces, tau):
    """``g(q) - [0; tau] - sum_c J_c^T F_c`` (nv,) [N, N m] with Pinocchio (forces on every contact frame)."""
    model, data = robot.model, robot.model.createData()
    g = pin.computeGeneralizedGravity(model, data, q).copy()
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    JtF = sum(
        pin.getFrameJacobian(model, data, robot.frame_id(frame), pin.LOCAL_WORLD_ALIGNED)[:3].T @ forces[i]
        for i, frame in enumerate(robot.contact_frames)
    )
    return g - np.r_[np.zeros(6), tau] - JtF


def _assert_holds(robot, plan):
    q = robot.q_nominal
    np.testing.assert_allclose(plan.q, np.tile(q, (len(plan.q), 1)))
    assert not np.any(plan.v) and not np.any(plan.a)
    for k in range(len(plan.tau)):
        residual = _equilibrium_residual(robot, q, plan.forces[k], plan.tau[k])
        assert np.abs(residual[:6]).max() < 1e-8, f"unbalanced base wrench {residual[:6]}"
        assert np.abs(residual[6:]).max() < 1e-8
    assert np.all(plan.forces[:, :4, 2] >= -1e-9), plan.forces[0, :4, 2]  # feet push, never pull
    assert np.all(np.abs(plan.tau) <= robot.joint_torque_limits)


def test_the_hold_uses_the_scheduled_stance_when_it_can_hold_the_pose(robot):
    """Walk at t = 0.65 s: RL swings (phase (0.8125 - 0.75) mod 1 < 0.25), and FL, FR, RR can hold the
    nominal pose (the CoM lies inside their triangle): the hold uses those three, none on RL."""
    plan = _failed_first_solve(robot, make_gait("walk", 0.8), 0.65)
    np.testing.assert_array_equal(plan.contact[:, 0], [True, True, False, True])
    _assert_holds(robot, plan)
    np.testing.assert_array_equal(plan.forces[:, 2], 0.0)  # RL carries nothing
    assert np.all(plan.forces[:, [0, 1, 3], 2] > 0.0)
    assert plan.forces[0, :4, 2].sum() == pytest.approx(robot.mass * robot.gravity, rel=1e-9)


def test_the_hold_stands_on_four_feet_when_none_is_scheduled(robot):
    """A gait with every foot in the air at t = 0 (all swings in phase): no stance to hold with, so the hold
    stands on all four feet (what the robot does at rest), not on none."""
    hop = Gait("hop", 0.8, 0.5, (0.0, 0.0, 0.0, 0.0))
    plan = _failed_first_solve(robot, hop, 0.0)
    assert not plan.contact[:, 0].any()
    _assert_holds(robot, plan)
    assert np.all(plan.forces[:, :4, 2] > 0.0)


@pytest.mark.parametrize(("gait", "t"), [("trot", 0.0), ("walk", 0.05)], ids=["trot_diagonal", "walk_fl_up"])
def test_the_hold_stands_on_four_feet_when_the_scheduled_stance_cannot_hold_the_pose(robot, gait, t):
    plan = _failed_first_solve(robot, make_gait(gait, 0.8), t)
    assert plan.contact[:, 0].sum() in (2, 3)  # the scheduled stance is a subset of the feet
    _assert_holds(robot, plan)
