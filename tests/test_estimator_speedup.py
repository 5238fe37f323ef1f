"""The fast paths of the state estimator and of the PyBullet plant step reproduce the slow implementation.

``tests/data/estimator_reference.npz`` holds the outputs of the implementation before the speed-up (commit
61750b2) on the deterministic inputs generated here: synthetic base and joint motion read by the hardware
profile's noisy sensors (:class:`wbmpc.sim.hardware.SyntheticSensors`), fed through the estimator in the
loop (:class:`wbmpc.sim.hardware.EstimatedState`, its contact lookups included) and the bare
:class:`wbmpc.estimation.StateEstimator`; and 200 steps of the emulated robot's plant (PyBullet behind the
motors and the motor drives) under random torques. The estimates and the plant must match to 1e-12 (the
plant bit for bit on the CPU that wrote the reference), counts exactly.

Regenerate the reference (only when the algorithm changes on purpose)::

    python tests/test_estimator_speedup.py --write
"""

import sys
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from wbmpc.estimation import ImuNoise, StateEstimator, contact_trust
from wbmpc.model.robot import load_b1_z1
from wbmpc.ocp.gait import make_gait, parse_gait_schedule
from wbmpc.sim.actuators import ActuatedPlant, Actuators
from wbmpc.sim.hardware import EstimatedState, HardwareProfile, PlannedContacts, SyntheticSensors
from wbmpc.sim.motor_drive import MotorDrive

REFERENCE = Path(__file__).resolve().parent / "data" / "estimator_reference.npz"
DT = 0.002  # [s] the estimator's period (500 Hz)
PLANT_DT = 0.0005  # [s] the emulated robot's plant step
N_STEPS = 200


# ---------------------------------------------------------------------------------------------- inputs
def _trajectory(robot, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Synthetic motion at ``n + 1`` samples ``DT`` apart: the base moving forward, bobbing, rolling,
    pitching and turning, the joints swinging about the nominal pose; velocities by finite differences.

    Returns:
        ``(q, v)`` of shapes (n + 1, nq), (n + 1, nv), Pinocchio convention.
    """
    t = DT * np.arange(n + 1)
    q = np.tile(robot.q_nominal, (n + 1, 1))
    q[:, 0] = 0.3 * t
    q[:, 1] = 0.02 * np.sin(3.0 * t)
    q[:, 2] += 0.01 * np.sin(4.0 * np.pi * t)
    for k, tk in enumerate(t):
        rpy = np.array([0.05 * np.sin(5.0 * tk), 0.04 * np.sin(4.0 * tk + 0.5), 0.3 * tk])
        q[k, 3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(rpy)).coeffs()
    q[:, 7:] += 0.1 * np.sin(3.0 * np.pi * t[:, None] + np.arange(robot.nj))
    v = np.zeros((n + 1, robot.nv))
    for k in range(1, n + 1):
        v[k] = pin.difference(robot.model, q[k - 1], q[k]) / DT
    return q, v


def _aborted_swing_plan(schedule):
    """A contact plan: ``schedule`` with foot FR held on the ground over [0.13, 0.21) s (a swing aborted)."""

    def plan(times):
        times = np.atleast_1d(np.asarray(times, dtype=float))
        contact = schedule.sample(times).contact.copy()
        contact[1, (times >= 0.13 - 1e-9) & (times < 0.21 - 1e-9)] = True
        return contact

    return plan


def _states(estimates) -> np.ndarray:
    return np.array([np.concatenate(e) for e in estimates])


def generate(robot) -> dict[str, np.ndarray]:
    """Every output compared with the reference (estimator scenarios a-c, trust d, plant runs e-f)."""
    q, v = _trajectory(robot, N_STEPS)
    out = {}

    # a: the estimator in the loop on a stand -> trot schedule, hardware sensors.
    schedule = parse_gait_schedule("stand:0.1,trot:1,stand:1", period=0.4)
    est = EstimatedState(robot, schedule, DT, HardwareProfile())
    est.reset(q[0], v[0])
    out["a_states"] = _states(est.measure(q[k], v[k], DT * k) for k in range(1, N_STEPS + 1))
    out["a_P"], out["a_P_attitude"] = est.estimator.P, est.estimator.P_attitude

    # b: a contact plan with an aborted swing, an IMU with an orientation output, another tuning.
    imu = ImuNoise(gyro=0.002, accelerometer=0.04, gyro_bias=(0.004, 0.0, -0.002), orientation=0.01)
    profile = HardwareProfile(imu=imu, seed=3)
    est = EstimatedState(robot, PlannedContacts(_aborted_swing_plan(make_gait("trot", 0.3))), DT, profile)
    est.reset(q[0], v[0])
    out["b_states"] = _states(est.measure(q[k], v[k], DT * k) for k in range(1, N_STEPS + 1))[::4]
    out["b_P"], out["b_P_attitude"] = est.estimator.P, est.estimator.P_attitude

    # c: the bare estimator: unfiltered rates, no trust (stance flags), then IMU dead reckoning.
    gait = make_gait("walk", 0.4)
    for name, kinematics in (("c", True), ("c_imu", False)):
        sensors = SyntheticSensors(DT, HardwareProfile(seed=5))
        est = StateEstimator(robot, DT, velocity_cutoff_hz=None, use_kinematics=kinematics)
        sensors.reset(q[0], v[0])
        est.reset(q[0], v[0])
        states = []
        for k in range(1, N_STEPS + 1):
            imu_reading, joints = sensors.readings(q[k], v[k])
            states.append(est.update(imu_reading, joints, gait.contact(DT * k)))
        out[f"{name}_states"] = _states(states)[::4]
        out[f"{name}_P"], out[f"{name}_bias"] = est.P, est.gyro_bias

    # d: contact trust of a gait and a schedule over times around their switches.
    times = np.arange(0.0, 0.8, 0.0035)
    schedules = {"gait": make_gait("trot", 0.4), "schedule": parse_gait_schedule("stand:0.2,walk:0.4,trot:1")}
    for name, sched in schedules.items():
        out[f"d_trust_{name}"] = np.array([contact_trust(sched, t) for t in times])
        out[f"d_trust_{name}_coarse"] = np.array([contact_trust(sched, t, 0.02, 3) for t in times[::5]])
        out[f"d_trust_{name}_flags"] = np.array([contact_trust(sched, t, 0.0) for t in times[::5]])

    out |= _plant_runs(robot)
    return out


def _plant_runs(robot) -> dict[str, np.ndarray]:
    """e: the emulated robot's plant (PyBullet behind the motors, the motor drives in front) under random
    feed-forward torques, a base push and a gripper push; f: the bare plant clipping its torques."""
    from wbmpc.sim.pybullet_plant import PyBulletPlant

    rng = np.random.default_rng(11)
    nj, limits = robot.nj, robot.joint_torque_limits
    profile = HardwareProfile()
    offset = np.array(profile.base_com_offset)
    plant = ActuatedPlant(
        PyBulletPlant(robot, dt=PLANT_DT, base_com_offset=offset, clip_torques=False),
        Actuators(profile.motor_model(robot), limits, PLANT_DT),
    )
    drive = MotorDrive(np.full(nj, 40.0), np.full(nj, 1.5), limits, latency_steps=6)
    state = plant.reset(robot.q_nominal, np.zeros(robot.nv))
    states, forces = [], []
    for k in range(N_STEPS):
        if k % 4 == 0:
            drive.command(rng.normal(0.0, 40.0, nj), robot.q_nominal[7:], np.zeros(nj))
        wrench = np.array([30.0, -10.0, 0.0, 0.0, 0.0, 3.0]) if 50 <= k < 60 else None
        push = np.array([0.0, 15.0, -5.0]) if 100 <= k < 110 else None
        tau = drive.torque(state.q[7:], state.v[6:])
        if 150 <= k < 160:  # beyond the drives' limits: the motors clip
            tau = tau + rng.normal(0.0, 80.0, nj)
        state = plant.step(tau, external_wrench=wrench, ee_force=push)
        states.append((state.q, state.v))
        forces.append(plant.contact_forces())
    out = {
        "e_states": _states(states)[::2],
        "e_forces": np.array(forces)[::2],
        "e_time": np.array([state.t]),
        "e_clips": plant.torque_clip_counts,
        "e_motor": plant.motor_torque,
        "e_friction": plant.friction_torque,
        "e_drive_clips": drive.clipped_steps,
        "e_counts": np.array([plant.violation_counts[k] for k in ("slipping", "penetrating")]),
        "e_ee_force": plant.ee_contact_force(),
    }
    plant.close()

    with PyBulletPlant(robot, dt=PLANT_DT) as bare:
        state = bare.reset(robot.q_nominal, np.zeros(robot.nv))
        for _ in range(50):
            state = bare.step(rng.normal(0.0, 120.0, nj))
        out["f_state"] = np.concatenate([state.q, state.v])
        out["f_clips"] = bare.torque_clip_counts
        out["f_contact"] = bare.contact
    return out


# ---------------------------------------------------------------------------------------------- tests
@pytest.fixture(scope="module")
def outputs():
    return generate(load_b1_z1())


@pytest.fixture(scope="module")
def reference():
    with np.load(REFERENCE) as data:
        return dict(data)


def test_the_reference_is_small():
    assert REFERENCE.stat().st_size < 200_000


@pytest.mark.parametrize("prefix", ["a_", "b_", "c_", "d_"])
def test_estimates_match_the_reference(outputs, reference, prefix):
    keys = [k for k in reference if k.startswith(prefix)]
    assert keys
    for key in keys:
        assert outputs[key].shape == reference[key].shape, key
        diff = np.max(np.abs(outputs[key] - reference[key]))
        assert diff <= 1e-12, f"{key}: max |difference| {diff:.3g}"


def test_plant_steps_match_the_reference_to_the_last_bits(outputs, reference):
    """Counts and flags equal; floating-point outputs equal up to a few units in the last place.

    Bit identity held on the CPU that wrote the reference (AVX2) but not on an AVX-512 one, where numpy's
    vectorised math rounds some results differently (1.1e-16 on the 100-step states): the tolerance is
    that rounding, ten thousand times below any change of the plant's physics.
    """
    keys = [k for k in reference if k[:2] in ("e_", "f_")]
    assert len(keys) == 12
    for key in keys:
        assert outputs[key].dtype == reference[key].dtype, key
        assert outputs[key].shape == reference[key].shape, key
        if np.issubdtype(reference[key].dtype, np.floating):
            diff = np.max(np.abs(outputs[key] - reference[key]), initial=0.0)
            assert diff <= 1e-12, f"{key}: max |difference| {diff:.3g}"
        else:
            assert np.array_equal(outputs[key], reference[key]), f"{key} differs from the reference"


if __name__ == "__main__":
    if sys.argv[1:] != ["--write"]:
        sys.exit("usage: python tests/test_estimator_speedup.py --write")
    REFERENCE.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(REFERENCE, **generate(load_b1_z1()))
    print(f"wrote {REFERENCE} ({REFERENCE.stat().st_size} bytes)")
