"""The two-stage state estimator (IMU + leg kinematics) against PyBullet ground truth while trotting."""

import numpy as np
import pinocchio as pin
import pytest

from wbmpc.control.mpc import MPCConfig, WholeBodyMPC
from wbmpc.estimation import (
    EstimatorNoise,
    ImuNoise,
    ImuReading,
    JointReading,
    StateEstimator,
    contact_trust,
    synthesize_imu,
)
from wbmpc.model.robot import load_b1_z1
from wbmpc.ocp import OCPSettings
from wbmpc.ocp.gait import make_gait
from wbmpc.quick import pick
from wbmpc.sim.closed_loop import ClosedLoopConfig, run_closed_loop
from wbmpc.sim.loop_config import PlantConfig

DT = 0.002  # the low-level (logging) rate, 500 Hz
# A MEMS-grade IMU after its start-up calibration, and 12-bit-ish encoders.
IMU_NOISE = ImuNoise(
    gyro=0.003,
    accelerometer=0.05,
    gyro_bias=(0.005, -0.004, 0.003),
    accelerometer_bias=(0.05, -0.03, 0.04),
)
ENCODER_NOISE = 0.001  # [rad]
ENCODER_RATE_NOISE = 0.01  # [rad/s], before the estimator's 50 Hz low-pass


@pytest.fixture(scope="module")
def robot():
    return load_b1_z1()


@pytest.fixture(scope="module")
def trot(robot):
    """Ground truth of a short MPC-controlled trot on PyBullet at 0.2 m/s (500 Hz log)."""
    gait = make_gait("trot")
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=8), MPCConfig(gait=gait, dt_max=0.06))
    mpc.verbose = False
    result = run_closed_loop(
        mpc,
        ClosedLoopConfig(duration=pick(full=2.0, quick=1.0), plant=PlantConfig(kind="pybullet")),
        progress=False,
    )
    assert not result.fell
    log = result.log.arrays()
    assert np.allclose(np.diff(log["t"]), DT)
    return {"t": log["t"], "q": log["q"], "v": log["v"], "contact": log["contact"], "gait": gait}


def _estimate(robot, trot, imu_noise=None, encoders=True, q=None, v=None, **kwargs):
    """Feed the estimator offline from the logged ground truth; also record the covariances' health."""
    rng = np.random.default_rng(0)
    q = trot["q"] if q is None else q
    v = trot["v"] if v is None else v
    est = StateEstimator(robot, DT, **kwargs)
    est.reset(q[0], v[0])
    qs, vs, health = [q[0]], [v[0]], []
    for k in range(1, len(q)):
        imu = synthesize_imu(q[k], v[k], q[k - 1], v[k - 1], DT, noise=imu_noise, rng=rng)
        sq, sv = (ENCODER_NOISE, ENCODER_RATE_NOISE) if encoders else (0.0, 0.0)
        joints = JointReading(
            q[k, 7:] + sq * rng.standard_normal(robot.nj), v[k, 6:] + sv * rng.standard_normal(robot.nj)
        )
        t = trot["t"][k]
        q_hat, v_hat = est.update(imu, joints, trot["contact"][k], contact_trust(trot["gait"], t))
        qs.append(q_hat)
        vs.append(v_hat)
        health.append(
            [
                _asymmetry(est.P),
                np.linalg.eigvalsh(est.P).min(),
                _asymmetry(est.P_attitude),
                np.linalg.eigvalsh(est.P_attitude).min(),
            ]
        )
    return np.array(qs), np.array(vs), np.array(health)


def _asymmetry(P):
    return np.abs(P - P.T).max()


def _errors(q_true, v_true, q_hat, v_hat):
    """Velocity RMS [m/s], final position error [m], distance walked [m], max orientation error [deg]."""
    v_rms = np.sqrt(np.mean(np.sum((v_hat[:, :3] - v_true[:, :3]) ** 2, axis=1)))
    drift = np.linalg.norm(q_hat[-1, :3] - q_true[-1, :3])
    walked = np.sum(np.linalg.norm(np.diff(q_true[:, :2], axis=0), axis=1))
    angle = max(np.linalg.norm(pin.log3(_rot(a).T @ _rot(b))) for a, b in zip(q_hat, q_true, strict=True))
    return v_rms, drift, walked, np.degrees(angle)


def _rot(q):
    return pin.Quaternion(q[3:7]).normalized().toRotationMatrix()


@pytest.fixture(scope="module")
def noisy(robot, trot):
    return _estimate(robot, trot, imu_noise=IMU_NOISE)


# ---------------------------------------------------------------------------------------------- accuracy
def test_estimate_tracks_pybullet_trot_with_noisy_sensors(trot, noisy):
    q_hat, v_hat, _ = noisy
    v_rms, drift, walked, angle = _errors(trot["q"], trot["v"], q_hat, v_hat)
    print(
        f"v_rms={v_rms:.4f} m/s, drift={drift:.4f} m over {walked:.3f} m, max attitude error={angle:.3f} deg"
    )
    assert walked > 0.1  # the robot did walk
    assert v_rms < 0.05  # measured ~0.013 m/s
    assert drift < 0.05 * walked  # < 5 cm per metre walked (measured ~1.3 %)
    assert angle < 1.5  # [deg]; measured ~0.6 (mostly the unobservable yaw bias)
    assert np.allclose(q_hat[:, 7:], trot["q"][:, 7:], atol=5 * ENCODER_NOISE)  # joints passed through
    w_rms = np.sqrt(np.mean((v_hat[:, 3:6] - trot["v"][:, 3:6]) ** 2))
    assert w_rms < 0.01  # [rad/s] bias-corrected gyro


def test_exact_readings_give_a_near_exact_estimate(robot, trot):
    q_hat, v_hat, _ = _estimate(robot, trot, imu_noise=None, encoders=False)
    v_rms, drift, walked, angle = _errors(trot["q"], trot["v"], q_hat, v_hat)
    print(f"exact: v_rms={v_rms:.5f} m/s, drift={drift:.5f} m over {walked:.3f} m, angle={angle:.4f} deg")
    assert v_rms < 0.005 and drift < 0.005 and angle < 0.1  # measured 0.0016 m/s, 0.9 mm, 0.01 deg


def test_leg_kinematics_matter_imu_only_drifts(robot, trot, noisy):
    q_imu, v_imu, _ = _estimate(robot, trot, imu_noise=IMU_NOISE, use_kinematics=False)
    v_rms_imu, drift_imu, _, _ = _errors(trot["q"], trot["v"], q_imu, v_imu)
    v_rms, drift, _, _ = _errors(trot["q"], trot["v"], *noisy[:2])
    print(
        f"IMU only: v_rms={v_rms_imu:.4f} m/s, drift={drift_imu:.4f} m (with legs {v_rms:.4f}, {drift:.4f})"
    )
    assert v_rms_imu > 2 * v_rms  # measured ~6.5x (2 s run), ~3x (1 s quick run)
    assert drift_imu > 5 * drift  # measured ~20x (2 s), ~10x (1 s)


def test_imu_orientation_output_sharpens_the_attitude(robot, trot):
    imu_noise = ImuNoise(**{**IMU_NOISE.__dict__, "orientation": 0.005})
    q_hat, v_hat, _ = _estimate(robot, trot, imu_noise=imu_noise)
    v_rms, _, _, angle = _errors(trot["q"], trot["v"], q_hat, v_hat)
    assert angle < 0.3 and v_rms < 0.05  # measured 0.08 deg, 0.012 m/s


def test_velocity_is_in_the_base_frame(robot, trot):
    """The trot turned 90 deg about world z: q's position and orientation turn, v (base frame) does not."""
    yaw = pin.exp3(np.array([0.0, 0.0, np.pi / 2]))
    q = trot["q"].copy()
    q[:, :3] = q[:, :3] @ yaw.T
    q[:, 3:7] = [pin.Quaternion(yaw @ _rot(x)).coeffs() for x in trot["q"]]
    q_hat, v_hat, _ = _estimate(robot, trot, imu_noise=None, encoders=False, q=q)
    v_rms, drift, _, angle = _errors(q, trot["v"], q_hat, v_hat)
    assert v_rms < 0.005 and drift < 0.005 and angle < 0.1


def test_covariances_stay_symmetric_positive_definite(noisy):
    health = noisy[2]
    assert np.all(health[:, [0, 2]] < 1e-12)
    assert np.all(health[:, [1, 3]] > 0)


# ---------------------------------------------------------------------------------------------- unit tests
@pytest.mark.parametrize("rotvec", [(0.0, 0.0, 0.0), (0.05, -0.1, 2.0)])
def test_standing_still_with_exact_readings_keeps_the_state(robot, rotvec):
    q0 = robot.q_nominal
    q0[:3] = (0.3, -0.2, q0[2])
    q0[3:7] = pin.Quaternion(pin.exp3(np.array(rotvec))).coeffs()
    v0 = np.zeros(robot.nv)
    est = StateEstimator(robot, DT)
    est.reset(q0, v0)
    imu = synthesize_imu(q0, v0, q0, v0, DT)
    joints = JointReading(q0[7:], np.zeros(robot.nj))
    for k in range(500):
        q_hat, v_hat = est.update(imu, joints, np.ones(4, bool) if k % 2 else np.array([1, 0, 0, 1], bool))
    assert np.allclose(q_hat, q0, atol=1e-9)
    assert np.allclose(v_hat, 0.0, atol=1e-9)
    assert np.allclose(est.gyro_bias, 0.0, atol=1e-9)


def test_synthesized_imu_reads_gravity_and_acceleration():
    q = np.zeros(8)
    q[3:7] = pin.Quaternion(pin.exp3(np.array([0.3, -0.2, 1.0]))).coeffs()
    R = _rot(q)
    v_prev, v = np.zeros(7), np.zeros(7)
    a = np.array([1.0, -2.0, 0.5])
    v[:3] = R.T @ (a * DT)  # base-frame velocity after one period of constant world acceleration a
    v[3:6] = (0.1, 0.2, 0.3)
    imu = synthesize_imu(q, v, q, v_prev, DT)
    assert np.allclose(imu.accelerometer, R.T @ (a + [0, 0, 9.81]))
    assert np.allclose(imu.gyro, v[3:6]) and imu.orientation is None
    biased = synthesize_imu(q, v, q, v_prev, DT, noise=ImuNoise(gyro_bias=(0.01, 0, 0), orientation=0.0))
    assert np.allclose(biased.gyro - imu.gyro, (0.01, 0, 0))
    assert np.allclose(np.abs(biased.orientation @ q[3:7]), 1.0)


def test_contact_trust_ramps_at_touchdown_and_liftoff():
    gait = make_gait("trot")  # FL swings over [0, 0.4) s, stands over [0.4, 0.8) s
    assert contact_trust(gait, 0.2)[0] == 0.0  # swing
    assert contact_trust(gait, 0.6)[0] == 1.0  # mid-stance
    assert contact_trust(gait, 0.4)[0] == 0.0  # touchdown
    assert 0.0 < contact_trust(gait, 0.42)[0] < 1.0
    assert 0.0 < contact_trust(gait, 0.78)[0] < 1.0  # lift-off ahead
    assert np.array_equal(contact_trust(gait, 0.6, window=0.0), gait.contact(0.6).astype(float))


def test_bad_inputs_raise_value_errors_naming_the_input(robot):
    q0, v0 = robot.q_nominal, np.zeros(robot.nv)
    est = StateEstimator(robot, DT)
    imu = synthesize_imu(q0, v0, q0, v0, DT)
    joints = JointReading(q0[7:], np.zeros(robot.nj))
    contact = np.ones(4, bool)
    with pytest.raises(RuntimeError, match="reset"):
        est.update(imu, joints, contact)
    with pytest.raises(ValueError, match="q0"):
        est.reset(q0[:-1], v0)
    est.reset(q0, v0)
    with pytest.raises(ValueError, match="imu.gyro"):
        ImuReading(gyro=[np.nan, 0, 0], accelerometer=[0, 0, 9.81])
    with pytest.raises(ValueError, match="imu.accelerometer"):
        ImuReading(gyro=[0, 0, 0], accelerometer=[0, 9.81])
    with pytest.raises(ValueError, match="imu.orientation"):
        ImuReading(gyro=[0, 0, 0], accelerometer=[0, 0, 9.81], orientation=[0, 0, 0, 0])
    with pytest.raises(ValueError, match="joints.velocities"):
        JointReading(q0[7:], np.zeros(3))
    with pytest.raises(ValueError, match="joints.positions"):
        JointReading(np.full(robot.nj, np.inf), np.zeros(robot.nj))
    with pytest.raises(ValueError, match="joints.positions"):
        est.update(imu, JointReading(q0[8:], np.zeros(robot.nj - 1)), contact)
    with pytest.raises(ValueError, match="contact"):
        est.update(imu, joints, np.ones(3, bool))
    with pytest.raises(ValueError, match="trust"):
        est.update(imu, joints, contact, trust=[1.0, 1.0, np.nan, 1.0])
    with pytest.raises(ValueError, match="trust"):
        est.update(imu, joints, contact, trust=[1.0, 2.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="imu"):
        est.update("imu", joints, contact)
    with pytest.raises(ValueError, match="EstimatorNoise.gyro"):
        EstimatorNoise(gyro=-1.0)
    with pytest.raises(ValueError, match="dt"):
        StateEstimator(robot, 0.0)
    with pytest.raises(ValueError, match="dt"):
        synthesize_imu(q0, v0, q0, v0, 0.0)
    with pytest.raises(ValueError, match="v_prev"):
        synthesize_imu(q0, v0, q0, v0[:-1], DT)
    # A failed update leaves the filter usable.
    q_hat, _ = est.update(imu, joints, contact)
    assert np.allclose(q_hat, q0, atol=1e-9)
