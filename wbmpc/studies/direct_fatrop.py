"""Benchmark: the casadi-plugin compiled path against the direct primal-dual warm-started Fatrop driver.

Both solve the same ticks in one process (same BLASFEO), taking turns round after round (one pass over the
ticks per variant, as ``wbmpc.studies.realtime`` does, so that drift hits them alike): the ticks are
recorded from a short closed loop of the default benchmark (B1 + Z1, N = 15, trot with the arm reference,
rigid plant, the plugin path in the loop), each tick's parameters and shifted primal guess kept. Per tick:

* ``plugin``: the MPC's compiled ``nlpsol`` (what ``WholeBodyMPC`` calls today), warm primal; its duals are
  re-initialised by Fatrop (bound multipliers 1, least squares for the equalities);
* ``direct, primal warm``: the direct driver with the same start (checks that it is the same algorithm);
* ``direct, primal-dual warm``: the direct driver from the same primal guess with the duals and the barrier
  parameter of its previous tick's solution (no least-squares initialisation).

Then per whole tick: two MPCs (``SolverSettings(direct=False)`` and ``direct=True``) each call ``solve()``
(parameters in, plan out) on the recorded observations, each with its own warm-start chain; and each MPC
in the closed loop itself (falls, convergence, iterations, how far the two runs' states get apart). Mean
and p95 times per solve and per tick, iterations, the load average and the CPU go to
``data/bench/direct_fatrop.json``::

    python -m wbmpc.studies.direct_fatrop --rounds 2 --flags=-O1 --flags="-O3 -march=native"
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


def riccati_flops(layouts) -> dict:
    """Floating-point operations of one factorisation of Fatrop's Riccati recursion (its OCP
    ``AugSystemSolver``, ``src/ocp/aug_system_solver.cpp`` of Fatrop 1.1.8), per stage and in total.

    Per stage with ``n = nu + nx`` and ``m = n + 1`` (the gradient row), ``nx'`` the next state, ``ng`` path
    equalities (all of rank ``r = min(ng, nu)``) and ``ni`` inequalities, counting a multiply-add as 2 and
    the triangular updates as half of a full product: ``B^T P`` (``2 m nx'^2``) and its ``syrk``
    (``n^2 nx'``), the inequality ``syrk`` (``n^2 ni``), the transposed LU of the equality rows
    (``r^2 nu - r^3 / 3``), its ``trsm`` (``(m - r) r^2``), the elimination ``gemm`` and ``syrk``
    (``2 (m - r) n r + (m - r)(n - r) r``), the Cholesky of the reduced input block
    (``(nu - r)^3 / 3 + (nx + 1)(nu - r)^2``) and the Schur complement (``nx^2 (nu - r)``). The back and
    forward substitutions are O(n^2) and left out. An estimate of the work, not of Fatrop's exact count.

    Args:
        layouts: :func:`wbmpc.solver.direct.problem.stage_layouts`.

    Returns:
        ``{"per_stage": [...], "total": ...}`` [FLOP].
    """
    per_stage = []
    for i, s in enumerate(layouts):
        nu, nx, ng, ni = s.nu, s.nx, s.eq_rows.size, s.ineq_rows.size
        nxp1 = layouts[i + 1].nx if i + 1 < len(layouts) else 0
        n, m = nu + nx, nu + nx + 1
        r = min(ng, nu)
        flops = 2 * m * nxp1**2 + n**2 * nxp1 + n**2 * ni
        flops += r**2 * nu - r**3 / 3 + (m - r) * r**2 + 2 * (m - r) * n * r + (m - r) * (n - r) * r
        flops += (nu - r) ** 3 / 3 + (nx + 1) * (nu - r) ** 2 + nx**2 * (nu - r)
        per_stage.append(float(flops))
    return {"per_stage": per_stage, "total": float(sum(per_stage))}


_KERNEL_BENCH_C = r"""
/* Times BLASFEO's kernels of one Riccati stage (see riccati_flops) on the process's libblasfeo. */
#include <blasfeo.h>
#include <stdlib.h>
#include <time.h>
static double now(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}
/* kind: 0 gemm_nt(m, n, k), 1 syrk_ln_mn(m, n, k), 2 potrf_l_mn(m, n). Returns seconds per call. */
double wbmpc_kernel_seconds(int kind, int m, int n, int k, int repeats) {
    int s = m > n ? m : n; s = s > k ? s : k;
    struct blasfeo_dmat A, B, C, D;
    void *mem = malloc(4 * blasfeo_memsize_dmat(s, s) + 256);
    char *p = (char *)(((size_t)mem + 63) / 64 * 64);
    blasfeo_create_dmat(s, s, &A, p); p += blasfeo_memsize_dmat(s, s);
    blasfeo_create_dmat(s, s, &B, p); p += blasfeo_memsize_dmat(s, s);
    blasfeo_create_dmat(s, s, &C, p); p += blasfeo_memsize_dmat(s, s);
    blasfeo_create_dmat(s, s, &D, p);
    blasfeo_dgese(s, s, 0.01, &A, 0, 0); blasfeo_dgese(s, s, 0.01, &B, 0, 0);
    blasfeo_dgese(s, s, 0.0, &C, 0, 0); blasfeo_ddiare(s, 10.0 * s, &C, 0, 0);
    double best = 1e9;
    for (int round = 0; round < 5; ++round) {
        double t0 = now();
        for (int r = 0; r < repeats; ++r) {
            if (kind == 0)
                blasfeo_dgemm_nt(m, n, k, 1.0, &A, 0, 0, &B, 0, 0, 1.0, &C, 0, 0, &D, 0, 0);
            else if (kind == 1)
                blasfeo_dsyrk_ln_mn(m, n, k, 1.0, &A, 0, 0, &A, 0, 0, 1.0, &C, 0, 0, &D, 0, 0);
            else
                blasfeo_dpotrf_l_mn(m, n, &C, 0, 0, &D, 0, 0);
        }
        double t = (now() - t0) / repeats;
        if (t < best) best = t;
    }
    free(mem);
    return best;
}
"""


def blasfeo_kernel_rates(layouts, repeats: int = 2000) -> dict:
    """GFLOP/s that the process's BLASFEO reaches on the main kernels of the Riccati stages of ``layouts``
    (``gemm_nt``, ``syrk_ln_mn``, ``potrf_l_mn`` at the sizes :func:`riccati_flops` counts), and the time
    of those kernels for one whole factorisation [s]. Compiles a small C file with gcc (a temporary folder).

    Raises:
        RuntimeError: gcc failed.
    """
    import ctypes
    import subprocess
    import tempfile

    from wbmpc.solver.direct.build import casadi_dir

    include = casadi_dir() / "include"
    with tempfile.TemporaryDirectory() as tmp:
        src, lib = Path(tmp) / "kernels.c", Path(tmp) / "libkernels.so"
        src.write_text(_KERNEL_BENCH_C)
        command = ["gcc", "-O2", "-shared", "-fPIC", str(src), f"-I{include}", "-o", str(lib)]
        command += [f"-L{casadi_dir()}", "-lblasfeo"]
        done = subprocess.run(command, capture_output=True, text=True)
        if done.returncode != 0:
            raise RuntimeError(f"compiling the kernel benchmark failed: {done.stderr[-1000:]}")
        kernels = ctypes.CDLL(str(lib))  # its libblasfeo.so.0 is the one the process mapped already
        kernels.wbmpc_kernel_seconds.restype = ctypes.c_double
        kernels.wbmpc_kernel_seconds.argtypes = [ctypes.c_int] * 5
        rates, total_s, cache = [], 0.0, {}
        for i, st in enumerate(layouts):
            nu, nx, ng, ni = st.nu, st.nx, st.eq_rows.size, st.ineq_rows.size
            nxp1 = layouts[i + 1].nx if i + 1 < len(layouts) else 0
            n, m, r = nu + nx, nu + nx + 1, min(ng, nu)
            calls = [
                ("gemm_nt", 0, m, nxp1, nxp1, 2 * m * nxp1 * nxp1),
                ("syrk_ln_mn", 1, m, n, nxp1, n * n * nxp1),
                ("syrk_ln_mn", 1, m, n, ni, n * n * ni),
                ("gemm_nt", 0, m - r, n, r, 2 * (m - r) * n * r),
                ("syrk_ln_mn", 1, m - r, n - r, r, (m - r) * (n - r) * r),
                ("potrf_l_mn", 2, nu - r + nx + 1, nu - r, 0, (nu - r) ** 3 / 3 + (nx + 1) * (nu - r) ** 2),
                ("syrk_ln_mn", 1, nx + 1, nx, nu - r, nx * nx * (nu - r)),
            ]
            for name, kind, a, b, c, flops in calls:
                if min(a, b) <= 0 or (kind != 2 and c <= 0):
                    continue
                key = (kind, a, b, c)
                if key not in cache:
                    cache[key] = kernels.wbmpc_kernel_seconds(kind, a, b, c, repeats)
                seconds = cache[key]
                total_s += seconds
                rates.append({"stage": i, "kernel": name, "size": [a, b, c], "gflops": flops / seconds / 1e9})
        return {"kernels": rates, "factorisation_kernels_s": total_s}


def replay(mpc, direct, ticks: list[RecordedTick]) -> dict:
    """Solver calls on identical inputs: the plugin's ``nlpsol``, the direct driver from the same start
    (primal warm, Fatrop's dual start) and the direct driver primal-dual warm started from its previous
    tick, each variant in its own pass over the ticks (a turn: a real MPC worker runs one solver, whose
    data stay in the caches; interleaving them tick by tick evicts each other's); per variant times [ms],
    iterations, statuses, largest primal difference to the plugin."""
    solver = mpc._solver(cold=False)
    cfg = mpc.solver_settings
    names = ("plugin", "direct_primal", "direct_pd")
    out = {name: {"solve_ms": [], "iterations": [], "status": [], "profile": []} for name in names}
    warm = [tick for tick in ticks if not tick.cold]
    reference = []
    for tick in warm:
        start = time.perf_counter()
        sol = solver(x0=tick.x0, p=tick.p, lbg=mpc.ocp.lbg, ubg=mpc.ocp.ubg)
        elapsed = time.perf_counter() - start
        stats = solver.stats()
        reference.append(np.array(sol["x"]).ravel())
        fatrop = stats.get("fatrop", {})
        out["plugin"]["solve_ms"].append(1e3 * elapsed)
        out["plugin"]["iterations"].append(int(stats["iter_count"]))
        out["plugin"]["status"].append("success" if stats["success"] else str(stats.get("return_status")))
        out["plugin"]["profile"].append(
            {
                "search_direction": fatrop.get("compute_sd_time", np.nan),
                "initialization": fatrop.get("initialization_time", np.nan),
                "hessian": stats.get("t_wall_nlp_hess_l", np.nan),
                "jacobian": stats.get("t_wall_nlp_jac_g", np.nan),
                "fatrop": fatrop.get("time_total", np.nan),
            }
        )
    max_diff = {"direct_primal": 0.0, "direct_pd": 0.0}
    for name in ("direct_primal", "direct_pd"):
        previous = None
        for tick, w_plugin in zip(warm, reference, strict=True):
            if name == "direct_pd" and previous is not None:
                mu = min(max(previous.mu, 1e-12), cfg.mu_init_warm)
                r = direct.solve(tick.p, tick.x0, mu_init=mu, duals=previous)
            else:  # primal warm; also the first tick of the primal-dual chain
                r = direct.solve(tick.p, tick.x0, mu_init=cfg.mu_init_warm)
            out[name]["solve_ms"].append(1e3 * r.timings["wall"])
            out[name]["iterations"].append(r.iterations)
            out[name]["status"].append(r.status)
            out[name]["profile"].append(r.timings)
            max_diff[name] = max(max_diff[name], float(np.max(np.abs(r.w - w_plugin))))
            previous = r if r.success else None
    summary = {}
    for name, rec in out.items():
        keys = rec["profile"][0].keys()
        summary[name] = {
            **_stats(rec["solve_ms"]),
            "iterations_mean": float(np.mean(rec["iterations"])),
            "converged_fraction": float(np.mean([s == "success" for s in rec["status"]])),
            "profile_mean_ms": {k: 1e3 * float(np.nanmean([p[k] for p in rec["profile"]])) for k in keys},
        }
        if name in max_diff:
            summary[name]["max_abs_primal_difference_to_plugin"] = max_diff[name]
    return summary


def replay_mpc(plugin_mpc, direct_mpc, ticks: list[RecordedTick]) -> dict:
    """Whole ticks: each MPC's ``solve()`` (parameters, prechecks, warm start, solve, plan) on the recorded
    observations, one MPC's pass after the other's (turns, as :func:`replay`), each with its own
    warm-start chain from a cold first tick; [ms] per solve (the solver's share, ``solve_time``) and per
    tick (``timings["total"]``), iterations, statuses."""
    out = {}
    for name, mpc in (("plugin", plugin_mpc), ("direct", direct_mpc)):
        mpc.reset()
        rec = {"solve_ms": [], "tick_ms": [], "fatrop_ms": [], "iterations": [], "success": []}
        for i, tick in enumerate(ticks):
            plan = mpc.solve(tick.q_hat, tick.v_hat, tick.t, tick.commands)
            if i == 0:
                continue  # the cold start
            # Fatrop's own time of the solve (its optimize): the rest of solve_time is the call around it.
            rec["fatrop_ms"].append(
                1e3 * mpc._solver(cold=False).stats().get("fatrop", {}).get("time_total", np.nan)
            )
            rec["solve_ms"].append(1e3 * plan.solve_time)
            rec["tick_ms"].append(1e3 * plan.timings["total"])
            rec["iterations"].append(plan.iterations)
            rec["success"].append(plan.success)
        out[name] = {
            "per_solve": _stats(rec["solve_ms"]),
            "per_tick": _stats(rec["tick_ms"]),
            "fatrop_mean_ms": float(np.nanmean(rec["fatrop_ms"])),
            "iterations_mean": float(np.mean(rec["iterations"])),
            "converged_fraction": float(np.mean(rec["success"])),
        }
    return out


def closed_loops(plugin_mpc, direct_mpc, duration: float) -> dict:
    """Both MPCs in the default closed loop (trot, rigid plant, delay off), one after the other: whether the
    robot fell, convergence, iterations, solve times [ms] and how far the direct run's base and joints get
    from the plugin run's (the plans differ only within the tolerance)."""
    from wbmpc.sim.closed_loop import ClosedLoopConfig, run_closed_loop

    runs, out = {}, {}
    for name, mpc in (("plugin", plugin_mpc), ("direct", direct_mpc)):
        result = run_closed_loop(mpc, ClosedLoopConfig(duration=duration), progress=False)
        log = result.log
        runs[name] = np.asarray(log.q)
        out[name] = {
            "fell": bool(result.fell),
            "converged_fraction": float(np.mean(log.success)),
            "iterations_mean": float(np.mean(log.iterations[1:])),
            "solve": _stats([1e3 * t for t in log.solve_time[1:]]),
        }
    n = min(len(runs["plugin"]), len(runs["direct"]))
    difference = np.abs(runs["direct"][:n] - runs["plugin"][:n])
    out["max_abs_difference"] = {
        "base_position_m": float(difference[:, :3].max()),
        "joint_positions_rad": float(difference[:, 7:].max()),
    }
    return out


def summary_table(result: dict) -> str:
    """A markdown table of a benchmark result (rounds pooled by their means): per variant and solver, the
    solver call, the MPC's solve and whole tick [ms], iterations."""
    lines = [
        "| flags | solver | solver call mean / p95 [ms] | MPC solve mean / p95 [ms] "
        "| whole tick mean / p95 [ms] | iterations | closed loop solve mean / p95 [ms] |",
        "|---|---|---|---|---|---|---|",
    ]

    def pooled(rounds, *path):
        values = []
        for r in rounds:
            x = r
            for key in path:
                x = x[key]
            values.append(x)
        return float(np.mean(values))

    for flags, variant in result["variants"].items():
        rounds = variant["rounds"]
        for calls, mpc in (("plugin", "plugin"), ("direct_primal", None), ("direct_pd", "direct")):
            call = f"{pooled(rounds, 'solver_calls', calls, 'mean_ms'):.2f} / "
            call += f"{pooled(rounds, 'solver_calls', calls, 'p95_ms'):.2f}"
            iterations = pooled(rounds, "solver_calls", calls, "iterations_mean")
            if mpc is None:
                lines.append(f"| {flags} | direct, primal warm | {call} | | | {iterations:.2f} | |")
                continue
            solve = f"{pooled(rounds, 'whole_ticks', mpc, 'per_solve', 'mean_ms'):.2f} / "
            solve += f"{pooled(rounds, 'whole_ticks', mpc, 'per_solve', 'p95_ms'):.2f}"
            tick = f"{pooled(rounds, 'whole_ticks', mpc, 'per_tick', 'mean_ms'):.2f} / "
            tick += f"{pooled(rounds, 'whole_ticks', mpc, 'per_tick', 'p95_ms'):.2f}"
            loop = f"{pooled(rounds, 'closed_loop', mpc, 'solve', 'mean_ms'):.2f} / "
            loop += f"{pooled(rounds, 'closed_loop', mpc, 'solve', 'p95_ms'):.2f}"
            label = "plugin (casadi nlpsol)" if mpc == "plugin" else "direct, primal-dual warm"
            lines.append(f"| {flags} | {label} | {call} | {solve} | {tick} | {iterations:.2f} | {loop} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(
        prog="python -m wbmpc.studies.direct_fatrop", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--duration", type=float, default=1.5, help="closed loop recorded [s] (default 1.5)")
    parser.add_argument("--rounds", type=int, default=2, help="replays of the recorded ticks (default 2)")
    parser.add_argument(
        "--flags",
        action="append",
        help="gcc flags of both libraries, one variant per use (default: the default build's, -O1)",
    )
    parser.add_argument("--output", type=Path, default=OUTPUT)
    args = parser.parse_args(argv)
    if args.rounds < 1 or not args.duration > 0:
        parser.error("--rounds must be >= 1 and --duration > 0")
    from wbmpc.control.mpc import MPCConfig, SolverSettings, WholeBodyMPC
    from wbmpc.model.robot import load_b1_z1
    from wbmpc.ocp import OCPSettings
    from wbmpc.solver import blasfeo
    from wbmpc.solver.direct import DirectFatrop

    flag_sets = [tuple(f.split()) for f in (args.flags or [" ".join(codegen_default_flags())])]
    robot = load_b1_z1()

    def make(direct: bool, flags: tuple[str, ...]):
        solver = SolverSettings(compiled=True, compile_flags=flags, direct=direct, release_flags=None)
        mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=15), MPCConfig(), solver)
        mpc.verbose = False
        mpc.prepare()  # build or load before timing
        return mpc

    variants = {}
    for flags in flag_sets:
        plugin_mpc, direct_mpc = make(False, flags), make(True, flags)
        cfg = plugin_mpc.solver_settings
        direct = DirectFatrop(plugin_mpc.ocp, tol=cfg.tol, max_iter=cfg.max_iter, flags=flags, progress=False)
        variants[" ".join(flags)] = (plugin_mpc, direct_mpc, direct)
    ticks = record_ticks(next(iter(variants.values()))[0], args.duration)
    layouts = next(iter(variants.values()))[2].layouts
    kernels = blasfeo_kernel_rates(layouts)  # before the timed rounds; hot caches: BLASFEO's best case
    started = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
    load_before = list(os.getloadavg())
    rounds: dict[str, list] = {name: [] for name in variants}
    for _ in range(args.rounds):
        for name, (plugin_mpc, direct_mpc, direct) in variants.items():
            calls = replay(plugin_mpc, direct, ticks)
            entry = {"solver_calls": calls, "whole_ticks": replay_mpc(plugin_mpc, direct_mpc, ticks)}
            entry["closed_loop"] = closed_loops(plugin_mpc, direct_mpc, args.duration)
            rounds[name].append(entry)
    result = {
        "what": "casadi-plugin compiled path vs the direct Fatrop driver (wbmpc.solver.direct), interleaved",
        "problem": "B1 + Z1, N = 15, default settings, trot closed loop (rigid plant), 80 Hz ticks",
        "cpu": cpu_name(),
        "blasfeo": blasfeo.info().get("choice"),
        "started_utc": started,
        "load_average_before": load_before,
        "load_average_after": list(os.getloadavg()),
        "ticks": len(ticks),
        "riccati_flops_per_factorisation": riccati_flops(layouts)["total"],
        "blasfeo_kernels_of_one_factorisation": kernels,
        "variants": {
            name: {
                "rounds": rounds[name],
                "plugin_build_s": plugin_mpc.compiled_nlp.build_s if plugin_mpc.compiled_nlp else None,
                "direct_build_s": direct.built.build_s if direct.built else None,
            }
            for name, (plugin_mpc, _, direct) in variants.items()
        },
    }
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=1) + "\n")
    print(summary_table(result))
    return result


def codegen_default_flags() -> tuple[str, ...]:
    from wbmpc.solver.codegen import DEFAULT_FLAGS

    return DEFAULT_FLAGS


if __name__ == "__main__":
    main()
