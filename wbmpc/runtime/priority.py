"""Real-time scheduling for the controller's loop, where the operating system allows it.

legged_control runs its 500 Hz loop at a real-time priority beside the MPC thread; so does the runtime
when it may: :func:`realtime_priority` puts the calling thread under ``SCHED_FIFO`` (Linux; it needs
``CAP_SYS_NICE``, e.g. root or an ``rtprio`` limit in ``/etc/security/limits.conf``) for the duration of
a ``with`` block and restores the previous policy after it. Where that is refused it says why and changes
nothing: the loop then runs at the ordinary priority, as before.

A ``SCHED_FIFO`` thread is never preempted by ordinary ones: on the CPU the controller shares with the
emulated robot its tick runs the moment it is due, and the robot's physics takes what is left (the
kernel's real-time throttling, 95 % of each second by default, keeps a runaway loop from freezing the
machine). Processes started from that thread do not inherit the policy (``SCHED_RESET_ON_FORK``).
"""

from __future__ import annotations

import contextlib
import os

__all__ = ["check_priority", "realtime_priority"]


def check_priority(priority, name: str = "priority") -> int | None:
    """``priority`` if it is ``None`` or a ``SCHED_FIFO`` priority (an integer in 1..99).

    Raises:
        ValueError: anything else, naming ``name``.
    """
    if priority is not None and (
        isinstance(priority, bool) or not isinstance(priority, int) or not 1 <= priority <= 99
    ):
        raise ValueError(f"{name} must be a SCHED_FIFO priority in 1..99 or None, got {priority!r}")
    return priority


@contextlib.contextmanager
def realtime_priority(priority: int | None):
    """``SCHED_FIFO`` at ``priority`` (1-99) for the calling thread inside the block.

    Args:
        priority: The real-time priority, or ``None`` to change nothing.

    Yields:
        What the block runs under: ``"SCHED_FIFO <priority>"``, or ``"SCHED_OTHER"`` with the reason when
        real-time scheduling was not asked for or was refused.

    Raises:
        ValueError: a priority outside 1-99.
    """
    if check_priority(priority) is None:
        yield "SCHED_OTHER (no real-time priority asked for)"
        return
    if not hasattr(os, "sched_setscheduler"):
        yield "SCHED_OTHER (this platform has no sched_setscheduler)"
        return
    before = os.sched_getscheduler(0), os.sched_getparam(0)
    # Not inherited: a process started from the loop (a restarted robot, fault injection) booting at
    # this priority would hold the controller's CPU until it first blocks (seen: 0.28 s).
    policy = os.SCHED_FIFO | getattr(os, "SCHED_RESET_ON_FORK", 0)
    try:
        os.sched_setscheduler(0, policy, os.sched_param(priority))
    except OSError as error:
        yield f"SCHED_OTHER (SCHED_FIFO {priority} refused: {error.strerror})"
        return
    try:
        yield f"SCHED_FIFO {priority}"
    finally:
        os.sched_setscheduler(0, before[0], before[1])
