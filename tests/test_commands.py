"""Commands that mean what a user means: velocities that belong to a gait schedule's segments, "hold the
arm still" in the heading frame (a world-fixed hand with a walking base flagged before planning), the yaw
rate carried to the hand, signed command tracking, and the measured delay of the whole solve call."""

import numpy as np
import pinocchio as pin
import pytest

from wbmpc.control.arm_task import ArmReference, velocity_command
from wbmpc.control.mpc import Commands, MPCConfig, WholeBodyMPC
from wbmpc.control.prechecks import arm_reach, ee_world_hold
from wbmpc.model.robot import load_b1_z1
from wbmpc.ocp import OCPSettings
from wbmpc.ocp.gait import GaitSchedule, make_gait, parse_gait_schedule
from wbmpc.sim.closed_loop import (
    ClosedLoopConfig,
    _delay_steps,
    base_velocity_heading,
    command_tracking,
    run_closed_loop,
)
from wbmpc.sim.loop_config import CommandSchedule, LowLevelConfig


@pytest.fixture(scope="module")
def robot():
    return load_b1_z1()


@pytest.fixture(scope="module")
def mpc(robot):
    return WholeBodyMPC(robot, OCPSettings(n_nodes=10), MPCConfig())


# --- segment velocities -------------------------------------------------------------------------------
def test_segment_velocities_parse_and_name_round_trip():
    s = parse_gait_schedule("stand:1,trot@0.5:4,trot@0.3/0.1:2,trot@0/0/0.3:2,stand:1")
    assert s.velocities == (None, (0.5, 0.0, 0.0), (0.3, 0.1, 0.0), (0.0, 0.0, 0.3), None)
    assert s.name == "stand:1+trot@0.5:4+trot@0.3/0.1:2+trot@0/0/0.3:2+stand:1"
    assert s.velocity_at(0.5) == (0.0, 0.0, 0.0)  # a stand segment stands still
    assert s.velocity_at(3.0) == (0.5, 0.0, 0.0)
    assert s.velocity_at(6.0) == (0.3, 0.1, 0.0)
    assert s.velocity_at(8.0) == (0.0, 0.0, 0.3)
    assert s.velocity_at(9.5) == (0.0, 0.0, 0.0)
    plain = parse_gait_schedule("stand:1,trot:2")
    assert plain.velocity_at(0.5) == (0.0, 0.0, 0.0) and plain.velocity_at(2.0) is None  # the run's
    assert make_gait("stand").velocity_at(3.0) == (0.0, 0.0, 0.0)
    assert make_gait("trot").velocity_at(3.0) is None


@pytest.mark.parametrize(
    "spec, words",
    [
        ("trot@fast:2", "vx[/vy[/yaw rate]]"),
        ("trot@0.1/0.2/0.3/0.4:2", "vx[/vy[/yaw rate]]"),
        ("trot@nan:2", "finite"),
        ("stand:1,trot@:2", "vx[/vy[/yaw rate]]"),
    ],
)
def test_bad_segment_velocity_is_named(spec, words):
    with pytest.raises(ValueError, match="velocity after '@'") as err:
        parse_gait_schedule(spec)
    assert words in str(err.value)


def test_bad_segment_velocity_tuple_is_named():
    with pytest.raises(ValueError, match="segment 0 velocity must be 3 finite numbers"):
        GaitSchedule([(make_gait("trot"), 1.0, (0.1, 0.2))])


def test_a_change_of_speed_continues_the_trot_cycle():
    """trot@0.2 from 1 s, trot@0.5 from 2.4 s: after the switch the contacts are the unbroken trot's, by
    tick arithmetic (0.5 ms ticks; the trot begins at tick 2000, its period is 1600 ticks, FL+RR swing over
    the first 800 of each cycle, FR+RL over the next 800). A cycle restarted at the switch (tick 4800) would
    lift FL+RR there, right after they landed at tick 4400."""
    s = parse_gait_schedule("stand:1,trot@0.2:1.4,trot@0.5:3")
    assert list(s.start_ticks) == [0, 2000, 4800]
    table = {  # tick -> swinging pair, (tick - 2000) mod 1600 by hand
        4399: "FL+RR",  # 799
        4400: "FR+RL",  # 800
        4799: "FR+RL",  # 1199
        4800: "FR+RL",  # 1200
        4801: "FR+RL",  # 1201
        5199: "FR+RL",  # 1599
        5200: "FL+RR",  # 0
        5999: "FL+RR",  # 799
        6000: "FR+RL",  # 800
    }
    ticks = np.array(list(table))
    contact = s.sample(ticks * s.tick).contact
    for k, tick in enumerate(ticks):
        expected = np.ones(4, bool)
        expected[[0, 3] if table[tick] == "FL+RR" else [1, 2]] = False
        np.testing.assert_array_equal(contact[:, k], expected, err_msg=f"tick {tick}")


def test_commands_come_from_the_segment_then_the_callable():
    schedule = parse_gait_schedule("stand:1,trot:2,trot@-0.1/0/0.2:2")
    config = ClosedLoopConfig(commands=CommandSchedule(base_velocity=(0.3, 0.0, 0.0), base_yaw_rate=0.1))
    stand, walk, told = (config.commands.at(t, schedule) for t in (0.5, 2.0, 4.0))
    np.testing.assert_array_equal(stand["base_velocity"], 0.0)
    assert stand["base_yaw_rate"] == 0.0
    np.testing.assert_array_equal(walk["base_velocity"], [0.3, 0.0, 0.0])
    assert walk["base_yaw_rate"] == 0.1
    np.testing.assert_array_equal(told["base_velocity"], [-0.1, 0.0, 0.0])
    assert told["base_yaw_rate"] == 0.2
    config.commands.overrides = lambda t: {"base_velocity": (0.05, 0.0, 0.0)}
    np.testing.assert_array_equal(config.commands.at(0.5, schedule)["base_velocity"], [0.05, 0.0, 0.0])


# --- the arm held still -------------------------------------------------------------------------------
def test_world_fixed_hand_with_walking_base_says_when_the_reach_runs_out(robot):
    q = robot.q_nominal
    walk = Commands(base_linear_velocity=np.array([0.2, 0.0, 0.0]))
    (finding,) = ee_world_hold(robot, q, walk.validated())
    assert finding.code == "ee_world_hold_with_walking_base" and finding.severity == "warning"
    t_out = finding.data["time_to_reach_limit_s"]
    assert 0.0 < t_out < 10.0 and "heading" in finding.message
    # By another route: move the base (and so the shoulder) t_out * 0.2 m forward with the hand pinned in
    # the world; the hand is then exactly the arm's reach from its first joint.
    model, data = robot.model, robot.model.createData()
    pin.framesForwardKinematics(model, data, q)
    hand = data.oMf[robot.frame_id(robot.ee_frame)].translation.copy()
    moved = q.copy()
    moved[0] += 0.2 * t_out
    pin.framesForwardKinematics(model, data, moved)
    shoulder = data.oMi[model.getJointId(robot.arm_joint_names[0])].translation
    assert abs(np.linalg.norm(hand - shoulder) - arm_reach(robot)["reach"]) < 1e-9
    assert finding.data["distance_m"] == pytest.approx(0.2 * t_out)


def test_hand_moving_with_the_base_or_standing_is_not_flagged(robot):
    q = robot.q_nominal
    along = Commands(base_linear_velocity=np.array([0.2, 0.0, 0.0]), ee_velocity=np.array([0.2, 0.0, 0.0]))
    assert ee_world_hold(robot, q, along.validated()) == []
    assert ee_world_hold(robot, q, Commands().validated()) == []
    per_stage = Commands(base_linear_velocity=np.array([0.2, 0.0, 0.0]), ee_velocity=np.zeros((3, 9)))
    assert ee_world_hold(robot, q, per_stage.validated()) == []


def test_the_heading_frame_carries_the_hand_when_the_base_turns(robot):
    """A hold point fixed in the heading frame, the hand on it: the command is the heading frame's own
    velocity at the hand, checked against a finite difference of the hold point's world position while the
    base moves at v and turns at omega."""
    model, data = robot.model, robot.model.createData()
    q = robot.q_nominal
    pin.framesForwardKinematics(model, data, q)
    hand = data.oMf[robot.frame_id(robot.ee_frame)].translation.copy()
    hold = ArmReference.still().centered_at(q, hand)
    v_base, omega, h = np.array([0.2, -0.1, 0.0]), 0.3, 1e-6
    command, _ = velocity_command(hold, q, hand, 0.0, v_base, yaw_rate=omega)

    def world_point(dt):
        moved = q.copy()
        moved[:3] += v_base * dt
        rotation = pin.Quaternion(q[3:7]).toRotationMatrix() @ pin.rpy.rpyToMatrix(0, 0, omega * dt)
        moved[3:7] = pin.Quaternion(rotation).coeffs()
        from wbmpc.control.arm_task import world_reference

        return world_reference(hold, moved, 0.0)

    np.testing.assert_allclose(command, (world_point(h) - world_point(-h)) / (2 * h), atol=1e-6)


def test_hold_still_means_still_relative_to_the_walking_body(mpc, robot):
    """arm_reference=None: the hand keeps its place in the heading frame while the robot trots forward, and
    no world-hold finding is raised; the world frame is an explicit choice, and is flagged."""
    config = ClosedLoopConfig(
        duration=1.5, commands=CommandSchedule(arm_reference=None, base_velocity=(0.2, 0.0, 0.0))
    )
    result = run_closed_loop(mpc, config, progress=False)
    a = result.log.arrays()
    assert not result.fell
    hand, q = a["ee_position"], a["q"]
    moved = q[-1, 0] - q[0, 0]
    assert moved > 0.1  # it walks forward
    assert abs((hand[-1, 0] - hand[0, 0]) - moved) < 0.03  # and the hand with it
    assert result.summary["ee_max_error_m"] < 0.03
    assert "ee_world_hold_with_walking_base" not in result.summary["diagnostics"]["findings"]
    world = ClosedLoopConfig(
        duration=0.1, commands=CommandSchedule(arm_reference=None, ee_velocity_frame="world")
    )
    flagged = run_closed_loop(mpc, world, progress=False).summary["diagnostics"]["findings"]
    assert flagged.get("ee_world_hold_with_walking_base", 0) >= 1


def test_stand_segment_stands_still_and_the_delay_is_the_whole_call(mpc, robot):
    """stand:0.5 then trot with the run's 0.2 m/s: the base does not drift while standing (it drifted 27 cm
    over a 2 s stand when the stand segment was commanded the walking speed). With ``delay="measured"`` the
    plan reaches the low level after the whole solve call (here made 12 ms), not the solver's share."""
    schedule = parse_gait_schedule("stand:0.5,trot:1")
    config = ClosedLoopConfig(
        duration=1.5,
        delay="measured",
        commands=CommandSchedule(gait=schedule, arm_reference=None),
        low_level=LowLevelConfig(kd=5.0),
    )
    solve = mpc.solve

    def slow_call(*args, **kwargs):
        plan = solve(*args, **kwargs)
        plan.timings = {**plan.timings, "total": 0.012}
        plan.solve_time = 0.001
        return plan

    mpc.solve = slow_call
    try:
        result = run_closed_loop(mpc, config, progress=False)
    finally:
        del mpc.solve
    a = result.log.arrays()
    standing = a["t"] < 0.5
    assert np.max(np.abs(a["q"][standing, 0] - a["q"][0, 0])) < 0.01
    assert a["q"][-1, 0] - a["q"][0, 0] > 0.05
    assert result.summary["converged_fraction"] == 1.0
    lag = (a["apply_t"] - a["solve_t"])[1:]  # the first plan applies at once (nothing to hold before it)
    np.testing.assert_allclose(lag, 0.012, atol=1e-9)
    assert _delay_steps(ClosedLoopConfig(delay="measured"), 0.0126) == 26  # rounded up to plant steps


# --- tracking --------------------------------------------------------------------------------------------
def test_command_tracking_is_signed_and_per_stretch(robot):
    """A synthetic log: 1 s at +0.2 m/s forward then 2 s at -0.1 m/s with a -0.3 rad/s yaw rate, the base
    heading 90 degrees left (forward is world +y): the stretches' achieved values keep their signs."""
    t = np.arange(0, 3.0, 0.002)
    q = np.tile(robot.q_nominal, (t.size, 1))
    q[:, 3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(0, 0, np.pi / 2)).coeffs()
    v = np.zeros((t.size, robot.nv))
    first = t < 1.0
    forward = np.where(first, 0.2, -0.1)
    v[:, 0] = forward  # base frame x is the heading's forward
    v[:, 5] = np.where(first, 0.0, -0.3)
    cmd = np.zeros((t.size, 3))
    cmd[:, 0] = forward
    arrays = {"t": t, "q": q, "v": v, "base_velocity_cmd": cmd, "base_yaw_rate_cmd": v[:, 5]}
    np.testing.assert_allclose(base_velocity_heading(q[:1], v[:1])[0], [0.2, 0.0, 0.0], atol=1e-12)
    first_stretch, second = command_tracking(arrays, settle=0.2)
    assert first_stretch["t_start"] == pytest.approx(0.2)
    np.testing.assert_allclose(first_stretch["achieved"], [0.2, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(second["achieved"], [-0.1, 0.0, -0.3], atol=1e-12)
    assert second["ratio"][0] == pytest.approx(1.0) and second["ratio"][1] is None


# --- tracking on the plants ---------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "command",
    [(0.2, 0.0, 0.0), (0.5, 0.0, 0.0), (0.0, 0.2, 0.0), (0.0, 0.0, 0.3)],
    ids=["forward 0.2", "forward 0.5", "left 0.2", "yaw 0.3"],
)
def test_rigid_plant_tracks_signed_commands(robot, command):
    """Stand 2 s, trot 1.5 s with the command (compiled, N = 15): the achieved component has the command's
    sign and is within 25 % of it over the last half second (loose: a short run; the committed table
    data/results/command_tracking.csv has the 6 s runs), and the other components stay small."""
    from wbmpc.studies.command_tracking import run_case

    row = run_case("rigid", command, 1.5, robot)
    assert not row["fell"]
    assert 0.75 < row["ratio"] < 1.25, row
    scale = max(abs(c) for c in command)
    assert all(abs(d) < 0.25 * scale + 0.02 for d in row["drift_other_axes"]), row


def test_emulated_robot_with_a_real_solve_delay_keeps_walking(robot):
    """The emulated robot (full hardware profile, estimator, calibrated base CoM) with every plan arriving
    25 ms after its measurement, compensated: stand, then trot forward without falling or failing solves.

    25 ms is two MPC periods, above the 95th percentile of the whole solve call measured on both CI machine
    kinds (13 ms on the AMD EPYC in the previous run of data/hardware/emulated_calibrated.json; 20-23 ms on
    the Intel Xeon, docs/emulated_robot.md). It is
    fixed rather than ``"measured"`` so that the outcome is this code's, not the load of the machine running
    the suite; the measured-delay runs are the study's (``python -m wbmpc.studies.emulated_calibrated``)
    and the measured-delay wiring is tested with injected solve times (tests/test_sim_harness.py)."""
    from wbmpc.analysis import record_emulated_run
    from wbmpc.model.base_com import shift_base_com
    from wbmpc.sim.hardware import HardwareProfile

    calibrated = shift_base_com(robot, HardwareProfile().base_com_offset)
    result, _ = record_emulated_run(
        gait="stand:0.5,trot@0.2:2", robot=robot, mpc_robot=calibrated, delay=0.025
    )
    s = result.summary
    assert s["delay"] == 0.025 and s["joint_pd"] == "drive"
    assert not result.fell and s["converged_fraction"] > 0.97
    trot = s["tracking"][-1]
    assert trot["commanded"][0] == 0.2 and trot["achieved"][0] > 0.1  # forward, not backwards


def test_cold_start_of_a_robot_without_an_arm_carries_its_weight():
    """The cold guess of the B1 (no arm) has static forces that carry its weight on the stance feet: it used
    to ask the statics for an end-effector force the robot has not got, and fell back to zero forces."""
    from wbmpc.model.robot import load_b1

    b1 = load_b1()
    mpc = WholeBodyMPC(b1, OCPSettings(n_nodes=4), MPCConfig(gait=make_gait("stand")))
    q, v = b1.q_nominal, np.zeros(b1.nv)
    params = mpc.parameters(q, v, 0.0, Commands())
    forces = mpc.ocp.split(mpc.cold_guess(q, v, params), mpc.ocp.params.pack(params))["F"]
    vertical = np.asarray(forces).reshape(-1, 4, 3)[:, :, 2].sum(axis=1)
    np.testing.assert_allclose(vertical, b1.mass * b1.gravity, rtol=1e-6)


# --- the studies' command lines refuse bad arguments before any work ------------------------------------
@pytest.mark.parametrize(
    "module, argv, words",
    [
        ("command_tracking", ["--trot", "0.5"], "--trot must be > 1 s"),
        ("command_tracking", ["--calibration", "/nonexistent/calib.yaml"], "no such file"),
        ("emulated_ablation", ["--gait", "trot@fast:2"], "--gait"),
        ("emulated_ablation", ["--variant", "nonsense"], "invalid choice"),
        ("emulated_calibrated", ["targets", "--calibration", "/nonexistent/calib.yaml"], "no such file"),
        ("emulated_calibrated", ["targets", "--gait", "stand:2,trot@x:1"], "--gait"),
    ],
)
def test_study_command_lines_refuse_bad_arguments(module, argv, words, capsys, monkeypatch):
    import importlib

    import wbmpc.model.robot

    def no_work(*args, **kwargs):
        raise AssertionError("a robot was loaded before the arguments were checked")

    monkeypatch.setattr(wbmpc.model.robot, "load_b1_z1", no_work)
    study = importlib.import_module(f"wbmpc.studies.{module}")
    with pytest.raises(SystemExit) as exit_info:
        study.main(argv)
    assert exit_info.value.code == 2
    assert words in capsys.readouterr().err


@pytest.mark.parametrize(
    "make, words",
    [
        (
            lambda: ClosedLoopConfig(commands=CommandSchedule(ee_velocity_frame="base")),
            "ee_velocity_frame must be 'heading' or 'world'",
        ),
        (
            lambda: ClosedLoopConfig(low_level=LowLevelConfig(joint_pd="motor")),
            "joint_pd must be 'controller' or 'drive'",
        ),
        (lambda: ClosedLoopConfig(mpc_schedule="asap"), "mpc_schedule must be 'ticks' or 'free'"),
        (lambda: ClosedLoopConfig(commands=CommandSchedule(ramp=(0.0, 1.0))), "CommandSchedule.ramp"),
        (lambda: ClosedLoopConfig(commands=CommandSchedule(ramp=(1.0,))), "CommandSchedule.ramp"),
        (lambda: OCPSettings(torque_limit_fraction=0.0), "torque_limit_fraction"),
        (lambda: GaitSchedule([(make_gait("trot"), 1.0, (0.1, 0.0, 0.0), "extra")]), "segment 0 must be"),
    ],
)
def test_new_settings_refuse_bad_values(make, words):
    """Bad values of this issue's new settings are refused at construction, naming the field."""
    with pytest.raises(ValueError, match=words):
        make()


def test_validated_commands_are_float_arrays():
    """validated() converts lists and integers (a new Commands) and keeps float arrays as they are."""
    given = Commands(base_linear_velocity=[1, 0, 0], ee_force=(0, 0, -5), base_height=1)
    out = given.validated()
    assert out is not given and given.base_linear_velocity == [1, 0, 0]  # the caller's left alone
    for name in ("base_linear_velocity", "base_angular_velocity", "ee_velocity", "ee_force"):
        value = getattr(out, name)
        assert isinstance(value, np.ndarray) and value.dtype == float and value.shape == (3,)
    np.testing.assert_array_equal(out.ee_force, [0.0, 0.0, -5.0])
    assert type(out.base_height) is float and out.base_height == 1.0
    again = out.validated()
    for name in ("base_linear_velocity", "base_angular_velocity", "ee_velocity", "ee_force"):
        assert getattr(again, name) is getattr(out, name)  # nothing converted twice
