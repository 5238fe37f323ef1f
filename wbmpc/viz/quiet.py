"""Known-harmless native output filtered out of notebooks; everything else still shows.

PyBullet's C code writes straight to the process's file descriptors, past Python's ``sys.stdout`` and
``sys.stderr``: a banner on import (``pybullet build time: ...``, stderr) and, for every load of the default
B1 + Z1, a two-line ``b3Warning`` on stdout that its massless root link ``base`` gets zero inertia (harmless:
a massless root rigidly fixed to the trunk carries nothing). In a notebook those fill output boxes.
:func:`quiet_known_native_output` puts a pipe in front of file descriptors 1 and 2 (inherited by child
processes, e.g. a Dask worker), drops exactly those lines and forwards every other line unchanged to where
the descriptor pointed before (the kernel's capture, a terminal)::

    from wbmpc.viz.quiet import quiet_known_native_output
    quiet_known_native_output()   # first thing in a notebook, before PyBullet is imported

Any other ``b3Warning`` (another link's inertia, a missing mesh...) is kept, header and message.
"""

from __future__ import annotations

import atexit
import os
import re
import sys
import threading
from collections.abc import Iterable

BANNER = re.compile(r"^pybullet build time: ")
B3_HEADER = re.compile(r"^b3Warning\[[^\]]*\]:\s*$")
BAD_INERTIA = re.compile(r"^Bad inertia tensor properties, setting inertia to zero for link: (\S+)\s*$")
DEFAULT_ROOT_LINKS = ("base",)  # the default robot's massless root link (example-robot-data's B1)


class LineFilter:
    """Decides, line by line, what is forwarded: everything but the known-harmless lines.

    A ``b3Warning[...]:`` header is held until its message line arrives; both are dropped when the message
    is the zero-inertia note of one of ``root_links``, both forwarded otherwise.
    """

    def __init__(self, root_links: Iterable[str] = DEFAULT_ROOT_LINKS):
        self.root_links = frozenset(root_links)
        self._held: bytes | None = None
        self.dropped = 0

    def feed(self, line: bytes) -> list[bytes]:
        """The lines to forward now for one input ``line`` (with its newline, if it had one)."""
        text = line.decode("utf-8", "replace")
        held, self._held = self._held, None
        if held is not None:
            match = BAD_INERTIA.match(text)
            if match and match.group(1) in self.root_links:
                self.dropped += 2
                return []
            return [held, *self.feed(line)]
        if BANNER.match(text):
            self.dropped += 1
            return []
        if B3_HEADER.match(text):
            self._held = line
            return []
        return [line]

    def flush(self) -> list[bytes]:
        """A held header with no message yet: forward it."""
        held, self._held = self._held, None
        return [held] if held is not None else []


class _FdFilter:
    """A pipe in front of one file descriptor and the thread that filters it into the original."""

    def __init__(self, fd: int, root_links: Iterable[str]):
        self.fd = fd
        self.original = os.dup(fd)
        read_end, write_end = os.pipe()
        os.dup2(write_end, fd)
        os.close(write_end)
        self.filter = LineFilter(root_links)
        self._thread = threading.Thread(
            target=self._pump, args=(read_end,), daemon=True, name=f"quiet-fd{fd}"
        )
        self._thread.start()

    def restore(self, timeout: float = 1.0) -> None:
        """Point the descriptor back at its original target and let the thread forward what is left."""
        os.dup2(self.original, self.fd)  # drops this process's write end of the pipe: the thread sees EOF
        self._thread.join(timeout)

    def _pump(self, read_end: int) -> None:
        pending = b""
        with os.fdopen(read_end, "rb", buffering=0) as pipe:
            while chunk := pipe.read(65536):
                pending += chunk
                *lines, pending = pending.split(b"\n")
                out = [piece for line in lines for piece in self.filter.feed(line + b"\n")]
                if pending and self.filter._held is None and not _may_become_filtered(pending):
                    out.extend(self.filter.feed(pending))  # a partial line (a prompt): forward now
                    pending = b""
                if out:
                    os.write(self.original, b"".join(out))
        os.write(self.original, b"".join(self.filter.flush()) + pending)


def _may_become_filtered(partial: bytes) -> bool:
    """Whether a partial line could still turn into a filtered one (then it waits for its newline)."""
    return any(p.startswith(partial[: len(p)]) for p in (b"pybullet build time: ", b"b3Warning["))


_ACTIVE: dict[int, _FdFilter] = {}


def quiet_known_native_output(root_links: Iterable[str] = DEFAULT_ROOT_LINKS) -> dict[int, LineFilter]:
    """Filter PyBullet's banner and root-link zero-inertia notes out of file descriptors 1 and 2.

    Idempotent: a second call keeps the filters in place. Python's own streams are flushed first, so
    nothing written before is reordered.

    Args:
        root_links: Link names whose "Bad inertia tensor properties, setting inertia to zero" note is
            dropped (the massless root of the default robot); the note for any other link is kept.

    Returns:
        The line filters by file descriptor (their ``dropped`` counts what was filtered).
    """
    for stream in (sys.stdout, sys.stderr, sys.__stdout__, sys.__stderr__):
        try:
            stream.flush()
        except (AttributeError, ValueError, OSError):
            pass
    for fd in (1, 2):
        if fd not in _ACTIVE:
            _ACTIVE[fd] = _FdFilter(fd, root_links)
            atexit.register(_ACTIVE[fd].restore)
    return {fd: f.filter for fd, f in _ACTIVE.items()}
