"""Figures of closed-loop runs and plans, on small synthetic data (no MPC solve)."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
import pinocchio as pin
import pytest
from conftest import fake_plan
from matplotlib.figure import Figure

from wbmpc.model.robot import load_b1_z1
from wbmpc.viz.plots import (
    base_rpy,
    figure_dir,
    heading_velocity,
    plot_closed_loop,
    plot_plan,
    plot_solve_profiles,
    plot_torques,
    repo_root,
    save_figure,
)


@pytest.fixture(scope="module")
def robot():
    return load_b1_z1()


@pytest.fixture(scope="module")
def log(robot):
    """A 0.4 s fake run: 500 Hz series, MPC records at 80 Hz, one failed solve."""
    rng = np.random.default_rng(0)
    t = np.arange(200) / 500.0
    q = np.tile(robot.q_nominal, (t.size, 1))
    q[:, 0] = 0.2 * t
    q[:, 2] += 0.01 * np.sin(2 * np.pi * t)
    for i, ti in enumerate(t):  # small pitch oscillation
        q[i, 3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(0.0, 0.02 * np.sin(4 * ti), 0.0)).coeffs()
    v = np.zeros((t.size, robot.nv))
    v[:, 0] = 0.2
    ee = np.column_stack([0.5 + 0.2 * t, np.zeros_like(t), 0.8 + 0.05 * np.sin(2 * t)])
    ref = ee + 0.005
    ref[0] = np.nan  # no reference before the first solve
    solve_t = np.arange(0, t[-1], 1 / 80)
    n = solve_t.size
    return {
        "t": t,
        "q": q,
        "v": v,
        "tau": rng.normal(scale=20.0, size=(t.size, robot.nj)),
        "tau_ff": rng.normal(scale=20.0, size=(t.size, robot.nj)),
        "contact": np.column_stack([t < 0.2, t >= 0.2, t >= 0.2, t < 0.2]),
        "ee_position": ee,
        "ee_reference": ref,
        "solve_t": solve_t,
        "solve_time": 0.15 + 0.02 * rng.random(n),
        "iterations": rng.integers(3, 8, n),
        "success": np.arange(n) != 5,
        "fallback": np.arange(n) == 5,
    }


@pytest.fixture(scope="module")
def plan(robot):
    return fake_plan(robot, t0=0.5, ee_force_z=0.0)


def _check_labels(fig: Figure, n_axes: int) -> None:
    assert isinstance(fig, Figure)
    assert len(fig.axes) == n_axes
    for ax in fig.axes:
        assert ax.get_ylabel(), f"axis without a y label: {ax}"
    assert any(ax.get_xlabel() for ax in fig.axes)


def test_plot_closed_loop(robot, log):
    fig = plot_closed_loop(log, robot, base_velocity_command=0.2, title="synthetic")
    _check_labels(fig, 8)
    labels = [ax.get_ylabel() for ax in fig.axes]
    assert "base height [m]" in labels and "solve time [ms]" in labels and "iterations" in labels
    # The command line is drawn on the velocity axis.
    ax_v = fig.axes[labels.index("forward velocity [m/s]")]
    assert any(np.allclose(line.get_ydata(), 0.2) for line in ax_v.get_lines())


def test_plot_closed_loop_without_command(robot, log):
    _check_labels(plot_closed_loop(log, robot), 8)


def test_plot_torques(robot, log):
    fig = plot_torques(log, robot)
    _check_labels(fig, 3)
    expected = ["RL_calf_joint [N m]", "RR_calf_joint [N m]", "joint2 [N m]"]
    assert [ax.get_ylabel() for ax in fig.axes] == expected
    # Both limits are drawn at +- the model's torque limit.
    j = robot.joint_index_v("joint2") - 6
    flat = [line.get_ydata() for line in fig.axes[2].get_lines() if len(set(line.get_ydata())) == 1]
    levels = {float(y[0]) for y in flat}
    assert {robot.joint_torque_limits[j], -robot.joint_torque_limits[j]} <= levels


def test_plot_torques_custom_joints(robot, log):
    _check_labels(plot_torques(log, robot, joints=("FL_hip_joint",)), 1)


def test_plot_plan(robot, plan):
    fig = plot_plan(plan, robot)
    _check_labels(fig, 5)
    assert fig.axes[-1].get_xlabel() == "time in the horizon [s]"
    assert "15 nodes" in fig.axes[-1].get_title()


def test_plot_plan_shows_the_base_velocity_and_its_command(robot, plan):
    from types import SimpleNamespace

    moving = SimpleNamespace(**vars(plan), v=np.zeros((len(plan.q), robot.nv)))
    moving.v[:, 0] = np.linspace(0.0, 0.3, len(plan.q))  # base frame x = forward for a level base
    fig = plot_plan(moving, robot, commands=SimpleNamespace(base_linear_velocity=np.array([0.35, 0.0, 0.0])))
    ax_v = next(ax for ax in fig.axes if ax.get_ylabel().startswith("base velocity"))
    lines = {line.get_label(): line for line in ax_v.get_lines()}
    np.testing.assert_allclose(lines["forward (plan)"].get_ydata(), moving.v[:, 0], atol=1e-12)
    assert np.allclose(lines["forward command 0.35 m/s"].get_ydata(), 0.35)


def _legends_outside(fig: Figure) -> None:
    fig.canvas.draw()
    for ax in fig.axes:
        legend = ax.get_legend()
        if legend is None:
            continue
        box, frame = legend.get_window_extent(), ax.get_window_extent()
        assert box.x0 >= frame.x1 - 1, f"the legend of {ax.get_ylabel()!r} covers the panel"


def test_legends_do_not_cover_the_data(robot, log, plan):
    _legends_outside(plot_plan(plan, robot))
    _legends_outside(plot_closed_loop(log, robot, base_velocity_command=0.2))
    _legends_outside(plot_torques(log, robot))


def test_plots_leave_pyplot_alone(robot, log, plan):
    before = plt.get_fignums()
    plot_closed_loop(log, robot)
    plot_torques(log, robot)
    plot_plan(plan, robot)
    assert plt.get_fignums() == before


def test_save_figure(tmp_path, robot, plan):
    path = save_figure(plot_plan(plan, robot), "plan", directory=tmp_path / "figs")
    assert path == tmp_path / "figs" / "plan.png"
    data = path.read_bytes()
    assert len(data) > 1000 and data[:8] == b"\x89PNG\r\n\x1a\n"
    assert save_figure(Figure(), "empty.png", directory=tmp_path).name == "empty.png"


def test_figure_dir_is_in_the_repo():
    assert (repo_root() / "pyproject.toml").is_file()
    assert figure_dir() == repo_root() / "data" / "output" / "figures"


def test_base_rpy_and_heading_velocity(robot):
    q = robot.q_nominal
    q[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(0.1, -0.2, np.pi / 2)).coeffs()
    np.testing.assert_allclose(base_rpy(q[None])[0], [0.1, -0.2, np.pi / 2], atol=1e-12)
    # Forward in the base frame, with roll and pitch: the heading-frame velocity is the level part.
    v = np.zeros(robot.nv)
    v[0] = 1.0
    R = pin.rpy.rpyToMatrix(0.1, -0.2, np.pi / 2)
    world = R @ v[:3]
    expected = pin.rpy.rpyToMatrix(0.0, 0.0, np.pi / 2).T @ world
    np.testing.assert_allclose(heading_velocity(q[None], v[None])[0], expected, atol=1e-12)


# --- the robustness heatmaps of notebook 06 ---------------------------------------------------------------
def test_heatmap_values_read_on_every_cell():
    from wbmpc.studies import sweeps

    rows = [{"m": m, "p": p, "ratio": v} for m, p, v in ((0.0, 0.0, 1.0), (0.0, 0.5, 0.0), (0.4, 0.0, 0.5))]
    fig = sweeps.heatmap(rows, "ratio", x="p", y="m", cmap="magma", vmin=0.0, vmax=1.0, fontsize=9)
    colours = {text.get_text(): text.get_color() for text in fig.axes[0].texts}
    assert colours["1"] == "black" and colours["0"] == "white"  # pale yellow and black cells of magma
    assert {text.get_fontsize() for text in fig.axes[0].texts} == {9}


def test_robustness_figures_leave_single_cells_out(tmp_path):
    from wbmpc.studies import sweeps

    rows = [
        {"magnitude": m, "phase": p, "direction": "lateral", "status": "ok", "calf_torque_ratio": 0.8}
        for m in (0.4, 0.8)
        for p in (0.0, 0.5)
    ] + [{"magnitude": 0.8, "phase": 0.0, "direction": "forward", "status": "fell", "calf_torque_ratio": 1.0}]
    assert [p.name for p in sweeps.robustness_figures(rows, tmp_path)] == ["robustness_lateral.png"]


def test_committed_sweep_tables_are_found_from_anywhere(tmp_path, monkeypatch):
    from wbmpc.studies import sweeps

    monkeypatch.chdir(tmp_path)
    assert sweeps.committed_table("robustness_grid")
    with pytest.raises(FileNotFoundError, match=r"data/results/sweeps/no_such_table\.csv is missing"):
        sweeps.committed_table("no_such_table")


def test_plot_solve_profiles_stacks_each_variants_mean():
    """Each bar is the variant's evaluations + Fatrop + the plugin around it, split in its parts."""
    profile = {"evaluations": 12.0, "solver": 6.0, "search_direction": 5.0, "initialization": 0.5}
    profile["overhead"] = 1.0
    variants = {"a": {"profile_mean_ms": profile}, "b": {"profile_mean_ms": {**profile, "evaluations": 2.0}}}
    fig = plot_solve_profiles(variants, "CPU", 30.0, "target")
    ax = fig.axes[0]
    ends = {}
    for patch in ax.patches:
        y = round(patch.get_y() + patch.get_height() / 2)
        ends[y] = max(ends.get(y, 0.0), patch.get_x() + patch.get_width())
        assert patch.get_width() >= 0
    assert ends == pytest.approx({0: 19.0, 1: 9.0})
    assert [t.get_text() for t in ax.get_yticklabels()] == ["a", "b"]
    assert ax.get_legend() is not None and "target" in [t.get_text() for t in ax.get_legend().get_texts()]
    with pytest.raises(ValueError, match=r"variant 'c' has no \['overhead'\]"):
        plot_solve_profiles({"c": {"profile_mean_ms": {k: 1.0 for k in profile if k != "overhead"}}})
    with pytest.raises(ValueError, match="at least one variant"):
        plot_solve_profiles({})
