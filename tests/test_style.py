"""Lint gate: ``ruff check wbmpc tests`` must be clean (formatting is advisory, not checked)."""

import importlib.util
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]


def _ruff_cmd() -> list[str] | None:
    if importlib.util.find_spec("ruff") is not None:
        return [sys.executable, "-m", "ruff"]
    exe = shutil.which("ruff")
    return [exe] if exe else None


def test_ruff_check():
    cmd = _ruff_cmd()
    if cmd is None:
        pytest.skip("ruff is not installed (pip install ruff, or use scripts/test.sh)")
    proc = subprocess.run(
        [*cmd, "check", "--no-cache", "wbmpc", "tests"],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
    )
    if proc.returncode != 0:
        pytest.fail(f"ruff check found problems:\n{proc.stdout}{proc.stderr}", pytrace=False)
