"""Quick mode: the single switch that shrinks notebooks and demos for tests and CI.

Set ``WBMPC_QUICK=1`` (``scripts/test.sh`` does) to run every notebook end to end in seconds
instead of minutes. Code never reads the environment variable directly; it calls
:func:`quick_mode` or, more often, :func:`pick`.
"""

from __future__ import annotations

import os
from typing import TypeVar

T = TypeVar("T")

QUICK_ENV = "WBMPC_QUICK"
_TRUE_VALUES = frozenset({"1", "true", "yes"})


def quick_mode() -> bool:
    """Return True when quick mode is on.

    Quick mode is on when the environment variable ``WBMPC_QUICK`` is set to ``1``, ``true`` or
    ``yes`` (case-insensitive, surrounding whitespace ignored). Any other value, or no value, means
    full mode. The variable is read on every call, so tests can toggle it with ``monkeypatch``.

    Returns:
        True in quick mode, False otherwise.
    """
    return os.environ.get(QUICK_ENV, "").strip().lower() in _TRUE_VALUES


def pick(full: T, quick: T) -> T:
    """Choose between a full-run value and a quick-mode value.

    Notebooks and scripts call this inline wherever a size drives the run time, so the same code
    runs at full size for a person and shrunk under test (after RussTedrake/underactuated's
    ``running_as_test``)::

        N = pick(full=50, quick=10)            # MPC horizon nodes
        n_steps = pick(full=2000, quick=20)    # closed-loop simulation steps
        max_iter = pick(full=500, quick=30)    # solver iterations

    Args:
        full: Value used in a normal (full) run.
        quick: Value used when quick mode is on (see :func:`quick_mode`).

    Returns:
        ``quick`` in quick mode, ``full`` otherwise.
    """
    return quick if quick_mode() else full
