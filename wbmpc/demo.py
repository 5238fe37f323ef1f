"""Closed-loop demo entry point (placeholder until the MPC lands): ``python -m wbmpc.demo``."""

from __future__ import annotations

import argparse


def main(argv: list[str] | None = None) -> int:
    """Parse arguments and run the demo.

    Args:
        argv: Command-line arguments (defaults to ``sys.argv[1:]``).

    Returns:
        Process exit code.
    """
    parser = argparse.ArgumentParser(prog="python -m wbmpc.demo", description=__doc__)
    parser.add_argument("--robot", default="b1_z1", help="robot to run (default: b1_z1)")
    args = parser.parse_args(argv)
    print(f"wbmpc demo ({args.robot}): the closed-loop demo arrives with the MPC.")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
