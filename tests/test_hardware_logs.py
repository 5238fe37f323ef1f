"""Analysis of robot logs (issue 13): solve-time jitter, gait-phase alignment and touchdown detection on
synthetic signals; the base CoM offset identified from the leg torques of an emulated standing robot."""

import numpy as np
import pytest

from wbmpc import analysis as hl
from wbmpc.io.logs import RunLog
from wbmpc.model.base_com import base_com_link, shift_base_com

DT = 0.002  # low-level period [s]


def _trot_contact(t: np.ndarray, period: float = 0.8, start: float = 0.0) -> np.ndarray:
    """Scheduled stance flags (T, 4) of a trot: FL+RR swing in the first half of each cycle, FR+RL in
    the second, every foot in stance before ``start`` (in whole samples, as schedules are in ticks)."""
    k = np.round((t - start) / DT).astype(int)
    first = np.mod(k, round(period / DT)) < round(period / DT / 2)
    contact = np.stack([~first, first, first, ~first], axis=1)
    contact[k < 0] = True
    return contact


# ---------------------------------------------------------------------------------------------- jitter
def test_solve_time_jitter_counts_solves_over_the_budget():
    times = np.r_[0.5, np.full(60, 0.010), np.full(30, 0.015), np.full(10, 0.030)]  # cold solve first
    log = RunLog(solves={"solve_t": np.arange(times.size) * 0.0125, "solve_time": times})
    jitter = hl.solve_time_jitter(log)
    assert jitter.solve_ms.size == 100  # the cold start left out
    assert jitter.fraction_over == pytest.approx(0.40)
    assert jitter.median_ms == pytest.approx(10.0)
    assert jitter.counts.sum() == 100 and jitter.edges_ms[-1] >= 30.0
    np.testing.assert_allclose(jitter.period_ms, 12.5)
    assert hl.solve_time_jitter(log, budget=0.02).fraction_over == pytest.approx(0.10)
    with pytest.raises(ValueError, match="no solves"):
        hl.solve_time_jitter(RunLog(solves={"solve_t": np.array([]), "solve_time": np.array([])}))


# ---------------------------------------------------------------------------------------- gait phase
def test_gait_phase_and_alignment_find_a_known_lag():
    t = np.arange(3000) * DT
    contact = _trot_contact(t, start=1.0)
    phase = hl.gait_phase(t, contact, foot=0)
    assert np.all(np.isnan(phase[t < 1.0]))
    k = np.arange(t.size)
    cycle = (k >= 500) & (k < 2500)  # cycles of 400 samples from t = 1 s
    np.testing.assert_allclose(phase[cycle], np.mod(k[cycle] - 500, 400) / 400, atol=1e-9)

    def log(lag):
        tau = np.zeros((t.size, 16))
        tau[:, 9] = 50.0 + 20.0 * np.sin(2 * np.pi * (t - 1.0 - lag) / 0.8)  # RL calf
        return RunLog(
            signals={"t": t, "contact": contact, "tau": tau},
            meta={"joint_names": [str(i) for i in range(16)]},
        )

    aligned = hl.align_by_phase(log(0.04), log(0.0), "tau", 9, t_min=1.0)
    assert aligned.period_s == pytest.approx(0.8, abs=1e-6)
    assert aligned.lag_s == pytest.approx(0.04, abs=0.8 / 50)  # within one phase bin
    assert aligned.rms_difference == pytest.approx(20 * np.sqrt(2) * np.sin(np.pi * 0.05), rel=0.1)
    same = hl.align_by_phase(log(0.0), log(0.0), "tau", "9", t_min=1.0)
    assert same.lag_s == 0.0 and same.rms_difference < 1e-9
    with pytest.raises(ValueError, match="no complete gait cycle"):
        hl.align_by_phase(log(0.0), log(0.0), "tau", 9, t_min=10.0)


# ----------------------------------------------------------------------------------------- touchdowns
def test_touchdowns_are_found_at_the_velocity_jump():
    """A swinging calf (smooth velocity) stopped by the ground: a step in velocity, late by a known time."""
    rng = np.random.default_rng(0)
    t = np.arange(2000) * DT
    contact = _trot_contact(t, start=0.4)[:, 0]
    liftoffs = t[1:][np.diff(contact.astype(int)) == -1]
    touchdowns = t[1:][np.diff(contact.astype(int)) == 1]
    delays = np.resize([0.0, 0.010, 0.020, 0.030, -0.010], touchdowns.size)  # late (and one early) contacts
    v = np.zeros_like(t)
    for lift, td, delay in zip(liftoffs, touchdowns, delays, strict=False):
        landing = td + delay
        swing = (t >= lift) & (t < landing)
        v[swing] = 3.0 * np.sin(2 * np.pi * (t[swing] - lift) / (td - lift))  # smooth swing, 3 rad/s peak
        after = (t >= landing) & (t < landing + 0.03)
        v[after] += -2.0 * np.exp(-(t[after] - landing) / 0.005)  # the impact: a jump of 2 rad/s
    v += 0.01 * rng.standard_normal(t.size)
    found = hl.detect_touchdowns(t, contact, v)
    assert found.scheduled.size == touchdowns.size
    np.testing.assert_allclose(found.mismatch, delays[: found.scheduled.size], atol=1.5 * DT)
    summary = found.summary()
    assert summary["detected"] == touchdowns.size
    quiet = hl.detect_touchdowns(t, contact, 0.01 * rng.standard_normal(t.size))  # no impact at all
    assert np.all(np.isnan(quiet.detected))


# ------------------------------------------------------------------------------------ CoM from torques
def test_foot_forces_from_static_torques_match_the_static_equilibrium():
    from wbmpc.model.robot import load_b1_z1
    from wbmpc.model.statics import static_equilibrium

    robot = load_b1_z1()
    eq = static_equilibrium(robot, robot.q_nominal, np.ones(robot.n_feet, bool))
    forces = hl.foot_forces_from_torques(robot, robot.q_nominal[None], eq.tau[None])[0]
    assert forces[:, 2].sum() == pytest.approx(robot.mass * robot.gravity, rel=0.02)
    shifted = shift_base_com(robot, (-0.19, 0.0, 0.0), front_force_ratio=0.4)
    assert shifted.front_force_ratio == 0.4 and robot.front_force_ratio == 0.5
    link, mass = base_com_link(robot)
    assert link == "trunk"
    moved = shifted.model.inertias[1].lever - robot.model.inertias[1].lever
    np.testing.assert_allclose(
        moved, np.array([-0.19, 0.0, 0.0]) * mass / robot.model.inertias[1].mass, atol=1e-12
    )
    assert shifted.model.inertias[1].mass == pytest.approx(robot.model.inertias[1].mass)


def _emulated_standing_log(robot, profile, seconds: float = 1.0) -> RunLog:
    """The emulated robot (every plant mismatch of ``profile``) held standing by static-equilibrium torques
    of the nominal model and a joint PD, logged at 500 Hz as a robot would (commanded torques, encoders,
    odometry)."""
    from wbmpc.model.statics import static_equilibrium
    from wbmpc.sim.closed_loop import ClosedLoopConfig, make_plant
    from wbmpc.sim.loop_config import PlantConfig

    eq = static_equilibrium(robot, robot.q_nominal, np.ones(robot.n_feet, bool))
    rows = {"t": [], "q": [], "v": [], "tau": []}
    dt = 0.0005
    loop = ClosedLoopConfig(plant=PlantConfig(kind="pybullet", dt=dt, hardware=profile))
    with make_plant(robot, loop) as plant:  # the emulated robot: its motors in front of PyBullet
        state = plant.reset(robot.q_nominal, np.zeros(robot.nv))
        tau = eq.tau
        for k in range(round(seconds / dt)):
            if k % 4 == 0:  # 500 Hz low level
                tau = eq.tau + 300.0 * (robot.q_nominal[7:] - state.q[7:]) - 10.0 * state.v[6:]
                for key, value in zip(rows, (k * dt, state.q, state.v, tau), strict=True):
                    rows[key].append(np.copy(value))
            state = plant.step(tau)
    signals = {k: np.array(v) for k, v in rows.items()}
    signals["contact"] = np.ones((len(signals["t"]), robot.n_feet), bool)
    return RunLog(signals=signals, meta={"joint_names": robot.joint_names})


def test_com_offset_identified_from_an_emulated_standing_log():
    """Leg torques -> foot forces -> centre of pressure vs the model CoM: the emulated offset within 1 cm."""
    from wbmpc.model.robot import load_b1_z1
    from wbmpc.sim.hardware import HardwareProfile

    robot = load_b1_z1()
    for offset in ((-0.19, 0.0, 0.0), (0.05, 0.04, 0.0)):
        log = _emulated_standing_log(robot, HardwareProfile(base_com_offset=offset))
        ident = hl.identify_com_offset(log, robot, mask=hl.standing_mask(log, t_min=0.3))
        print(f"emulated {offset}, identified {ident.offset.round(4)} m ({ident.samples} samples)")
        assert ident.samples > 20
        np.testing.assert_allclose(ident.offset[:2], offset[:2], atol=0.01)
        if offset[0] < 0:
            assert 0.57 < ident.rear_share < 0.65  # the rear legs carry the shifted base
    nominal = hl.identify_com_offset(
        _emulated_standing_log(robot, HardwareProfile(base_com_offset=None)), robot
    )
    np.testing.assert_allclose(nominal.offset[:2], 0.0, atol=0.01)
