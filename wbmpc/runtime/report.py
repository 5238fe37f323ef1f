"""A wall-clock run read back: its summary and per-tick log, the latency of each plan, one figure of it all.

:func:`run_runtime <wbmpc.runtime.run.run_runtime>` writes ``summary.json`` and ``runtime_log.npz`` into its
output folder; :func:`load_run` reads both, :func:`plan_latencies` gives each plan's end-to-end latency
(from the measurement it was made from to the first tick that used it) and :func:`plot_run` draws the loop
period, the compute time per tick, the age of the plan in use and the latencies against their targets
(issue 21: period p99 within 0.5 ms of 2 ms, plan age p95 at most two MPC periods).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["RuntimeRun", "load_run", "plan_latencies", "plot_estimate", "plot_run"]


@dataclass
class RuntimeRun:
    """One run: ``summary`` (the JSON, milliseconds) and ``log`` (per tick: ``t`` [s], ``lateness``,
    ``compute``, ``plan_age`` [s, NaN in damping], ``plan_seq``, ``plan_obs_t`` [s], ``damping``, the
    estimate and the commands); ``truth``: the emulated robot's true base (``t`` [s] since its physics
    started, ``base`` (n, 7)), ``None`` when the run did not write it."""

    summary: dict
    log: dict[str, np.ndarray]
    truth: dict[str, np.ndarray] | None = None

    @property
    def period_s(self) -> float:
        return float(self.summary["config"]["period"])

    @property
    def damping_from_s(self) -> float | None:
        return self.summary.get("damping_from_s")


def load_run(folder: str | Path) -> RuntimeRun:
    """Read a run's folder (``summary.json`` and ``runtime_log.npz``).

    Raises:
        FileNotFoundError: the folder or one of the two files is missing (named, with the command that
            writes them).
    """
    folder = Path(folder)
    missing = [name for name in ("summary.json", "runtime_log.npz") if not (folder / name).is_file()]
    if missing:
        raise FileNotFoundError(
            f"{folder} has no {' and no '.join(missing)}: write a run there with "
            f"python -m wbmpc.runtime --output {folder}"
        )
    summary = json.loads((folder / "summary.json").read_text())
    with np.load(folder / "runtime_log.npz") as data:
        log = {key: data[key] for key in data.files}
    truth = None
    if (folder / "robot_truth.npz").is_file():
        with np.load(folder / "robot_truth.npz") as data:
            truth = {key: data[key] for key in data.files}
    return RuntimeRun(summary, log, truth)


def plan_latencies(log: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """``(t_first_use, latency)`` [s] of every plan the controller used: the tick it first used a plan at,
    and that tick's time minus the plan's measurement time (the first plan, made at rest before the loop,
    left out)."""
    seq, t, obs = (np.asarray(log[key]) for key in ("plan_seq", "t", "plan_obs_t"))
    damping = np.asarray(log["damping"], dtype=bool)
    first = np.flatnonzero(np.diff(seq, prepend=seq[:1]) != 0)
    first = first[~damping[first]]
    return t[first], t[first] - obs[first]


def plot_run(run: RuntimeRun, mpc_period_s: float | None = None):
    """Four panels: loop period histogram, compute per tick, plan age in use, latency; damping shaded.

    Args:
        run: The run.
        mpc_period_s: The MPC's period [s] the plan-age target is two of; ``None``: the configured one
            (``1 / mpc_rate``; the free-running worker may plan more often, which the latency panel shows).

    Returns:
        The matplotlib figure.
    """
    import matplotlib.pyplot as plt

    log, period = run.log, run.period_s
    t = np.asarray(log["t"])
    uses, latency = plan_latencies(log)
    if mpc_period_s is None:
        mpc_period_s = 1.0 / float(run.summary["config"]["mpc_rate"])
    fig, axes = plt.subplots(2, 2, figsize=(11, 6.5))
    ax = axes[0, 0]
    periods = np.diff(t) * 1e3
    ax.hist(periods, bins=np.linspace(0, max(8 * period * 1e3, periods.max(initial=0)), 60), color="tab:blue")
    ax.axvspan((period - 5e-4) * 1e3, (period + 5e-4) * 1e3, color="tab:green", alpha=0.15, label="±0.5 ms")
    ax.set(xlabel="loop period [ms]", ylabel="ticks", yscale="log", title="Loop period")
    ax.legend(loc="best", fontsize=8)
    ax = axes[0, 1]
    ax.plot(t, np.asarray(log["compute"]) * 1e3, lw=0.5, color="tab:blue", label="compute")
    ax.axhline(period * 1e3, color="tab:red", ls="--", lw=1, label="period")
    ax.set(xlabel="time [s]", ylabel="compute per tick [ms]", title="Controller tick")
    ax.legend(loc="best", fontsize=8)
    ax = axes[1, 0]
    ax.plot(t, np.asarray(log["plan_age"]) * 1e3, lw=0.7, color="tab:blue", label="age of the plan in use")
    if np.isfinite(mpc_period_s):
        ax.axhline(2e3 * mpc_period_s, color="tab:red", ls="--", lw=1, label="2 MPC periods")
    ax.set(xlabel="time [s]", ylabel="plan age [ms]", title="Plan age at use")
    ax.legend(loc="best", fontsize=8)
    ax = axes[1, 1]
    ax.plot(uses, latency * 1e3, ".", ms=3, color="tab:blue")
    ax.set(xlabel="time of first use [s]", ylabel="latency [ms]", title="Measurement to first command")
    damping = run.damping_from_s
    for ax in axes[0, 1], axes[1, 0], axes[1, 1]:
        if damping is not None:
            ax.axvspan(damping, t[-1], color="tab:gray", alpha=0.2, lw=0)
    fig.tight_layout()
    return fig


def plot_estimate(run: RuntimeRun):
    """The controller's base estimate against the emulated robot's truth: forward position, height and the
    tilt error (the angle between the estimated and the true base z axes) over the run.

    Raises:
        ValueError: the run has no truth (a real robot, or a run written before it was recorded).
    """
    import matplotlib.pyplot as plt

    from wbmpc.runtime.metrics import aligned_truth, tilt_errors

    if run.truth is None:
        raise ValueError("this run has no robot_truth.npz: only an emulated robot knows its true base")
    t, q_hat = np.asarray(run.log["t"]), np.asarray(run.log["q_hat"])
    true_t = np.asarray(run.truth["t"]) + t[0]  # the robot's physics starts at the first command
    base = np.asarray(run.truth["base"])
    _, truth = aligned_truth(t, run.truth["t"], base, t[0])
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    for ax, i, name in ((axes[0], 0, "forward position x [m]"), (axes[1], 2, "base height z [m]")):
        ax.plot(true_t, base[:, i], color="k", lw=1.2, label="true")
        ax.plot(t, q_hat[:, i], color="tab:blue", lw=0.8, label="estimated")
        ax.set(xlabel="time [s]", ylabel=name)
        ax.legend(loc="best", fontsize=8)
    axes[2].plot(t, np.degrees(tilt_errors(q_hat, truth)), lw=0.7, color="tab:blue")
    axes[2].set(xlabel="time [s]", ylabel="tilt error [deg]", title="Estimated vs true base z axis")
    damping = run.damping_from_s
    for ax in axes:
        if damping is not None:
            ax.axvspan(damping, t[-1], color="tab:gray", alpha=0.2, lw=0)
    fig.tight_layout()
    return fig
