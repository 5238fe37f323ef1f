"""Tests for wbmpc.ocp.gait."""

import casadi as ca
import numpy as np
import pytest

from wbmpc.model.robot import FOOT_NAMES
from wbmpc.model.statics import default_force_distribution
from wbmpc.ocp.gait import (
    Gait,
    GaitSchedule,
    SwingParams,
    make_gait,
    parse_gait_schedule,
    swing_height_profile,
    swing_vertical_velocity,
    symbolic_swing_vertical_velocity,
    to_ticks,
)

GAITS = ["trot", "walk", "stand", "pace", "bound"]
FL, FR, RL, RR = range(4)
TIMES = np.linspace(0.0, 3.2, 1601)  # 4 cycles of 0.8 s, 2 ms steps, hits the phase boundaries


def test_foot_order():
    assert FOOT_NAMES == ("FL", "FR", "RL", "RR")


def test_trot_diagonals_alternate():
    s = make_gait("trot").sample(TIMES)
    c = s.contact
    np.testing.assert_array_equal(c[FL], c[RR])
    np.testing.assert_array_equal(c[FR], c[RL])
    np.testing.assert_array_equal(c[FL], ~c[FR])  # exactly one diagonal swings at a time
    assert np.all(s.n_contacts == 2) and np.all(s.n_contacts > 0)
    g = make_gait("trot")
    assert not g.contact(0.1)[FL] and g.contact(0.1)[FR]  # FL+RR swing in phase [0, 0.5)
    assert g.contact(0.5)[FL] and not g.contact(0.5)[FR]


def test_walk_three_stance_feet_and_order():
    g = make_gait("walk")
    s = g.sample(TIMES)
    assert np.all(s.n_contacts == 3)
    assert g.n_stance_nominal == 3
    swinging = [FOOT_NAMES[int(np.flatnonzero(~g.contact(t))[0])] for t in (0.1, 0.3, 0.5, 0.7)]
    assert swinging == ["FL", "RR", "FR", "RL"]


def test_pace_bound_stand():
    pace, bound, stand = make_gait("pace"), make_gait("bound"), make_gait("stand")
    cp, cb = pace.sample(TIMES).contact, bound.sample(TIMES).contact
    np.testing.assert_array_equal(cp[FL], cp[RL])
    np.testing.assert_array_equal(cp[FR], cp[RR])
    np.testing.assert_array_equal(cp[FL], ~cp[FR])
    np.testing.assert_array_equal(cb[FL], cb[FR])
    np.testing.assert_array_equal(cb[RL], cb[RR])
    np.testing.assert_array_equal(cb[FL], ~cb[RL])
    s = stand.sample(TIMES)
    assert s.contact.all() and not s.swing_phase.any() and stand.swing_duration == 0.0
    assert stand.n_stance_nominal == 4


@pytest.mark.parametrize("name", GAITS)
@pytest.mark.parametrize("period", [0.5, 0.8])
def test_periodic(name, period):
    g = make_gait(name, period)
    t = np.random.default_rng(0).uniform(0, period, 200)
    a, b = g.sample(t), g.sample(t + 3 * period)
    np.testing.assert_array_equal(a.contact, b.contact)
    np.testing.assert_allclose(a.swing_phase, b.swing_phase, atol=1e-9)
    assert a.contact.shape == (4, 200) and a.n_contacts.shape == (200,)
    np.testing.assert_array_equal(a.n_contacts, a.contact.sum(axis=0))


def test_swing_phase_linear():
    g = make_gait("trot", 0.8)
    assert g.swing_duration == pytest.approx(0.4)
    t = np.linspace(0.0, 0.4, 41)[:-1]  # FL's swing
    phase = g.sample(t).swing_phase
    np.testing.assert_allclose(phase[FL], t / 0.4, atol=1e-12)
    assert np.all(phase[FR] == 0.0)  # stance feet report 0
    assert np.all((phase >= 0) & (phase < 1))
    np.testing.assert_allclose(g.swing_phase(0.9), [0.25, 0, 0, 0.25], atol=1e-12)  # next cycle


def test_paper_velocity_values():
    # d = 0.2 s, 6 h / d = 2.1: phi = 0.2 -> s = 0.4: 0.1 (1 - 1.6 + 0.48) + 2.1 * 0.24 = 0.492;
    # phi = 0.8 -> s = 0.6: -0.2 (1.08 - 1.2) - 2.1 * 0.24 = -0.48
    assert swing_vertical_velocity(0.2, 0.4, 0.07, 0.1, -0.2) == pytest.approx(0.492, abs=1e-9)
    assert swing_vertical_velocity(0.8, 0.4, 0.07, 0.1, -0.2) == pytest.approx(-0.48, abs=1e-9)


@pytest.mark.parametrize(
    "T, h, v_lo, v_td", [(0.4, 0.07, 0.1, -0.2), (0.3, 0.12, 0.0, 0.0), (0.25, 0.05, 0.3, -0.5)]
)
def test_spline_position_integrates_velocity(T, h, v_lo, v_td):
    phi = np.linspace(0.0, 1.0, 4001)
    v = swing_vertical_velocity(phi, T, h, v_lo, v_td)
    z = swing_height_profile(phi, T, h, v_lo, v_td)
    t = phi * T
    z_int = np.concatenate(([0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))))
    np.testing.assert_allclose(z, z_int, atol=1e-4)
    assert z[0] == pytest.approx(0.0, abs=1e-12) and z[-1] == pytest.approx(0.0, abs=1e-12)
    assert v[0] == pytest.approx(v_lo) and v[-1] == pytest.approx(v_td)
    assert swing_height_profile(0.5, T, h, v_lo, v_td) == pytest.approx(h)
    assert swing_vertical_velocity(0.5, T, h, v_lo, v_td) == pytest.approx(0.0, abs=1e-12)
    # apex h at mid-swing (z rises monotonically while h > v_lo T / 6, true for these cases)
    assert z.max() == pytest.approx(h, rel=1e-9) and phi[np.argmax(z)] == pytest.approx(0.5)


def test_symbolic_matches_numpy():
    rng = np.random.default_rng(1)
    for sym in (ca.SX, ca.MX):
        phi, T, h, lo, td = (sym.sym(n) for n in ("phi", "T", "h", "lo", "td"))
        f = ca.Function("vz", [phi, T, h, lo, td], [symbolic_swing_vertical_velocity(phi, T, h, lo, td)])
        for p in rng.uniform(0.0, 1.0, 50):
            T, h = rng.uniform(0.2, 0.5), rng.uniform(0.03, 0.15)
            args = (p, T, h, rng.uniform(0, 0.3), -rng.uniform(0, 0.3))
            assert float(f(*args)) == pytest.approx(float(swing_vertical_velocity(*args)), abs=1e-12)


@pytest.mark.parametrize("name", GAITS)
@pytest.mark.parametrize("ratio", [0.0, 0.3, 0.5, 0.65, 1.0])
def test_force_distribution_sums_to_weight(name, ratio):
    mass, g = 52.0, 9.81
    contact = make_gait(name).sample(TIMES).contact
    f = default_force_distribution(contact, mass, g, front_ratio=ratio)
    assert f.shape == contact.shape
    np.testing.assert_allclose(f.sum(axis=0), mass * g, rtol=1e-12)
    assert np.all(f[~contact] == 0.0) and np.all(f >= 0.0)


def test_force_distribution_front_ratio():
    w = 10.0 * 9.81
    f = default_force_distribution(np.ones(4, bool), 10.0, front_ratio=0.6)
    assert f.shape == (4,)
    np.testing.assert_allclose(f, [0.3 * w, 0.3 * w, 0.2 * w, 0.2 * w])
    f = default_force_distribution(np.array([True, False, True, True]), 10.0, front_ratio=0.6)  # walk
    np.testing.assert_allclose(f, [0.6 * w, 0.0, 0.2 * w, 0.2 * w])
    f = default_force_distribution(np.array([False, False, True, True]), 10.0, front_ratio=0.6)  # rear only
    np.testing.assert_allclose(f, [0.0, 0.0, 0.5 * w, 0.5 * w])
    np.testing.assert_array_equal(default_force_distribution(np.zeros(4, bool), 10.0), np.zeros(4))


def test_swing_params():
    p = SwingParams()
    assert (p.height, p.v_liftoff, p.v_touchdown) == (0.07, 0.1, -0.2)
    for bad in (0.0, -0.1, 0.5, float("nan")):
        with pytest.raises(ValueError, match="height"):
            SwingParams(height=bad)
    with pytest.raises(ValueError, match="v_touchdown"):
        SwingParams(v_touchdown=float("inf"))


def test_bad_inputs():
    with pytest.raises(ValueError, match="name") as err:
        make_gait("gallop")
    assert "trot" in str(err.value) and "walk" in str(err.value)
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="period"):
            make_gait("trot", bad)
    with pytest.raises(ValueError, match="swing_fraction"):
        Gait("x", 1.0, 1.0, (0, 0, 0, 0))
    with pytest.raises(ValueError, match="offsets"):
        Gait("x", 1.0, 0.5, (0, 0, 0))
    with pytest.raises(ValueError, match="times"):
        make_gait("trot").sample(np.array([0.0, np.nan]))
    with pytest.raises(ValueError, match="phi"):
        swing_vertical_velocity(1.5, 0.4, 0.07, 0.1, -0.2)
    with pytest.raises(ValueError, match="T"):
        swing_height_profile(0.2, 0.0, 0.07, 0.1, -0.2)
    with pytest.raises(ValueError, match="contact"):
        default_force_distribution(np.ones(3, bool), 10.0)
    with pytest.raises(ValueError, match="mass"):
        default_force_distribution(np.ones(4, bool), -1.0)
    with pytest.raises(ValueError, match="front_ratio"):
        default_force_distribution(np.ones(4, bool), 10.0, front_ratio=1.5)


# --- gaps found by mutation testing (docs/mutation_report.md) ----------------------------------------------
# Ticks of 0.5 ms; trot period 1600 ticks, FL + RR swing on [0, 800) of each cycle, FR + RL on [800, 1600).
A, B, ALL = (False, True, True, False), (True, False, False, True), (True,) * 4  # contacts FL, FR, RL, RR


def test_to_ticks_rounds_to_whole_integer_ticks():
    ticks = to_ticks(np.array([0.0, 0.00024, 0.00026, 1.2, -0.0005]))
    assert ticks.dtype == np.int64
    np.testing.assert_array_equal(ticks, [0, 0, 1, 2400, -1])


def test_a_gait_on_its_own_tick_samples_in_its_ticks():
    """A 1 ms tick: the trot's 0.8 s period is 800 ticks, so at 0.4 s (tick 400) FR + RL swing; read in
    0.5 ms ticks (tick 800 of a 800-tick cycle) FL + RR would."""
    gait = make_gait("trot", 0.8, tick=0.001)
    assert gait.tick == 0.001
    np.testing.assert_array_equal(gait.sample(np.array([0.0, 0.3994, 0.4])).contact.T, [A, A, B])
    schedule = parse_gait_schedule("stand:1,trot:2", tick=0.001)
    assert schedule.tick == 0.001 and all(g.tick == 0.001 for g in schedule.gaits)
    np.testing.assert_array_equal(schedule.start_ticks, [0, 1000])
    np.testing.assert_array_equal(schedule.sample(np.array([0.999, 1.0, 1.4])).contact.T, [ALL, A, B])
    assert schedule.gait_at(0.999).name == "stand" and schedule.gait_at(1.0).name == "trot"


def test_schedule_lookups_at_the_switch_ticks_and_before_the_start():
    """gait_at, velocity_at, contact, swing_phase and n_contacts at the switches of stand:2,trot@0.3:6,stand
    (ticks 4000 and 16000): the new segment from its first tick on; before t = 0 the first segment."""
    schedule = parse_gait_schedule("stand:2,trot@0.3:6,stand:2")
    for t, name, velocity in (
        (1.9995, "stand", 0.0),
        (2.0, "trot", 0.3),
        (7.9995, "trot", 0.3),
        (8.0, "stand", 0.0),
    ):
        assert schedule.gait_at(t).name == name, t
        assert schedule.velocity_at(t) == (velocity, 0.0, 0.0), t
    np.testing.assert_array_equal(schedule.contact(2.0), A)
    np.testing.assert_array_equal(schedule.contact(2.4), B)
    np.testing.assert_allclose(schedule.swing_phase(2.2), [0.5, 0.0, 0.0, 0.5])
    walk_last = parse_gait_schedule("stand:1,trot:1")  # before the start: the first segment, not the last
    assert walk_last.gait_at(-0.01).name == "stand" and walk_last.contact(-0.01).all()
    assert walk_last.velocity_at(-0.01) == (0.0, 0.0, 0.0)
    sample = schedule.sample(np.array([-0.01, 1.0, 2.0, 2.4, 8.0]))
    np.testing.assert_array_equal(sample.n_contacts, [4, 4, 2, 2, 4])
    trot = make_gait("trot")
    for lookup in (
        schedule.contact,
        schedule.swing_phase,
        schedule.gait_at,
        schedule.velocity_at,
        trot.contact,
        trot.swing_phase,
        trot.velocity_at,
    ):
        with pytest.raises(ValueError, match="^t must be finite, got nan$"):
            lookup(float("nan"))


def test_a_schedule_that_starts_with_a_trot_starts_its_cycle_at_tick_0():
    schedule = parse_gait_schedule("trot:1.2,stand:1")
    np.testing.assert_array_equal(schedule.sample(np.array([0.0, 0.4, 1.1995])).contact.T, [A, B, A])


def test_switch_ticks_of_extended_segments_by_hand():
    """Where a segment ends (ticks), worked out by hand from the trot's switch ticks (multiples of 800 after
    the trot's own start):
    * stand:0.0005 -> 1 tick (a stand never swings: its nominal end);
    * trot:0.0005 first -> 800 (FL + RR lifted at tick 0 and land at 800: a one-tick-old swing is not cut);
    * stand:0.3,trot:1 -> the trot starts at 600, nominally ends at 2600 (its tick 2000, mid-swing), so
      at 3000 (its tick 2400);
    * stand:2,trot:5.9005 -> nominally 15801 (the trot's tick 11801), extended by 199 ticks to 16000."""
    cases = {
        "stand:0.0005,trot:1": [0, 1],
        "trot:0.0005,stand:1": [0, 800],
        "stand:0.3,trot:1,stand:1": [0, 600, 3000],
        "stand:2,trot:5.9005,stand:2": [0, 4000, 16000],
    }
    for spec, ticks in cases.items():
        np.testing.assert_array_equal(parse_gait_schedule(spec).start_ticks, ticks, err_msg=spec)
    switch = "so that no swing is cut by the switch to"
    (note,) = parse_gait_schedule("stand:2,trot:5.9005,stand:2").notes
    assert note == f"trot segment 1 extended by 0.0995 s to t = 8 s {switch} stand"
    (note,) = parse_gait_schedule("stand:0.3,trot:1,walk:1").notes
    assert note == f"trot segment 1 extended by 0.2 s to t = 1.5 s {switch} walk"


def test_an_extension_stops_after_one_period():
    """Swings that overlap (swing fraction 0.6: some foot is always mid-swing): the segment is extended by
    at most one period (1600 ticks), never forever."""
    overlap = Gait("overlap", 0.8, 0.6, (0.0, 0.5, 0.5, 0.0))
    assert all(overlap.mid_swing(k) for k in range(0, 1600, 7))
    schedule = GaitSchedule([(overlap, 0.1), (make_gait("stand"), 1.0)])
    np.testing.assert_array_equal(schedule.start_ticks, [0, 200 + 1600])


def test_a_change_of_speed_continues_the_cycle_over_several_segments():
    """stand:1 then three trot segments of other speeds: one trot cycle from tick 2000 through all three."""
    schedule = parse_gait_schedule("stand:1,trot@0.2:1.4,trot@0.5:1,trot@0.3:2")
    np.testing.assert_array_equal(schedule.cycle_origins, [0, 2000, 2000, 2000])
    ticks = np.array([4800, 6799, 6800, 7000, 7200])  # (tick - 2000) mod 1600: 1200, 1599, 0, 200, 400
    np.testing.assert_array_equal(schedule.sample(ticks * 0.0005).contact.T, [B, B, A, A, A])


def test_each_new_gait_starts_its_cycle_at_its_own_start():
    """trot, stand, then two trot segments: the third segment's cycle starts at its own start (4400, after a
    stand), the fourth continues it. stand:1,trot:1.2,walk:1: the walk starts lifting FL at its start."""
    schedule = parse_gait_schedule("trot:1,stand:1,trot@0.2:1,trot@0.4:1")
    np.testing.assert_array_equal(schedule.start_ticks, [0, 2400, 4400, 6400])  # the first trot extended
    np.testing.assert_array_equal(schedule.cycle_origins, [0, 2400, 4400, 4400])
    ticks = np.array([4400, 6400, 6800])  # the trot's own ticks 0, 2000 (mod 1600: 400), 2400 (800)
    np.testing.assert_array_equal(schedule.sample(ticks * 0.0005).contact.T, [A, A, B])
    walk = parse_gait_schedule("stand:1,trot:1.2,walk:1")
    np.testing.assert_array_equal(walk.start_ticks, [0, 2000, 4400])
    np.testing.assert_array_equal(walk.contact(2.2), [False, True, True, True])  # FL lifts at the switch


def test_segment_velocities_parse_name_and_default():
    """``trot@vx[/vy[/yaw rate]]``: missing components are zero, the name drops trailing zeros only; a
    segment without one: a stand stands still, a walking gait takes the run's command (None)."""
    schedule = parse_gait_schedule("stand:1,trot@0.3/0.1:2,trot@0/0/0.3:2,trot:1")
    assert schedule.velocities == (None, (0.3, 0.1, 0.0), (0.0, 0.0, 0.3), None)
    assert schedule.name == "stand:1+trot@0.3/0.1:2+trot@0/0/0.3:2+trot:1"
    assert schedule.velocity_at(0.5) == (0.0, 0.0, 0.0) and schedule.velocity_at(5.5) is None
    assert (
        make_gait("stand").velocity_at(1.0) == (0.0, 0.0, 0.0) and make_gait("trot").velocity_at(1.0) is None
    )
    for spec in ("trot@0.1/0.2/0.3/0.4:2", "trot@:2", "trot@fast:2"):
        with pytest.raises(ValueError, match=r"the velocity after '@' must be vx\[/vy\[/yaw rate\]\]"):
            parse_gait_schedule(spec)


def test_segment_velocities_and_names():
    schedule = parse_gait_schedule("stand:1,trot@0:2")
    assert schedule.name == "stand:1+trot@0:2" and schedule.velocity_at(2.0) == (0.0, 0.0, 0.0)
    trot = make_gait("trot")
    with pytest.raises(ValueError, match="segment 0 velocity must be 3 finite numbers"):
        GaitSchedule([(trot, 1.0, 5.0)])
    with pytest.raises(
        ValueError, match=r"segment 0 must be \(gait, duration\) or \(gait, duration, velocity\)"
    ):
        GaitSchedule([(trot, 1.0, (0.1, 0.0, 0.0), "extra")])
    with pytest.raises(ValueError, match="gait tick 0.001 s differs from the schedule's 0.0005 s"):
        GaitSchedule([(make_gait("trot", tick=0.001), 1.0)])
    with pytest.raises(ValueError, match="tick must be finite and > 0"):
        GaitSchedule([(trot, 1.0)], tick=0.0)


def test_a_lone_gait_name_is_one_segment_that_goes_on():
    schedule = parse_gait_schedule("trot")
    assert len(schedule.gaits) == 1 and schedule.duration >= 1e8
    t = np.array([0.0, 0.4, 1000.0, 1000.4])
    np.testing.assert_array_equal(schedule.sample(t).contact, make_gait("trot").sample(t).contact)


def test_gait_validation_names_the_field():
    with pytest.raises(ValueError, match="period must be a real number, got 'fast'"):
        Gait("x", "fast", 0.5, (0.0, 0.5, 0.5, 0.0))
    with pytest.raises(ValueError, match="tick must be finite and > 0"):
        Gait("x", 0.8, 0.5, (0.0, 0.5, 0.5, 0.0), tick=0.0)
    with pytest.raises(ValueError, match="tick must be finite and > 0"):
        Gait("x", 0.8, 0.5, (0.0, 0.5, 0.5, 0.0), tick=-0.0005)
    with pytest.raises(ValueError, match="period must be finite and > 0"):
        Gait("x", -0.8, 0.5, (0.0, 0.5, 0.5, 0.0))
    with pytest.raises(ValueError, match="swing_fraction must be finite"):
        Gait("x", 0.8, float("nan"), (0.0, 0.5, 0.5, 0.0))
    for offsets in ((0.0, 0.5, 0.5, 1.5), (-0.1, 0.5, 0.5, 0.0)):
        with pytest.raises(ValueError, match="offsets must be 4 phases in"):
            Gait("x", 0.8, 0.5, offsets)
    gait = Gait("x", 0.8, 0.5, [0, 0.5, 0.5, 0])  # a list: stored as a tuple of floats (hashable)
    assert gait.offsets == (0.0, 0.5, 0.5, 0.0) and isinstance(gait.offsets, tuple) and hash(gait)
    # Off the tick grid: the message gives the tick in ms and the nearest valid period.
    with pytest.raises(ValueError, match=r"period = 0.8002 s is not a multiple of the schedule tick 0.5 ms"):
        make_gait("trot", 0.8002)
    with pytest.raises(ValueError, match=r"use e.g. 0.8 s"):
        make_gait("trot", 0.8002)
    with pytest.raises(ValueError, match=r"use e.g. 0.0005 s"):
        make_gait("trot", 0.0002)


def test_swing_validation_bounds_and_names():
    SwingParams(v_liftoff=2.0, v_touchdown=-2.0)  # the bounds are allowed
    with pytest.raises(ValueError, match=r"SwingParams.v_liftoff must be in \[0, 2\]"):
        SwingParams(v_liftoff=2.5)
    with pytest.raises(ValueError, match=r"SwingParams.v_touchdown must be in \[-2, 0\]"):
        SwingParams(v_touchdown=-2.5)
    with pytest.raises(ValueError, match="SwingParams.v_touchdown must be finite"):
        SwingParams(v_touchdown=float("nan"))
    for kwargs, message in (
        ({"T": 0.0}, "T must be finite and > 0"),
        ({"h": float("nan")}, "h must be finite"),
        ({"v_lo": float("inf")}, "v_lo must be finite"),
        ({"v_td": float("nan")}, "v_td must be finite"),
    ):
        args = {"T": 0.4, "h": 0.07, "v_lo": 0.1, "v_td": -0.2} | kwargs
        with pytest.raises(ValueError, match=message):
            swing_height_profile(0.2, **args)
    with pytest.raises(ValueError, match=r"phi must be in \[0, 1\]"):
        swing_height_profile(-0.1, 0.4, 0.07, 0.1, -0.2)


def test_force_distribution_edge_cases():
    w = 10.0 * 9.81
    only_fl = np.array([True, False, False, False])
    np.testing.assert_allclose(
        default_force_distribution(only_fl, 10.0), [w, 0.0, 0.0, 0.0]
    )  # one front foot
    only_rr = np.array([False, False, False, True])
    np.testing.assert_allclose(default_force_distribution(only_rr, 10.0), [0.0, 0.0, 0.0, w])
    for shape in ((4, 2, 2), (4, 1, 1)):
        with pytest.raises(ValueError, match="contact must be a bool array"):
            default_force_distribution(np.ones(shape, bool), 10.0)
    with pytest.raises(ValueError, match=r"gravity must be a finite number > 0 \[m/s\^2\], got -9.81"):
        default_force_distribution(np.ones(4, bool), 10.0, gravity=-9.81)
    with pytest.raises(ValueError, match=r"mass must be a finite number > 0 \[kg\], got 0.0"):
        default_force_distribution(np.ones(4, bool), 0.0)
    with pytest.raises(ValueError, match=r"front_ratio must be a finite number in \[0, 1\], got nan"):
        default_force_distribution(np.ones(4, bool), 10.0, front_ratio=float("nan"))
    # 0/1 numbers are stance flags too (the same forces as bools); anything else is refused.
    flags = np.array([[1, 0, 1, 1], [0, 1, 1, 0]]).T
    for numeric in (flags, flags.astype(float)):
        np.testing.assert_array_equal(
            default_force_distribution(numeric, 10.0, front_ratio=0.6),
            default_force_distribution(flags.astype(bool), 10.0, front_ratio=0.6),
        )
    with pytest.raises(ValueError, match="contact must be a bool array"):
        default_force_distribution(np.array([1.0, 0.5, 1.0, 1.0]), 10.0)
