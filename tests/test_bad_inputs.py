"""Bad inputs are refused up front with an error that names the input (a growing catalogue, issue 12)."""

import numpy as np
import pytest

from wbmpc.control.mpc import Commands, MPCConfig, WholeBodyMPC
from wbmpc.model.robot import load_b1_z1
from wbmpc.ocp import OCPSettings
from wbmpc.ocp.gait import make_gait
from wbmpc.sim.closed_loop import ClosedLoopConfig

MPC_CONFIGS = [
    ({"dt_min": 0.0}, "dt_min must be a positive number"),
    ({"dt_min": 1e-6}, "dt_min = 1e-06 s is outside"),
    ({"dt_max": 10.0}, "dt_max = 10.0 s is outside"),
    ({"dt_min": 0.05, "dt_max": 0.02}, "dt_max (0.02) must be >= dt_min"),
    ({"mu": -0.5}, "mu must be a positive number"),
    ({"tol": float("nan")}, "tol must be a positive number"),
    ({"mu_init_cold": 0.0}, "mu_init_cold must be a positive number"),
    ({"max_iter": 0}, "max_iter must be an integer >= 1"),
    ({"max_iter": 2.5}, "max_iter must be an integer >= 1"),
    ({"cold_max_iter": -1}, "cold_max_iter must be an integer >= 1"),
    ({"retry_max_iter": True}, "retry_max_iter must be an integer >= 1"),
    ({"Q": -np.ones(44)}, "Q must be a 1-D array of finite weights >= 0"),
    ({"R": np.full(10, np.nan)}, "R must be a 1-D array of finite weights >= 0"),
    ({"front_force_ratio": 1.5}, "front_force_ratio must be in [0, 1]"),
    ({"solver": "snopt"}, "unknown solver 'snopt'"),
    ({"solver": "ipopt", "compiled": True}, "compiled needs solver='fatrop'"),
    ({"gait": "trot"}, "gait must be a Gait or GaitSchedule"),
]


@pytest.mark.parametrize("kwargs, message", MPC_CONFIGS, ids=[m for _, m in MPC_CONFIGS])
def test_mpc_config(kwargs, message):
    with pytest.raises(ValueError) as err:
        MPCConfig(**kwargs)
    assert message in str(err.value)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"n_nodes": 2}, "n_nodes must be an integer >= 3"),
        ({"n_nodes": 15.0}, "n_nodes must be an integer >= 3"),
        ({"n_nodes": 1000}, "n_nodes = 1000 is above 100"),
        ({"n_tau_nodes": 0}, "n_tau_nodes must be in [1, n_nodes - 1 = 14]"),
        ({"formulation": "magic"}, "unknown formulation 'magic'"),
    ],
)
def test_ocp_settings(kwargs, message):
    with pytest.raises(ValueError) as err:
        OCPSettings(**kwargs)
    assert message in str(err.value)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"delay": -1.0}, "delay must be 'off', 'measured' or seconds >= 0"),
        ({"plant": "mujoco"}, "unknown plant 'mujoco'"),
        ({"gait": "trot"}, "gait must be a Gait or GaitSchedule"),
    ],
)
def test_closed_loop_config(kwargs, message):
    with pytest.raises(ValueError) as err:
        ClosedLoopConfig(**kwargs)
    assert message in str(err.value)


@pytest.fixture(scope="module")
def mpc():
    robot = load_b1_z1()
    return WholeBodyMPC(robot, OCPSettings(n_nodes=4), MPCConfig(gait=make_gait("stand"), dt_max=0.03))


@pytest.mark.parametrize(
    "name, value, message",
    [
        ("Q", np.ones(3), "MPCConfig.Q must hold 44 finite weights"),
        ("R", np.ones(3), "MPCConfig.R must hold"),
    ],
)
def test_weights_of_the_wrong_size_for_the_robot(mpc, name, value, message):
    setattr(mpc.config, name, value)
    try:
        with pytest.raises(ValueError, match=message):
            mpc.solve(mpc.robot.q_nominal, np.zeros(mpc.robot.nv))
    finally:
        setattr(mpc.config, name, None)


@pytest.mark.parametrize(
    "q, v, commands, message",
    [
        ("short", None, None, "q_hat must have shape (23,)"),
        ("nan", None, None, "q_hat contains NaN"),
        (None, "short", None, "v_hat must have shape (22,)"),
        (None, None, Commands(ee_force=np.array([0.0, np.nan, 0.0])), "command ee_force contains NaN"),
        (None, None, Commands(base_linear_velocity=np.zeros(2)), "base_linear_velocity must have shape (3,)"),
    ],
)
def test_solve_inputs(mpc, q, v, commands, message):
    robot = mpc.robot
    q_hat, v_hat = robot.q_nominal, np.zeros(robot.nv)
    if q == "short":
        q_hat = q_hat[:-1]
    elif q == "nan":
        q_hat = q_hat.copy()
        q_hat[0] = np.nan
    if v == "short":
        v_hat = v_hat[:-1]
    with pytest.raises(ValueError) as err:
        mpc.solve(q_hat, v_hat, commands=commands)
    assert message in str(err.value)


def test_zero_quaternion_is_named(mpc):
    q = mpc.robot.q_nominal.copy()
    q[3:7] = 0.0
    with pytest.raises(ValueError, match="base quaternion"):
        mpc.solve(q, np.zeros(mpc.robot.nv))


def test_an_upward_arm_force_above_the_weight_is_refused(mpc):
    with pytest.raises(ValueError, match="command refused: .*weight"):
        mpc.solve(
            mpc.robot.q_nominal, np.zeros(mpc.robot.nv), commands=Commands(ee_force=np.array([0, 0, 1e3]))
        )


def test_arm_commands_on_a_robot_without_arm_are_refused():
    from wbmpc.model.robot import load_b1

    b1 = load_b1()
    mpc = WholeBodyMPC(b1, OCPSettings(n_nodes=4), MPCConfig(gait=make_gait("stand"), dt_max=0.03))
    with pytest.raises(ValueError, match="command refused: .*arm"):
        mpc.solve(b1.q_nominal, np.zeros(b1.nv), commands=Commands(ee_velocity=np.array([0.1, 0, 0])))


def test_a_force_beyond_the_arm_torque_limits_is_explained_on_the_plan(mpc):
    """100 N down needs about 57 N m at joint3 (limit 30): the plan carries the finding."""
    plan = mpc.solve(
        mpc.robot.q_nominal, np.zeros(mpc.robot.nv), commands=Commands(ee_force=np.array([0, 0, -100.0]))
    )
    codes = {f.code for f in plan.findings}
    assert "ee_force_exceeds_torque_limit" in codes
    assert any("joint3" in f.message for f in plan.findings)
