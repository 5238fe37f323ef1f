"""The friction cone of the OCP: its rows at hand-computed forces, and a solve in which it binds.

The cone rows are ``F_z / W >= 0`` and ``(mu^2 F_z^2 - F_x^2 - F_y^2) / W^2 >= 0`` per foot (``W`` the robot's
weight), each relaxed by ``1 - c`` for a swing foot. Standing solves never load the feet sideways, so a
wrong exponent of ``mu`` or a flipped tangential sign only shows at known tangential forces or in a solve
that needs them.
"""

import casadi as ca
import numpy as np
import pytest

from wbmpc.control.mpc import Commands, MPCConfig, WholeBodyMPC
from wbmpc.model.robot import load_b1_z1
from wbmpc.ocp import OCP, OCPSettings
from wbmpc.ocp.gait import make_gait

TOL = 1e-3  # the solver tolerance (paper)


@pytest.fixture(scope="module")
def robot():
    return load_b1_z1()


@pytest.fixture(scope="module")
def cone(robot):
    """``(forces (4, 3), contact (4,), mu) -> (normal rows (4,), cone rows (4,))`` of every stage, from the
    OCP's own constraint vector (3 nodes: stage 0 with node 0's state as the measurement, and stage 1)."""
    ocp = OCP(robot, OCPSettings(n_nodes=3, n_tau_nodes=1))
    g = ca.Function("g", [ocp.nlp["x"], ocp.nlp["p"]], [ocp.nlp["g"]])
    stages = [s for s in ocp.stages if "friction_cone" in s.rows]
    assert len(stages) == 2  # both stages with inputs
    N, nv = ocp.n_nodes, robot.nv

    def evaluate(forces, contact, mu):
        values = {name: np.zeros(rows * cols) for name, (_, (rows, cols)) in ocp.params.blocks.items()}
        values |= {"q_hat": robot.q_nominal, "dt_min": 0.01, "dt_max": 0.1, "mu": mu}
        values["contact"] = np.tile(np.asarray(contact, float)[:, None], (1, N - 1))
        p = ocp.params.pack(values)
        all_forces = np.zeros((N - 1, len(robot.contact_frames), 3))
        all_forces[:, :4] = forces
        w = ocp.join(
            robot.q_nominal,
            np.zeros((N, nv)),
            np.zeros((N, nv)),
            np.zeros((N - 1, nv)),
            all_forces,
            np.zeros((1, robot.nj)),
        )
        out = np.asarray(g(w, p)).ravel()
        rows = [out[s.rows["friction_cone"]] for s in stages]
        assert all(r.shape == (8,) for r in rows)
        np.testing.assert_array_equal(rows[0], rows[1])  # the same rows on every stage
        return rows[0][0::2], rows[0][1::2]

    return evaluate


# Foot forces [N] and mu = 0.5 with mu^2 F_z^2 - F_t^2 worked out by hand (F_z = 200 N: mu F_z = 100 N).
# Feet FL, FR, RL, RR pull in +x, -x, +y, -y: inside (|F_t| = 60 N), on (100 N), outside (120 N) the cone.
CONE_CASES = {
    "inside": (
        [[60.0, 0.0, 200.0], [-60.0, 0.0, 200.0], [0.0, 60.0, 200.0], [0.0, -60.0, 200.0]],
        [6400.0, 6400.0, 6400.0, 6400.0],  # 0.25 * 40000 - 3600
    ),
    "on": (
        [[100.0, 0.0, 200.0], [-100.0, 0.0, 200.0], [0.0, 100.0, 200.0], [0.0, -100.0, 200.0]],
        [0.0, 0.0, 0.0, 0.0],
    ),
    "outside": (
        [[120.0, 0.0, 200.0], [-120.0, 0.0, 200.0], [0.0, 120.0, 200.0], [0.0, -120.0, 200.0]],
        [-4400.0, -4400.0, -4400.0, -4400.0],  # 10000 - 14400
    ),
    # Both tangential axes at once: (60, 80) and (-60, -80) are on the cone, (72, -96) is 120 N.
    "diagonal": (
        [[60.0, 80.0, 200.0], [-60.0, -80.0, 200.0], [72.0, -96.0, 200.0], [-36.0, 48.0, 200.0]],
        [0.0, 0.0, -4400.0, 6400.0],
    ),
    # Loads of different size: F_z = 80 N allows 40 N; F_z = 400 N allows 200 N.
    "loads": (
        [[30.0, 0.0, 80.0], [0.0, -50.0, 80.0], [-160.0, 120.0, 400.0], [0.0, 250.0, 400.0]],
        [700.0, -900.0, 0.0, -22500.0],  # 1600 - 900, 1600 - 2500, 40000 - 40000, 40000 - 62500
    ),
}


@pytest.mark.parametrize("case", list(CONE_CASES))
def test_cone_rows_at_hand_computed_forces(cone, robot, case):
    forces, expected = CONE_CASES[case]
    W = robot.mass * robot.gravity
    normal, rows = cone(np.array(forces), np.ones(4), 0.5)
    np.testing.assert_allclose(rows * W**2, expected, rtol=1e-12, atol=1e-8)
    np.testing.assert_allclose(normal * W, np.array(forces)[:, 2], rtol=1e-12)
    # Feasible (>= 0) exactly when |F_t| <= mu F_z.
    ft = np.linalg.norm(np.array(forces)[:, :2], axis=1)
    assert np.array_equal(rows >= -1e-15, ft <= 0.5 * np.array(forces)[:, 2] + 1e-12)


def test_cone_rows_scale_with_mu_squared(cone, robot):
    """mu enters squared: at mu = 0.7 (mu^2 = 0.49) and mu = 0.2 (0.04) the same forces give other rows."""
    W = robot.mass * robot.gravity
    forces = np.array([[60.0, 0.0, 200.0], [0.0, -60.0, 200.0], [30.0, 40.0, 100.0], [0.0, 0.0, 50.0]])
    _, rows = cone(forces, np.ones(4), 0.7)  # 0.49 F_z^2 - F_t^2
    np.testing.assert_allclose(rows * W**2, [16000.0, 16000.0, 2400.0, 1225.0], rtol=1e-12)
    _, rows = cone(forces, np.ones(4), 0.2)  # 0.04 F_z^2 - F_t^2
    np.testing.assert_allclose(rows * W**2, [-2000.0, -2000.0, -2100.0, 100.0], rtol=1e-12)


def test_swing_rows_are_relaxed_and_a_pulling_foot_is_refused(cone, robot):
    """A swing foot's rows carry a unit slack; a stance foot pulling on the ground (F_z < 0) violates the
    normal row although mu^2 F_z^2 >= F_t^2 (the quadratic cone alone is two-sided)."""
    W = robot.mass * robot.gravity
    forces = np.array([[120.0, 0.0, 200.0], [0.0, 0.0, 0.0], [10.0, 0.0, -50.0], [0.0, 0.0, 300.0]])
    normal, rows = cone(forces, [0.0, 0.0, 1.0, 1.0], 0.5)
    np.testing.assert_allclose(rows * W**2, [-4400.0 + W**2, W**2, 525.0, 22500.0], rtol=1e-12)
    np.testing.assert_allclose(normal * W, [200.0 + W, W, -50.0, 300.0], rtol=1e-12)
    assert normal[2] < 0 and rows[2] > 0


def test_a_sideways_arm_force_makes_the_cone_bind(robot):
    """Standing on mu = 0.1 while the environment pushes the gripper diagonally (30 N in +x and +y): the
    stance feet need tangential force in both axes. Every stance force of the plan is inside the cone
    ``mu F_z >= |F_t|`` and at least one is on it (the cone is what limits the plan)."""
    mu = 0.1
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=6), MPCConfig(gait=make_gait("stand"), dt_max=0.04, mu=mu))
    mpc.verbose = False
    plan = mpc.solve(
        robot.q_nominal, np.zeros(robot.nv), t=0.0, commands=Commands(ee_force=np.array([30.0, 30.0, 0.0]))
    )
    assert plan.success, plan.status
    assert plan.constraint_violation < TOL
    W = robot.mass * robot.gravity
    F = plan.forces[:, :4][plan.contact.T]
    assert len(F) == 4 * (mpc.n_nodes - 1)  # standing: every foot in stance on every stage
    fz, ft = F[:, 2], np.linalg.norm(F[:, :2], axis=1)
    assert np.all(fz >= -plan.constraint_violation * W)
    # The cone rows (in units of W^2) hold to the constraint violation the solver reports.
    bound = np.sqrt(mu**2 * fz**2 + plan.constraint_violation * W**2)
    assert np.all(ft <= bound), f"|F_t| exceeds mu F_z by up to {np.max(ft - mu * fz):.2f} N"
    ratio = ft / (mu * fz)
    assert ratio.max() > 0.99, ratio.max()  # active: the feet push sideways as hard as friction allows
    # Both tangential axes carry load (a flipped sign of either term would leave that axis unbounded).
    total = plan.forces[0, :4, :2].sum(axis=0)
    assert total[0] < -5.0 and total[1] < -5.0, total
