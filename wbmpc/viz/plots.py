"""Matplotlib figures of closed-loop runs and MPC plans.

Every function builds and returns a :class:`matplotlib.figure.Figure` without touching pyplot's global state
(no ``plt.show()``, nothing left open), so they work the same in notebooks, scripts and tests. In a notebook
show a figure with ``display(fig)``; store it with :func:`save_figure`.

The foot colours (FL, FR, RL, RR) and the end-effector colour are shared with :mod:`wbmpc.viz`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import pinocchio as pin
from matplotlib.figure import Figure

from wbmpc.model.robot import Robot

FOOT_COLORS = ("#ff7f0e", "#2ca02c", "#9467bd", "#8c564b")  # FL, FR, RL, RR
EE_COLOR = "#1f77b4"
LIMIT_COLOR = "#d62728"
NODE_TICK_COLOR = "0.85"
DEFAULT_TORQUE_JOINTS = ("RL_calf_joint", "RR_calf_joint", "joint2")
# Legends beside the axes (right of the panel), so that they never cover a curve.
OUTSIDE_LEGEND = {
    "loc": "upper left",
    "bbox_to_anchor": (1.01, 1.0),
    "borderaxespad": 0.0,
    "fontsize": "small",
}


# --- files -----------------------------------------------------------------------------------------------
def repo_root() -> Path:
    """The repository root: the first folder above this package that holds ``pyproject.toml``.

    Falls back to the current directory for an installed (non-editable) package.
    """
    for folder in Path(__file__).resolve().parents:
        if (folder / "pyproject.toml").is_file():
            return folder
    return Path.cwd()


def figure_dir() -> Path:
    """``<repo>/data/output/figures`` (git-ignored), where :func:`save_figure` writes."""
    return repo_root() / "data" / "output" / "figures"


def save_figure(fig: Figure, name: str, directory: str | Path | None = None, dpi: int = 120) -> Path:
    """Save a figure as ``<directory>/<name>.png``.

    Args:
        fig: The figure.
        name: File name, with or without the ``.png`` suffix.
        directory: Target folder (created if missing); :func:`figure_dir` by default.
        dpi: Resolution [dots per inch].

    Returns:
        The path of the PNG file.
    """
    folder = Path(directory) if directory is not None else figure_dir()
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / (name if name.endswith(".png") else f"{name}.png")
    fig.savefig(path, dpi=dpi)
    return path


# --- closed loop -----------------------------------------------------------------------------------------
def base_rpy(q: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw [rad] of the base for configurations (n, nq), (n, 3)."""
    return np.array([pin.rpy.matrixToRpy(pin.Quaternion(qi[3:7]).normalized().matrix()) for qi in q])


def heading_velocity(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Base linear velocity [m/s] in the heading frame (x forward, y left, z up), (n, 3).

    ``v[:, :3]`` is the base velocity in the base frame (Pinocchio's free-flyer convention); it is rotated
    to the world and then into the frame that only follows the base yaw.
    """
    out = np.empty((len(q), 3))
    for i, (qi, vi) in enumerate(zip(q, v, strict=True)):
        R = pin.Quaternion(qi[3:7]).normalized().toRotationMatrix()
        yaw = np.arctan2(R[1, 0], R[0, 0])
        c, s = np.cos(yaw), np.sin(yaw)
        world = R @ vi[:3]
        out[i] = [c * world[0] + s * world[1], -s * world[0] + c * world[1], world[2]]
    return out


def plot_closed_loop(
    log: Mapping[str, np.ndarray],
    robot: Robot,
    base_velocity_command: float | None = None,
    title: str | None = None,
) -> Figure:
    """Overview of a closed-loop run (8 panels sharing the time axis).

    Panels: base height; base roll and pitch; forward base velocity against the command; end-effector x and
    z against the reference; end-effector error norm; MPC solve time per update with its median; solver
    iterations per update (failed or fallback updates in red); the scheduled contacts.

    Args:
        log: ``ClosedLoopLog.arrays()``: ``t, q, v, contact, ee_position, ee_reference`` at the low-level
            rate and ``solve_t, solve_time, iterations, success, fallback`` per MPC update.
        robot: The robot (foot names).
        base_velocity_command: Commanded forward velocity [m/s] to draw, if known.
        title: Figure title.

    Returns:
        The figure.
    """
    t, q, v = (np.asarray(log[k], dtype=float) for k in ("t", "q", "v"))
    fig = Figure(figsize=(14, 10), layout="constrained")
    axes = fig.subplots(4, 2, sharex=True)
    (ax_h, ax_rp), (ax_v, ax_ee), (ax_err, ax_time), (ax_it, ax_c) = axes
    if title:
        fig.suptitle(title)

    ax_h.plot(t, q[:, 2], color="k")
    ax_h.set_ylabel("base height [m]")

    rpy = np.degrees(base_rpy(q)) if len(q) else np.zeros((0, 3))
    ax_rp.plot(t, rpy[:, 0], label="roll")
    ax_rp.plot(t, rpy[:, 1], label="pitch")
    ax_rp.set_ylabel("base roll, pitch [deg]")
    ax_rp.legend(**OUTSIDE_LEGEND)

    forward = heading_velocity(q, v)[:, 0] if len(q) else np.zeros(0)
    ax_v.plot(t, forward, color="k", lw=0.8, label="measured")
    if base_velocity_command is not None:
        ax_v.axhline(base_velocity_command, color=LIMIT_COLOR, ls="--", label="command")
    ax_v.set_ylabel("forward velocity [m/s]")
    if ax_v.get_lines():
        ax_v.legend(**OUTSIDE_LEGEND)

    ee, ref = np.asarray(log["ee_position"], dtype=float), np.asarray(log["ee_reference"], dtype=float)
    for axis, name, color in ((0, "x", EE_COLOR), (2, "z", "#17becf")):
        ax_ee.plot(t, ee[:, axis], color=color, label=f"{name}")
        ax_ee.plot(t, ref[:, axis], color=color, ls="--", lw=1, label=f"{name} reference")
    ax_ee.set_ylabel("end effector (world) [m]")
    ax_ee.legend(**OUTSIDE_LEGEND)

    error = 1e3 * np.linalg.norm(ee - ref, axis=1)  # NaN before the first reference
    ax_err.plot(t, error, color=EE_COLOR)
    ax_err.set_ylabel("end-effector error [mm]")
    finite = error[np.isfinite(error)]
    if finite.size:
        rms = float(np.sqrt(np.mean(finite**2)))
        ax_err.axhline(rms, color="0.4", ls=":", label=f"RMS {rms:.1f} mm")
        ax_err.legend(**OUTSIDE_LEGEND)

    solve_t = np.asarray(log["solve_t"], dtype=float)
    solve_ms = 1e3 * np.asarray(log["solve_time"], dtype=float)
    ax_time.plot(solve_t, solve_ms, ".-", color="k", lw=0.6, ms=3)
    warm = solve_ms[1:] if solve_ms.size > 1 else solve_ms  # the first solve is a cold start
    if warm.size:
        median = float(np.median(warm))
        ax_time.axhline(median, color=LIMIT_COLOR, ls="--", label=f"median {median:.0f} ms (warm)")
        ax_time.legend(**OUTSIDE_LEGEND)
        if solve_ms.max() > 5 * median:
            ax_time.set_yscale("log")
    ax_time.set_ylabel("solve time [ms]")

    iterations = np.asarray(log["iterations"])
    bad = ~np.asarray(log["success"], dtype=bool) | np.asarray(log["fallback"], dtype=bool)
    ax_it.step(solve_t, iterations, where="post", color="k", lw=0.8)
    if bad.any():
        ax_it.plot(solve_t[bad], iterations[bad], "o", color=LIMIT_COLOR, ms=4, label="failed / fallback")
        ax_it.legend(**OUTSIDE_LEGEND)
    ax_it.set_ylabel("iterations")

    _contact_chart(ax_c, t, np.asarray(log["contact"], dtype=bool), robot)

    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    for ax in axes.ravel():
        ax.grid(alpha=0.3)
    return fig


def _contact_chart(ax, t: np.ndarray, contact: np.ndarray, robot: Robot) -> None:
    """Stance intervals per foot as horizontal bars (``contact`` (n, n_feet) sampled at times ``t``)."""
    names = [f.removesuffix("_foot") for f in robot.foot_frames]
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    for i in range(contact.shape[1] if contact.ndim == 2 else 0):
        c = contact[:, i].astype(int)
        starts = np.flatnonzero(np.diff(np.concatenate([[0], c])) == 1)
        ends = np.flatnonzero(np.diff(np.concatenate([c, [0]])) == -1)
        spans = [(t[s], t[e] - t[s] + dt) for s, e in zip(starts, ends, strict=True)]
        ax.broken_barh(spans, (i - 0.35, 0.7), color=FOOT_COLORS[i % len(FOOT_COLORS)])
    ax.set_yticks(range(len(names)), names)
    ax.set_ylim(len(names) - 0.5, -0.5)
    ax.set_ylabel("stance")


def plot_torques(log: Mapping[str, np.ndarray], robot: Robot, joints: Sequence[str] | None = None) -> Figure:
    """Applied joint torques against their limits, one panel per joint.

    Args:
        log: ``ClosedLoopLog.arrays()`` (``t``, ``tau``, optionally ``tau_ff``).
        robot: The robot (joint indices and torque limits).
        joints: Joint names; by default the two rear knees (the most loaded leg joints) and, on a robot
            with the Z1 arm, its shoulder pitch (the default joints the robot does not have are left out).

    Returns:
        The figure.
    """
    if joints is None:
        joints = [name for name in DEFAULT_TORQUE_JOINTS if name in robot.joint_names]
    t = np.asarray(log["t"], dtype=float)
    tau = np.asarray(log["tau"], dtype=float)
    tau_ff = np.asarray(log["tau_ff"], dtype=float) if "tau_ff" in log else None
    limits = robot.joint_torque_limits
    fig = Figure(figsize=(9, 2.2 * len(joints) + 0.6), layout="constrained")
    axes = np.atleast_1d(fig.subplots(len(joints), 1, sharex=True))
    for ax, name in zip(axes, joints, strict=True):
        j = robot.joint_index_v(name) - 6
        if tau_ff is not None and tau_ff.shape == tau.shape:  # wide and light, under the applied torque
            ax.plot(t, tau_ff[:, j], color=EE_COLOR, lw=3, alpha=0.35, label="MPC feed-forward")
        ax.plot(t, tau[:, j], color="k", lw=0.9, label="applied")
        for sign in (1, -1):
            label = "limit" if sign > 0 else None
            ax.axhline(sign * limits[j], color=LIMIT_COLOR, ls="--", lw=1, label=label)
        ax.set_ylabel(f"{name} [N m]")
        ax.grid(alpha=0.3)
    axes[0].legend(**OUTSIDE_LEGEND)
    axes[-1].set_xlabel("time [s]")
    return fig


# --- one plan --------------------------------------------------------------------------------------------
def plot_plan(plan, robot: Robot, commands=None) -> Figure:
    """What one MPC solve plans over its horizon (5 panels sharing the horizon time axis).

    Panels: vertical force of each foot per stage (a step plot: stage ``k`` holds over
    ``[t_k, t_{k+1})``) with the half-weight line; the base velocity in the heading frame at the nodes
    (forward and lateral, with the commanded ones); end-effector height and base height at the nodes; the
    time grid (node ticks, step sizes) with the contact schedule. Light vertical lines mark the nodes on
    every panel. Legends stand beside the panels, never over the data.

    Args:
        plan: A :class:`wbmpc.control.mpc.MPCSolution`.
        robot: The robot (frames, mass).
        commands: The :class:`wbmpc.control.config.Commands` of the solve, to draw the commanded base
            velocity; ``None`` draws none.

    Returns:
        The figure.
    """
    times = np.asarray(plan.node_times, dtype=float) - plan.t
    dts = np.asarray(plan.dts, dtype=float)
    q = np.asarray(plan.q, dtype=float)
    forces = np.asarray(plan.forces, dtype=float)
    contact = np.asarray(plan.contact, dtype=bool)
    fig = Figure(figsize=(10, 11), layout="constrained")
    ax_f, ax_v, ax_ee, ax_base, ax_grid = fig.subplots(5, 1, sharex=True, height_ratios=[3, 2, 2, 2, 2])
    for ax in (ax_f, ax_v, ax_ee, ax_base, ax_grid):
        for tk in times:
            ax.axvline(tk, color=NODE_TICK_COLOR, lw=0.8, zorder=0)

    for i, foot in enumerate(robot.foot_frames):
        # Rear feet dashed: in a trot diagonal feet carry equal forces and would hide each other.
        ax_f.stairs(
            forces[:, i, 2],
            times,
            color=FOOT_COLORS[i % len(FOOT_COLORS)],
            lw=2,
            ls="--" if foot.startswith("R") else "-",
            label=foot.removesuffix("_foot"),
        )
    half_weight = 0.5 * robot.mass * robot.gravity
    ax_f.axhline(half_weight, color="0.3", ls=":", lw=1, label=f"m g / 2 = {half_weight:.0f} N")
    ax_f.set_ylabel("foot force $F_z$ [N]")
    ax_f.legend(**OUTSIDE_LEGEND)

    v_nodes = getattr(plan, "v", None)
    if v_nodes is not None and len(q):
        heading = heading_velocity(q, np.asarray(v_nodes, dtype=float))
        ax_v.plot(times, heading[:, 0], "o-", color="k", ms=4, label="forward (plan)")
        ax_v.plot(times, heading[:, 1], "s-", color="0.55", ms=3, lw=1, label="lateral (plan)")
    if commands is not None:
        command = np.asarray(commands.base_linear_velocity, dtype=float)
        ax_v.axhline(
            command[0], color=LIMIT_COLOR, ls="--", lw=1.2, label=f"forward command {command[0]:g} m/s"
        )
        if command[1]:
            ax_v.axhline(
                command[1], color=LIMIT_COLOR, ls=":", lw=1.2, label=f"lateral command {command[1]:g} m/s"
            )
    ax_v.set_ylabel("base velocity [m/s]\n(heading frame)")
    if ax_v.get_lines():
        ax_v.legend(**OUTSIDE_LEGEND)

    if robot.has_arm:
        model, data = robot.model, robot.model.createData()
        ee_id = robot.frame_id(robot.ee_frame)
        ee_z = []
        for qk in q:
            pin.framesForwardKinematics(model, data, qk)
            ee_z.append(data.oMf[ee_id].translation[2])
        ax_ee.plot(times, ee_z, "o-", color=EE_COLOR, ms=4)
    ax_ee.set_ylabel("end-effector height [m]")

    ax_base.plot(times, q[:, 2], "o-", color="k", ms=4)
    ax_base.set_ylabel("base height [m]")

    for i in range(contact.shape[0]):
        spans = [(times[k], dts[k]) for k in np.flatnonzero(contact[i])]
        ax_grid.broken_barh(spans, (i - 0.35, 0.7), color=FOOT_COLORS[i % len(FOOT_COLORS)])
    ax_grid.plot(times, np.full(len(times), -0.8), "|", color="k", ms=10)
    ax_grid.set_yticks(range(contact.shape[0]), [f.removesuffix("_foot") for f in robot.foot_frames])
    ax_grid.set_ylim(contact.shape[0] - 0.5, -1.2)
    ax_grid.set_ylabel("stance per stage")
    ax_grid.set_title(
        f"time grid: {len(times)} nodes, steps {1e3 * dts[0]:.0f} → {1e3 * dts[-1]:.0f} ms, "
        f"horizon {times[-1]:.2f} s",
        fontsize="medium",
    )
    ax_grid.set_xlabel("time in the horizon [s]")
    for ax in (ax_f, ax_v, ax_ee, ax_base):
        ax.grid(axis="y", alpha=0.3)
    status = "converged" if plan.success else "NOT converged"
    fig.suptitle(
        f"MPC plan at t = {plan.t:.3f} s: {status}, {plan.iterations} iterations, "
        f"{1e3 * plan.solve_time:.0f} ms"
    )
    return fig


PROFILE_PARTS = ("evaluations", "search_direction", "initialization", "rest of Fatrop", "overhead")


def plot_solve_profiles(
    variants: Mapping[str, dict], title: str = "", line_ms: float | None = None, line_label: str = ""
) -> Figure:
    """Stacked bars of where each variant's mean solve goes, from a ``wbmpc.studies.realtime`` record.

    Args:
        variants: ``record["variants"]``: per variant a ``profile_mean_ms`` with ``evaluations``, ``solver``,
            ``search_direction``, ``initialization`` and ``overhead`` [ms] (the rest of Fatrop is
            ``solver`` minus its search direction and initialisation).
        title: Axes title (e.g. the CPU).
        line_ms: A vertical reference line [ms] (e.g. a target), with ``line_label``.

    Raises:
        ValueError: no variants, or a profile without one of those entries (names the variant).
    """
    if not variants:
        raise ValueError("plot_solve_profiles needs at least one variant")
    needed = ("evaluations", "solver", "search_direction", "initialization", "overhead")
    for name, v in variants.items():
        missing = [k for k in needed if k not in v.get("profile_mean_ms", {})]
        if missing:
            raise ValueError(f"variant {name!r} has no {missing} in its profile_mean_ms")
    fig = Figure(figsize=(7, 0.45 * len(variants) + 1), layout="constrained")
    ax = fig.add_subplot()
    for i, v in enumerate(variants.values()):
        p = dict(v["profile_mean_ms"])
        p["rest of Fatrop"] = p["solver"] - p["search_direction"] - p["initialization"]
        left = 0.0
        for j, part in enumerate(PROFILE_PARTS):
            ax.barh(i, p[part], left=left, color=f"C{j}", label=part if i == 0 else None)
            left += p[part]
    ax.set_yticks(range(len(variants)), list(variants), fontsize=8)
    ax.invert_yaxis()
    if line_ms is not None:
        ax.axvline(line_ms, color="k", ls="--", lw=1, label=line_label or None)
    ax.set(xlabel="mean solve time [ms]", title=title)
    ax.legend(fontsize=7, loc="lower right")
    return fig
