"""Benchmark: the casadi-plugin compiled path against the direct primal-dual warm-started Fatrop driver.

Both solve the same ticks, interleaved in one process (same BLASFEO, same machine state): the ticks are
recorded from a short closed loop of the default benchmark (B1 + Z1, N = 15, trot with the arm reference,
rigid plant, the plugin path in the loop), each tick's parameters and shifted primal guess kept. Per tick:

* ``plugin``: the MPC's compiled ``nlpsol`` (what ``WholeBodyMPC`` calls today), warm primal; its duals are
  re-initialised by Fatrop (bound multipliers 1, least squares for the equalities);
* ``direct, primal warm``: the direct driver with the same start (checks that it is the same algorithm);
* ``direct, primal-dual warm``: the direct driver from the same primal guess with the duals and the barrier
  parameter of its previous tick's solution (no least-squares initialisation).

Per solve and per whole tick (the MPC's ``solve()`` with each solver, parameters in, plan out) the mean and
p95 times, iterations and the CPU go to ``data/bench/direct_fatrop.json``::

    python -m wbmpc.studies.direct_fatrop --ticks 120 --rounds 2
"""

from __future__ import annotations

import argparse
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

REPO_ROOT = Path(__file__).resolve().parents[2]
OUTPUT = REPO_ROOT / "data" / "bench" / "direct_fatrop.json"


@dataclass
class RecordedTick:
    """One MPC tick of a closed loop: what the solver was called with and what the loop measured.

    Attributes:
        t: Time [s]; q_hat, v_hat: measured state; commands: the tick's commands.
        p: Parameter vector; x0: the MPC's initial primal guess (shifted previous plan, or the cold guess).
        cold: Whether the MPC started this tick cold.
        status, iterations, w: The plugin path's result in the loop (``w``: its primal solution, or None).
    """

    t: float
    q_hat: np.ndarray
    v_hat: np.ndarray
    commands: object
    p: np.ndarray
    x0: np.ndarray
    cold: bool
    status: str
    iterations: int
    w: np.ndarray | None = None


def record_ticks(mpc, duration: float = 1.0, progress: bool = False) -> list[RecordedTick]:
    """Run ``mpc`` in the default closed loop (trot, rigid plant) for ``duration`` [s]; record every tick
    (the arguments of each ``mpc.solve`` call, the solver's inputs and the plan).

    Raises:
        ValueError: ``duration`` <= 0.
    """
    from wbmpc.sim.closed_loop import ClosedLoopConfig, run_closed_loop

    if not duration > 0:
        raise ValueError(f"duration must be > 0 s, got {duration!r}")
    ticks: list[RecordedTick] = []
    solve = mpc.solve

    def recording_solve(q_hat, v_hat, t=0.0, commands=None, warm_start=True):
        plan = solve(q_hat, v_hat, t, commands, warm_start)
        inputs = mpc.last_inputs
        ticks.append(
            RecordedTick(
                t=float(t),
                q_hat=np.array(q_hat, float),
                v_hat=np.array(v_hat, float),
                commands=commands,
                p=np.array(inputs["p"], float).ravel(),
                x0=np.array(inputs["x0"], float).ravel(),
                cold="lam_g0" not in inputs,
                status=plan.status,
                iterations=int(plan.iterations),
                w=None if plan.w is None or plan.fallback else np.array(plan.w, float),
            )
        )
        return plan

    mpc.solve = recording_solve  # on this instance only, for the run
    try:
        run_closed_loop(mpc, ClosedLoopConfig(duration=duration), progress=progress)
    finally:
        del mpc.solve
    return ticks


def _stats(ms: list[float]) -> dict:
    a = np.asarray(ms, float)
    return {
        "mean_ms": float(a.mean()),
        "p95_ms": float(np.percentile(a, 95)),
        "max_ms": float(a.max()),
        "n": int(a.size),
    }


def cpu_name() -> str:
    """The CPU's model name from ``/proc/cpuinfo`` (``"unknown"`` elsewhere)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return "unknown"


def replay(mpc, direct, ticks: list[RecordedTick]) -> dict:
    """Solve every tick with the plugin, the direct driver (primal warm) and the direct driver (primal-dual
    warm from its previous tick), interleaved; per-variant times [ms], iterations, statuses, differences."""
    solver = mpc._solver(cold=False)
    cfg = mpc.solver_settings
    out = {
        name: {"solve_ms": [], "iterations": [], "status": []}
        for name in ("plugin", "direct_primal", "direct_pd")
    }
    max_diff = {"direct_primal": 0.0, "direct_pd": 0.0}
    previous = None
    for tick in ticks:
        if tick.cold:
            previous = None
            continue
        start = time.perf_counter()
        sol = solver(x0=tick.x0, p=tick.p, lbg=mpc.ocp.lbg, ubg=mpc.ocp.ubg)
        elapsed = time.perf_counter() - start
        stats = solver.stats()
        w_plugin = np.array(sol["x"]).ravel()
        out["plugin"]["solve_ms"].append(1e3 * elapsed)
        out["plugin"]["iterations"].append(int(stats["iter_count"]))
        out["plugin"]["status"].append("success" if stats["success"] else str(stats.get("return_status")))
        r = direct.solve(tick.p, tick.x0, mu_init=cfg.mu_init_warm)
        out["direct_primal"]["solve_ms"].append(1e3 * r.timings["wall"])
        out["direct_primal"]["iterations"].append(r.iterations)
        out["direct_primal"]["status"].append(r.status)
        max_diff["direct_primal"] = max(max_diff["direct_primal"], float(np.max(np.abs(r.w - w_plugin))))
        if previous is not None:
            r = direct.solve(tick.p, tick.x0, mu_init=max(previous.mu, 1e-9), duals=previous)
        out["direct_pd"]["solve_ms"].append(1e3 * r.timings["wall"])
        out["direct_pd"]["iterations"].append(r.iterations)
        out["direct_pd"]["status"].append(r.status)
        max_diff["direct_pd"] = max(max_diff["direct_pd"], float(np.max(np.abs(r.w - w_plugin))))
        previous = r if r.success else None
    summary = {}
    for name, rec in out.items():
        summary[name] = {
            **_stats(rec["solve_ms"]),
            "iterations_mean": float(np.mean(rec["iterations"])),
            "converged_fraction": float(np.mean([s == "success" for s in rec["status"]])),
        }
        if name in max_diff:
            summary[name]["max_abs_primal_difference_to_plugin"] = max_diff[name]
    return summary


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(
        prog="python -m wbmpc.studies.direct_fatrop", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--duration", type=float, default=1.5, help="closed loop recorded [s] (default 1.5)")
    parser.add_argument("--rounds", type=int, default=2, help="replays of the recorded ticks (default 2)")
    parser.add_argument("--output", type=Path, default=OUTPUT)
    args = parser.parse_args(argv)
    if args.rounds < 1 or not args.duration > 0:
        parser.error("--rounds must be >= 1 and --duration > 0")
    from wbmpc.control.mpc import MPCConfig, SolverSettings, WholeBodyMPC
    from wbmpc.model.robot import load_b1_z1
    from wbmpc.ocp import OCPSettings
    from wbmpc.solver import blasfeo
    from wbmpc.solver.direct import DirectFatrop

    robot = load_b1_z1()
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=15), MPCConfig(), SolverSettings(compiled=True))
    mpc.verbose = False
    mpc.prepare()
    direct = DirectFatrop(mpc.ocp, tol=mpc.solver_settings.tol, max_iter=mpc.solver_settings.max_iter)
    ticks = record_ticks(mpc, args.duration)
    rounds = [replay(mpc, direct, ticks) for _ in range(args.rounds)]
    result = {
        "cpu": cpu_name(),
        "blasfeo": blasfeo.info().get("choice"),
        "load_average": list(os.getloadavg()),
        "ticks": len(ticks),
        "rounds": rounds,
        "unix_time": time.time(),
    }
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=1))
    print(json.dumps(result, indent=1))
    return result


if __name__ == "__main__":
    main()
