"""Soak benchmark: a long standing run with a streamed log, and the process memory over simulated time.

``python -m wbmpc.studies.soak [--minutes 10] [--output data/bench/soak.json]`` simulates the B1 + Z1
standing on the rigid plant (small horizon, arm holding its pose) with the log streamed to disk in 1 s
chunks (:func:`wbmpc.sim.closed_loop.run_closed_loop` with ``log_path``), samples the resident set size
(RSS, ``/proc/self/statm``) every 10 s of simulated time, then repeats a shorter run with the log in memory
for comparison. It writes both RSS curves, the growth after the first simulated minute (target: within
50 MB for the streamed run) and the growth per simulated minute of each run, with the machine.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time
from pathlib import Path

import numpy as np

REPO_ROOT = Path(__file__).resolve().parents[2]
TARGET_GROWTH_MB = 50.0


def rss_mb() -> float:
    """Resident set size of this process [MB] (``/proc/self/statm``; peak RSS where that is missing)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6
    except OSError:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3


class _WallLimitError(Exception):
    """The run used up its wall-time budget (raised inside the loop: the streamed log is kept, partial)."""


class RssSampler:
    """A ``command_schedule`` that overrides nothing and samples the RSS every ``every`` simulated seconds.

    Args:
        every: Sampling period [s] of simulated time.
        max_wall: Wall-time budget [s]; past it the run is stopped by an exception (``None``: no limit).
        verbose: Print one line per sample.
    """

    def __init__(self, every: float, max_wall: float | None = None, verbose: bool = True):
        self.every, self.max_wall, self.verbose = every, max_wall, verbose
        self.samples: list[dict] = []
        self.start = time.perf_counter()
        self._next = 0.0

    def __call__(self, t: float) -> dict:
        if t + 1e-9 >= self._next:
            wall = time.perf_counter() - self.start
            self.samples.append(
                {"t_sim_s": round(t, 6), "wall_s": round(wall, 2), "rss_mb": round(rss_mb(), 2)}
            )
            if self.verbose:
                print(
                    f"  t = {t:7.1f} s simulated, {wall:7.1f} s wall, RSS {self.samples[-1]['rss_mb']:.1f} MB"
                )
                sys.stdout.flush()
            self._next += self.every
            if self.max_wall is not None and wall > self.max_wall:
                raise _WallLimitError(f"wall-time budget of {self.max_wall:.0f} s used up at t = {t:.1f} s")
        return {}


def growth(samples: list[dict], after: float = 60.0) -> dict:
    """RSS growth after ``after`` simulated seconds: total, maximum, and slope per simulated minute [MB]
    (the slope is ``None`` with fewer than two samples: JSON has no NaN).

    Raises:
        ValueError: no samples.
    """
    if not samples:
        raise ValueError("growth needs at least one RSS sample")
    t = np.array([s["t_sim_s"] for s in samples])
    rss = np.array([s["rss_mb"] for s in samples])
    late = t >= after - 1e-9
    if late.sum() < 2:  # too short: measure from the start
        late = np.ones_like(t, bool)
    slope = float(np.polyfit(t[late] / 60.0, rss[late], 1)[0]) if late.sum() >= 2 else None
    return {
        "from_t_s": float(t[late][0]),
        "to_t_s": float(t[late][-1]),
        "growth_mb": float(rss[late][-1] - rss[late][0]),
        "max_above_start_mb": float(rss[late].max() - rss[late][0]),
        "slope_mb_per_sim_minute": slope,
    }


def run(
    minutes: float, nodes: int, log_path: Path | None, every: float, max_wall: float | None, verbose=True
):
    """One standing run; returns its record (settings, RSS curve, growth, summary excerpt)."""
    from wbmpc.control.mpc import MPCConfig, WholeBodyMPC
    from wbmpc.io.logs import load_log
    from wbmpc.model.robot import load
    from wbmpc.ocp import OCPSettings
    from wbmpc.ocp.gait import make_gait
    from wbmpc.sim.closed_loop import ClosedLoopConfig, run_closed_loop
    from wbmpc.sim.loop_config import CommandSchedule

    robot = load("b1_z1")
    mpc = WholeBodyMPC(robot, OCPSettings(n_nodes=nodes), MPCConfig(gait=make_gait("stand")))
    mpc.verbose = False
    sampler = RssSampler(every, max_wall, verbose)
    config = ClosedLoopConfig(
        duration=60.0 * minutes,
        commands=CommandSchedule(base_velocity=(0.0, 0.0, 0.0), arm_reference=None, overrides=sampler),
    )
    start = time.perf_counter()
    stopped = None
    try:
        result = run_closed_loop(mpc, config, progress=False, log_path=log_path)
        summary = result.summary
    except (_WallLimitError, KeyboardInterrupt) as exc:  # the streamed log keeps what ran, marked partial
        if log_path is None:
            raise
        stopped = str(exc) or "interrupted (Ctrl-C)"
        summary = load_log(log_path).meta.get("summary") or {}
    wall = time.perf_counter() - start
    record = {
        "streamed_log": log_path is not None,
        "requested_minutes": minutes,
        "simulated_s": summary.get("duration_s"),
        "stopped_early": stopped,
        "wall_s": round(wall, 1),
        "rss_samples": sampler.samples,
        "rss_after_run_mb": round(rss_mb(), 2),  # after consolidating the log and computing the summary
        "rss_growth_after_first_minute": growth(sampler.samples),
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3,
        "summary": {
            k: summary.get(k)
            for k in ("mpc_solves", "converged_fraction", "fallbacks", "fell", "max_tilt_rad", "solve_ms")
        },
    }
    if log_path is not None and log_path.exists():
        record["log_file_mb"] = round(log_path.stat().st_size / 1e6, 1)
        record["log_partial"] = bool(load_log(log_path).meta.get("partial")) if stopped else False
    return record


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(prog="python -m wbmpc.studies.soak", description=__doc__.splitlines()[0])
    parser.add_argument(
        "--minutes", type=float, default=10.0, help="simulated minutes, streamed (default 10)"
    )
    parser.add_argument(
        "--compare-minutes",
        type=float,
        default=1.5,
        help="simulated minutes of the in-memory comparison run (default 1.5; 0: skip)",
    )
    parser.add_argument("--nodes", type=int, default=6, help="MPC nodes incl. the terminal one (default 6)")
    parser.add_argument("--every", type=float, default=10.0, help="RSS sampling period [simulated s]")
    parser.add_argument(
        "--max-wall-minutes", type=float, default=None, help="stop the streamed run after this"
    )
    parser.add_argument(
        "--log", type=Path, default=REPO_ROOT / "data/output/soak/log.npz", help="streamed log"
    )
    parser.add_argument("--output", type=Path, default=REPO_ROOT / "data/bench/soak.json", help="result JSON")
    args = parser.parse_args(argv)
    for flag in ("minutes", "nodes", "every"):
        if not getattr(args, flag) > 0:
            parser.error(f"--{flag} must be > 0, got {getattr(args, flag)}")
    from wbmpc.sim.closed_loop import machine_description

    max_wall = None if args.max_wall_minutes is None else 60.0 * args.max_wall_minutes
    print(f"streamed run: {args.minutes} simulated minutes, log {args.log}")
    streamed = run(args.minutes, args.nodes, args.log, args.every, max_wall)
    runs = [streamed]
    if args.compare_minutes > 0:
        print(f"in-memory run: {args.compare_minutes} simulated minutes")
        runs.append(run(args.compare_minutes, args.nodes, None, args.every, None))
    growth_mb = streamed["rss_growth_after_first_minute"]["growth_mb"]
    result = {
        "benchmark": "soak: standing run, process RSS over simulated time",
        "command": "python -m wbmpc.studies.soak " + " ".join(argv if argv is not None else sys.argv[1:]),
        "settings": {
            "robot": "b1_z1",
            "gait": "stand",
            "plant": "rigid",
            "nodes": args.nodes,
            "arm": "holds its pose (no reference)",
            "mpc_rate_hz": 80.0,
            "low_level_rate_hz": 500.0,
            "plant_dt_s": 0.0005,
            "log_chunk_s": 1.0,
            "rss_every_sim_s": args.every,
        },
        "machine": machine_description(),
        "target_growth_mb": TARGET_GROWTH_MB,
        "streamed_growth_after_first_minute_mb": growth_mb,
        "within_target": bool(abs(growth_mb) <= TARGET_GROWTH_MB),
        "slope_mb_per_sim_minute": {
            ("streamed" if r["streamed_log"] else "in_memory"): r["rss_growth_after_first_minute"][
                "slope_mb_per_sim_minute"
            ]
            for r in runs
        },
        "runs": runs,
    }
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=2, allow_nan=False) + "\n")
    print(
        json.dumps(
            {k: result[k] for k in ("streamed_growth_after_first_minute_mb", "slope_mb_per_sim_minute")}
        )
    )
    print(f"written {args.output}")
    return result


if __name__ == "__main__":
    main()
