"""Solve-time benchmark of the MPC in closed loop: compiled vs in-process, Fatrop vs IPOPT, node count.

Every record is a closed-loop run on the default robot (trot at 0.2 m/s + the arm's low/high reference,
rigid-contact Pinocchio plant), with the first ``warmup`` solves discarded. Timing assertions never go in
tests: this command measures and writes ``data/bench/solve_times.json`` (a list of records) and a figure
``data/output/bench/solve_times.png``.

    python -m wbmpc.bench            # full run (about 15 minutes on 2 cores)
    python -m wbmpc.bench --quick    # about a minute (also with WBMPC_QUICK=1)
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from wbmpc.quick import quick_mode

REPO_ROOT = Path(__file__).resolve().parent.parent


def run_case(
    robot,
    solver: str,
    compiled: bool,
    nodes: int,
    steps: int,
    warmup: int,
    progress: bool,
    formulation: str = "inverse_dynamics",
    kp: float = 0.0,
    kd: float = 0.0,
) -> dict:
    """One closed-loop run; statistics over the solves after the warm-up.

    Args:
        kp, kd: Low-level joint PD gains [N m/rad], [N m s/rad] (0: pure feed-forward torques).
    """
    from wbmpc.closed_loop import ClosedLoopConfig, machine_description, run_closed_loop
    from wbmpc.gait import make_gait
    from wbmpc.mpc import MPCConfig, WholeBodyMPC
    from wbmpc.ocp import OCPSettings

    config = MPCConfig(gait=make_gait("trot"), solver=solver, compiled=compiled)
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=nodes, formulation=formulation), config)
    mpc.verbose = progress
    start = time.perf_counter()
    mpc._solver(cold=True)  # build (or load from the cache) before timing anything
    mpc._solver(cold=False)
    setup_s = time.perf_counter() - start
    loop = ClosedLoopConfig(duration=(steps + warmup) / 80.0, kp=kp, kd=kd)
    result = run_closed_loop(mpc, loop, progress=progress)
    log = result.log
    ms = 1e3 * np.asarray(log.solve_time[warmup:])
    iterations = np.asarray(log.iterations[warmup:])
    timings = log.timings[warmup:]

    def mean_ms(key):
        values = [t[key] for t in timings if key in t]
        return float(1e3 * np.mean(values)) if values else None

    build = mpc.compiled_nlp
    return {
        "formulation": mpc.ocp.settings.formulation,
        "solver": solver,
        "compiled": compiled,
        "nodes": nodes,
        "steps": int(ms.size),
        "kp": kp,
        "kd": kd,
        "warmup_steps": warmup,
        "mean_ms": float(ms.mean()),
        "std_ms": float(ms.std()),
        "median_ms": float(np.median(ms)),
        "p95_ms": float(np.percentile(ms, 95)),
        "max_ms": float(ms.max()),
        "iterations_mean": float(iterations.mean()),
        "converged_fraction": float(np.mean(log.success[warmup:])),
        "constraint_violation_max": float(np.max(log.violation[warmup:])),
        "profile_mean_ms": {
            key: mean_ms(key)
            for key in (
                "evaluations",
                "hessian",
                "jacobian",
                "solver",
                "search_direction",
                "initialization",
                "overhead",
            )
        },
        "fell": result.fell,
        "max_tilt_rad": result.summary["max_tilt_rad"],
        "ee_rms_m": result.summary.get("ee_rms_m"),
        "build_s": build.build_s if build else None,
        "build_peak_mb": build.build_peak_mb if build else None,
        "c_megabytes": build.c_bytes / 1e6 if build else None,
        "setup_s": setup_s,
        "machine": machine_description(),
    }


def cases(quick: bool) -> list[tuple[str, bool, int]]:
    """(solver, compiled, nodes) of each record."""
    if quick:
        return [("fatrop", False, 5), ("ipopt", False, 5)]
    return [
        ("fatrop", False, 15),
        ("fatrop", True, 15),
        ("ipopt", False, 15),
        ("fatrop", True, 5),
        ("fatrop", True, 10),
        ("fatrop", True, 20),
        ("fatrop", True, 30),
    ]


def plot(records: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    from wbmpc.plots import save_figure

    fig = Figure(figsize=(11, 4))
    ax1, ax2 = fig.subplots(1, 2)
    main = [r for r in records if r["nodes"] == max(r["nodes"] for r in records if not r["compiled"])]
    labels = [f"{r['solver']}\n{'compiled' if r['compiled'] else 'in-process'}" for r in main]
    parts = [
        (
            r["profile_mean_ms"].get("evaluations") or 0,
            r["profile_mean_ms"].get("solver") or 0,
            r["profile_mean_ms"].get("overhead") or 0,
        )
        for r in main
    ]
    bottom = np.zeros(len(main))
    for i, (name, color) in enumerate(
        (
            ("derivative evaluations", "tab:blue"),
            ("solver (linear algebra)", "tab:orange"),
            ("Python/CasADi overhead", "tab:gray"),
        )
    ):
        values = np.array([p[i] for p in parts])
        ax1.bar(labels, values, bottom=bottom, color=color, label=name)
        bottom += values
    ax1.set(ylabel="mean solve time [ms]", title=f"{main[0]['nodes']} nodes, warm-started closed loop")
    ax1.legend(fontsize=8)
    sweep = sorted(
        (r for r in records if r["compiled"] and r["solver"] == "fatrop"), key=lambda r: r["nodes"]
    )
    if sweep:
        n = [r["nodes"] for r in sweep]
        ax2.errorbar(
            n,
            [r["mean_ms"] for r in sweep],
            yerr=[r["std_ms"] for r in sweep],
            fmt="o-",
            capsize=3,
            label="mean ± std",
        )
        ax2.plot(n, [r["p95_ms"] for r in sweep], "s--", label="p95")
        ax2.set(xlabel="nodes N (incl. terminal)", ylabel="solve time [ms]", title="compiled Fatrop vs N")
        ax2.legend(fontsize=8)
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path.name, path.parent)


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(prog="python -m wbmpc.bench", description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small problem, few steps (about a minute)")
    parser.add_argument("--steps", type=int, default=None, help="measured MPC steps per case (default 200)")
    parser.add_argument("--warmup", type=int, default=None, help="discarded solves at the start (default 20)")
    parser.add_argument(
        "--output", type=Path, default=None, help="JSON path (default data/bench/solve_times.json)"
    )
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args(argv)
    from wbmpc.robot import load_b1_z1

    quick = args.quick or quick_mode()
    steps = args.steps or (20 if quick else 200)
    warmup = args.warmup if args.warmup is not None else (5 if quick else 20)
    output = args.output or REPO_ROOT / (
        "data/output/bench/solve_times_quick.json" if quick else "data/bench/solve_times.json"
    )
    robot = load_b1_z1()
    records = []
    for solver, compiled, nodes in cases(quick):
        print(
            f"[bench] {solver} {'compiled' if compiled else 'in-process'} N={nodes}: {steps} steps",
            flush=True,
        )
        record = run_case(robot, solver, compiled, nodes, steps, warmup, progress=not args.quiet)
        print(
            f"        mean {record['mean_ms']:.1f} ms, median {record['median_ms']:.1f}, "
            f"p95 {record['p95_ms']:.1f}, iterations {record['iterations_mean']:.2f}",
            flush=True,
        )
        records.append(record)
        output.parent.mkdir(parents=True, exist_ok=True)
        output.write_text(json.dumps(records, indent=2))  # partial results survive an interruption
    plot(records, REPO_ROOT / "data/output/bench" / (output.stem + ".png"))
    print(f"[bench] wrote {output}")
    return records


if __name__ == "__main__":
    main()
