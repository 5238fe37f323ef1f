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
