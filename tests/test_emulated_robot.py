"""The emulated robot (issue 13): each hardware mismatch changes the PyBullet plant as stated, and the MPC
keeps standing with the state estimator in the loop and on the full "hardware" profile."""

import numpy as np
import pinocchio as pin
import pytest

from wbmpc.control.mpc import MPCConfig, WholeBodyMPC
from wbmpc.model.robot import load_b1_z1
from wbmpc.model.statics import static_equilibrium
from wbmpc.ocp import OCPSettings
from wbmpc.ocp.gait import make_gait
from wbmpc.sim.actuators import ActuatedPlant, Actuators, MotorModel
from wbmpc.sim.closed_loop import ClosedLoopConfig, run_closed_loop
from wbmpc.sim.hardware import EstimatedState, HardwareProfile, rear_leg_share
from wbmpc.sim.loop_config import CommandSchedule, PlantConfig, SensingConfig
from wbmpc.sim.plant import ContactPlant
from wbmpc.sim.presets import hardware_config
from wbmpc.sim.pybullet_plant import PyBulletPlant

DT = 0.0005  # plant step [s]


@pytest.fixture(scope="module")
def robot():
    return load_b1_z1()


@pytest.fixture(scope="module")
def standing_mpc(robot):
    """A small standing MPC (8 nodes, in-process Fatrop): short runs on 2 shared cores."""
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=8), MPCConfig(gait=make_gait("stand"), dt_max=0.06))
    mpc.verbose = False
    return mpc


def _motor_plant(robot, motors: MotorModel, **options) -> ActuatedPlant:
    """PyBullet behind the motors (the plant's own clipping off: the motors saturate first)."""
    plant = PyBulletPlant(robot, dt=DT, clip_torques=False, **options)
    return ActuatedPlant(plant, Actuators(motors, robot.joint_torque_limits, DT))


def _airborne(robot, v_joints=None):
    """A state 3 m above the ground (no contacts for the next tens of milliseconds)."""
    q = robot.q_nominal.copy()
    q[2] = 3.0
    v = np.zeros(robot.nv)
    if v_joints is not None:
        v[6:] = v_joints
    return q, v


# ---------------------------------------------------------------------------------------------- profile
def test_profile_values_and_switches(robot):
    motors = HardwareProfile().motor_model(robot)
    calf = robot.joint_names.index("FL_calf_joint")
    arm = robot.joint_names.index("joint2")
    assert motors.coulomb[calf] == 1.0 and motors.armature[calf] == 0.04
    assert motors.armature[arm] == 0.005 and motors.latency == 0.003
    np.testing.assert_allclose(HardwareProfile().base_com_offset, [-0.19, 0.0, 0.0])
    ideal_profile = HardwareProfile.ideal()
    ideal = ideal_profile.motor_model(robot)
    assert not any(np.any(getattr(ideal, k)) for k in ("coulomb", "viscous", "armature"))
    assert ideal_profile.base_com_offset is None and ideal.latency == 0.0
    config = hardware_config(duration=1.0)
    assert (config.plant.kind, config.sensing.state, config.delay) == ("pybullet", "estimated", "measured")
    low = config.low_level
    assert (low.kp, low.kd, low.arm_gains, low.joint_pd, config.sensing.velocity_cutoff_hz) == (
        0.0,
        20.0,
        (5.0, 1.0),
        "drive",
        50.0,
    )
    assert config.commands.ramp == (0.3, 0.5) and config.delay_compensation


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: SensingConfig(state="filtered"), "state must be"),
        (lambda: PlantConfig(hardware=HardwareProfile()), "needs PlantConfig\\(kind='pybullet'\\)"),
        (lambda: PlantConfig(kind="pybullet", hardware="b1"), "HardwareProfile"),
        (lambda: ClosedLoopConfig(sensing="estimated"), "ClosedLoopConfig.sensing must be a SensingConfig"),
    ],
)
def test_config_rejects_bad_state_and_hardware(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_profile_rejects_bad_values():
    with pytest.raises(ValueError, match="leg_armature"):
        HardwareProfile(leg_armature=(0.1, -0.1, 0.0))
    with pytest.raises(ValueError, match="torque_latency"):
        HardwareProfile(torque_latency=-0.001)


# ---------------------------------------------------------------------------------------------- mismatches
def test_friction_torque_opposes_velocity(robot):
    c, b, vs = 1.0, 0.2, 0.05
    rates = np.linspace(-2.0, 2.0, robot.nj)  # includes small rates of both signs
    motors = MotorModel(coulomb=c, viscous=b, friction_velocity=vs)
    with _motor_plant(robot, motors, joint_damping=False) as plant:
        plant.reset(*_airborne(robot, rates))
        plant.step(np.zeros(robot.nj))
        tau_f = plant.friction_torque
    np.testing.assert_allclose(tau_f, -(c * np.tanh(rates / vs) + b * rates), atol=1e-12)
    assert np.all(tau_f * rates < 0)  # opposes the motion
    assert np.all(np.abs(tau_f) <= c + b * np.abs(rates))  # smooth: below c + b |v| near zero


def test_friction_decelerates_a_free_joint(robot):
    calf = robot.joint_names.index("FL_calf_joint")
    rates = np.zeros(robot.nj)
    rates[calf] = 1.0
    final = []
    for c in (0.0, 1.0):
        with _motor_plant(robot, MotorModel(coulomb=c), joint_damping=False) as plant:
            plant.reset(*_airborne(robot, rates))
            for _ in range(20):
                state = plant.step(np.zeros(robot.nj))
            final.append(state.v[6 + calf])
    assert final[0] - final[1] > 0.1  # 1 N m on ~0.04 kg m^2 for 10 ms: ~0.25 rad/s slower


def test_armature_adds_reflected_inertia(robot):
    """A calf torque step in the air: the acceleration is that of M + diag(I_a), not of M."""
    calf = robot.joint_names.index("FL_calf_joint")
    armature = HardwareProfile().motor_model(robot).armature
    tau = np.zeros(robot.nj)
    tau[calf] = 2.0
    n = 20
    measured = []
    for a in (0.0, armature):
        with _motor_plant(robot, MotorModel(armature=a), joint_damping=False) as plant:
            plant.reset(*_airborne(robot))
            for _ in range(n):
                state = plant.step(tau)
            measured.append(state.v[6 + calf] / (n * DT))
    model, data = robot.model, robot.model.createData()
    M = pin.crba(model, data, _airborne(robot)[0])
    M = np.triu(M) + np.triu(M, 1).T
    predicted = []
    for a in (0.0, armature):
        qdd = np.linalg.solve(
            M + np.diag(np.r_[np.zeros(6), np.broadcast_to(a, robot.nj)]), np.r_[np.zeros(6), tau]
        )
        predicted.append(qdd[6 + calf])
    print(f"calf acceleration without/with armature: measured {measured}, predicted {predicted} rad/s^2")
    assert measured[0] == pytest.approx(predicted[0], rel=0.05)
    assert measured[1] == pytest.approx(predicted[1], rel=0.1)  # the two-step estimate lags ~1 ms
    assert measured[1] < 0.7 * measured[0]


def _standing_share(robot, **options) -> tuple[float, np.ndarray]:
    """Rear-leg share of the vertical foot force, holding the nominal pose (static torques + stiff PD)."""
    eq = static_equilibrium(robot, robot.q_nominal, np.ones(robot.n_feet, bool))
    forces = []
    with PyBulletPlant(robot, dt=DT, **options) as plant:
        state = plant.reset(robot.q_nominal, np.zeros(robot.nv))
        for k in range(1000):
            tau = eq.tau + 300.0 * (robot.q_nominal[7:] - state.q[7:]) - 10.0 * state.v[6:]
            state = plant.step(tau)
            if k >= 500:
                forces.append(plant.contact_forces())
    return rear_leg_share(np.array(forces)), state.q


def test_com_offset_moves_the_weight_to_the_rear_legs(robot):
    nominal, _ = _standing_share(robot)
    offset = np.asarray(HardwareProfile().base_com_offset)
    shifted, q = _standing_share(robot, base_com_offset=offset)
    print(f"rear-leg share: nominal {nominal:.3f}, with the base CoM offset {offset} m: {shifted:.3f}")
    assert nominal == pytest.approx(0.48, abs=0.02)  # the model's CoM is 1.3 cm ahead of the centre
    assert shifted == pytest.approx(0.60, abs=0.03)
    assert q[2] > 0.5  # still standing


def test_torque_latency_delays_a_torque_step(robot):
    latency = 0.003
    with _motor_plant(robot, MotorModel(latency=latency)) as plant:
        plant.reset(*_airborne(robot))
        step_at, applied = 4, []
        for k in range(20):
            plant.step(np.full(robot.nj, 1.0 if k >= step_at else 0.0))
            applied.append(plant.motor_torque[0])
    first = int(np.argmax(np.array(applied) > 0.5))
    assert (first - step_at) * DT == pytest.approx(latency)
    assert np.all(np.array(applied[first:]) == 1.0)


def test_motors_work_in_front_of_the_rigid_plant_too(robot):
    """The motors are no PyBullet feature: on the rigid-contact plant a saturated, delayed torque step
    reaches the joints at the limit, ``latency`` late, with the friction torque of the joint rates added."""
    limits = robot.joint_torque_limits
    latency, c, vs = 0.002, 0.5, 0.05
    rigid = ContactPlant(robot.model, robot.foot_frames, dt=DT, foot_radius=robot.foot_radius)
    plant = ActuatedPlant(
        rigid, Actuators(MotorModel(coulomb=c, friction_velocity=vs, latency=latency), limits, DT)
    )
    plant.reset(robot.q_nominal, np.zeros(robot.nv))
    stance = np.ones(robot.n_feet, bool)
    applied = []
    for k in range(10):
        rates = plant.state.v[6:]
        plant.step(np.full(robot.nj, 1e4 if k >= 2 else 0.0), stance)
        applied.append(plant.motor_torque)
        np.testing.assert_allclose(plant.friction_torque, -c * np.tanh(rates / vs), atol=1e-12)
    delay = round(latency / DT)
    np.testing.assert_array_equal(applied[1 + delay], 0.0)
    np.testing.assert_array_equal(applied[2 + delay], limits)  # clipped at the limits, then delayed
    assert np.all(plant.torque_clip_counts == 10 - 2)


def test_sensor_noise_has_the_stated_standard_deviation(robot):
    profile = HardwareProfile()
    sensor = EstimatedState(robot, make_gait("stand"), 0.002, profile)
    q, v = robot.q_nominal, np.zeros(robot.nv)
    sensor.reset(q, v)
    readings = [sensor.readings(q, v) for _ in range(2000)]
    joints = np.array([j.positions - q[7:] for _, j in readings])
    rates = np.array([j.velocities for _, j in readings])
    gyro = np.array([imu.gyro for imu, _ in readings])
    acc = np.array([imu.accelerometer for imu, _ in readings])
    assert joints.std() == pytest.approx(profile.encoder_noise, rel=0.05)
    assert rates.std() == pytest.approx(profile.encoder_velocity_noise, rel=0.05)
    np.testing.assert_allclose(gyro.std(axis=0), profile.imu.gyro, rtol=0.1)
    np.testing.assert_allclose(gyro.mean(axis=0), profile.imu.gyro_bias, atol=4 * profile.imu.gyro / 40)
    np.testing.assert_allclose(acc.std(axis=0), profile.imu.accelerometer, rtol=0.1)
    g = np.array([0.0, 0.0, robot.gravity])
    np.testing.assert_allclose(acc.mean(axis=0) - g, profile.imu.accelerometer_bias, atol=0.01)


# ---------------------------------------------------------------------------------------------- closed loop
def test_estimated_state_closed_loop_keeps_standing(standing_mpc):
    """Noisy, biased IMU and noisy encoders; the MPC and the low level see only the estimate."""
    sensors = HardwareProfile.ideal(
        imu=HardwareProfile().imu, encoder_noise=5e-4, encoder_velocity_noise=0.05
    )
    config = ClosedLoopConfig(
        duration=1.5,
        plant=PlantConfig(kind="pybullet", hardware=sensors),
        sensing=SensingConfig(state="estimated", velocity_cutoff_hz=50.0),
        commands=CommandSchedule(base_velocity=(0.0, 0.0, 0.0)),
    )
    result = run_closed_loop(standing_mpc, config, progress=False)
    err = result.summary["estimate_error"]
    print(f"estimate errors: {err}")
    assert not result.fell
    assert result.summary["max_tilt_rad"] < 0.05
    log = result.log.arrays()
    assert not np.allclose(log["q_meas"], log["q"])  # the controller saw the estimate, not the truth
    assert err["height_max_m"] < 0.01
    assert err["velocity_rms_mps"] < 0.03
    assert err["tilt_max_rad"] < 0.02


def test_hardware_profile_keeps_standing(standing_mpc):
    """Every mismatch on (fixed one-period computation delay instead of the measured one, reproducible)."""
    result = run_closed_loop(
        standing_mpc,
        hardware_config(duration=1.5, delay=0.0125, commands=CommandSchedule(base_velocity=(0.0, 0.0, 0.0))),
        progress=False,
    )
    s = result.summary
    log = result.log.arrays()
    share = rear_leg_share(log["foot_forces"][len(log["t"]) // 2 :])
    print(f"tilt {s['max_tilt_rad']:.3f} rad, height {s['base_height_range_m']}, rear share {share:.3f}")
    print(f"estimate errors: {s['estimate_error']}")
    assert not result.fell
    assert s["max_tilt_rad"] < 0.15
    assert s["base_height_range_m"][0] > 0.4
    assert share > 0.55  # the rear legs carry the offset base
    assert s["estimate_error"]["height_max_m"] < 0.02
