"""The motor drivers' PD law (at every plant step on the joint state, the latency on the setpoints) and the
computation-delay compensation (plan from the state predicted for when the plan arrives)."""

import numpy as np
import pytest

from wbmpc.sim.motor_drive import MotorDrive


def test_law_latency_hold_and_clipping():
    drive = MotorDrive(kp=10.0, kd=2.0, torque_limits=np.array([5.0, 100.0]), latency_steps=2)
    q, v = np.array([0.1, -0.2]), np.array([0.5, 0.0])
    np.testing.assert_array_equal(drive.torque(q, v), 0.0)  # no command yet
    drive.command(np.array([1.0, 1.0]), np.array([0.0, 0.0]), np.array([0.0, 1.0]))
    # The first command is used at once (nothing to hold before it): 1 + 10 (0 - q) + 2 (v_des - v).
    first = np.array([1.0 - 1.0 - 1.0, 1.0 + 2.0 + 2.0])
    np.testing.assert_allclose(drive.torque(q, v), first)
    drive.command(np.array([50.0, 0.0]), np.array([0.0, 0.0]), np.array([0.0, 0.0]))  # sent at step 2
    np.testing.assert_allclose(drive.torque(q, v), first)  # step 2: still the old setpoints
    np.testing.assert_allclose(drive.torque(q, v), first)  # step 3
    assert drive.violations == 0
    # Step 4 = sent + 2: the new command, its first joint clipped to 5 N m and counted.
    np.testing.assert_allclose(drive.torque(q, v), [5.0, 2.0])
    assert drive.violations == 1
    np.testing.assert_array_equal(drive.clipped_steps, [1, 0])
    # The damping acts on the state given at each step (not on a filtered or delayed one).
    np.testing.assert_allclose(drive.torque(q, v + 1.0)[1], 2.0 - 2.0)


@pytest.mark.parametrize(
    "kwargs, words",
    [
        ({"kp": -1.0}, "kp"),
        ({"kd": np.nan}, "kd"),
        ({"latency_steps": -1}, "latency_steps"),
        ({"latency_steps": 1.5}, "latency_steps"),
    ],
)
def test_bad_drive_settings_are_named(kwargs, words):
    settings = {"kp": 1.0, "kd": 1.0, "torque_limits": np.ones(2), "latency_steps": 0} | kwargs
    with pytest.raises(ValueError, match=words):
        MotorDrive(**settings)


# --- delay compensation ------------------------------------------------------------------------------
def test_predicted_state_keeps_the_deviation_and_adds_the_plans_motion():
    """On the plan, the predicted configuration is the plan's at t + d; off it, the deviation rides along
    (checked in the tangent space against the plan's own difference); the velocity is the measured one."""
    from types import SimpleNamespace

    import pinocchio as pin

    from wbmpc.control.delay import predict_state
    from wbmpc.model.robot import load_b1

    robot = load_b1()
    model = robot.model
    times = np.array([0.0, 0.01, 0.03, 0.06])
    rng = np.random.default_rng(0)
    q = [robot.q_nominal]
    for _ in times[1:]:
        q.append(pin.integrate(model, q[-1], 0.05 * rng.standard_normal(model.nv)))
    v = rng.standard_normal((times.size, model.nv))
    plan = SimpleNamespace(node_times=times, q=np.array(q), v=v)
    q_on, v_on = predict_state(model, plan, plan.q[1], v[1], 0.01, 0.03)
    np.testing.assert_allclose(pin.difference(model, q_on, plan.q[2]), 0.0, atol=1e-12)
    np.testing.assert_allclose(v_on, v[1], atol=1e-12)
    offset = 0.01 * rng.standard_normal(model.nv)
    q_off, v_off = predict_state(model, plan, pin.integrate(model, plan.q[1], offset), v[1] + 0.1, 0.01, 0.03)
    # The prediction moved by the plan's step from node 1 to node 2 (small-offset first order).
    step = pin.difference(model, plan.q[1], plan.q[2])
    moved = pin.difference(model, pin.integrate(model, plan.q[1], offset), q_off)
    np.testing.assert_allclose(moved[6:], step[6:], atol=1e-12)  # joints: exactly additive
    np.testing.assert_allclose(v_off, v[1] + 0.1, atol=1e-12)


def test_delay_estimate_fixed_quantile_and_cap():
    from wbmpc.control.delay import DelayEstimate

    assert DelayEstimate(fixed=0.02).expected() == 0.02
    estimate = DelayEstimate(window=5, quantile=1.0, cap=0.05)  # at most 4 MPC periods
    assert estimate.expected() == 0.0
    for seconds in (0.010, 0.012, 0.030, 0.011, 0.013, 0.014):  # the first falls out of the window
        estimate.record(seconds)
    assert estimate.expected() == 0.030
    estimate.record(0.2)
    assert estimate.expected() == 0.05  # capped
    with pytest.raises(ValueError, match="quantile"):
        DelayEstimate(quantile=1.5)


def test_command_ramp_limits_the_acceleration():
    from wbmpc.control.command_ramp import CommandRamp

    ramp = CommandRamp(linear=1.0, yaw=0.5)
    v, w = ramp(0.0, np.zeros(3), 0.0)
    np.testing.assert_array_equal(v, 0.0)
    v, w = ramp(0.1, np.array([0.3, 0.4, 0.0]), 1.0)  # a 0.5 m/s step: 0.1 m/s along it after 0.1 s
    np.testing.assert_allclose(v, [0.06, 0.08, 0.0])
    assert w == pytest.approx(0.05)
    for k in range(2, 12):
        v, w = ramp(0.1 * k, np.array([0.3, 0.4, 0.0]), 1.0)
    np.testing.assert_allclose(v, [0.3, 0.4, 0.0])  # reached after 0.5 s, then held
    assert w == pytest.approx(0.55)
    with pytest.raises(ValueError, match="CommandRamp.linear"):
        CommandRamp(linear=0.0)


def test_torque_limit_fraction_scales_the_torque_rows():
    """The plan's torque rows are (tau - 0) / (fraction * limit): at the same point, half the fraction gives
    twice the row values; a fraction outside (0, 1] is refused."""
    from wbmpc.control.mpc import Commands, MPCConfig, WholeBodyMPC
    from wbmpc.model.robot import load_b1
    from wbmpc.ocp import OCPSettings
    from wbmpc.ocp.gait import make_gait
    from wbmpc.ocp.inspection import ConstraintInspector

    robot = load_b1()
    rows = {}
    for fraction in (1.0, 0.5):
        settings = OCPSettings(n_nodes=4, torque_limit_fraction=fraction)
        mpc = WholeBodyMPC(robot, settings, MPCConfig(gait=make_gait("stand")))
        q, v = robot.q_nominal, np.zeros(robot.nv)
        params = mpc.parameters(q, v, 0.0, Commands())
        w, p = mpc.cold_guess(q, v, params), mpc.ocp.params.pack(params)
        inspector = ConstraintInspector(mpc.ocp)
        rows[fraction] = inspector.evaluate(w, p)[inspector.groups["torque_limits"]]
    assert np.max(np.abs(rows[1.0])) > 0.05  # the standing torques are not zero
    np.testing.assert_allclose(rows[0.5], 2.0 * rows[1.0], rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match="torque_limit_fraction"):
        OCPSettings(torque_limit_fraction=1.2)
