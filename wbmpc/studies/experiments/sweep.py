"""``robustness_sweep``: success over lateral kick magnitudes and gait phases (a benchmark)."""

from __future__ import annotations

import numpy as np

from wbmpc.ocp.gait import make_gait
from wbmpc.sim.closed_loop import machine_description
from wbmpc.sim.disturbances import Kick
from wbmpc.studies.experiments.common import (
    GAIT_PERIOD,
    ExperimentResult,
    _base_loop,
    _figure,
    _pick,
    _run,
    _setup,
)


def robustness_sweep(quick=None, progress=True, robot=None, magnitudes=None, phases=None) -> ExperimentResult:
    """Success (no fall) over a grid of lateral kick magnitudes [m/s] and gait phases (a benchmark).

    Phase 0 is the lift-off of a diagonal pair; 0.25 mid-swing; 0.5 the next lift-off (the other pair).
    """
    quick, robot, nodes, mpc_config, solver = _setup(quick, robot, gait=make_gait("trot", GAIT_PERIOD))
    magnitudes = magnitudes or _pick(quick, full=(0.4, 0.6, 0.8, 1.0), quick=(0.8,))
    phases = phases or _pick(quick, full=(0.0, 0.125, 0.25, 0.375), quick=(0.0,))
    t0 = _pick(quick, full=1.2, quick=0.4)  # a lift-off (a multiple of half the trot period): phase 0
    grid, runs = [], {}
    for m in magnitudes:
        for ph in phases:
            t_kick = t0 + ph * GAIT_PERIOD
            loop = _base_loop(
                duration=t_kick + _pick(quick, full=2.0, quick=0.5),
                disturbances=(Kick(t_kick, (0.0, m, 0.0)),),
            )
            result = _run(robot, nodes, mpc_config, loop, progress=False, solver=solver)
            runs[f"{m:g}_{ph:g}"] = result
            grid.append(
                {
                    "magnitude_m_per_s": m,
                    "phase": ph,
                    "success": not result.fell,
                    "max_tilt_rad": result.summary["max_tilt_rad"],
                }
            )
            if progress:
                print(
                    f"[robustness] kick {m} m/s at phase {ph}: {'ok' if not result.fell else 'FELL'}",
                    flush=True,
                )
    summary = {
        "quick": quick,
        "grid": grid,
        "success_rate": float(np.mean([g["success"] for g in grid])),
        "success_rate_by_magnitude": {
            f"{m:g}": float(np.mean([g["success"] for g in grid if g["magnitude_m_per_s"] == m]))
            for m in magnitudes
        },
        "machine": machine_description(),
    }
    fig, ax = _figure(1, height=3.0, width=5.0)
    table = np.array([[float(g["success"]) for g in grid if g["magnitude_m_per_s"] == m] for m in magnitudes])
    ax[0].imshow(table, cmap="RdYlGn", vmin=0, vmax=1, aspect="auto")
    ax[0].set_xticks(range(len(phases)), [f"{p:g}" for p in phases])
    ax[0].set_yticks(range(len(magnitudes)), [f"{m:g}" for m in magnitudes])
    ax[0].set(
        xlabel="gait phase of the kick", ylabel="lateral kick [m/s]", title="Success (green) over the grid"
    )
    return ExperimentResult("robustness_sweep", summary, runs, fig)
