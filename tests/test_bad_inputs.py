"""Bad inputs are refused up front with an error that names the input (a growing catalogue, issue 12)."""

import functools
import warnings
from pathlib import Path

import numpy as np
import pytest

from wbmpc import checks
from wbmpc.control.arm_task import ArmReference
from wbmpc.control.low_level import LowLevelController
from wbmpc.control.mpc import Commands, MPCConfig, SolverSettings, WholeBodyMPC
from wbmpc.estimation import EstimatorNoise, StateEstimator
from wbmpc.estimation.filters import LowPassFilter
from wbmpc.io.logs import LogWriter, RunLog, load_log, save_log
from wbmpc.io.rosbag import TopicMap
from wbmpc.model.robot import RobotModelError, example_robot_data_dir, load, load_b1_z1, load_robot
from wbmpc.model.statics import static_equilibrium
from wbmpc.ocp import OCPSettings
from wbmpc.ocp.gait import Gait, GaitSchedule, SwingParams, make_gait, parse_gait_schedule
from wbmpc.sim.actuators import MotorModel
from wbmpc.sim.closed_loop import ClosedLoopConfig
from wbmpc.sim.disturbances import Kick, Push
from wbmpc.sim.loop_config import CommandSchedule, LowLevelConfig, PlantConfig, SensingConfig
from wbmpc.sim.pybullet_plant import Box, Payload, Wall
from wbmpc.sim.sensing import SensorNoise
from wbmpc.solver.deploy import export
from wbmpc.solver.nlpsol import make_nlpsol, solver_options

MPC_CONFIGS = [
    ({"dt_min": 0.0}, "dt_min must be a positive number"),
    ({"dt_min": 1e-6}, "dt_min = 1e-06 s is outside"),
    ({"dt_max": 10.0}, "dt_max = 10.0 s is outside"),
    ({"dt_min": 0.05, "dt_max": 0.02}, "dt_max (0.02) must be >= dt_min"),
    ({"mu": -0.5}, "mu must be a positive number"),
    ({"Q": -np.ones(44)}, "Q must be a 1-D array of finite weights >= 0"),
    ({"R": np.full(10, np.nan)}, "R must be a 1-D array of finite weights >= 0"),
    ({"front_force_ratio": 1.5}, "front_force_ratio must be in [0, 1]"),
    ({"gait": "trot"}, "gait must be a Gait or GaitSchedule"),
    ({"kick_recovery": -0.3}, "kick_recovery must be a positive number"),
    ({"kick_recovery_phase": 0.0}, "kick_recovery_phase must be a positive number"),
    ({"touchdown_speed": float("nan")}, "touchdown_speed must be a positive number"),
    ({"kick_ee_release": 0.0}, "kick_ee_release must be a positive number"),
    ({"kick_recovery_hold": "yes"}, "kick_recovery_hold must be True or False"),
]


@pytest.mark.parametrize("kwargs, message", MPC_CONFIGS, ids=[m for _, m in MPC_CONFIGS])
def test_mpc_config(kwargs, message):
    with pytest.raises(ValueError) as err:
        MPCConfig(**kwargs)
    assert message in str(err.value)


SOLVER_SETTINGS = [
    ({"tol": float("nan")}, "SolverSettings.tol must be a positive number"),
    ({"tol": True}, "SolverSettings.tol must be a positive number"),
    ({"mu_init_cold": 0.0}, "SolverSettings.mu_init_cold must be a positive number"),
    ({"max_iter": 0}, "SolverSettings.max_iter must be an integer >= 1"),
    ({"max_iter": 2.5}, "SolverSettings.max_iter must be an integer >= 1"),
    ({"cold_max_iter": -1}, "SolverSettings.cold_max_iter must be an integer >= 1"),
    ({"retry_max_iter": True}, "SolverSettings.retry_max_iter must be an integer >= 1"),
    ({"solver": "snopt"}, "unknown solver 'snopt'"),
    ({"solver": "ipopt", "compiled": True}, "compiled needs solver='fatrop'"),
]


@pytest.mark.parametrize("kwargs, message", SOLVER_SETTINGS, ids=[m for _, m in SOLVER_SETTINGS])
def test_solver_settings(kwargs, message):
    with pytest.raises(ValueError) as err:
        SolverSettings(**kwargs)
    assert message in str(err.value)


def test_solver_settings_are_fixed_and_the_mpc_refuses_others():
    """Build-time settings cannot change under a built MPC (frozen), and a wrong type is named."""
    import dataclasses

    settings = SolverSettings(max_iter=7)
    with pytest.raises(dataclasses.FrozenInstanceError):
        settings.max_iter = 8
    with pytest.raises(ValueError, match="solver must be a SolverSettings"):
        WholeBodyMPC(_b1z1(), OCPSettings(n_nodes=4), MPCConfig(), {"max_iter": 7})
    with pytest.raises(TypeError):
        MPCConfig(max_iter=7)  # not a runtime field any more


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
        ({"plant": "mujoco"}, "ClosedLoopConfig.plant must be a PlantConfig, got 'mujoco'"),
        ({"commands": {"gait": "trot"}}, "ClosedLoopConfig.commands must be a CommandSchedule"),
    ],
)
def test_closed_loop_config(kwargs, message):
    with pytest.raises(ValueError) as err:
        ClosedLoopConfig(**kwargs)
    assert message in str(err.value)


def test_command_schedule_refuses_a_gait_name():
    with pytest.raises(ValueError, match="CommandSchedule.gait must be a Gait or GaitSchedule"):
        CommandSchedule(gait="trot")


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


# ============================================================================================================
# The catalogue (issue 12): each case builds one bad input and names the exception and a message fragment that
# says which input is wrong. Cases are grouped by the class of the original problem:
#   silent  - was accepted silently (NaN poses, negative gains, a payload that became static, ...);
#   unclear - raised, but the error did not name the cause (ZeroDivisionError, Boost.Python, ...);
#   named   - already refused with a clear message (kept so that it stays so).
# ============================================================================================================
NAN, INF = float("nan"), float("inf")
ROBOTS = example_robot_data_dir() / "b1_description"
B1Z1_URDF, B1Z1_SRDF = ROBOTS / "urdf/b1-z1.urdf", ROBOTS / "srdf/b1-z1.srdf"
B1_URDF, B1_SRDF = ROBOTS / "urdf/b1.urdf", ROBOTS / "srdf/b1.srdf"
FEET = ("FL_foot", "FR_foot", "RL_foot", "RR_foot")
LOCKED = ("joint5", "joint6", "jointGripper")


def _robot(**kwargs):
    """``load_robot`` on the B1 + Z1 files with the default arguments overridden by ``kwargs``."""
    args = {"urdf": B1Z1_URDF, "srdf": B1Z1_SRDF, "foot_frames": FEET, "ee_frame": "gripperMover"}
    args |= {"locked_joints": LOCKED, "reference_pose": "standing_with_arm_up"}
    return load_robot(**(args | kwargs))


@functools.cache
def _b1z1():
    return load_b1_z1()


def _srdf_file(text: str) -> Path:
    import tempfile

    path = Path(tempfile.mkdtemp(prefix="wbmpc_bad_srdf_")) / "poses.srdf"
    path.write_text(text)
    return path


def _three_feet_mpc():
    robot = _robot(foot_frames=FEET[:3])
    return WholeBodyMPC(robot, OCPSettings(n_nodes=4))


def _mpc_solve(**kwargs):
    mpc = _module_mpc()
    args = {"q_hat": mpc.robot.q_nominal, "v_hat": np.zeros(mpc.robot.nv)} | kwargs
    return mpc.solve(**args)


@functools.cache
def _module_mpc():
    return WholeBodyMPC(_b1z1(), OCPSettings(n_nodes=4), MPCConfig(gait=make_gait("stand"), dt_max=0.03))


def _statics(contact, **kwargs):
    robot = _b1z1()
    return static_equilibrium(robot, robot.q_nominal, contact, **kwargs)


def _estimator(**kwargs):
    return StateEstimator(_b1z1(), **({"dt": 0.002} | kwargs))


def _closed_loop(**kwargs):
    return ClosedLoopConfig(**kwargs)


def _pb_loop(**kwargs):
    return ClosedLoopConfig(**({"plant": PlantConfig(kind="pybullet")} | kwargs))


def _mutated_steps():
    config = ClosedLoopConfig()
    config.mpc_rate = 0.0  # a field changed after construction is checked when the run starts
    return config.steps()


def _runtime_config(**kwargs):
    from wbmpc.runtime.run import RuntimeConfig

    return RuntimeConfig(**kwargs)


def _deadline_loop(**kwargs):
    from wbmpc.runtime.clock import DeadlineLoop

    return DeadlineLoop(0.002, **kwargs)


def _runtime_controller(**kwargs):
    from wbmpc.runtime.controller import RuntimeController
    from wbmpc.sim.presets import hardware_config

    robot = _b1z1()
    return RuntimeController(
        robot, hardware_config(), lambda times: np.ones((4, np.size(times)), bool), **kwargs
    )


C = ValueError
R = RobotModelError
CATALOGUE = [
    # --- closed loop: rates, durations, gains, commands ------------------------------------------------
    (
        "silent",
        "loop kp < 0",
        lambda: _closed_loop(low_level=LowLevelConfig(kp=-10.0)),
        C,
        "LowLevelConfig.kp must be a finite number >= 0",
    ),
    (
        "silent",
        "loop kd < 0",
        lambda: _closed_loop(low_level=LowLevelConfig(kd=-1.0)),
        C,
        "LowLevelConfig.kd must be",
    ),
    ("silent", "loop kp NaN", lambda: _closed_loop(low_level=LowLevelConfig(kp=NAN)), C, "LowLevelConfig.kp"),
    ("silent", "loop kd inf", lambda: _closed_loop(low_level=LowLevelConfig(kd=INF)), C, "LowLevelConfig.kd"),
    (
        "silent",
        "loop kp string",
        lambda: _closed_loop(low_level=LowLevelConfig(kp="30")),
        C,
        "LowLevelConfig.kp",
    ),
    (
        "silent",
        "arm_gains negative",
        lambda: _closed_loop(low_level=LowLevelConfig(arm_gains=(-5.0, 1.0))),
        C,
        "LowLevelConfig.arm_gains",
    ),
    (
        "silent",
        "arm_gains NaN",
        lambda: _closed_loop(low_level=LowLevelConfig(arm_gains=(5.0, NAN))),
        C,
        "LowLevelConfig.arm_gains",
    ),
    (
        "silent",
        "arm_gains three",
        lambda: _closed_loop(low_level=LowLevelConfig(arm_gains=(5.0, 1.0, 2.0))),
        C,
        "LowLevelConfig.arm_gains",
    ),
    ("silent", "arm_kp < 0", lambda: _closed_loop(arm_kp=-4.0), C, "ClosedLoopConfig.arm_kp"),
    ("unclear", "mpc_rate 0", lambda: _closed_loop(mpc_rate=0), C, "ClosedLoopConfig.mpc_rate must be"),
    (
        "unclear",
        "low_level_rate 0",
        lambda: _closed_loop(low_level=LowLevelConfig(rate=0)),
        C,
        "LowLevelConfig.rate",
    ),
    ("silent", "mpc_rate < 0", lambda: _closed_loop(mpc_rate=-80.0), C, "ClosedLoopConfig.mpc_rate"),
    ("unclear", "mpc_rate NaN", lambda: _closed_loop(mpc_rate=NAN), C, "ClosedLoopConfig.mpc_rate"),
    ("unclear", "plant_dt 0", lambda: _closed_loop(plant=PlantConfig(dt=0.0)), C, "PlantConfig.dt"),
    ("unclear", "plant_dt NaN", lambda: _closed_loop(plant=PlantConfig(dt=NAN)), C, "PlantConfig.dt"),
    (
        "named",
        "plant_dt not dividing",
        lambda: _closed_loop(plant=PlantConfig(dt=0.0007)).steps(),
        C,
        "PlantConfig.dt=0.0007 s must divide",
    ),
    (
        "silent",
        "low level slower than MPC",
        lambda: _closed_loop(mpc_rate=80.0, low_level=LowLevelConfig(rate=40.0)),
        C,
        "LowLevelConfig.rate (40.0 Hz) must be >= ClosedLoopConfig.mpc_rate",
    ),
    ("unclear", "duration NaN", lambda: _closed_loop(duration=NAN), C, "ClosedLoopConfig.duration"),
    ("silent", "duration 0", lambda: _closed_loop(duration=0.0), C, "ClosedLoopConfig.duration"),
    ("silent", "duration < 0", lambda: _closed_loop(duration=-1.0), C, "ClosedLoopConfig.duration"),
    ("unclear", "duration inf", lambda: _closed_loop(duration=INF), C, "ClosedLoopConfig.duration"),
    (
        "silent",
        "duration below a plant step",
        lambda: _closed_loop(duration=1e-4),
        C,
        "shorter than one plant step",
    ),
    ("silent", "mutated after construction", _mutated_steps, C, "ClosedLoopConfig.mpc_rate"),
    ("silent", "max_tilt 0", lambda: _closed_loop(max_tilt=0.0), C, "ClosedLoopConfig.max_tilt"),
    (
        "silent",
        "base_velocity NaN",
        lambda: _closed_loop(commands=CommandSchedule(base_velocity=(NAN, 0, 0))),
        C,
        "CommandSchedule.base_velocity",
    ),
    (
        "unclear",
        "base_velocity two",
        lambda: _closed_loop(commands=CommandSchedule(base_velocity=(0.2, 0.0))),
        C,
        "CommandSchedule.base_velocity",
    ),
    (
        "silent",
        "base_yaw_rate NaN",
        lambda: _closed_loop(commands=CommandSchedule(base_yaw_rate=NAN)),
        C,
        "CommandSchedule.base_yaw_rate",
    ),
    (
        "silent",
        "ee_force inf",
        lambda: _closed_loop(commands=CommandSchedule(ee_force=(0, 0, INF))),
        C,
        "CommandSchedule.ee_force",
    ),
    (
        "unclear",
        "ee_velocity string",
        lambda: _closed_loop(commands=CommandSchedule(ee_velocity="up")),
        C,
        "CommandSchedule.ee_velocity",
    ),
    (
        "named",
        "delay NaN",
        lambda: _closed_loop(delay=NAN),
        C,
        "delay must be 'off', 'measured' or seconds >= 0",
    ),
    ("silent", "delay inf", lambda: _closed_loop(delay=INF), C, "ClosedLoopConfig.delay"),
    ("named", "delay word", lambda: _closed_loop(delay="sometimes"), C, "delay must be 'off'"),
    (
        "silent",
        "velocity cutoff 0",
        lambda: _closed_loop(sensing=SensingConfig(velocity_cutoff_hz=0.0)),
        C,
        "SensingConfig.velocity_cutoff_hz",
    ),
    (
        "silent",
        "velocity cutoff NaN",
        lambda: _closed_loop(sensing=SensingConfig(velocity_cutoff_hz=NAN)),
        C,
        "SensingConfig.velocity_cutoff_hz",
    ),
    (
        "silent",
        "ground friction < 0",
        lambda: _closed_loop(plant=PlantConfig(ground_friction=-0.8)),
        C,
        "PlantConfig.ground_friction",
    ),
    (
        "unclear",
        "arm_reference a tuple",
        lambda: _closed_loop(commands=CommandSchedule(arm_reference=(0.5, 0.0, 0.4))),
        C,
        "CommandSchedule.arm_reference must be an ArmReference",
    ),
    (
        "unclear",
        "sensor_noise a float",
        lambda: _closed_loop(sensing=SensingConfig(noise=0.01)),
        C,
        "SensingConfig.noise must be a SensorNoise",
    ),
    (
        "unclear",
        "command_schedule a dict",
        lambda: _closed_loop(commands=CommandSchedule(overrides={"ee_force": (0, 0, -10)})),
        C,
        "CommandSchedule.overrides must be a function",
    ),
    (
        "named",
        "plant name",
        lambda: _closed_loop(plant=PlantConfig(kind="gazebo")),
        C,
        "unknown plant 'gazebo'",
    ),
    (
        "named",
        "scene on the rigid plant",
        lambda: _closed_loop(plant=PlantConfig(scene=[Box((0.1, 0.1, 0.1), (1, 0, 0))])),
        C,
        "need PlantConfig(kind='pybullet')",
    ),
    ("silent", "motor friction < 0", lambda: MotorModel(coulomb=-1.0), C, "MotorModel.coulomb must be"),
    (
        "silent",
        "motor armature NaN",
        lambda: MotorModel(armature=[0.1, NAN]),
        C,
        "MotorModel.armature must be",
    ),
    ("named", "disturbance type", lambda: _pb_loop(disturbances=["kick"]), C, "unknown disturbance 'kick'"),
    (
        "named",
        "loop gait a name",
        lambda: _closed_loop(commands=CommandSchedule(gait="trot")),
        C,
        "gait must be a Gait or GaitSchedule",
    ),
    # --- disturbances -----------------------------------------------------------------------------------
    ("unclear", "kick time NaN", lambda: Kick(NAN, (0, 1, 0)), C, "Kick.time must be"),
    ("silent", "kick time < 0", lambda: Kick(-1.0, (0, 1, 0)), C, "Kick.time must be a finite number >= 0"),
    ("unclear", "kick time string", lambda: Kick("1.0", (0, 1, 0)), C, "Kick.time"),
    ("named", "kick delta_v two", lambda: Kick(1.0, (0, 1)), C, "Kick.delta_v must be 3 or 6"),
    ("named", "kick delta_v NaN", lambda: Kick(1.0, (0, NAN, 0)), C, "Kick.delta_v"),
    ("unclear", "kick delta_v string", lambda: Kick(1.0, "up"), C, "Kick.delta_v"),
    ("silent", "push start NaN", lambda: Push(NAN, 0.5, (10, 0, 0)), C, "Push.start must be"),
    ("silent", "push start < 0", lambda: Push(-0.5, 0.5, (10, 0, 0)), C, "Push.start"),
    ("named", "push duration 0", lambda: Push(1.0, 0.0, (10, 0, 0)), C, "Push.duration must be"),
    ("silent", "push duration NaN", lambda: Push(1.0, NAN, (10, 0, 0)), C, "Push.duration"),
    (
        "named",
        "push target",
        lambda: Push(1.0, 0.5, (10, 0, 0), target="arm"),
        C,
        "Push.target must be 'base' or 'ee'",
    ),
    (
        "named",
        "push ee wrench",
        lambda: Push(1.0, 0.5, (10, 0, 0, 0, 0, 1), target="ee"),
        C,
        "Push.force must be 3",
    ),
    ("named", "push force inf", lambda: Push(1.0, 0.5, (INF, 0, 0)), C, "Push.force"),
    # --- scene objects ----------------------------------------------------------------------------------
    (
        "silent",
        "payload mass < 0",
        lambda: Payload(-2.0, (1, 0, 0.05)),
        C,
        "Payload.mass must be a finite number > 0",
    ),
    ("silent", "payload mass NaN", lambda: Payload(NAN, (1, 0, 0.05)), C, "Payload.mass"),
    ("silent", "payload mass 0", lambda: Payload(0.0, (1, 0, 0.05)), C, "Payload.mass"),
    ("silent", "payload radius 0", lambda: Payload(1.0, (1, 0, 0.05), radius=0.0), C, "Payload.radius"),
    ("silent", "payload position NaN", lambda: Payload(1.0, (1, NAN, 0.05)), C, "Payload.position"),
    (
        "named",
        "payload attach",
        lambda: Payload(1.0, (1, 0, 0.05), attach="glue"),
        C,
        "Payload.attach must be",
    ),
    ("named", "payload without position", lambda: Payload(1.0), C, "Payload.position is required"),
    (
        "silent",
        "tether length 0",
        lambda: Payload(1.0, (1, 0, 0.05), attach="tether", tether_length=0.0),
        C,
        "Payload.tether_length",
    ),
    (
        "silent",
        "tether stiffness < 0",
        lambda: Payload(1.0, (1, 0, 0.05), tether_stiffness=-1.0),
        C,
        "Payload.tether_stiffness",
    ),
    (
        "silent",
        "payload friction < 0",
        lambda: Payload(1.0, (1, 0, 0.05), friction=-0.1),
        C,
        "Payload.friction",
    ),
    (
        "silent",
        "rolling friction NaN",
        lambda: Payload(1.0, (1, 0, 0.05), rolling_friction=NAN),
        C,
        "Payload.rolling_friction",
    ),
    (
        "silent",
        "wall zero normal",
        lambda: Wall((1, 0, 0.5), (0, 0, 0)),
        C,
        "Wall.normal must be a non-zero direction",
    ),
    ("silent", "wall normal NaN", lambda: Wall((1, 0, 0.5), (NAN, 0, 0)), C, "Wall.normal"),
    ("unclear", "wall normal two", lambda: Wall((1, 0, 0.5), (1, 0)), C, "Wall.normal"),
    ("silent", "wall size < 0", lambda: Wall((1, 0, 0.5), (-1, 0, 0), size=(2.0, -1.0)), C, "Wall.size"),
    ("silent", "wall thickness 0", lambda: Wall((1, 0, 0.5), (-1, 0, 0), thickness=0.0), C, "Wall.thickness"),
    ("silent", "wall position NaN", lambda: Wall((1, NAN, 0.5), (-1, 0, 0)), C, "Wall.position"),
    ("silent", "box size 0", lambda: Box((0.3, 0.0, 0.3), (1, 0, 0.15)), C, "Box.size"),
    ("silent", "box mass < 0", lambda: Box((0.3, 0.3, 0.3), (1, 0, 0.15), mass=-5.0), C, "Box.mass"),
    ("silent", "box yaw NaN", lambda: Box((0.3, 0.3, 0.3), (1, 0, 0.15), yaw=NAN), C, "Box.yaw"),
    (
        "silent",
        "box friction < 0",
        lambda: Box((0.3, 0.3, 0.3), (1, 0, 0.15), friction=-1.0),
        C,
        "Box.friction",
    ),
    ("unclear", "box position two", lambda: Box((0.3, 0.3, 0.3), (1, 0)), C, "Box.position"),
    # --- commands, MPC config, OCP settings, solve inputs ----------------------------------------------
    ("silent", "base_height < 0", lambda: Commands(base_height=-0.5).validated(), C, "command base_height"),
    ("silent", "base_height 0", lambda: Commands(base_height=0.0).validated(), C, "command base_height"),
    ("silent", "base_height NaN", lambda: Commands(base_height=NAN).validated(), C, "command base_height"),
    ("silent", "base_height 50 m", lambda: Commands(base_height=50.0).validated(), C, "command base_height"),
    (
        "unclear",
        "base_height string",
        lambda: Commands(base_height="0.5").validated(),
        C,
        "command base_height",
    ),
    (
        "named",
        "ee_velocity (2,)",
        lambda: Commands(ee_velocity=np.zeros(2)).validated(),
        C,
        "command ee_velocity must have shape (3,)",
    ),
    (
        "named",
        "angular velocity inf",
        lambda: Commands(base_angular_velocity=[0, 0, INF]).validated(),
        C,
        "command base_angular_velocity",
    ),
    (
        "unclear",
        "swing a dict",
        lambda: MPCConfig(swing={"height": 0.1}),
        C,
        "MPCConfig.swing must be a SwingParams",
    ),
    (
        "unclear",
        "compile_flags a string",
        lambda: SolverSettings(compile_flags="-O2"),
        C,
        "SolverSettings.compile_flags must be a list",
    ),
    (
        "named",
        "mu_init_warm NaN",
        lambda: SolverSettings(mu_init_warm=NAN),
        C,
        "SolverSettings.mu_init_warm must be a positive number",
    ),
    ("named", "dt_max inf", lambda: MPCConfig(dt_max=INF), C, "MPCConfig.dt_max must be a positive number"),
    (
        "named",
        "front_force_ratio NaN",
        lambda: MPCConfig(front_force_ratio=NAN),
        C,
        "MPCConfig.front_force_ratio must be in [0, 1]",
    ),
    (
        "unclear",
        "n_tau_nodes float",
        lambda: OCPSettings(n_tau_nodes=2.5),
        C,
        "n_tau_nodes must be in [1, n_nodes - 1",
    ),
    (
        "named",
        "n_tau_nodes = n_nodes",
        lambda: OCPSettings(n_nodes=5, n_tau_nodes=5),
        C,
        "n_tau_nodes must be in [1, n_nodes - 1 = 4]",
    ),
    ("named", "n_nodes bool", lambda: OCPSettings(n_nodes=True), C, "n_nodes must be an integer >= 3"),
    (
        "unclear",
        "ee_force_input a string",
        lambda: OCPSettings(ee_force_input="no"),
        C,
        "OCPSettings.ee_force_input must be True or False",
    ),
    (
        "named",
        "initial_state_variables a string",
        lambda: OCPSettings(initial_state_variables="yes"),
        C,
        "OCPSettings.initial_state_variables must be True or False",
    ),
    (
        "named",
        "split of a primal vector of the wrong size",
        lambda: _module_mpc().ocp.split(np.zeros(3)),
        C,
        "w must have shape",
    ),
    (
        "named",
        "split without the parameters that give node 0's state",
        lambda: _module_mpc().ocp.split(np.zeros(_module_mpc().ocp.n_variables)),
        C,
        "split(w, p) needs p",
    ),
    (
        "named",
        "PlannedContacts of a non-function",
        lambda: __import__("wbmpc.sim.hardware", fromlist=["PlannedContacts"]).PlannedContacts([1, 0, 1, 1]),
        C,
        "plan must be a function times -> contact flags",
    ),
    ("unclear", "three feet", _three_feet_mpc, C, "has 3 foot frames"),
    (
        "unclear",
        "MPC of a robot name",
        lambda: WholeBodyMPC("b1_z1"),
        C,
        "robot must be a wbmpc.model.robot.Robot",
    ),
    (
        "unclear",
        "MPC settings a dict",
        lambda: WholeBodyMPC(_b1z1(), {"n_nodes": 5}),
        C,
        "settings must be an OCPSettings",
    ),
    ("unclear", "solve time NaN", lambda: _mpc_solve(t=NAN), C, "t must be a finite number"),
    (
        "unclear",
        "solve commands a dict",
        lambda: _mpc_solve(commands={"ee_force": (0, 0, 0)}),
        C,
        "commands must be a Commands",
    ),
    ("named", "solve v_hat NaN", lambda: _mpc_solve(v_hat=np.full(22, NAN)), C, "v_hat contains NaN"),
    (
        "named",
        "solve base_height NaN",
        lambda: _mpc_solve(commands=Commands(base_height=NAN)),
        C,
        "command base_height",
    ),
    # --- robot loading ----------------------------------------------------------------------------------
    (
        "silent",
        "foot radius < 0",
        lambda: _robot(foot_radius=-0.02),
        R,
        "foot_radius must be a finite number in [0, 1]",
    ),
    ("silent", "foot radius NaN", lambda: _robot(foot_radius=NAN), R, "foot_radius"),
    ("silent", "foot radius 2 m", lambda: _robot(foot_radius=2.0), R, "foot_radius"),
    (
        "silent",
        "same foot four times",
        lambda: _robot(foot_frames=("FL_foot",) * 4),
        R,
        "foot_frames names ['FL_foot'] more than once",
    ),
    (
        "unclear",
        "foot_frames a string",
        lambda: _robot(foot_frames="FL_foot"),
        R,
        "foot_frames must be a list of names, got the string 'FL_foot'",
    ),
    (
        "unclear",
        "foot frame ids",
        lambda: _robot(foot_frames=(10, 20, 30, 40)),
        R,
        "foot_frames must hold names",
    ),
    ("named", "no feet", lambda: _robot(foot_frames=()), R, "foot_frames must hold at least 1"),
    (
        "unclear",
        "unknown frame lists frames",
        lambda: _robot(foot_frames=("FL_fot", *FEET[1:])),
        R,
        "did you mean ['FL_foot'",
    ),
    ("unclear", "unknown ee frame lists frames", lambda: _robot(ee_frame="gripper"), R, "frames: ["),
    ("unclear", "ee frame an id", lambda: _robot(ee_frame=5), R, "ee_frame must be a name"),
    (
        "named",
        "ee frame is a foot",
        lambda: _robot(ee_frame="FL_foot"),
        R,
        "ee_frame 'FL_foot' is also one of the foot_frames",
    ),
    (
        "unclear",
        "locked joint ids",
        lambda: _robot(locked_joints=(17, 18)),
        R,
        "locked_joints must hold names",
    ),
    (
        "unclear",
        "locked joints a string",
        lambda: _robot(locked_joints="joint5"),
        R,
        "locked_joints must be a list of names",
    ),
    ("named", "unknown locked joint", lambda: _robot(locked_joints=("joint9",)), R, "unknown joint 'joint9'"),
    (
        "unclear",
        "extra frame bad offset",
        lambda: _robot(extra_frames={"tcp": ("gripperMover", (0.05, 0.0))}),
        R,
        "extra_frames['tcp']",
    ),
    (
        "unclear",
        "extra frame not a pair",
        lambda: _robot(extra_frames={"tcp": "gripperMover"}),
        R,
        "extra_frames['tcp'] must be (parent_frame, (x, y, z))",
    ),
    (
        "silent",
        "extra pose NaN",
        lambda: _robot(extra_poses={"reach": {"joint1": NAN}}),
        R,
        "extra_poses['reach']['joint1']",
    ),
    (
        "unclear",
        "extra pose joint id",
        lambda: _robot(extra_poses={"reach": {3: 0.5}}),
        R,
        "joints are given by name",
    ),
    (
        "silent",
        "q_reference NaN",
        lambda: _robot(srdf=None, reference_pose=None, q_reference=np.full(26, NAN)),
        R,
        "q_reference must be finite",
    ),
    (
        "named",
        "q_reference short",
        lambda: _robot(srdf=None, reference_pose=None, q_reference=np.zeros(5)),
        R,
        "q_reference must have shape (26,)",
    ),
    (
        "silent",
        "q_reference zero quaternion",
        lambda: _robot(srdf=None, reference_pose=None, q_reference=np.zeros(26)),
        R,
        "q_reference[3:7] is the base quaternion",
    ),
    ("named", "unknown pose", lambda: _robot(reference_pose="sitting"), R, "SRDF pose 'sitting' not found"),
    ("unclear", "pose an index", lambda: _robot(reference_pose=0), R, "reference_pose must be a name"),
    (
        "silent",
        "front_force_ratio NaN",
        lambda: _robot(front_force_ratio=NAN),
        R,
        "front_force_ratio must be",
    ),
    (
        "unclear",
        "front_force_ratio string",
        lambda: _robot(front_force_ratio="half"),
        R,
        "front_force_ratio must be",
    ),
    (
        "named",
        "front_force_ratio 1",
        lambda: _robot(front_force_ratio=1.0),
        R,
        "front_force_ratio must be a finite number in (0, 1)",
    ),
    (
        "named",
        "missing URDF",
        lambda: _robot(urdf="/nonexistent/robot.urdf"),
        R,
        "URDF file not found: /nonexistent/robot.urdf",
    ),
    ("named", "missing SRDF", lambda: _robot(srdf="/nonexistent/robot.srdf"), R, "SRDF file not found"),
    ("unclear", "URDF a number", lambda: _robot(urdf=42), R, "urdf must be a file path"),
    (
        "unclear",
        "malformed SRDF",
        lambda: _robot(srdf=_srdf_file('<robot name="x">\n<group_state name="a">\n')),
        R,
        "poses.srdf is not valid XML",
    ),
    (
        "silent",
        "SRDF of another robot",
        lambda: _robot(
            srdf=_srdf_file(
                '<robot name="go1"><group_state name="stand" group="all">'
                '<joint name="FL_hip" value="0"/><joint name="FL_thigh" value="0.8"/></group_state></robot>'
            ),
            reference_pose="stand",
        ),
        R,
        "the SRDF's joints do not match the URDF's",
    ),
    ("named", "built-in robot name", lambda: load("spot"), R, "unknown robot 'spot'"),
    ("named", "unknown pose of a robot", lambda: _b1z1().pose("sit"), R, "unknown pose 'sit'"),
    ("unclear", "frame id of an int", lambda: _b1z1().frame_id(3), R, "frames are given by name"),
    (
        "named",
        "joint index of unknown joint",
        lambda: _b1z1().joint_index_v("elbow"),
        R,
        "unknown joint 'elbow'",
    ),
    # --- gaits and swing --------------------------------------------------------------------------------
    ("named", "swing height NaN", lambda: SwingParams(height=NAN), C, "SwingParams.height must be finite"),
    (
        "named",
        "swing height 0.8",
        lambda: SwingParams(height=0.8),
        C,
        "SwingParams.height must be in (0, 0.5)",
    ),
    (
        "silent",
        "swing lift-off downwards",
        lambda: SwingParams(v_liftoff=-0.1),
        C,
        "SwingParams.v_liftoff must be in [0, 2]",
    ),
    (
        "silent",
        "swing touchdown upwards",
        lambda: SwingParams(v_touchdown=0.3),
        C,
        "SwingParams.v_touchdown must be in [-2, 0]",
    ),
    (
        "named",
        "swing lift-off NaN",
        lambda: SwingParams(v_liftoff=NAN),
        C,
        "SwingParams.v_liftoff must be finite",
    ),
    (
        "named",
        "gait offsets three",
        lambda: Gait("g", 0.8, 0.5, (0.0, 0.5, 0.5)),
        C,
        "offsets must be 4 phases in [0, 1)",
    ),
    (
        "named",
        "gait offset 1.0",
        lambda: Gait("g", 0.8, 0.5, (0.0, 0.5, 0.5, 1.0)),
        C,
        "offsets must be 4 phases",
    ),
    (
        "named",
        "gait offset NaN",
        lambda: Gait("g", 0.8, 0.5, (0.0, 0.5, 0.5, NAN)),
        C,
        "offsets must be 4 phases",
    ),
    (
        "unclear",
        "gait offsets words",
        lambda: Gait("g", 0.8, 0.5, ("a", "b", "c", "d")),
        C,
        "offsets must be 4 phases",
    ),
    (
        "named",
        "gait period NaN",
        lambda: Gait("g", NAN, 0.5, (0.0, 0.5, 0.5, 0.0)),
        C,
        "period must be finite and > 0",
    ),
    (
        "named",
        "gait swing fraction 1",
        lambda: Gait("g", 0.8, 1.0, (0.0, 0.5, 0.5, 0.0)),
        C,
        "swing_fraction must be in [0, 1)",
    ),
    (
        "named",
        "gait period off tick",
        lambda: make_gait("trot", 0.80025),
        C,
        "not a multiple of the schedule tick",
    ),
    ("named", "unknown gait", lambda: make_gait("gallop"), C, "unknown gait 'gallop'"),
    ("named", "schedule empty", lambda: GaitSchedule([]), C, "GaitSchedule needs at least one"),
    (
        "named",
        "schedule duration NaN",
        lambda: GaitSchedule([(make_gait("stand"), NAN)]),
        C,
        "segment 0 (stand) duration must be finite",
    ),
    (
        "named",
        "schedule duration < 0",
        lambda: GaitSchedule([(make_gait("stand"), -1.0)]),
        C,
        "segment 0 (stand) duration",
    ),
    (
        "named",
        "schedule item a name",
        lambda: GaitSchedule([("trot", 2.0)]),
        C,
        "segment 0: 'trot' is not a Gait",
    ),
    (
        "named",
        "schedule item single",
        lambda: GaitSchedule([make_gait("trot")]),
        C,
        "segment 0 must be a (gait, duration) pair",
    ),
    (
        "named",
        "schedule string duration",
        lambda: parse_gait_schedule("stand:two"),
        C,
        "duration 'two' is not a number",
    ),
    ("named", "schedule t NaN", lambda: make_gait("trot").contact(NAN), C, "t must be finite"),
    # --- arm reference, low level, sensing, estimation, statics -----------------------------------------
    ("unclear", "arm period NaN", lambda: ArmReference(period=NAN), C, "ArmReference.period"),
    ("named", "arm period 0", lambda: ArmReference(period=0.0), C, "ArmReference.period"),
    (
        "silent",
        "arm amplitude NaN",
        lambda: ArmReference(amplitude=(0.05, NAN, 0.15)),
        C,
        "ArmReference.amplitude",
    ),
    (
        "unclear",
        "arm amplitude two",
        lambda: ArmReference(amplitude=(0.05, 0.15)),
        C,
        "ArmReference.amplitude",
    ),
    ("silent", "arm phase inf", lambda: ArmReference(phase=(0.0, INF, 0.0)), C, "ArmReference.phase"),
    ("silent", "arm center NaN", lambda: ArmReference(center=(0.5, NAN, 0.4)), C, "ArmReference.center"),
    ("silent", "arm ramp < 0", lambda: ArmReference(ramp=-1.0), C, "ArmReference.ramp"),
    ("silent", "low level kp < 0", lambda: LowLevelController(kp=-1.0), C, "kp must be finite gains >= 0"),
    (
        "silent",
        "low level kd NaN",
        lambda: LowLevelController(kd=np.array([1.0, NAN])),
        C,
        "kd must be finite gains",
    ),
    (
        "named",
        "sensor noise < 0",
        lambda: SensorNoise(joint_position=-0.01),
        C,
        "SensorNoise.joint_position must be",
    ),
    ("named", "sensor noise NaN", lambda: SensorNoise(base_velocity=NAN), C, "SensorNoise.base_velocity"),
    (
        "unclear",
        "sensor noise string",
        lambda: SensorNoise(joint_velocity="0.1"),
        C,
        "SensorNoise.joint_velocity",
    ),
    (
        "unclear",
        "sensor seed < 0",
        lambda: SensorNoise(seed=-1),
        C,
        "SensorNoise.seed must be an integer >= 0",
    ),
    ("unclear", "sensor seed float", lambda: SensorNoise(seed=0.5), C, "SensorNoise.seed"),
    ("named", "filter cutoff 0", lambda: LowPassFilter(0.0, 0.002), C, "cutoff_hz must be > 0"),
    ("named", "filter dt 0", lambda: LowPassFilter(50.0, 0.0), C, "dt must be > 0"),
    (
        "named",
        "estimator noise < 0",
        lambda: EstimatorNoise(gyro=-0.1),
        C,
        "EstimatorNoise.gyro must be finite and >= 0",
    ),
    ("named", "estimator noise NaN", lambda: EstimatorNoise(foot_slip=NAN), C, "EstimatorNoise.foot_slip"),
    (
        "named",
        "estimator noise 0",
        lambda: EstimatorNoise(foot_position=0.0),
        C,
        "EstimatorNoise.foot_position must be > 0",
    ),
    ("named", "estimator dt 0", lambda: _estimator(dt=0.0), C, "dt must be > 0"),
    ("named", "estimator dt NaN", lambda: _estimator(dt=NAN), C, "dt must be > 0"),
    (
        "named",
        "estimator cutoff < 0",
        lambda: _estimator(velocity_cutoff_hz=-50.0),
        C,
        "cutoff_hz must be > 0",
    ),
    ("named", "estimator reset NaN", lambda: _estimator().reset(np.full(26, NAN), np.zeros(22)), C, "q0"),
    (
        "named",
        "statics no stance foot",
        lambda: _statics([False] * 4),
        C,
        "contact: at least one foot must be in contact",
    ),
    ("named", "statics three flags", lambda: _statics([True] * 3), C, "contact must be 4 booleans"),
    (
        "named",
        "statics ee force NaN",
        lambda: _statics([True] * 4, ee_force=(0, NAN, 0)),
        C,
        "ee_force must be finite",
    ),
    ("named", "statics weight 1", lambda: _statics([True] * 4, weight=1.0), C, "weight must be in (0, 1)"),
    # --- the runtime and the direct driver's settings (issues 21, 22) --------------------------------------
    (
        "silent",
        "runtime realtime_priority 0",
        lambda: _runtime_config(realtime_priority=0),
        C,
        "realtime_priority must be a SCHED_FIFO priority in 1..99",
    ),
    (
        "silent",
        "runtime controller_phase beyond the period",
        lambda: _runtime_config(controller_phase=0.002),
        C,
        "controller_phase must be in [0, period = 0.002) s",
    ),
    (
        "silent",
        "solver threads 0",
        lambda: SolverSettings(threads=0),
        C,
        "SolverSettings.threads must be an integer >= 1 and <= 8",
    ),
    (
        "silent",
        "solver direct not a bool",
        lambda: SolverSettings(direct="yes"),
        C,
        "SolverSettings.direct must be True, False or None",
    ),
    (
        "silent",
        "solver direct with IPOPT",
        lambda: SolverSettings(solver="ipopt", direct=True),
        C,
        "direct needs solver='fatrop'",
    ),
    (
        "silent",
        "solver release_build not a bool",
        lambda: SolverSettings(release_build="no"),
        C,
        "release_build must be True or False",
    ),
    (
        "silent",
        "deadline loop phase beyond the period",
        lambda: _deadline_loop(phase_s=0.003),
        C,
        "phase_s",
    ),
    (
        "silent",
        "runtime controller seq_step 0",
        lambda: _runtime_controller(seq_step=0),
        C,
        "seq_step",
    ),
    # --- rosbag topic map -------------------------------------------------------------------------------
    (
        "named",
        "topic map no joint states",
        lambda: TopicMap(joint_states=None),
        C,
        "TopicMap.joint_states cannot be None",
    ),
    (
        "silent",
        "topic without slash",
        lambda: TopicMap(imu="imu"),
        C,
        "TopicMap.imu must be a topic name starting with '/'",
    ),
    ("silent", "topic a number", lambda: TopicMap(odometry=5), C, "TopicMap.odometry must be a topic name"),
    ("silent", "topic with a space", lambda: TopicMap(meta="/wbmpc meta"), C, "TopicMap.meta"),
    (
        "named",
        "foot topic no template",
        lambda: TopicMap(foot_forces="/feet/force"),
        C,
        "TopicMap.foot_forces must contain '{foot}'",
    ),
    (
        "unclear",
        "required a string",
        lambda: TopicMap(required="imu"),
        C,
        "TopicMap.required must be a list of names",
    ),
    (
        "named",
        "required unknown",
        lambda: TopicMap(required=["lidar"]),
        C,
        "TopicMap.required names unknown fields ['lidar']",
    ),
    ("silent", "required but None", lambda: TopicMap(imu=None), C, "TopicMap.required lists ['imu']"),
    (
        "silent",
        "foot names repeated",
        lambda: TopicMap(foot_names=["FL", "FL", "RL", "RR"]),
        C,
        "TopicMap.foot_names names ['FL'] more than once",
    ),
    (
        "silent",
        "foot names empty",
        lambda: TopicMap(foot_names=[]),
        C,
        "TopicMap.foot_names must hold at least 1",
    ),
    (
        "unclear",
        "joint names a string",
        lambda: TopicMap(joint_names="FL_hip_joint"),
        C,
        "TopicMap.joint_names must be a list of names",
    ),
    (
        "silent",
        "joint name map a list",
        lambda: TopicMap(joint_name_map=["a", "b"]),
        C,
        "TopicMap.joint_name_map must map",
    ),
    (
        "silent",
        "ignore joints ints",
        lambda: TopicMap(ignore_joints=[1, 2]),
        C,
        "TopicMap.ignore_joints must hold names",
    ),
    (
        "silent",
        "frame id empty",
        lambda: TopicMap(base_frame=""),
        C,
        "TopicMap.base_frame must be a non-empty frame id",
    ),
    (
        "named",
        "gap factor 1",
        lambda: TopicMap(max_gap_factor=1.0),
        C,
        "TopicMap.max_gap_factor must be a finite number > 1",
    ),
    ("named", "gap factor NaN", lambda: TopicMap(max_gap_factor=NAN), C, "TopicMap.max_gap_factor"),
    (
        "named",
        "unknown topic map key",
        lambda: TopicMap.from_dict({"lidar": "/scan"}),
        C,
        "unknown TopicMap keys ['lidar']",
    ),
    (
        "unclear",
        "topic map bad JSON",
        lambda: TopicMap.from_json('{"imu": }'),
        C,
        "TopicMap JSON: the JSON string is not valid JSON",
    ),
    # --- solver options, deployment, plants (the redesign's new entry points) ----------------------------
    (
        "named",
        "solver options unknown solver",
        lambda: solver_options("snopt", tol=1e-3, max_iter=10, mu_init=1e-4, warm=True),
        C,
        "solver must be one of ('fatrop', 'ipopt'), got 'snopt'",
    ),
    (
        "named",
        "solver options tol 0",
        lambda: solver_options("fatrop", tol=0.0, max_iter=10, mu_init=1e-4, warm=True),
        C,
        "tol must be",
    ),
    (
        "named",
        "solver options max_iter 0",
        lambda: solver_options("fatrop", tol=1e-3, max_iter=0, mu_init=1e-4, warm=True),
        C,
        "max_iter must be",
    ),
    (
        "named",
        "export with IPOPT options",
        lambda: export(None, "/nonexistent/never_written", {"ipopt": {}}),
        C,
        "export needs Fatrop's options",
    ),
    (
        "named",
        "rigid plant pushed at the hand",
        lambda: _rigid_plant().step(np.zeros(_b1z1().nj), np.ones(4, bool), ee_force=np.ones(3)),
        C,
        "the rigid-contact plant has no scene: ee_force needs the PyBullet plant",
    ),
    (
        "named",
        "array with NaN",
        lambda: checks.array("q_hat", [0.0, NAN], 2),
        C,
        "q_hat must be finite (q_hat contains NaN or inf",
    ),
    (
        "named",
        "array of the wrong shape",
        lambda: checks.array("v_hat", np.zeros(3), 22),
        C,
        "v_hat must have shape (22,), got (3,)",
    ),
    # --- run logs (issue 23): the path, the field, the file and the fix --------------------------------
    (
        "unclear",
        "load_log a directory",
        lambda: load_log(_tmp()),
        IsADirectoryError,
        "is a directory, not a log file",
    ),
    (
        "unclear",
        "load_log a directory of logs",
        lambda: load_log(_log_file("run.npz").parent),
        IsADirectoryError,
        "give the path of a .npz log (logs in it: run.npz)",
    ),
    (
        "unclear",
        "log format_version a string",
        lambda: load_log(_log_file("format_version.npz", meta={"format_version": "1"})),
        C,
        "format_version.npz: meta field 'format_version' must be an integer >= 0 (this wbmpc writes 1), "
        "got '1' (str); fix that field",
    ),
    (
        "silent",
        "log partial a string",
        lambda: load_log(_log_file("partial.npz", meta={"partial": "no"})),
        C,
        "partial.npz: meta field 'partial' must be true or false, got 'no'",
    ),
    (
        "unclear",
        "log t_reached a string",
        lambda: load_log(_log_file("t_reached.npz", meta={"t_reached": "2.5 s"})),
        C,
        "meta field 't_reached' must be a number of seconds or null, got '2.5 s'",
    ),
    (
        "silent",
        "log summary a list",
        lambda: load_log(_log_file("summary.npz", meta={"summary": [1, 2]})),
        C,
        "meta field 'summary' must be an object or null",
    ),
    (
        "silent",
        "log chunks a float",
        lambda: load_log(_log_file("chunks.npz", meta={"chunks": 2.5})),
        C,
        "chunks.npz: meta field 'chunks' must be an integer >= 0, got 2.5 (float)",
    ),
    (
        "silent",
        "log requested duration a string",
        lambda: load_log(_log_file("duration.npz", meta={"requested_duration_s": "10"})),
        C,
        "meta field 'requested_duration_s' must be a number of seconds or null, got '10' (str)",
    ),
    (
        "unclear",
        "streamed log meta.json with a bad field",
        lambda: load_log(_parts_folder({"format_version": "one"})),
        C,
        "meta.json: meta field 'format_version' must be an integer >= 0",
    ),
    (
        "silent",
        "log joint names a string",
        lambda: save_log(RunLog(signals={"t": np.arange(3.0)}, meta={"joint_names": "FL_hip"}), _tmp() / "a"),
        C,
        "the log's meta: meta field 'joint_names' must be a list of joint names, got 'FL_hip' (str)",
    ),
    (
        "unclear",
        "log time column of strings",
        lambda: load_log(_log_file("strings.npz", columns={"signals/t": np.array(["0", "1"])})),
        C,
        "strings.npz: time column 't' must hold numbers (seconds), got dtype <U1",
    ),
    (
        "unclear",
        "log column a scalar",
        lambda: save_log(RunLog(signals={"t": np.arange(3.0), "x": np.float64(1.0)}), _tmp() / "a"),
        C,
        "column 'x' is a scalar (np.float64(1.0)): every column needs one row per sample",
    ),
    (
        "unclear",
        "save_log under a file",
        lambda: save_log(RunLog(signals={"t": np.arange(3.0)}), _file("results") / "run.npz"),
        NotADirectoryError,
        "results is a file, not a folder; choose an output path outside it, or move or remove",
    ),
    (
        "unclear",
        "save_log two folders under a file",
        lambda: save_log(RunLog(signals={"t": np.arange(3.0)}), _file("out") / "a" / "run.npz"),
        NotADirectoryError,
        "out is a file, not a folder",
    ),
    (
        "unclear",
        "streamed log under a file",
        lambda: LogWriter(_file("streamed") / "run.npz"),
        NotADirectoryError,
        "streamed is a file, not a folder; choose an output path outside it",
    ),
    (
        "unclear",
        "save_log onto a folder",
        lambda: save_log(RunLog(signals={"t": np.arange(3.0)}), _tmp("run.npz")),
        IsADirectoryError,
        "run.npz: it is a folder; give a file name",
    ),
    (
        "unclear",
        "log a text file",
        lambda: load_log(_file("notes.npz", b"hello, not a log")),
        C,
        "notes.npz is not a .npz log: it does not start like a zip archive (first bytes b'hello, n')",
    ),
    (
        "unclear",
        "log a pickle",
        lambda: load_log(_file("pickled.npz", __import__("pickle").dumps({"t": [0.0]}))),
        C,
        "wbmpc never loads pickled data: re-write the log with wbmpc.io.logs.save_log",
    ),
    (
        "unclear",
        "log column of objects",
        lambda: load_log(_log_file("objects.npz", columns={"signals/t": np.array([0.0, "a"], dtype=object)})),
        C,
        "objects.npz: entry 'signals/t' holds Python objects (pickled data), which wbmpc logs never contain",
    ),
    (
        "unclear",
        "log an empty file",
        lambda: load_log(_file("empty.npz", b"")),
        C,
        "empty.npz is empty (0 bytes)",
    ),
    (
        "unclear",
        "log a single .npy",
        lambda: load_log(_npy_file()),
        C,
        "single.npy is a single .npy array, not a .npz log",
    ),
    # --- compiled solver library (issue 23) ------------------------------------------------------------
    (
        "unclear",
        "compiled library of another horizon",
        lambda: _nlpsol_from(_foreign_library()),
        C,
        "was built for N = 15 nodes, not for N = 4 nodes: it has 10 variables (this OCP: 282)",
    ),
    (
        "unclear",
        "compiled library of another horizon: the fix",
        lambda: _nlpsol_from(_foreign_library()),
        C,
        "Rebuild it for this OCP (wbmpc.solver.codegen.build(ocp, force=True); SolverSettings(compiled=True) "
        "builds its own), or clear the cache (delete",
    ),
    (
        "unclear",
        "compiled library missing",
        lambda: _nlpsol_from(_tmp() / "libwbmpc_nlp.so"),
        FileNotFoundError,
        "no compiled NLP library at",
    ),
    (
        "unclear",
        "compiled library not a library",
        lambda: _nlpsol_from(_file("libwbmpc_nlp.so", b"not an ELF file")),
        C,
        "libwbmpc_nlp.so does not load",
    ),
    # --- commands beyond physical limits (issue 23): refused where they are built ------------------------
    (
        "unclear",
        "command speed 1e6 m/s",
        lambda: CommandSchedule(base_velocity=(1e6, 0.0, 0.0)),
        C,
        "CommandSchedule.base_velocity: base speed 1e+06 m/s is beyond the physical limit of 10 m/s",
    ),
    (
        "unclear",
        "command lateral speed 50 m/s",
        lambda: CommandSchedule(base_velocity=(0.0, 50.0, 0.0)),
        C,
        "base speed 50 m/s is beyond the physical limit of 10 m/s",
    ),
    (
        "unclear",
        "command yaw rate in deg/s",
        lambda: CommandSchedule(base_yaw_rate=90.0),
        C,
        "CommandSchedule.base_yaw_rate: yaw rate 90 rad/s is beyond the physical limit of 10 rad/s",
    ),
    (
        "unclear",
        "command hand speed 50 m/s",
        lambda: CommandSchedule(ee_velocity=(0.0, 0.0, 50.0)),
        C,
        "CommandSchedule.ee_velocity: end-effector speed 50 m/s is beyond the physical limit of 10 m/s",
    ),
    (
        "unclear",
        "gait schedule segment at 1e6 m/s",
        lambda: MPCConfig(gait=parse_gait_schedule("stand:1,trot@1e6:2")),
        C,
        "MPCConfig.gait segment 1 (trot@1e+06): base speed 1e+06 m/s is beyond the physical limit of 10 m/s",
    ),
    (
        "unclear",
        "command schedule gait segment at 30 m/s",
        lambda: CommandSchedule(gait=parse_gait_schedule("trot@30:2")),
        C,
        "CommandSchedule.gait segment 0 (trot@30): base speed 30 m/s",
    ),
    (
        "unclear",
        "command override at 100 m/s",
        lambda: CommandSchedule(overrides=lambda t: {"base_velocity": (100.0, 0, 0)}).at(0.5),
        C,
        "CommandSchedule.overrides at t = 0.500 s: base speed 100 m/s is beyond the physical limit",
    ),
    (
        "named",
        "measured velocity NaN",
        lambda: _mpc_solve(v_hat=np.full(22, NAN)),
        C,
        "v_hat must be finite (v_hat contains NaN or inf",
    ),
]


def _tmp(name: str | None = None) -> Path:
    """A new empty folder (or, with ``name``, a new empty folder of that name inside one)."""
    import tempfile

    folder = Path(tempfile.mkdtemp(prefix="wbmpc_bad_log_"))
    if name is not None:
        (folder / name).mkdir()
        return folder / name
    return folder


def _file(name: str, data: bytes = b"x") -> Path:
    path = _tmp() / name
    path.write_bytes(data)
    return path


def _log_file(name: str, meta: dict | None = None, columns: dict | None = None) -> Path:
    """A log archive written by hand (as another tool would), with the given meta and columns."""
    import json

    path = _tmp() / name
    columns = {"signals/t": np.arange(3.0)} if columns is None else columns
    np.savez(path, **columns, meta=np.array(json.dumps(meta or {})))
    return path


def _parts_folder(meta: dict) -> Path:
    """The ``.parts`` folder a killed streamed run leaves, with the given ``meta.json``."""
    import json

    parts = _tmp("run.npz.parts")
    (parts / "meta.json").write_text(json.dumps(meta))
    return parts


def _npy_file() -> Path:
    path = _tmp() / "single.npy"
    np.save(path, np.zeros(3))
    return path


@functools.cache
def _foreign_library() -> Path:
    """A compiled ``nlp`` of 10 variables with the build record of a 15-node cache entry."""
    import json
    import subprocess

    import casadi as ca

    folder = _tmp("0123456789abcdef")
    x, p = ca.SX.sym("x", 10), ca.SX.sym("p", 3)
    nlp = ca.Function("nlp", [x, p], [ca.sumsqr(x), x[:5]], ["x", "p"], ["f", "g"])
    generator = ca.CodeGenerator("foreign.c")
    generator.add(nlp)
    generator.add(ca.Function("nlp_hess_l", [x, p], [ca.SX.eye(10)], ["x", "p"], ["hess"]))
    generator.generate(str(folder) + "/")
    library = folder / "libwbmpc_nlp.so"
    subprocess.run(
        ["gcc", "-shared", "-fPIC", "-O0", str(folder / "foreign.c"), "-o", str(library)], check=True
    )
    (folder / "build.json").write_text(json.dumps({"ocp_settings": {"n_nodes": 15}}))
    return library


def _nlpsol_from(library: Path):
    mpc = _module_mpc()
    return make_nlpsol(
        "x", "fatrop", mpc.ocp.nlp, mpc.solver_options(False), library, n_nodes=mpc.ocp.n_nodes
    )


def _rigid_plant():
    from wbmpc.sim.plant import ContactPlant

    robot = _b1z1()
    plant = ContactPlant(robot.model, robot.foot_frames, foot_radius=robot.foot_radius)
    plant.reset(robot.q_nominal, np.zeros(robot.nv))
    return plant


@pytest.mark.parametrize(
    "kind, call, error, message",
    [(c[0], c[2], c[3], c[4]) for c in CATALOGUE],
    ids=[f"{c[0]}: {c[1]}" for c in CATALOGUE],
)
def test_catalogue(kind, call, error, message):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(error) as err:
            call()
    assert message in str(err.value), f"{kind}: {err.value}"
    assert err.type is error or issubclass(err.type, error)


# --- corrupt logs: never the advice to unpickle (issue 23) -------------------------------------------------
@pytest.mark.parametrize(
    "data", [b"hello, not a log", b"\x80\x04\x95 pickled", b"PK\x03\x04 truncated zip", b""], ids=repr
)
def test_a_corrupt_log_never_advises_allow_pickle(data):
    with pytest.raises(ValueError) as err:
        load_log(_file("corrupt.npz", data))
    assert "corrupt.npz" in str(err.value)
    assert "allow_pickle" not in str(err.value) and "pickle.load" not in str(err.value)


def test_an_object_column_is_refused_by_name_never_unpickled():
    path = _log_file("objects.npz", columns={"signals/t": np.arange(2.0), "signals/x": np.array([{}, 1])})
    with pytest.raises(ValueError) as err:
        load_log(path)
    assert "entry 'signals/x' holds Python objects" in str(err.value)
    assert "allow_pickle" not in str(err.value)


# --- absurd measurements: a failed solve that names them, the loop goes on (issue 23) ----------------------
def _absurd(kind: str):
    robot = _b1z1()
    q, v = robot.q_nominal.copy(), np.zeros(robot.nv)
    if kind == "base speed":
        v[0] = 1e3
    elif kind == "base rate":
        v[5] = 200.0
    elif kind == "joint position":
        q[7 + robot.joint_names.index("FL_calf_joint")] = 2.0
    elif kind == "joint speed":
        v[6 + robot.joint_names.index("RR_thigh_joint")] = 1e3
    return q, v


ABSURD = [
    (
        "base speed",
        "absurd measurement: base speed |v_hat[0:3]| [m/s] = 1000, no legged robot moves faster than 20",
    ),
    ("base rate", "absurd measurement: base angular speed |v_hat[3:6]| [rad/s] = 200, above 50 rad/s"),
    ("joint position", "joint position FL_calf_joint (q_hat[9]) = 2, 2.6 beyond its limits [-2.600, -0.600]"),
    ("joint speed", "joint speed RR_thigh_joint (v_hat[16]) [rad/s] = 1000, over 5 times its limit"),
]


@pytest.mark.parametrize("kind, message", ABSURD, ids=[k for k, _ in ABSURD])
def test_an_absurd_measurement_fails_the_solve_by_name_and_the_controller_falls_back(kind, message):
    mpc = _module_mpc()
    mpc.reset()
    good = mpc.solve(mpc.robot.q_nominal, np.zeros(mpc.robot.nv))
    assert good.success
    failures = mpc.stats["failures"]
    plan = mpc.solve(*_absurd(kind), t=0.02)
    assert not plan.success and plan.fallback and not plan.hold  # the previous plan, shifted
    assert plan.status == "absurd_measurement" and message in plan.reason
    assert "the controller falls back" in plan.reason
    assert any(f.code == "absurd_measurement" and message in f.message for f in plan.findings)
    assert mpc.stats["failures"] == failures + 1
    assert mpc.solve(mpc.robot.q_nominal, np.zeros(mpc.robot.nv), t=0.04).success  # the next tick solves
    mpc.reset()
    held = mpc.solve(*_absurd(kind))  # no plan yet: the static hold, still named
    assert held.hold and held.status == "absurd_measurement" and message in held.reason


def test_an_absurd_measurement_in_the_closed_loop_is_counted_and_explained_and_the_run_goes_on(
    monkeypatch, capsys
):
    from wbmpc.sim.closed_loop import run_closed_loop
    from wbmpc.sim.planner import Planner

    mpc = _module_mpc()
    mpc.reset()
    real = Planner.plan

    def faulty_sensor(self, q_meas, v_meas, t, plan_in_use, record_delay=True):
        if 0.1 <= t < 0.15:  # the base velocity estimate reads 1 km/s for a few ticks
            v_meas = v_meas.copy()
            v_meas[0] = 1e3
        return real(self, q_meas, v_meas, t, plan_in_use, record_delay)

    monkeypatch.setattr(Planner, "plan", faulty_sensor)
    config = ClosedLoopConfig(duration=0.3, commands=CommandSchedule(base_velocity=(0.0, 0.0, 0.0)))
    result = run_closed_loop(mpc, config, progress=False)
    assert not result.fell
    reasons = result.summary["diagnostics"]["failure_reasons"]
    assert set(reasons) == {"absurd_measurement"} and reasons["absurd_measurement"] == 4  # 80 Hz for 50 ms
    status = list(result.log.run_log().solves["status"])
    assert status.count("absurd_measurement") == 4 and status.count("success") == len(status) - 4
    printed = capsys.readouterr().out
    assert "absurd_measurement" in printed and "base speed |v_hat[0:3]| [m/s] = 1000" in printed


def test_a_non_unit_quaternion_is_solved_with_a_warning_that_names_it():
    """Any non-zero quaternion is a rotation (the MPC normalises it); a norm far from 1 is worth a look."""
    mpc = _module_mpc()
    mpc.reset()
    q = mpc.robot.q_nominal.copy()
    q[3:7] *= 2.0
    plan = mpc.solve(q, np.zeros(mpc.robot.nv))
    assert plan.success
    warned = [f for f in plan.findings if f.code == "non_unit_quaternion"]
    assert [f.severity for f in warned] == ["warning"]
    message = "suspicious measurement: |q_hat[3:7]| (base quaternion norm) = 2, a unit quaternion has norm 1"
    assert message in warned[0].message


def test_a_plausible_measurement_is_not_called_absurd():
    from wbmpc.control.prechecks import absurd_measurement

    robot = _b1z1()
    q, v = robot.q_nominal.copy(), np.zeros(robot.nv)
    q[3:7] *= 1.05  # normalised by the MPC, not a fault
    v[0], v[5] = 3.0, 5.0
    q[7 + robot.joint_names.index("FL_calf_joint")] = -0.5  # 0.1 rad beyond: a joint_position_limit finding
    assert absurd_measurement(robot, q, v) == []


# --- the arm-torque precheck flags only what the MPC cannot meet (issue 23): both sides of the limit ------
@functools.cache
def _mpc_15_nodes():
    return WholeBodyMPC(_b1z1(), OCPSettings(n_nodes=15), MPCConfig(gait=make_gait("stand")))


def test_an_upward_force_the_mpc_meets_is_not_called_infeasible():
    """100 N up needs 40.7 N m at joint3 held still (limit 30): the plan lets the arm give way, meets it."""
    from wbmpc.control.prechecks import ee_force_feasibility

    robot = _b1z1()
    inside = np.array([0.0, 0.0, 100.0])
    findings = ee_force_feasibility(robot, robot.q_nominal, inside)
    assert [f.severity for f in findings] == ["warning"] and findings[0].code == "ee_force_needs_arm_motion"
    assert "joint3" in findings[0].message and "the arm has to move under the force" in findings[0].message
    mpc = _mpc_15_nodes()
    mpc.reset()
    plan = mpc.solve(robot.q_nominal, np.zeros(robot.nv), commands=Commands(ee_force=inside))
    assert plan.success, plan.reason
    np.testing.assert_allclose(plan.forces[0, -1], inside, atol=1e-6)
    assert not any(f.severity == "error" for f in plan.findings)


def test_a_force_clearly_beyond_the_arm_is_an_error_and_beyond_the_weight_is_refused():
    from wbmpc.control.prechecks import TORQUE_YIELD_FACTOR, ee_force_feasibility

    robot = _b1z1()
    beyond = ee_force_feasibility(robot, robot.q_nominal, np.array([0.0, 0.0, 150.0]))  # 65 N m at joint3
    errors = [f for f in beyond if f.severity == "error"]
    assert [f.code for f in errors] == ["ee_force_exceeds_torque_limit"]
    assert errors[0].data["joint"] == "joint3" and errors[0].data["needed"] > TORQUE_YIELD_FACTOR * 30.0
    assert "above its 30.0 N m limit" in errors[0].message
    weight = robot.mass * robot.gravity
    with pytest.raises(
        ValueError, match="command refused: upward end-effector force .* exceeds the robot's weight"
    ):
        _mpc_solve(commands=Commands(ee_force=np.array([0.0, 0.0, weight + 50.0])))


# --- a cache entry holding a library of another horizon is named with the fix (issue 23) -------------------
def test_a_cached_library_of_another_horizon_is_named_with_the_fix(tmp_path, monkeypatch):
    import json
    import shutil

    from wbmpc.solver import codegen

    robot = _b1z1()
    mpc = WholeBodyMPC(
        robot, OCPSettings(n_nodes=4), MPCConfig(gait=make_gait("stand")), SolverSettings(compiled=True)
    )
    mpc.verbose = False
    key, _ = codegen.cache_key(mpc.ocp, tuple(mpc.solver_settings.compile_flags))
    entry = tmp_path / key  # the entry of this 4-node OCP, holding a 15-node library (e.g. a copied cache)
    entry.mkdir()
    shutil.copy(_foreign_library(), entry / "libwbmpc_nlp.so")
    record = {"ocp_settings": {"n_nodes": 15}, "build_s": 1.0, "build_peak_mb": 1.0, "c_bytes": 1}
    record["library_sha256"] = codegen._sha256(entry / "libwbmpc_nlp.so")
    (entry / "build.json").write_text(json.dumps(record))
    monkeypatch.setenv("WBMPC_CACHE_DIR", str(tmp_path))
    with pytest.raises(ValueError) as err:
        mpc.solve(robot.q_nominal, np.zeros(robot.nv))
    message = str(err.value)
    assert (
        f"the compiled NLP library {entry / 'libwbmpc_nlp.so'} was built for N = 15 nodes, not for N = 4"
        in message
    )
    assert "wbmpc.solver.codegen.build(ocp, force=True)" in message and f"delete {entry}" in message
    assert "option has wrong length" not in message


# --- warned, not refused: the input can be right, the message says what to check and how to fix it ----------
def test_the_srdf_of_another_robot_is_warned():
    """b1.srdf on the B1 + Z1 URDF: every arm joint would silently be 0 in the reference pose."""
    with pytest.warns(UserWarning, match=r"the SRDF's joints do not match the URDF's: .*'joint1'"):
        _robot(srdf=B1_SRDF, reference_pose="standing", locked_joints=())


def test_a_disturbance_after_the_end_of_the_run_is_warned():
    with pytest.warns(UserWarning, match="after the end of the run"):
        _pb_loop(duration=1.0, disturbances=(Kick(2.0, (0, 1, 0)),))


def test_valid_inputs_still_pass_without_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _pb_loop(
            duration=1.0,
            delay=0.0125,
            disturbances=(Kick(0.5, (0, 1, 0)), Push(0.2, 0.1, (10, 0, 0, 0, 0, 1))),
            low_level=LowLevelConfig(kp=30.0, arm_gains=(5.0, 0.5)),
            plant=PlantConfig(
                kind="pybullet",
                scene=[
                    Payload(2.0, (1, 0, 0.05), attach="tether"),
                    Wall((1, 0, 0.5), (-1, 0, 0)),
                    Box((1, 1, 1), (2, 0, 0.5)),
                ],
            ),
        ).steps()
        _b1z1()
        load("b1")
        Commands(base_height=0.5).validated()
        TopicMap(required=["joint_states"], imu=None)
        SwingParams(height=0.1, v_liftoff=0.0, v_touchdown=0.0)
        ArmReference(center=(0.5, 0.0, 0.4), ramp=0.0)


# --- command lines: refused before any work, exit status 2, a one-line reason -------------------------------
def _cli(module: str):
    import importlib

    return importlib.import_module(f"wbmpc.studies.{module}").main


CLI_CASES = [
    ("demo", ["--nodes", "1000"], "--nodes must be <= 100"),
    ("demo", ["--nodes", "0"], "--nodes must be"),
    ("demo", ["--release"], "--release sets the compiler flags"),
    ("demo", ["--duration", "-1"], "--duration must be"),
    ("bench", ["--steps", "0"], "--steps must be an integer >= 1"),
    ("bench", ["--steps", "-5"], "--steps must be an integer >= 1"),
    ("bench", ["--warmup", "-1"], "--warmup must be an integer >= 0"),
    ("bench", ["--batch", "0"], "--batch must be an integer >= 1"),
    ("bench", ["--case", "fatrop,compiled,0"], "--case NODES must be an integer in [3, 100]"),
    ("bench", ["--case", "fatrop,compiled,500"], "--case NODES must be an integer in [3, 100]"),
    ("bench", ["--case", "snopt,compiled,15"], "expected SOLVER,MODE,NODES"),
    (
        "bench",
        ["--output", "/proc/bench.json"],
        "--output /proc/bench.json: its folder /proc is not a writable folder",
    ),
    ("bench", ["--output", "/tmp"], "--output /tmp is a folder"),
    ("bench", ["--steps", "ten"], "invalid int value: 'ten'"),
    ("table1", ["--steps", "0"], "--steps must be an integer >= 1"),
    ("table1", ["--steps", "-1"], "--steps must be an integer >= 1"),
    ("table1", ["--warmup", "-3"], "--warmup must be an integer >= 0"),
    ("table1", ["--nodes", "0"], "--nodes must be an integer in [3, 100]"),
    ("table1", ["--nodes", "2"], "--nodes must be an integer in [3, 100]"),
    ("table1", ["--nodes", "1000"], "--nodes must be an integer in [3, 100]"),
    ("table1", ["--kp", "-1"], "--kp must be a finite number >= 0"),
    ("table1", ["--kd", "nan"], "--kd must be a finite number >= 0"),
    (
        "table1",
        ["--output", "/proc/t.csv"],
        "--output /proc/t.csv: its folder /proc is not a writable folder",
    ),
    ("table1", ["--formulations", "magic"], "invalid choice: 'magic'"),
    ("experiments", ["kicks"], "unknown experiments ['kicks']"),
    ("experiments", ["arm_tracking", "wipe"], "unknown experiments ['wipe']"),
]


class _WorkStartedError(Exception):
    """Raised by the stand-in robot loader: a command line started working before refusing its input."""


@pytest.mark.parametrize(
    "module, argv, message", CLI_CASES, ids=[f"{m} {' '.join(a)}" for m, a, _ in CLI_CASES]
)
def test_command_lines(module, argv, message, capsys, monkeypatch):
    main = _cli(module)
    started = []

    def no_work(*args, **kwargs):
        started.append(args)
        raise _WorkStartedError(f"{module}: a robot was loaded before the argument check")

    # Every built-in robot goes through load_robot, looked up in wbmpc.model.robot at call time (the demo's
    # load() picks the loader from a table and the experiments import load_b1_z1 by name, so patching
    # load_b1_z1 itself would not see them).
    monkeypatch.setattr("wbmpc.model.robot.load_robot", no_work)
    with pytest.raises(SystemExit) as exit_info:
        main([*argv, "--quiet"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert message in err[-1], err
    assert not started


@pytest.mark.parametrize("module", ["demo", "bench", "table1", "experiments"])
def test_the_no_work_guard_sees_the_robot_loader_of_each_command_line(module, monkeypatch, tmp_path):
    """The guard above is only as good as the name it patches: with valid arguments each command line
    does reach the patched loader (so a check moved after the work would be caught)."""
    valid = {
        "demo": ["--nodes", "3", "--no-replay", "--output", str(tmp_path)],
        "bench": ["--steps", "1", "--output", str(tmp_path / "bench.json")],
        "table1": ["--steps", "1", "--output", str(tmp_path / "table1.csv")],
        "experiments": ["arm_tracking", "--quick", "--no-logs"],
    }

    def no_work(*args, **kwargs):
        raise _WorkStartedError(module)

    monkeypatch.setattr("wbmpc.model.robot.load_robot", no_work)
    with pytest.raises(_WorkStartedError):
        _cli(module)([*valid[module], "--quiet"])


def test_realtime_baseline_variants_need_a_baseline(capsys):
    """The real-time benchmark refuses a baseline variant without the checkout, before starting any run."""
    from wbmpc.studies import realtime

    with pytest.raises(SystemExit) as exit_info:
        realtime.main(["--variant", "baseline compiled"])
    assert exit_info.value.code == 2
    assert "the baseline variants need --baseline" in capsys.readouterr().err


def test_cli_node_bound_matches_the_ocp():
    from wbmpc.ocp.builder import MAX_NODES
    from wbmpc.studies import cli_checks

    assert cli_checks.MAX_NODES == MAX_NODES


def test_the_one_dot_product_finiteness_test_matches_the_elementwise_one():
    """checks.all_finite (the per-tick finiteness test of the readings, the plant's torques, the gait's times
    and the direct driver's vectors) says what np.isfinite says, also where x . x overflows."""
    rng = np.random.default_rng(5)
    cases = [rng.normal(size=40), np.full(40, 1e200), np.array([1e308, -1e308]), rng.normal(size=(4, 6))]
    for bad in (NAN, INF, -INF):
        for base in (rng.normal(size=40), np.full(40, 1e200)):
            x = base.copy()
            x[17] = bad
            cases.append(x)
    with np.errstate(over="ignore"):  # NumPy's remark on the overflowing squares
        for x in cases:
            assert checks.all_finite(x) == bool(np.isfinite(x).all()), x
        big = checks.array("tau", np.full(3, 1e200), 3)  # finite, though its square overflows: accepted
        assert np.all(big == 1e200)
        with pytest.raises(ValueError, match="tau must be finite"):
            checks.array("tau", [1e200, INF, 0.0], 3)
