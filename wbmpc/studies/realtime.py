"""Real-time benchmark: solver variants compared in one interleaved run, each in its own process.

A process holds one BLASFEO and one version of wbmpc, so every variant runs in a subprocess: native or
generic BLASFEO; the OCP layout (the default, node 0's state as pinned variables, or the paper's layout
that also pins the arm force as an input); compiled or in-process; optionally an older checkout of wbmpc
as the baseline; the variants take turns round after round, so
that the machine's drift and the other jobs on it hit them all alike. Each turn is a closed-loop run of
the default benchmark (B1 + Z1 trotting with the arm reference, rigid plant, N = 15) through
``wbmpc.studies.bench.run_case``; the solve times of all rounds are pooled per variant. Compare the
ratios, not the absolute times, across machines::

    git worktree add /tmp/wbmpc_b9ef13b b9ef13b      # the baseline, optional
    python -m wbmpc.studies.realtime --baseline /tmp/wbmpc_b9ef13b --rounds 3 --steps 80

writes ``data/bench/real_time.json`` (per variant: mean, median, p95, max [ms], iterations, the profile
of a solve, build time of the compiled library, the BLASFEO mapped, the CPU).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from wbmpc.solver.codegen import DEFAULT_FLAGS, RELEASE_FLAGS

REPO_ROOT = Path(__file__).resolve().parents[2]

# name -> (compiled, BLASFEO, OCP layout (OCPSettings fields), baseline checkout, gcc flags)
DEFAULT = DEFAULT_FLAGS
RELEASE = RELEASE_FLAGS  # -O3 -march=native: ~4x the build time, 1.6x gcc's memory
NODE0_VARIABLES = {"initial_state_variables": True}  # node 0's state pinned by equality rows
PAPER_LAYOUT = {"initial_state_variables": True, "ee_force_input": True}  # and the arm force an input
# run only when named with --variant
OPT_IN = (
    "baseline compiled, -O3 -march=native",
    "baseline compiled, native, -O3 -march=native",
    "direct, native",
    "direct, native, -O3 -march=native",
    "direct, in-process, native",
    "direct, in-process, native, 1 thread",
    "direct, native, -O3 -march=native, 2 threads",
    "baseline direct, native, -O3 -march=native",
)
#: The variants that solve with the direct Fatrop driver (wbmpc.solver.direct) and its evaluation threads
#: (None: the settings' default). The others pass direct=False (the plugin), except the baselines.
DIRECT = {
    "direct, native": None,
    "direct, native, -O3 -march=native": None,
    "direct, native, -O3 -march=native, 2 threads": 2,
    "direct, in-process, native": None,
    "direct, in-process, native, 1 thread": 1,
    "baseline direct, native, -O3 -march=native": None,  # a baseline that has the direct driver
}
VARIANTS = {
    "compiled, native": (True, "native", {}, False, DEFAULT),
    "compiled, native, -O3 -march=native": (True, "native", {}, False, RELEASE),
    "compiled, native, node-0 state variables": (True, "native", NODE0_VARIABLES, False, DEFAULT),
    "compiled, native, paper layout": (True, "native", PAPER_LAYOUT, False, DEFAULT),
    "compiled, generic": (True, "generic", {}, False, DEFAULT),
    "direct, native": (True, "native", {}, False, DEFAULT),
    "direct, native, -O3 -march=native": (True, "native", {}, False, RELEASE),
    "direct, native, -O3 -march=native, 2 threads": (True, "native", {}, False, RELEASE),
    "in-process, native": (False, "native", {}, False, DEFAULT),
    # The direct driver in process: its stage functions in CasADi's VM (nothing compiled per problem).
    "direct, in-process, native": (False, "native", {}, False, DEFAULT),
    "direct, in-process, native, 1 thread": (False, "native", {}, False, DEFAULT),
    "in-process, generic": (False, "generic", {}, False, DEFAULT),
    "baseline compiled": (True, "generic", {}, True, DEFAULT),
    # Opt-in (--variant): the baseline built with the release flags too, for a like-for-like ratio.
    "baseline compiled, -O3 -march=native": (True, "generic", {}, True, RELEASE),
    # Opt-in: a baseline that has the native BLASFEO (e.g. 0074138, issue 22's reference).
    "baseline compiled, native, -O3 -march=native": (True, "native", {}, True, RELEASE),
    "baseline in-process": (False, "generic", {}, True, DEFAULT),
    # Opt-in: the direct driver of a baseline that has it (to compare the Python around two drivers' calls).
    "baseline direct, native, -O3 -march=native": (True, "native", {}, True, RELEASE),
}

_WORKER = """
import json, sys, time
import numpy as np
from wbmpc.model.robot import load_b1_z1
from wbmpc.control.mpc import MPCConfig, WholeBodyMPC
from wbmpc.ocp import OCPSettings
from wbmpc.ocp.gait import make_gait
from wbmpc.sim.closed_loop import ClosedLoopConfig, run_closed_loop
compiled, steps, warmup = {compiled}, {steps}, {warmup}
flags = {{"compile_flags": {flags}}} if {flags} != ("-O1",) else {{}}
if {direct} or not {baseline}:  # a checkout before the direct driver has no such settings
    flags["direct"] = {direct}
    if {threads} is not None:
        flags["threads"] = {threads}
robot = load_b1_z1()
settings = OCPSettings(n_nodes=15, **{layout})  # the baseline's default layout is the paper's
try:
    from wbmpc.control.mpc import SolverSettings
except ImportError:  # an older checkout (the baseline): the solver settings are MPCConfig fields there
    mpc = WholeBodyMPC(robot, settings, MPCConfig(gait=make_gait("trot"), compiled=compiled, **flags))
else:
    try:  # the flags measured, no switch to a background release library mid-run
        solver = SolverSettings(compiled=compiled, release_flags=None, **flags)
    except TypeError:  # a checkout before the background release build
        solver = SolverSettings(compiled=compiled, **flags)
    mpc = WholeBodyMPC(robot, settings, MPCConfig(gait=make_gait("trot")), solver)
mpc.verbose = False
if hasattr(mpc, "prepare"):
    mpc.prepare()  # build or load before timing
else:  # an older checkout builds on its first solve (a warm-up solve, not timed)
    mpc.solve(robot.q_nominal, np.zeros(robot.nv))
    mpc.reset()
log = run_closed_loop(mpc, ClosedLoopConfig(duration=(steps + warmup) / 80.0), progress=False).log
ms = 1e3 * np.asarray(log.solve_time[warmup:])
timings = log.timings[warmup:]
keys = ("evaluations", "solver", "search_direction", "initialization", "overhead", "total")
profile = {{k: 1e3 * float(np.mean([t[k] for t in timings])) for k in keys if all(k in t for t in timings)}}
try:
    from wbmpc.solver import blasfeo
    library = blasfeo.info()["choice"]
except ImportError:  # a checkout before the native BLASFEO
    library = "generic (the casadi wheel's)"
build = mpc.compiled_nlp  # None for the direct driver (its own library)
record = {{
    "solve_ms": ms.tolist(),
    "mean_ms": float(ms.mean()),
    "iterations_mean": float(np.mean(log.iterations[warmup:])),
    "converged_fraction": float(np.mean(log.success[warmup:])),
    "profile_mean_ms": profile,
    "build_s": build.build_s if build else None,
    "compile_flags": list({flags}) if compiled else None,
    "build_peak_mb": build.build_peak_mb if build else None,
    "blasfeo": library,
    "decision_variables": int(mpc.ocp.n_variables),
}}
sys.stdout.write("\\nRECORD " + json.dumps(record) + "\\n")
"""


def run_turn(variant: str, steps: int, warmup: int, baseline: Path | None) -> dict:
    """One closed-loop run of ``variant`` in a fresh process; its benchmark record and solve times."""
    compiled, library, layout, is_baseline, flags = VARIANTS[variant]
    env = {**os.environ, "WBMPC_BLASFEO": library, "OMP_NUM_THREADS": "1"}
    cwd = REPO_ROOT
    if is_baseline:
        env["PYTHONPATH"] = str(baseline)  # the old checkout's wbmpc shadows this one
        cwd = baseline
    code = _WORKER.format(
        compiled=compiled,
        layout=repr(layout),
        steps=steps,
        warmup=warmup,
        baseline=is_baseline,
        flags=repr(tuple(flags)),
        direct=variant in DIRECT,
        threads=DIRECT.get(variant),
    )
    proc = subprocess.run([sys.executable, "-c", code], env=env, cwd=cwd, capture_output=True, text=True)
    lines = [line for line in proc.stdout.splitlines() if line.startswith("RECORD ")]
    if proc.returncode != 0 or not lines:
        raise RuntimeError(f"{variant}: worker failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    return json.loads(lines[-1][len("RECORD ") :])


def summarize(records: list[dict]) -> dict:
    """Pooled statistics over the turns of one variant."""
    ms = np.concatenate([np.asarray(r["solve_ms"], float) for r in records])
    profile = {
        key: float(np.mean([r["profile_mean_ms"].get(key, np.nan) for r in records]))
        for key in records[0].get("profile_mean_ms", {})
    }
    first = records[0]
    return {
        "solves": int(ms.size),
        "mean_ms": float(ms.mean()),
        "median_ms": float(np.median(ms)),
        "p95_ms": float(np.percentile(ms, 95)),
        "max_ms": float(ms.max()),
        "p95_over_mean": float(np.percentile(ms, 95) / ms.mean()),
        "turn_means_ms": [float(r["mean_ms"]) for r in records],
        "iterations_mean": float(np.mean([r["iterations_mean"] for r in records])),
        "converged_fraction": float(np.mean([r["converged_fraction"] for r in records])),
        "profile_mean_ms": profile,
        "build_s": first.get("build_s"),
        "compile_flags": first.get("compile_flags"),
        "build_peak_mb": first.get("build_peak_mb"),
        "blasfeo": first.get("blasfeo"),
        "decision_variables": first.get("decision_variables"),
    }


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(
        prog="python -m wbmpc.studies.realtime", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--rounds", type=int, default=3, help="turns per variant (default 3)")
    parser.add_argument("--steps", type=int, default=80, help="measured solves per turn (default 80)")
    parser.add_argument("--warmup", type=int, default=10, help="discarded solves per turn (default 10)")
    parser.add_argument("--baseline", type=Path, default=None, help="checkout of an older wbmpc to compare")
    parser.add_argument("--variant", action="append", choices=list(VARIANTS), help="only these (repeatable)")
    parser.add_argument("--output", type=Path, default=REPO_ROOT / "data/bench/real_time.json")
    args = parser.parse_args(argv)
    for flag, value, low in (
        ("--rounds", args.rounds, 1),
        ("--steps", args.steps, 1),
        ("--warmup", args.warmup, 0),
    ):
        if value < low:
            parser.error(f"{flag} must be >= {low}, got {value}")
    if args.baseline is not None and not (args.baseline / "wbmpc" / "__init__.py").is_file():
        parser.error(f"--baseline {args.baseline} is not a checkout of wbmpc (no wbmpc/__init__.py)")
    default = [v for v in VARIANTS if v not in OPT_IN]
    variants = args.variant or [v for v in default if args.baseline is not None or not VARIANTS[v][3]]
    if args.baseline is None and any(VARIANTS[v][3] for v in variants):
        parser.error("the baseline variants need --baseline <checkout of an older wbmpc>")
    from wbmpc.sim.closed_loop import machine_description
    from wbmpc.solver import blasfeo

    turns: dict[str, list[dict]] = {v: [] for v in variants}
    start = time.perf_counter()
    for round_index in range(args.rounds):
        for variant in variants:
            record = run_turn(variant, args.steps, args.warmup, args.baseline)
            turns[variant].append(record)
            print(
                f"[realtime] round {round_index + 1}: {variant}: mean {record['mean_ms']:.1f} ms", flush=True
            )
    results = {v: summarize(records) for v, records in turns.items()}
    reference = results.get("baseline compiled")
    for result in results.values():
        if reference is not None:
            result["mean_ratio_to_baseline_compiled"] = result["mean_ms"] / reference["mean_ms"]
    out = {
        "machine": machine_description(),
        "cpu": blasfeo.cpu_info(),
        "rounds": args.rounds,
        "steps_per_turn": args.steps,
        "warmup_per_turn": args.warmup,
        "baseline": str(args.baseline) if args.baseline else None,
        "load_average_at_end": list(os.getloadavg()),
        "wall_s": time.perf_counter() - start,
        "variants": results,
    }
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(out, indent=2))
    for name, result in results.items():
        ratio = result.get("mean_ratio_to_baseline_compiled")
        print(
            f"{name:45s} mean {result['mean_ms']:6.1f}  median {result['median_ms']:6.1f}  "
            f"p95 {result['p95_ms']:6.1f} ms  iterations {result['iterations_mean']:.2f}"
            + (f"  x{1 / ratio:.2f} faster than the baseline" if ratio else ""),
            flush=True,
        )
    print(f"[realtime] wrote {args.output}")
    return out


if __name__ == "__main__":
    main()
