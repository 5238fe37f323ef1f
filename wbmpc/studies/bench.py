"""Solve-time benchmark of the MPC in closed loop: compiled vs in-process, Fatrop vs IPOPT, node count.

Every record is a closed-loop run on the default robot (trot at 0.2 m/s + the arm's low/high reference,
rigid-contact Pinocchio plant), with the first ``warmup`` solves discarded. Timing assertions never go in
tests: this command measures and writes ``data/bench/solve_times.json`` (a list of records) and a figure
``data/output/bench/solve_times.png``.

    python -m wbmpc.studies.bench            # full run (about 15 minutes on 2 cores)
    python -m wbmpc.studies.bench --quick    # about a minute (also with WBMPC_QUICK=1)
    python -m wbmpc.studies.bench --blasfeo both --case fatrop,compiled,15 --steps 50 --output /tmp/b.json

Every record carries ``blasfeo`` (:func:`wbmpc.solver.blasfeo.info`: which BLASFEO Fatrop ran on, its
target, the CPU
model and flags). ``--blasfeo native|generic`` runs the cases on that library; ``both`` compares them: a
process holds one BLASFEO only, so each variant runs in its own worker subprocess (``WBMPC_BLASFEO`` set),
and the two workers take turns in batches of ``--batch`` solves (order A B B A ...), each paused while the
other solves, so slow phases of the shared machine hit both alike. The closed loop is deterministic (no
measured delay), so both workers solve the same sequence of problems; each record of a pair gets
``blasfeo_comparison`` (identical iterations, max |solution difference|, time ratio).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from wbmpc.quick import quick_mode
from wbmpc.studies import cli_checks

REPO_ROOT = Path(__file__).resolve().parents[2]


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
    gate=None,
    paper_layout: bool = False,
    compile_flags: tuple[str, ...] | None = None,
) -> dict:
    """One closed-loop run; statistics over the solves after the warm-up.

    Args:
        kp, kd: Low-level joint PD gains [N m/rad], [N m s/rad] (0: pure feed-forward torques).
        gate: Optional ``gate(mpc)`` called once the solvers are built; it may wrap ``mpc.solve`` (the
            ``--blasfeo both`` workers pause there between batches, outside the timed solver call).
        paper_layout: The paper's layout: the arm force and node 0's state as decision variables
            pinned by equality rows (``ee_force_input``, ``initial_state_variables`` of
            :class:`wbmpc.ocp.OCPSettings`).
        compile_flags: gcc flags of the compiled library (default: the MPC's).

    The solves go through the casadi plugin, compiled or in process (``SolverSettings(direct=False)``), as
    the committed benchmarks did; the direct driver has its own studies (:mod:`wbmpc.studies.realtime`'s
    ``direct, ...`` variants, :mod:`wbmpc.studies.direct_fatrop`).
    """
    from wbmpc.control.mpc import MPCConfig, SolverSettings, WholeBodyMPC
    from wbmpc.ocp import OCPSettings
    from wbmpc.ocp.gait import make_gait
    from wbmpc.sim.closed_loop import ClosedLoopConfig, machine_description, run_closed_loop
    from wbmpc.sim.loop_config import LowLevelConfig
    from wbmpc.solver import blasfeo

    config = MPCConfig(gait=make_gait("trot"))
    flags = {} if compile_flags is None else {"compile_flags": tuple(compile_flags)}
    # The flags measured: no switch to a background release library mid-run.
    solver_settings = SolverSettings(
        solver=solver, compiled=compiled, release_flags=None, direct=False, **flags
    )
    settings = OCPSettings(
        n_nodes=nodes,
        formulation=formulation,
        ee_force_input=paper_layout,
        initial_state_variables=paper_layout,
    )
    mpc = WholeBodyMPC(robot, settings, config, solver_settings)
    mpc.verbose = progress
    start = time.perf_counter()
    mpc._solver(cold=True)  # build (or load from the cache) before timing anything
    mpc._solver(cold=False)
    setup_s = time.perf_counter() - start
    if gate is not None:
        gate(mpc)
    loop = ClosedLoopConfig(duration=(steps + warmup) / 80.0, low_level=LowLevelConfig(kp=kp, kd=kd))
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
        "blasfeo": blasfeo.info(),
        "cpu_model": blasfeo.cpu_info()["cpu_model"],
        "cpu_flags": blasfeo.cpu_info()["cpu_flags"],
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

    from wbmpc.viz.plots import save_figure

    fig = Figure(figsize=(11, 4))
    ax1, ax2 = fig.subplots(1, 2)
    in_process = [r["nodes"] for r in records if not r["compiled"]]
    main = [r for r in records if r["nodes"] == max(in_process or [r["nodes"] for r in records])]
    labels = [
        f"{r['solver']}\n{'compiled' if r['compiled'] else 'in-process'}"
        + (f"\n{r['blasfeo_variant']}" if "blasfeo_variant" in r else "")
        for r in main
    ]
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
    for variant in sorted({r.get("blasfeo_variant", "") for r in records}):
        sweep = sorted(
            (
                r
                for r in records
                if r["compiled"] and r["solver"] == "fatrop" and r.get("blasfeo_variant", "") == variant
            ),
            key=lambda r: r["nodes"],
        )
        if not sweep:
            continue
        n = [r["nodes"] for r in sweep]
        suffix = f" ({variant} BLASFEO)" if variant else ""
        ax2.errorbar(
            n,
            [r["mean_ms"] for r in sweep],
            yerr=[r["std_ms"] for r in sweep],
            fmt="o-",
            capsize=3,
            label=f"mean ± std{suffix}",
        )
        ax2.plot(n, [r["p95_ms"] for r in sweep], "s--", label=f"p95{suffix}")
        ax2.set(xlabel="nodes N (incl. terminal)", ylabel="solve time [ms]", title="compiled Fatrop vs N")
        ax2.legend(fontsize=8)
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path.name, path.parent)


def parse_case(text: str) -> tuple[str, bool, int]:
    """``--case`` value ``SOLVER,MODE,NODES`` (e.g. ``fatrop,compiled,15``) -> (solver, compiled, nodes)."""
    try:
        solver, mode, nodes = (part.strip() for part in text.split(","))
        if solver not in ("fatrop", "ipopt") or mode not in ("compiled", "in-process"):
            raise ValueError
        return solver, mode == "compiled", int(nodes)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--case {text!r}: expected SOLVER,MODE,NODES, SOLVER fatrop|ipopt, MODE compiled|in-process"
        ) from None


def _worker() -> None:
    """``--worker``: run the cases the coordinator sends, pausing between batches of solves.

    Protocol (JSON lines): the coordinator writes ``{"cmd": "case", ...}``, ``{"cmd": "go"}`` or
    ``{"cmd": "exit"}`` on stdin; the worker answers each ``go`` with ``{"event": "paused"}`` (it waits for
    the next ``go``) or ``{"event": "record", ...}`` (the case is done).
    """
    from wbmpc.model.robot import load_b1_z1

    protocol = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)  # whatever CasADi or a solver prints goes to stderr, never into the protocol
    commands = iter(sys.stdin.readline, "")

    def send(message: dict) -> None:
        protocol.write(json.dumps(message) + "\n")

    running = False  # between a "go" and the next answer

    def wait_for_go() -> None:
        nonlocal running
        if running:
            send({"event": "paused"})  # the answer to the "go" that started this batch
        if json.loads(next(commands, '{"cmd": "exit"}'))["cmd"] != "go":
            raise SystemExit(0)
        running = True

    robot = load_b1_z1()
    for number, line in enumerate(commands):
        case = json.loads(line)
        if case["cmd"] != "case":
            break
        wait_for_go()  # builds take turns too: one worker generates the code, the other hits the cache
        solutions, iterations = [], []

        def gate(mpc, batch=case["batch"], solutions=solutions, iterations=iterations):
            solve = mpc.solve

            def gated_solve(*args, **kwargs):
                if len(iterations) % batch == 0:
                    wait_for_go()  # outside the solver's timing
                plan = solve(*args, **kwargs)
                iterations.append(int(plan.iterations))
                solutions.append(plan.w)
                return plan

            mpc.solve = gated_solve

        record = run_case(
            robot,
            case["solver"],
            case["compiled"],
            case["nodes"],
            case["steps"],
            case["warmup"],
            progress=False,
            gate=gate,
        )
        path = Path(case["scratch"]) / f"solutions_{os.getpid()}_{number}.npy"
        np.save(path, np.array(solutions))
        send({"event": "record", "record": record, "solutions": str(path), "iterations": iterations})
        running = False


def _compare(records: dict[str, dict], replies: dict[str, dict]) -> None:
    """Add ``blasfeo_comparison`` to both records of a pair (same closed loop, two BLASFEO libraries)."""
    (a, b) = records
    w = {v: np.load(replies[v]["solutions"]) for v in records}
    same_shape = w[a].shape == w[b].shape
    for v, other in ((a, b), (b, a)):
        records[v]["blasfeo_comparison"] = {
            "other": other,
            "iterations_identical": replies[v]["iterations"] == replies[other]["iterations"],
            "max_abs_solution_diff": float(np.max(np.abs(w[v] - w[other]))) if same_shape else None,
            "mean_ms_ratio": records[v]["mean_ms"] / records[other]["mean_ms"],
            "median_ms_ratio": records[v]["median_ms"] / records[other]["median_ms"],
        }


def run_variants(
    case_list: list[tuple[str, bool, int]],
    variants: list[str],
    steps: int,
    warmup: int,
    batch: int,
):
    """Yield one record per (case, variant), each variant in its own worker process, in alternating turns.

    Args:
        variants: BLASFEO choices (``WBMPC_BLASFEO`` of each worker).
        batch: Solves per turn (the turns go A B B A A B ... so neither variant always runs first).
    """
    from wbmpc.solver import blasfeo

    workers: dict[str, subprocess.Popen] = {}

    def talk(variant: str, message: dict) -> dict | None:
        proc = workers[variant]
        proc.stdin.write(json.dumps(message) + "\n")
        proc.stdin.flush()
        if message["cmd"] != "go":
            return None
        reply = proc.stdout.readline()
        if not reply:
            raise RuntimeError(f"bench worker {blasfeo.ENV}={variant} exited with code {proc.wait()}")
        return json.loads(reply)

    with tempfile.TemporaryDirectory(prefix="wbmpc-bench-") as scratch:
        try:
            for variant in variants:
                workers[variant] = subprocess.Popen(
                    [sys.executable, "-m", "wbmpc.studies.bench", "--worker"],
                    stdin=subprocess.PIPE,
                    stdout=subprocess.PIPE,
                    text=True,
                    cwd=REPO_ROOT,
                    env={**os.environ, blasfeo.ENV: variant},
                )
            for solver, compiled, nodes in case_list:
                case = {"cmd": "case", "solver": solver, "compiled": compiled, "nodes": nodes}
                case |= {"steps": steps, "warmup": warmup, "batch": batch, "scratch": scratch}
                for variant in variants:
                    talk(variant, case)
                replies: dict[str, dict] = {}
                turn = 0
                while len(replies) < len(variants):
                    for variant in variants if turn % 2 == 0 else variants[::-1]:
                        if variant not in replies:
                            reply = talk(variant, {"cmd": "go"})
                            if reply["event"] == "record":
                                replies[variant] = reply
                    turn += 1
                records = {v: replies[v]["record"] | {"blasfeo_variant": v} for v in variants}
                for variant, record in records.items():
                    if record["blasfeo"]["choice"] != variant:
                        print(
                            f"[bench] {variant} asked, worker ran {record['blasfeo']['reason']}", flush=True
                        )
                    record["blasfeo_batch"] = batch
                if len(variants) == 2:
                    _compare(records, replies)
                yield from records.values()
        finally:
            for proc in workers.values():
                try:
                    proc.stdin.write(json.dumps({"cmd": "exit"}) + "\n")
                    proc.stdin.close()
                    proc.wait(timeout=30)
                except (OSError, subprocess.TimeoutExpired):
                    proc.kill()
                    proc.wait()


def check_arguments(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Reject bad values before any work (argparse prints the one-line reason and exits with status 2)."""
    cli_checks.at_least(parser, "--steps", args.steps, 1, "measured MPC steps")
    cli_checks.at_least(parser, "--warmup", args.warmup, 0, "discarded solves")
    cli_checks.at_least(parser, "--batch", args.batch, 1, "solves per turn")
    for _, _, nodes in args.case or ():
        cli_checks.nodes(parser, "--case NODES", nodes)
    if args.output is not None:
        cli_checks.writable_file(parser, "--output", args.output, "solve_times.json")
    cli_checks.writable_folder(parser, "figure folder", REPO_ROOT / "data/output/bench")


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(
        prog="python -m wbmpc.studies.bench", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--quick", action="store_true", help="small problem, few steps (about a minute)")
    parser.add_argument("--steps", type=int, default=None, help="measured MPC steps per case (default 200)")
    parser.add_argument("--warmup", type=int, default=None, help="discarded solves at the start (default 20)")
    parser.add_argument(
        "--output", type=Path, default=None, help="JSON path (default data/bench/solve_times.json)"
    )
    parser.add_argument(
        "--blasfeo",
        choices=("native", "generic", "both"),
        default=None,
        help="BLASFEO under Fatrop (default: this process's, see wbmpc.solver.blasfeo); both: interleaved "
        "comparison of the Fatrop cases in two worker processes",
    )
    parser.add_argument("--batch", type=int, default=10, help="solves per turn with --blasfeo (default 10)")
    parser.add_argument(
        "--case",
        type=parse_case,
        action="append",
        default=None,
        help="run only this case, SOLVER,MODE,NODES, e.g. fatrop,compiled,15 (repeatable)",
    )
    parser.add_argument("--quiet", action="store_true")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        _worker()
        return []
    check_arguments(parser, args)
    from wbmpc.model.robot import load_b1_z1
    from wbmpc.solver import blasfeo

    quick = args.quick or quick_mode()
    steps = args.steps or (20 if quick else 200)
    warmup = args.warmup if args.warmup is not None else (5 if quick else 20)
    output = args.output or REPO_ROOT / (
        "data/output/bench/solve_times_quick.json" if quick else "data/bench/solve_times.json"
    )
    case_list = args.case or cases(quick)
    variants = {"both": ["native", "generic"], None: []}.get(args.blasfeo, [args.blasfeo])
    if args.blasfeo == "both":
        case_list = [c for c in case_list if c[0] == "fatrop"]  # IPOPT does not use BLASFEO
    if len(variants) == 1 and blasfeo.info()["choice"] == variants[0]:
        variants = []  # this process already runs on the requested library
    if variants:
        print(f"[bench] BLASFEO {' vs '.join(variants)}: {len(case_list)} case(s), {steps} steps", flush=True)
        produced = run_variants(case_list, variants, steps, warmup, max(1, args.batch))
    else:
        robot = load_b1_z1()

        def in_process():
            for solver, compiled, nodes in case_list:
                print(
                    f"[bench] {solver} {'compiled' if compiled else 'in-process'} N={nodes}: {steps} steps",
                    flush=True,
                )
                yield run_case(robot, solver, compiled, nodes, steps, warmup, progress=not args.quiet)

        produced = in_process()
    records = []
    for record in produced:
        variant = f" [{record['blasfeo_variant']}]" if "blasfeo_variant" in record else ""
        comparison = record.get("blasfeo_comparison")
        extra = (
            f", same iterations {comparison['iterations_identical']}, "
            f"max |dw| {comparison['max_abs_solution_diff']:.1e}"
            if comparison and comparison["max_abs_solution_diff"] is not None
            else ""
        )
        print(
            f"        {record['solver']} {'compiled' if record['compiled'] else 'in-process'} "
            f"N={record['nodes']}{variant}: mean {record['mean_ms']:.1f} ms, "
            f"median {record['median_ms']:.1f}, p95 {record['p95_ms']:.1f}, "
            f"iterations {record['iterations_mean']:.2f}{extra}",
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
