"""One contact schedule in integer plant ticks, shared by the MPC's stages and the plant; gait transitions;
no failed plan reaches the low level (the static hold)."""

import numpy as np
import pytest
from conftest import forward_progress

from wbmpc.control.mpc import Commands, MPCConfig, SolverSettings, WholeBodyMPC
from wbmpc.model.robot import load_b1_z1
from wbmpc.model.statics import static_equilibrium
from wbmpc.ocp import OCPSettings
from wbmpc.ocp.gait import SCHEDULE_TICK, GaitSchedule, make_gait, parse_gait_schedule, to_ticks
from wbmpc.quick import pick
from wbmpc.sim.closed_loop import ClosedLoopConfig, run_closed_loop
from wbmpc.sim.loop_config import CommandSchedule

PLANT_DT, MPC_DT = 0.0005, 0.0125
MIN_SWING_HEIGHT = -0.005  # [m] the deepest a swing foot may go below the ground
# A swing foot reaches the ground up to ~8 ms (16 plant steps) before its scheduled touchdown (the Euler
# discretisation of the vertical-velocity spline, about 1.2 mm deep); more than 20 steps per touchdown and
# foot would mean a foot left in the ground as before the fix (5,875 steps in the 10 s demo).
MAX_PENETRATING_STEPS_PER_TOUCHDOWN = 20


@pytest.fixture(scope="module")
def robot():
    return load_b1_z1()


def mpc_ticks(duration):
    return np.arange(round(duration / MPC_DT)) * MPC_DT


def test_every_trot_switch_is_one_exact_tick_of_the_plant():
    """On every MPC tick of a 10 s trot, node 0's contacts hold over the whole first stage (10 ms, 20 plant
    steps): a switch is never split between the MPC and the plant. The floating-point phase failed at
    t = 1.2, 2.4, 4.8 and 9.6 s, where the switch fell on a tick."""
    gait = make_gait("trot", 0.8)
    ticks = mpc_ticks(10.0)
    steps = ticks[:, None] + PLANT_DT * np.arange(20)[None, :]  # plant steps of stage 0
    contact = gait.sample(steps.ravel()).contact.reshape(4, *steps.shape)
    assert np.all(contact == contact[:, :, :1])
    switches = np.flatnonzero(np.any(contact[:, 1:, 0] != contact[:, :-1, 0], axis=0)) + 1
    np.testing.assert_allclose(ticks[switches], 0.4 * np.arange(1, 25), atol=1e-12)


# Contacts (FL, FR, RL, RR; 1 = stance) worked out by hand in ticks of 0.5 ms. Trot, period 0.8 s = 1600
# ticks, swing 800 ticks: FL + RR swing on [0, 800) of each cycle, FR + RL on [800, 1600). Ticks 2400,
# 4800, 9600 and 19200 (1.2, 2.4, 4.8 and 9.6 s) are where the floating-point phase put a switch on the
# wrong side.
STANCE_A, STANCE_B, ALL = (0, 1, 1, 0), (1, 0, 0, 1), (1, 1, 1, 1)  # A: FR + RL stand; B: FL + RR stand
TROT_TABLE = [
    (0, STANCE_A),
    (1, STANCE_A),
    (399, STANCE_A),
    (400, STANCE_A),
    (799, STANCE_A),
    (800, STANCE_B),
    (801, STANCE_B),
    (1599, STANCE_B),
    (1600, STANCE_A),
    (2399, STANCE_A),
    (2400, STANCE_B),
    (2401, STANCE_B),
    (4799, STANCE_B),
    (4800, STANCE_A),
    (9599, STANCE_B),
    (9600, STANCE_A),
    (19199, STANCE_B),
    (19200, STANCE_A),
    (20000, STANCE_B),
]
# Swing phases (elapsed fraction of the 800-tick swing) of the swinging feet at some of those ticks.
TROT_PHASES = [(0, 0.0), (1, 1 / 800), (400, 0.5), (799, 799 / 800), (800, 0.0), (1200, 0.5), (2400, 0.0)]
# stand:2,trot:6,stand:2: the trot runs on ticks [4000, 16000) with its cycle starting at 4000 (no swing is
# in the air at 16000, so no extension), then stand for good.
SCHEDULE_TABLE = [
    (0, ALL),
    (3999, ALL),
    (4000, STANCE_A),
    (4799, STANCE_A),
    (4800, STANCE_B),
    (5599, STANCE_B),
    (5600, STANCE_A),
    (15999, STANCE_A),
    (16000, ALL),
    (40000, ALL),
]


def _table(rows):
    ticks = np.array([tick for tick, _ in rows])
    return ticks, np.array([contact for _, contact in rows], dtype=bool).T


def test_trot_contacts_match_the_hand_computed_tick_table():
    gait = make_gait("trot", 0.8)
    assert SCHEDULE_TICK == PLANT_DT
    ticks, expected = _table(TROT_TABLE)
    np.testing.assert_array_equal(gait.sample(ticks * SCHEDULE_TICK).contact, expected)
    np.testing.assert_array_equal(gait.sample_ticks(ticks).contact, expected)
    for tick, contact in TROT_TABLE:
        np.testing.assert_array_equal(gait.contact(tick * SCHEDULE_TICK), contact, err_msg=f"tick {tick}")
    for tick, phase in TROT_PHASES:
        sample = gait.sample(np.array([tick * SCHEDULE_TICK]))
        swinging = ~sample.contact[:, 0]
        assert swinging.sum() == 2, tick
        np.testing.assert_allclose(sample.swing_phase[swinging, 0], phase, rtol=0, atol=1e-15)
        np.testing.assert_array_equal(sample.swing_phase[~swinging, 0], 0.0)


def test_a_stand_trot_stand_schedule_matches_the_hand_computed_tick_table(robot):
    schedule = parse_gait_schedule("stand:2,trot:6,stand:2")
    np.testing.assert_array_equal(schedule.start_ticks, [0, 4000, 16000])
    assert not schedule.notes
    ticks, expected = _table(SCHEDULE_TABLE)
    np.testing.assert_array_equal(schedule.sample(ticks * SCHEDULE_TICK).contact, expected)
    # The MPC's node 0 (sampled at the measurement time) follows the same table, for the trot too.
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=4), MPCConfig(gait=schedule))
    q, v = robot.q_nominal, np.zeros(robot.nv)
    for table in (SCHEDULE_TABLE, TROT_TABLE):
        mpc.config.gait = schedule if table is SCHEDULE_TABLE else make_gait("trot", 0.8)
        for tick, contact in table:
            node0 = mpc.parameters(q, v, tick * SCHEDULE_TICK, Commands())["contact"][:, 0] > 0.5
            np.testing.assert_array_equal(node0, contact, err_msg=f"tick {tick}")


def test_tick_arithmetic_is_exact_over_long_runs():
    gait = make_gait("trot", 0.8)
    t = np.arange(0, 3600.0, 0.4)  # an hour of switches
    sample = gait.sample(t)
    # At a switch instant the new pair is already lifting (phase 0) and the old one has landed.
    assert np.all(sample.contact.sum(axis=0) == 2)
    np.testing.assert_array_equal(sample.swing_phase[~sample.contact], 0.0)
    np.testing.assert_array_equal(to_ticks(t), np.round(t / PLANT_DT).astype(np.int64))


def test_mpc_node0_contacts_equal_the_plants_on_every_tick(robot):
    """The MPC's stage contacts come from the same schedule as the plant's: node 0 equals the plant's
    contacts at every MPC tick of a 10 s trot and of a stand-trot-stand schedule."""
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=4), MPCConfig(gait=make_gait("trot")))
    q, v = robot.q_nominal, np.zeros(robot.nv)
    for gait in (make_gait("trot"), parse_gait_schedule("stand:2,trot:6,stand:2")):
        mpc.config.gait = gait
        for t in mpc_ticks(10.0):
            node0 = mpc.parameters(q, v, t, Commands())["contact"][:, 0] > 0.5
            np.testing.assert_array_equal(node0, gait.contact(t), err_msg=f"t = {t}")


def test_schedule_sees_the_coming_gait_and_never_cuts_a_swing():
    schedule = parse_gait_schedule("stand:2,trot:5.9,stand:2")
    assert schedule.notes and "extended by 0.1 s" in schedule.notes[0]
    np.testing.assert_allclose(schedule.start_times, [0.0, 2.0, 8.0])
    assert schedule.name == "stand:2+trot:6+stand:2" and schedule.duration == pytest.approx(10.0)
    c = schedule.sample(np.array([1.9995, 2.0, 7.9995, 8.0]))
    assert c.contact[:, 0].all() and not c.contact[[0, 3], 1].any()  # the trot starts lifting FL + RR
    assert not c.contact[[0, 3], 2].any() and c.contact[:, 3].all()  # FL + RR land, then stand
    # A swing in progress is never cut: no foot goes from swing straight to stance mid-swing.
    t = np.arange(0, 10.0, PLANT_DT)
    s = schedule.sample(t)
    landing = s.contact[:, 1:] & ~s.contact[:, :-1]
    assert np.all(s.swing_phase[:, :-1][landing] > 0.99)
    # The durations of the swings follow the gait in force.
    np.testing.assert_allclose(np.unique(s.swing_duration), [0.0, 0.4])


@pytest.mark.parametrize(
    "spec, message",
    [
        ("", "schedule must be a string"),
        ("stand:2,trot", "needs a duration"),
        ("stand:x", "is not a number"),
        ("stand:2,gallop:1", "unknown gait"),
        ("stand:-1,trot:1", "duration must be finite and > 0"),
    ],
)
def test_bad_schedules_name_the_problem(spec, message):
    with pytest.raises(ValueError, match=message):
        parse_gait_schedule(spec)


def test_a_period_off_the_tick_grid_is_refused():
    with pytest.raises(ValueError, match="not a multiple of the schedule tick"):
        make_gait("trot", 0.80025)
    with pytest.raises(ValueError, match="is not a Gait"):
        GaitSchedule([("trot", 1.0)])


def _penetration_checks(result, n_touchdowns):
    s = result.summary
    assert not result.fell
    assert s["node0_contact_mismatches"] == 0
    assert s["swing_foot_min_height_m"] > MIN_SWING_HEIGHT, s["swing_foot_min_height_m"]
    assert s["contact_violations"]["penetrating"] <= MAX_PENETRATING_STEPS_PER_TOUCHDOWN * max(
        n_touchdowns, 1
    )


def test_trot_keeps_swing_feet_out_of_the_ground(robot):
    """Closed-loop trot through the switch ticks that failed before (1.2 and 2.4 s): no swing foot below
    -5 mm, node 0 equals the plant's contacts, and no iteration spike at the switches (was 11 to 17)."""
    duration = pick(full=10.0, quick=2.5)
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=15), MPCConfig(gait=make_gait("trot")))
    result = run_closed_loop(mpc, ClosedLoopConfig(duration=duration), progress=False)
    log = result.log.arrays()
    # The plant's contacts on every low-level step, by integer arithmetic on the tick (not by the Gait):
    # FL + RR stand on the second half of each 1600-tick cycle, FR + RL on the first.
    ticks = np.rint(log["t"] / PLANT_DT).astype(np.int64)
    assert ticks.max() >= 4800  # through the switches at 1.2 and 2.4 s
    pair_b = ticks % 1600 >= 800
    np.testing.assert_array_equal(log["contact"], np.stack([pair_b, ~pair_b, ~pair_b, pair_b], axis=1))
    # ... and by the feet themselves: stance feet stay on the ground, swing feet are high in mid-swing.
    height = log["foot_height"]
    stance = log["contact"].astype(bool)
    assert np.abs(height[stance]).max() < 0.003, np.abs(height[stance]).max()
    mid_swing = ~stance & (np.abs(ticks % 800 - 400) < 80)[:, None]  # 40 ms either side of the apex
    assert mid_swing.sum() > 100 and height[mid_swing].min() > 0.03, height[mid_swing].min()
    touchdowns = 2 * int(duration / 0.4)
    _penetration_checks(result, touchdowns)
    assert result.summary["iterations_max"] <= 10
    # It walked forward along its heading (0.2 m/s commanded): not backwards, not sideways.
    forward_progress(log["q"], minimum=0.4 * 0.2 * duration)


def test_stand_trot_stand_transitions_on_mpc_ticks(robot):
    """A stand -> trot switch and a trot -> stand switch, both on MPC ticks, in one run: no fall, swing feet
    out of the ground, the MPC's preview already planning the trot before it starts."""
    schedule = parse_gait_schedule(pick(full="stand:1,trot:4,stand:1", quick="stand:0.5,trot:1.2,stand:0.5"))
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=15), MPCConfig(gait=make_gait("stand")))
    loop = ClosedLoopConfig(
        duration=schedule.duration, commands=CommandSchedule(gait=schedule, base_velocity=(0.1, 0.0, 0.0))
    )
    result = run_closed_loop(mpc, loop, keep_plans=True, progress=False)
    _penetration_checks(result, 2 * round((schedule.start_times[2] - schedule.start_times[1]) / 0.4))
    # Forward, as commanded (0.1 m/s while trotting), not backwards or sideways.
    trotting = schedule.start_times[2] - schedule.start_times[1]
    forward_progress(result.log.arrays()["q"], minimum=0.4 * 0.1 * trotting)
    assert mpc.config.gait.name == "stand"  # the run's schedule replaced the MPC's only for the run
    # The plan computed one tick before the trot starts already lifts FL + RR from its second stage on.
    t_switch = schedule.start_times[1]
    before = next(p for p in result.log.plans if abs(p.t - (t_switch - MPC_DT)) < 1e-9)
    assert before.contact[:, 0].all() and not before.contact[[0, 3], 1:].all()
    assert result.summary["gait"] == schedule.name


# ------------------------------------------------------------------------------------ failed first solve
def test_a_failed_first_solve_returns_the_static_hold(robot):
    """An unconverged first iterate is never the plan: the static hold is, and it is not a warm start."""
    mpc = WholeBodyMPC(
        robot,
        OCPSettings(n_nodes=6),
        MPCConfig(gait=make_gait("stand"), dt_max=0.04),
        SolverSettings(cold_max_iter=1),
    )
    q = robot.q_nominal
    plan = mpc.solve(q, np.zeros(robot.nv), t=0.0)
    assert not plan.success and plan.fallback and plan.hold
    assert mpc.previous is None and mpc.stats["holds"] == 1
    eq = static_equilibrium(robot, q, np.ones(4, bool), ee_force=np.zeros(3))
    np.testing.assert_allclose(plan.tau[0], eq.tau, atol=1e-9)
    np.testing.assert_allclose(plan.q, np.tile(q, (mpc.n_nodes, 1)))
    assert not np.any(plan.v) and not np.any(plan.a)


class _FailingSolver:
    """A solver whose calls raise when ``fails(call number)`` says so (counted over all of an MPC's solvers),
    else the real one's; its ``stats()`` are the real solver's."""

    def __init__(self, solver, calls: dict, fails):
        self.solver, self.calls, self.fails = solver, calls, fails

    def __call__(self, **kwargs):
        self.calls["n"] += 1
        if self.fails(self.calls["n"]):
            raise RuntimeError("injected failure")
        return self.solver(**kwargs)

    def __getattr__(self, name):
        return getattr(self.solver, name)


def _inject_failures(mpc, monkeypatch, fails) -> None:
    """Make the solver calls for which ``fails(n)`` (n = 1, 2, ... over the run's solver calls) raise. Counted
    per call, not per solver built: the loop builds every solver before it starts (``prepare``)."""
    real, calls = mpc._solver, {"n": 0}
    monkeypatch.setattr(
        mpc, "_solver", lambda cold, max_iter=None: _FailingSolver(real(cold, max_iter), calls, fails)
    )


def test_closed_loop_holds_until_the_first_converged_plan(robot, monkeypatch):
    """The first three solves fail (injected): the loop applies the static hold, says so once, keeps
    standing, and then runs on converged plans."""
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=6), MPCConfig(gait=make_gait("stand"), dt_max=0.04))
    _inject_failures(mpc, monkeypatch, lambda call: call <= 3)
    result = run_closed_loop(
        mpc, ClosedLoopConfig(duration=0.25, commands=CommandSchedule(arm_reference=None)), progress=False
    )
    log = result.log.arrays()
    assert not result.fell
    np.testing.assert_array_equal(log["hold"][:3], True)
    assert not log["hold"][3:].any() and log["success"][3:].all()
    assert result.summary["holds"] == 3
    eq = static_equilibrium(robot, robot.q_nominal, np.ones(4, bool), ee_force=np.zeros(3))
    np.testing.assert_allclose(log["plan_tau"][0], eq.tau, atol=1e-9)
    q = log["q"]
    assert np.max(np.abs(q[:, 2] - q[0, 2])) < 0.01  # held, not collapsed


def test_a_failing_loop_says_why_once_and_counts(robot, monkeypatch, capsys):
    """Every solve after the first fails (injected): one printed line, every failure counted by reason."""
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=6), MPCConfig(gait=make_gait("stand"), dt_max=0.04))
    _inject_failures(mpc, monkeypatch, lambda call: call > 1)
    result = run_closed_loop(
        mpc, ClosedLoopConfig(duration=0.1, commands=CommandSchedule(arm_reference=None)), progress=False
    )
    printed = [line for line in capsys.readouterr().out.splitlines() if "solve failed" in line]
    assert len(printed) == 1 and "solver_exception" in printed[0] and "previous plan kept" in printed[0]
    diagnostics = result.summary["diagnostics"]
    assert diagnostics["failure_reasons"] == {"solver_exception": result.summary["mpc_solves"] - 1}
    log = result.log.run_log().solves
    assert set(log["status"][1:]) == {"solver_exception"} and "injected failure" in log["reason"][1]
