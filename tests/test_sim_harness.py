"""Simulation harness: sensing and filtering, columnar logs, computation delay, disturbances, errors."""

import numpy as np
import pinocchio as pin
import pytest

from wbmpc.control.mpc import MPCConfig, WholeBodyMPC
from wbmpc.estimation.filters import LowPassFilter
from wbmpc.io.logs import RunLog, load_log, save_log
from wbmpc.model.robot import load_b1_z1
from wbmpc.ocp import OCPSettings
from wbmpc.ocp.gait import make_gait
from wbmpc.sim.closed_loop import ClosedLoopConfig, run_closed_loop
from wbmpc.sim.disturbances import Kick, Push
from wbmpc.sim.loop_config import CommandSchedule, LowLevelConfig, PlantConfig, SensingConfig
from wbmpc.sim.sensing import SensorNoise, StateSensor


@pytest.fixture(scope="module")
def robot():
    return load_b1_z1()


def test_low_pass_step_response_and_attenuation():
    dt, fc = 0.002, 50.0
    f = LowPassFilter(fc, dt)
    alpha = dt / (dt + 1 / (2 * np.pi * fc))
    f(np.zeros(1))
    out = [f(np.ones(1))[0] for _ in range(5)]
    np.testing.assert_allclose(out, 1 - (1 - alpha) ** np.arange(1, 6))
    # A 200 Hz sine (4x the cut-off) comes out attenuated, a 2 Hz one passes.
    t = np.arange(0, 1, dt)
    for freq, low, high in ((200.0, 0.0, 0.35), (2.0, 0.95, 1.01)):
        f = LowPassFilter(fc, dt)
        y = np.array([f(np.array([np.sin(2 * np.pi * freq * ti)]))[0] for ti in t])
        amplitude = np.abs(y[len(y) // 2 :]).max()
        assert low <= amplitude <= high, (freq, amplitude)


def test_sensor_ground_truth_noise_and_filter(robot):
    q, v = robot.q_nominal, np.linspace(-1, 1, robot.nv)
    truth = StateSensor(robot.model, 0.002)
    assert truth.is_ground_truth
    qm, vm = truth.measure(q, v)
    assert np.array_equal(qm, q) and np.array_equal(vm, v)
    noisy = StateSensor(robot.model, 0.002, SensorNoise(joint_position=0.01, base_orientation=0.02, seed=3))
    samples = np.array([noisy.measure(q, v)[0] for _ in range(2000)])
    assert abs(np.std(samples[:, 7:] - q[7:]) - 0.01) < 0.001
    assert np.allclose(np.linalg.norm(samples[:, 3:7], axis=1), 1.0)  # still unit quaternions
    filtered = StateSensor(robot.model, 0.002, velocity_cutoff_hz=50.0)
    filtered.measure(q, np.zeros(robot.nv))
    _, v1 = filtered.measure(q, v)
    assert np.allclose(v1[:6], v[:6])  # the base velocity is not filtered
    assert np.all(np.abs(v1[6:]) < np.abs(v[6:]) + 1e-12) and np.abs(v1[6:] - v[6:]).max() > 0.1
    with pytest.raises(ValueError, match="joint_velocity"):
        SensorNoise(joint_velocity=-1.0)


def test_log_round_trip_and_errors(tmp_path):
    log = RunLog(
        signals={"t": np.arange(5) * 0.002, "q": np.random.default_rng(0).normal(size=(5, 3))},
        solves={"solve_t": np.array([0.0, 0.0125]), "status": np.array(["ok", "max iter"])},
        meta={"robot": "b1_z1", "summary": {"fell": False}},
    )
    path = save_log(log, tmp_path / "run")
    assert path.suffix == ".npz"
    back = load_log(path)
    np.testing.assert_array_equal(back["q"], log.signals["q"])
    assert list(back["status"]) == ["ok", "max iter"]
    assert back.meta["summary"] == {"fell": False} and back.meta["format_version"] == 1
    assert back.duration == pytest.approx(0.008)
    with pytest.raises(ValueError, match="column 'q' has 4 rows"):
        save_log(RunLog(signals={"t": np.zeros(5), "q": np.zeros((4, 3))}), tmp_path / "bad")
    with pytest.raises(FileNotFoundError, match="no log file"):
        load_log(tmp_path / "missing.npz")
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(ValueError, match="not a wbmpc log"):
        load_log(tmp_path / "other.npz")
    with pytest.raises(KeyError, match="no column 'tau'"):
        back["tau"]


def _com_velocity(robot, q, v):
    data = robot.model.createData()
    pin.centerOfMass(robot.model, data, q, v)
    return data.vcom[0]


# Whole solve-call times [s] given to the solves in turn with delay="measured", and the plant steps of
# 0.5 ms they round up to (by hand: 8.4 -> 9, 40, 60.2 -> 61).
INJECTED_SOLVE_TIMES = (0.0042, 0.02, 0.0301)
INJECTED_DELAY_STEPS = (9, 40, 61)


def _expected_solve_and_apply_steps(n_steps, per_mpc):
    """The documented timing with measured delay: a solve starts on an MPC tick once the previous plan has
    been applied; its plan applies its delay later (the first one at once: nothing to hold before it)."""
    solves, applies, busy_until = [], [], 0
    for step in range(0, n_steps, per_mpc):
        if step >= busy_until:
            k = len(solves)
            solves.append(step)
            applies.append(step if k == 0 else step + INJECTED_DELAY_STEPS[k % 3])
            busy_until = applies[-1]
    return solves, applies


@pytest.mark.parametrize("delay", ["off", 0.0125, "measured"])
def test_closed_loop_with_and_without_delay_keeps_standing(robot, delay, tmp_path, monkeypatch):
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=7), MPCConfig(gait=make_gait("stand")))
    mpc.verbose = False
    config = ClosedLoopConfig(
        duration=0.3,
        delay=delay,
        plant=PlantConfig(kind="pybullet"),
        low_level=LowLevelConfig(kd=5.0),
        sensing=SensingConfig(velocity_cutoff_hz=50.0),
        commands=CommandSchedule(arm_reference=None),
    )
    if delay == "measured":  # injected solve times: the outcome does not depend on this machine's speed
        solve, calls = mpc.solve, []

        def timed_solve(*args, **kwargs):
            plan = solve(*args, **kwargs)
            seconds = INJECTED_SOLVE_TIMES[len(calls) % 3]
            calls.append(seconds)
            plan.solve_time = seconds
            plan.timings = {**plan.timings, "total": seconds}
            return plan

        monkeypatch.setattr(mpc, "solve", timed_solve)
    result = run_closed_loop(mpc, config, progress=False)
    assert not result.fell and result.summary["max_tilt_rad"] < 0.05
    log = result.log
    lag = np.array(log.apply_t) - np.array(log.solve_t)
    if delay == "off":
        assert np.all(lag == 0)
    elif delay == "measured":  # each plan applies after its own solve time, rounded up to plant steps
        solves, applies = _expected_solve_and_apply_steps(600, 25)
        assert len(solves) == 12 < 0.3 * 80  # fewer solves than 80 Hz: none starts before the last applies
        np.testing.assert_allclose(log.solve_t, np.array(solves) * config.plant.dt, rtol=0, atol=1e-12)
        np.testing.assert_allclose(log.apply_t, np.array(applies) * config.plant.dt, rtol=0, atol=1e-12)
    else:
        assert np.allclose(lag[1:], 0.0125, atol=config.plant.dt)
    run = load_log(result.save(tmp_path / f"run_{delay}"))
    assert run["q"].shape == (len(log.t), robot.nq)
    assert run["foot_forces"].shape == (len(log.t), 4, 3)
    # The feet are the only ground contacts, so over the last 0.1 s their vertical impulse minus the weight's
    # equals the change of vertical momentum (the robot may still sway: a slow machine makes fewer solves).
    t, window = run["t"], slice(len(run["t"]) - 51, None)
    v_com_z = [_com_velocity(robot, q, v)[2] for q, v in zip(run["q"][window], run["v"][window], strict=True)]
    f_z = run["foot_forces"][window, :, 2].sum(axis=1)
    weight = robot.mass * robot.gravity
    impulse = np.sum((f_z[:-1] - weight) * np.diff(t[window]))
    assert abs(impulse - robot.mass * (v_com_z[-1] - v_com_z[0])) < 0.01 * weight * (t[-1] - t[window][0])
    assert run.meta["summary"]["delay"] == delay


def test_kick_changes_the_base_velocity_once(robot):
    """A lateral kick shows as a velocity jump of the logged base (world y) right after its time."""
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=7), MPCConfig(gait=make_gait("stand")))
    mpc.verbose = False
    config = ClosedLoopConfig(
        duration=0.2,
        disturbances=(Kick(0.1, (0.0, 0.3, 0.0)),),
        plant=PlantConfig(kind="pybullet"),
        low_level=LowLevelConfig(kd=5.0),
        commands=CommandSchedule(arm_reference=None),
    )
    log = run_closed_loop(mpc, config, progress=False).log.arrays()
    v_y = np.array(
        [
            (pin.Quaternion(q[3:7]).toRotationMatrix() @ v[:3])[1]
            for q, v in zip(log["q"], log["v"], strict=True)
        ]
    )
    before, after = v_y[log["t"] < 0.1], v_y[(log["t"] > 0.1) & (log["t"] < 0.104)]
    assert np.abs(before).max() < 0.05
    assert after.max() > 0.15


def test_bad_harness_configuration_is_named():
    with pytest.raises(ValueError, match="delay must be"):
        ClosedLoopConfig(delay="sometimes")
    with pytest.raises(ValueError, match="need PlantConfig\\(kind='pybullet'\\)"):
        ClosedLoopConfig(disturbances=(Kick(0.1, (0, 1, 0)),), plant=PlantConfig(kind="rigid"))
    with pytest.raises(ValueError, match="Push.target"):
        Push(0.0, 0.1, (1, 0, 0), target="arm")
    with pytest.raises(ValueError, match="Kick.delta_v"):
        Kick(0.0, (1.0, 0.0))


def test_a_fall_between_solves_ends_the_run_on_the_tick_it_happens(robot):
    """A roll kick tilts the base past ``max_tilt`` while the solver is busy (a 60 ms delay: one solve per
    five MPC periods): the run ends on the first logged tick beyond the limit, with ``fell`` set, not on a
    later solve after the base may have come back (the summary's max tilt and ``fell`` agree)."""
    from wbmpc.model.quaternion import tilt

    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=7), MPCConfig(gait=make_gait("stand")))
    mpc.verbose = False
    config = ClosedLoopConfig(
        duration=0.4,
        delay=0.06,
        max_tilt=0.05,
        disturbances=(Kick(0.1, (0, 0, 0, 3.0, 0, 0)),),
        plant=PlantConfig(kind="pybullet"),
        low_level=LowLevelConfig(kd=5.0),
        commands=CommandSchedule(arm_reference=None),
    )
    result = run_closed_loop(mpc, config, progress=False)
    tilts = np.array([tilt(q) for q in result.log.q])
    assert result.fell
    assert tilts[-1] > config.max_tilt and np.all(tilts[:-1] <= config.max_tilt)
    assert result.summary["max_tilt_rad"] == pytest.approx(tilts[-1])
