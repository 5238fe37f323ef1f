"""Argument checks of the study command lines: refuse a bad value before any work, with a one-line reason
(``parser.error``: usage, the reason, exit status 2)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

MAX_NODES = 100  # = wbmpc.ocp.builder.MAX_NODES (not imported: keeps the command lines' start light)


def at_least(parser: argparse.ArgumentParser, flag: str, value: int | None, low: int, what: str = "") -> None:
    """An optional integer option must be >= ``low`` (``None``: not given, the default applies)."""
    if value is not None and value < low:
        parser.error(f"{flag} must be an integer >= {low}{f' ({what})' if what else ''}, got {value}")


def nodes(parser: argparse.ArgumentParser, flag: str, value: int | None) -> None:
    """A node count (terminal node included) must be in [3, MAX_NODES]."""
    if value is not None and not 3 <= value <= MAX_NODES:
        parser.error(
            f"{flag} must be an integer in [3, {MAX_NODES}] (nodes including the terminal one), got {value}"
        )


def non_negative(parser: argparse.ArgumentParser, flag: str, value: float) -> None:
    """A finite number >= 0 (gains)."""
    if not (math.isfinite(value) and value >= 0):
        parser.error(f"{flag} must be a finite number >= 0, got {value}")


def writable_folder(parser: argparse.ArgumentParser, flag: str, folder: Path, what: str = "") -> None:
    """Create ``folder`` if needed and check that a file can be written in it."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / ".write-test"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        parser.error(f"{what or f'{flag} {folder}'} is not a writable folder: {exc}")


def writable_file(parser: argparse.ArgumentParser, flag: str, path: Path, example: str) -> None:
    """``path`` must be a file path (not a folder) in a writable folder (created if needed)."""
    if path.is_dir():
        parser.error(f"{flag} {path} is a folder; give a file path such as {path / example}")
    writable_folder(parser, flag, path.parent, f"{flag} {path}: its folder {path.parent}")


def user_robot(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """``--urdf``/``--srdf``/``--feet``/``--ee``/``--lock``/``--pose``: files that exist, options that go
    with ``--urdf`` only, four feet (checked before any model is loaded)."""
    given = [flag for flag in ("srdf", "feet", "ee", "lock", "pose") if getattr(args, flag) is not None]
    if args.urdf is None:
        if given:
            parser.error(f"--{given[0]} describes a robot of your own: give its --urdf too")
        return
    if args.robot is not None:
        parser.error(f"--robot {args.robot} and --urdf {args.urdf}: give one of them")
    for flag in ("urdf", "srdf"):
        path = getattr(args, flag)
        if path is not None and not path.is_file():
            what = "a folder, not a file" if path.is_dir() else "no such file"
            parser.error(f"--{flag} {path}: {what}")
    if args.srdf is None:
        parser.error(f"--urdf {args.urdf}: give its --srdf too (its group_state gives the pose to stand in)")
    if args.feet is not None:
        feet = [name.strip() for name in args.feet.split(",")]
        if len(feet) != 4 or not all(feet) or len(set(feet)) != 4:
            parser.error(f"--feet must be four different frame names FL,FR,RL,RR, got {args.feet!r}")
        args.feet = ",".join(feet)
    if args.ee is not None and not args.ee.strip():
        parser.error("--ee must be a frame name or none")
