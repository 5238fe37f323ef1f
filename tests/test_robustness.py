"""Robustness grid on the sweep engine (quick mode: in-process solver, 15 nodes, PyBullet), lift-off push.

The kick at a lift-off leaves one diagonal pair on the ground for a whole swing: without the MPC's swing abort
(``MPCConfig.kick_recovery``) a 0.8 m/s lateral kick there fell (every warm-started solve failed; full runs in
``data/results/sweeps/``); with it the pair that has just lifted off comes down and the robot recovers. The
second test is a closed-loop outcome test.
"""

import json

import pytest

pytest.importorskip("distributed")
pytest.importorskip("pybullet")

from wbmpc.studies import sweeps  # noqa: E402


@pytest.fixture(scope="module")
def table(tmp_path_factory):
    """A tiny grid in quick mode on a 1-worker cluster: no kick, and 0.8 m/s lateral at the lift-off."""
    path = tmp_path_factory.mktemp("robustness") / "robustness.csv"
    cases = sweeps.grid(
        magnitude=[0.0, 0.8], direction=["lateral"], phase=[0.0], delay=[0.0], seed=[None], quick=[True]
    )
    run = sweeps.run_sweep(cases, sweeps.robustness_case, path, workers=1, progress=False)
    assert sum(run.counts.values()) == 2 and "error" not in run.counts, run.rows
    return path


def test_quick_robustness_grid_gives_the_table_and_figures(table, tmp_path):
    rows = sweeps.read_table(table)
    assert {r["magnitude"] for r in rows} == {0.0, 0.8}
    for row in rows:
        assert row["status"] in ("ok", "fell") and row["error"] is None
        assert 0.0 <= row["calf_torque_ratio"] <= 1.0 + 1e-6  # applied torques are clipped to the limits
        assert 0.0 < row["converged_fraction"] <= 1.0
        assert isinstance(json.loads(row["failure_reasons"]), dict)
    (still,) = [r for r in rows if r["magnitude"] == 0.0]
    assert still["status"] == "ok" and still["swing_aborts"] == 0 and still["peak_speed_along_kick"] < 0.3
    paths = sweeps.robustness_figures(rows, tmp_path / "figures")
    assert [p.name for p in paths] == ["robustness_lateral.png"] and paths[0].stat().st_size > 10_000
    report = sweeps.robustness_report(rows)
    assert report["cases"] == 2 and report["survival_lift_off"] is not None


def test_lift_off_kick_is_survived_by_aborting_the_swing(table):
    """0.8 m/s lateral kick at the lift-off of a diagonal pair (phase 0), quick mode: no fall, and the pair
    that had just lifted off was brought down (the MPC aborted its swing)."""
    (row,) = [r for r in sweeps.read_table(table) if r["magnitude"] == 0.8]
    assert row["peak_speed_along_kick"] > 0.6  # the kick did hit
    assert row["status"] == "ok", row
    assert row["swing_aborts"] >= 2  # both feet of the pair
    assert row["max_tilt_rad"] < 0.35


def test_a_push_aborts_the_swing_that_just_started():
    """MPCConfig.kick_recovery: a base velocity that jumped off the last plan aborts the early swings (the
    feet are planned in stance until their nominal touchdown); a fast base with no plan changes nothing."""
    import numpy as np

    from wbmpc.control.mpc import Commands, MPCConfig, WholeBodyMPC
    from wbmpc.model.robot import load_b1_z1
    from wbmpc.ocp import OCPSettings
    from wbmpc.ocp.gait import make_gait

    robot = load_b1_z1()
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=6), MPCConfig(gait=make_gait("trot", 0.8)))
    q, t, commands = robot.q_nominal, 1.2125, Commands()  # 12.5 ms after the FR/RL pair lifted off
    kicked = np.zeros(robot.nv)
    kicked[1] = 0.8
    params = mpc.parameters(q, kicked, t, commands)
    swinging = params["contact"][:, 0] < 0.5
    assert swinging.sum() == 2
    assert mpc.recovery_parameters(params, q, kicked, t, commands) is params  # no plan: no push to tell
    mpc.previous = mpc.hold_plan(q, t - 0.0125, params)  # the last plan: standing still
    out = mpc.recovery_parameters(params, q, kicked, t, commands)
    assert mpc.stats["swing_aborts"] == 2 and mpc.recovering
    # The feet are on the ground here (nominal pose): planned in stance at once, with force targets.
    stages = np.nonzero(params["contact"][swinging].min(axis=0) < 0.5)[0]
    assert np.all(out["contact"][np.ix_(swinging, stages)] == 1.0)
    assert np.all(out["force_des"][np.ix_(swinging, stages)] > 0) and np.all(out["swing_vz"][swinging] == 0)
    np.testing.assert_allclose(out["force_des"][:, 0].sum(), params["force_des"][:, 0].sum())
    # Back near the command: recovered, no new abort; the aborted swing ends at its nominal touchdown.
    settled = mpc.recovery_parameters(
        mpc.parameters(q, np.zeros(robot.nv), 1.3, commands), q, np.zeros(robot.nv), 1.3, commands
    )
    assert (
        not mpc.recovering and mpc.stats["swing_aborts"] == 2 and np.all(settled["contact"][swinging, 0] == 1)
    )
    later = mpc.parameters(q, np.zeros(robot.nv), 1.61, commands)
    assert (
        mpc.recovery_parameters(later, q, np.zeros(robot.nv), 1.61, commands) is later
        and not mpc.aborted_swings
    )
    disabled = WholeBodyMPC(
        robot, OCPSettings(n_nodes=6), MPCConfig(gait=make_gait("trot", 0.8), kick_recovery=None)
    )
    disabled.previous = mpc.previous
    assert disabled.recovery_parameters(params, q, kicked, t, commands) is params
