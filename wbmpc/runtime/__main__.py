"""``python -m wbmpc.runtime``: stand, trot, stand on the wall clock against the emulated robot.

Examples::

    python -m wbmpc.runtime --robot emulated --duration 60 --output data/runtime/emulated
    python -m wbmpc.runtime --robot dds --domain 42 --iface lo --duration 60 --output data/runtime/dds

``--robot emulated`` runs the emulated robot in its own process behind shared memory; ``--robot dds``
behind DDS (``rt/lowcmd`` / ``rt/lowstate`` and the arm's ``rt/arm_lowcmd`` / ``rt/arm_lowstate``) on the
given domain and interface (loopback and wbmpc's own domain 42 by default: nobody else on the network can
drive it). Writes ``summary.json`` and ``runtime_log.npz`` to ``--output``.
"""

from __future__ import annotations

import argparse
import json
import sys


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m wbmpc.runtime", description=__doc__.splitlines()[0])
    parser.add_argument("--robot", choices=("emulated", "dds"), default="emulated")
    parser.add_argument("--domain", type=int, default=42, help="DDS domain (default 42, wbmpc's own)")
    parser.add_argument("--iface", default="lo", help="network interface DDS binds to (default lo)")
    parser.add_argument("--duration", type=float, default=10.0, help="length [s]: stand 2, trot, stand 2")
    parser.add_argument("--speed", type=float, default=0.2, help="trot speed command [m/s]")
    parser.add_argument("--nodes", type=int, default=15, help="MPC nodes")
    parser.add_argument("--in-process", action="store_true", help="in-process Fatrop (no compiled library)")
    solver = parser.add_mutually_exclusive_group()
    solver.add_argument(
        "--direct", action="store_true", help="the direct Fatrop driver in the MPC worker (the default)"
    )
    solver.add_argument("--plugin", action="store_true", help="the casadi nlpsol plugin in the MPC worker")
    parser.add_argument("--output", default=None, help="folder for summary.json and runtime_log.npz")
    args = parser.parse_args(argv)

    from wbmpc.runtime.run import RuntimeConfig, run_runtime

    try:
        config = RuntimeConfig(
            duration=args.duration,
            speed=args.speed,
            robot=args.robot,
            domain=args.domain,
            interface=args.iface,
            nodes=args.nodes,
            compiled=not args.in_process,
            direct=False if args.plugin else None,
        )
    except ValueError as error:
        parser.error(str(error))
    summary = run_runtime(config, args.output)
    keys = ("ticks", "overrun_fraction", "period_ms", "plan_age_ms", "latency_ms", "plans", "damping")
    print(json.dumps({k: summary.get(k) for k in keys} | {"robot": summary.get("robot")}, indent=1))
    return 0 if not summary["robot"].get("fell") and not summary.get("damping") else 1


if __name__ == "__main__":
    sys.exit(main())
