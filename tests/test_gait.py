"""Tests for wbmpc.ocp.gait."""

import casadi as ca
import numpy as np
import pytest

from wbmpc.ocp.gait import (
    FOOT_NAMES,
    Gait,
    SwingParams,
    default_force_distribution,
    make_gait,
    swing_height_profile,
    swing_vertical_velocity,
    symbolic_swing_vertical_velocity,
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
