"""A process's account of its run (counters, solve times, errors), handed to the parent through a file.

A ``multiprocessing.Queue`` is the wrong carrier here: a child that put a large account on it cannot exit
until the parent has read it all, and a child killed while its feeder thread writes leaves half a message
in the pipe, on which the parent's next read blocks for good. A file written whole and renamed into place
(``os.replace`` is atomic) is either there, complete, or not there at all (the process was killed first).
"""

from __future__ import annotations

import os
import pickle
from dataclasses import asdict
from pathlib import Path

__all__ = ["read_account", "write_account"]


def write_account(path: str | os.PathLike, account) -> None:
    """Write ``account`` (a picklable object) to ``path`` atomically."""
    path = Path(path)
    partial = path.with_name(path.name + f".{os.getpid()}.partial")
    partial.write_bytes(pickle.dumps(account, protocol=pickle.HIGHEST_PROTOCOL))
    os.replace(partial, path)


def read_account(path: str | os.PathLike) -> dict:
    """The account at ``path`` as a dict (a dataclass is converted), or ``{"errors": [why none]}``."""
    path = Path(path)
    if not path.is_file():
        return {"errors": ["no account received (the process was killed?)"]}
    account = pickle.loads(path.read_bytes())  # written by our own child process, never by anyone else
    return asdict(account) if hasattr(account, "__dataclass_fields__") else dict(account)
