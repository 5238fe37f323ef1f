"""Real-time scheduling of the controller's loop: asked for, granted or refused with the reason, restored
after the block, never inherited by a process started inside it."""

import os
import subprocess
import sys

import pytest

from wbmpc.runtime.priority import realtime_priority


def test_no_priority_changes_nothing_and_bad_priorities_are_refused():
    before = os.sched_getscheduler(0)
    with realtime_priority(None) as scheduling:
        assert scheduling.startswith("SCHED_OTHER") and os.sched_getscheduler(0) == before
    for bad in (0, 100, 2.5, True, "50"):
        with pytest.raises(ValueError, match="1..99"):
            with realtime_priority(bad):
                pass


def test_fifo_inside_the_block_restored_after_and_not_inherited():
    before = os.sched_getscheduler(0), os.sched_getparam(0).sched_priority
    with realtime_priority(20) as scheduling:
        if scheduling.startswith("SCHED_OTHER"):  # refused here: the reason is given, nothing changed
            assert "refused" in scheduling and os.sched_getscheduler(0) == before[0]
            pytest.skip(scheduling)
        assert scheduling == "SCHED_FIFO 20"
        assert os.sched_getscheduler(0) & ~getattr(os, "SCHED_RESET_ON_FORK", 0) == os.SCHED_FIFO
        assert os.sched_getparam(0).sched_priority == 20
        child = subprocess.run(
            [sys.executable, "-c", "import os; print(os.sched_getscheduler(0))"],
            capture_output=True,
            text=True,
            check=True,
        )
        assert int(child.stdout) == os.SCHED_OTHER  # a child boots at the ordinary priority
    assert (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority) == before
