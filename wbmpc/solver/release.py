"""The release-speed library without the release build's wait (issue 22, item 2).

A compiled MPC (``SolverSettings(compiled=True)`` or ``direct=True``) first solves with the library of
``SolverSettings.compile_flags`` (``-O1``: about half a minute to build) while the release library
(``SolverSettings.release_flags``, ``-O3 -march=native``: several minutes, faster solves) is built from the
same generated C in a background process at the lowest CPU priority. When it is in the cache the MPC switches
to it between two solves (:meth:`ReleaseUpgrade.poll`); a later MPC of the same problem finds it cached and
uses it from its first solve. Both libraries are keyed as today (:func:`wbmpc.solver.codegen.cache_key`, the
flags included), so a cached release library belongs to this problem and this compiler.

The background build outlives the process that started it (a notebook closed early still leaves the release
library for its next run), holds the key folder's lock while it compiles (concurrent builders of the key wait,
then reuse it) and writes its output to ``release-build.log`` in that folder. A failed release build is
reported once (a warning with the log's tail); the MPC keeps the library it has.

Quick mode (:mod:`wbmpc.quick`: tests, CI) leaves the release library out entirely, cached or not, so that
no result there depends on what a machine's cache holds.

Run as ``python -m wbmpc.solver.release SPEC.json`` by :meth:`ReleaseUpgrade.start`; not meant to be run by
hand.
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import subprocess
import sys
import time
import warnings
from pathlib import Path

from wbmpc.quick import quick_mode

__all__ = ["ReleaseUpgrade"]

#: Seconds between two looks at the background build from :meth:`ReleaseUpgrade.poll`.
POLL_PERIOD = 1.0
SPEC_NAME = "release-spec.json"
LOG_NAME = "release-build.log"
_REPO = Path(__file__).resolve().parents[2]


class ReleaseUpgrade:
    """Which flags an MPC's compiled library has now, and the background build of its release library.

    Args:
        ocp: The MPC's problem.
        kind: ``"nlp"`` (the casadi plugin's compiled NLP, :mod:`wbmpc.solver.codegen`) or ``"direct"``
            (the direct Fatrop driver, :mod:`wbmpc.solver.direct.build`).
        base_flags: Flags of the library built first (``SolverSettings.compile_flags``).
        release_flags: Flags of the release library, or ``None`` for none.
        directory: Cache folder (default :func:`wbmpc.solver.codegen.cache_dir`).
        build: Start the background build when the release library is not cached (False: use it only if
            it is; e.g. on the wall clock, where gcc would take a core from the control loops).

    Attributes:
        flags: The flags of the library to use now: ``release_flags`` once the release library is cached
            (at construction or after :meth:`poll` returned True), else ``base_flags``.
        enabled: Whether a release library is wanted (flags given, different from the base ones, not quick
            mode).
        failure: Why the background build failed (its log's tail), or ``None``.

    Raises:
        ValueError: an unknown ``kind``.
    """

    def __init__(
        self, ocp, kind: str, base_flags, release_flags, directory: Path | None = None, build: bool = True
    ):
        if kind not in ("nlp", "direct"):
            raise ValueError(f"kind must be 'nlp' or 'direct', got {kind!r}")
        self.ocp, self.kind, self.directory = ocp, kind, directory
        self.base_flags = tuple(base_flags)
        self.build = bool(build)
        self.release_flags = None if release_flags is None else tuple(release_flags)
        self.enabled = (
            self.release_flags is not None and self.release_flags != self.base_flags and not quick_mode()
        )
        self.process: subprocess.Popen | None = None
        self.failure: str | None = None
        self.started_at: float | None = None
        self._last_poll = 0.0
        self._elsewhere: Path | None = None  # the key folder of a release build run by another process
        self.flags = (
            self.release_flags if self.enabled and self._cached(self.release_flags) else self.base_flags
        )

    @property
    def on_release(self) -> bool:
        """True when :attr:`flags` are the release flags."""
        return self.enabled and self.flags == self.release_flags

    @property
    def building(self) -> bool:
        """True while the background build runs."""
        return self.process is not None and self.process.poll() is None

    def _cached(self, flags) -> bool:
        if self.kind == "nlp":
            from wbmpc.solver import codegen

            return codegen.cached(self.ocp, flags, self.directory) is not None
        from wbmpc.solver.direct import build as direct_build

        return direct_build.cached(self.ocp, flags, self.directory) is not None

    def _folders(self) -> tuple[Path, Path, str, dict]:
        """(base key folder, release key folder, release key, release description)."""
        from wbmpc.solver import codegen

        root = Path(self.directory or codegen.cache_dir())
        if self.kind == "nlp":
            base, _ = codegen.cache_key(self.ocp, self.base_flags)
            key, description = codegen.cache_key(self.ocp, self.release_flags)
            return root / base, root / key, key, description
        from wbmpc.solver.direct import build as direct_build

        base, _ = direct_build.cache_key(self.ocp, self.base_flags)
        key, description = direct_build.cache_key(self.ocp, self.release_flags)
        return root / f"direct-{base}", root / f"direct-{key}", key, description

    def start(self) -> bool:
        """Start the background build of the release library (call it once the base library is built).

        Does nothing when the release library is not wanted, already in use, being built, or not to be
        built here (``build=False``).

        Returns:
            True if a build was started.
        """
        if not self.enabled or self.on_release or self.process is not None or self.failure is not None:
            return False
        if not self.build:
            return False
        base, target, key, description = self._folders()
        source = base / "wbmpc_nlp.c" if self.kind == "nlp" else base / "sources"
        if not source.exists():  # a base library built before sources were kept: nothing to compile from
            self.failure = f"no generated sources at {source} (rebuild the base library)"
            return False
        target.mkdir(parents=True, exist_ok=True)
        running = _BUILDS.get(str(target))
        if running is not None and running.poll() is None:  # another MPC of this process started it
            self.process, self.started_at = running, time.monotonic()
            return True
        if _locked(target):  # another process builds this key (a sweep's worker): wait for its library
            self._elsewhere, self.started_at = target, time.monotonic()
            return True
        spec = {
            "kind": self.kind,
            "folder": str(target),
            "key": key,
            "description": description,
            "flags": list(self.release_flags),
            "source": str(source),
        }
        (target / SPEC_NAME).write_text(json.dumps(spec, indent=2))
        env = {
            **os.environ,
            "PYTHONPATH": os.pathsep.join(filter(None, [str(_REPO), os.environ.get("PYTHONPATH")])),
        }
        with open(target / LOG_NAME, "w") as log:
            self.process = subprocess.Popen(
                [sys.executable, "-m", "wbmpc.solver.release", str(target / SPEC_NAME)],
                stdout=log,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                env=env,
                cwd=str(_REPO),
                preexec_fn=_lowest_priority,
                start_new_session=True,  # it finishes even if this process is stopped or interrupted
            )
        _BUILDS[str(target)] = self.process
        self.started_at = time.monotonic()
        return True

    def poll(self, force: bool = False) -> bool:
        """Look at the background build (at most every :data:`POLL_PERIOD` s unless ``force``).

        Returns:
            True exactly once: when the release library has just become usable (:attr:`flags` are now the
            release flags and the caller must rebuild its solvers). A failed build warns once and leaves
            :attr:`flags` as they were.
        """
        if (self.process is None and self._elsewhere is None) or self.on_release:
            return False
        now = time.monotonic()
        if not force and now - self._last_poll < POLL_PERIOD:
            return False
        self._last_poll = now
        if self._elsewhere is not None:  # another process's build: done when its lock is free
            if _locked(self._elsewhere):
                return False
            self._elsewhere = None
            if self._cached(self.release_flags):
                self.flags = self.release_flags
                return True
            self.failure = "another process's release build ended without a library"
            return False
        code = self.process.poll()
        if code is None:
            return False
        _, target, _, _ = self._folders()
        self.process = None
        if code == 0 and self._cached(self.release_flags):
            self.flags = self.release_flags
            return True
        log = target / LOG_NAME
        tail = log.read_text(errors="replace")[-1500:] if log.is_file() else "(no log)"
        self.failure = f"exit code {code}: {tail}"
        warnings.warn(
            f"the background {' '.join(self.release_flags)} build of the {self.kind} library failed "
            f"(the MPC keeps its {' '.join(self.base_flags)} library); {log}:\n{tail}",
            stacklevel=3,
        )
        return False

    def wait(self, timeout: float | None = None) -> bool:
        """Block until the background build ends (for scripts and tests); then :meth:`poll`.

        Returns:
            What :meth:`poll` returns.

        Raises:
            subprocess.TimeoutExpired: still building after ``timeout`` s.
        """
        if self.process is not None:
            self.process.wait(timeout)
        return self.poll(force=True)

    def stop(self) -> None:
        """Kill the background build (its key folder's lock is released, its temporary folder is removed
        by the next build of the cache)."""
        if self.process is not None and self.process.poll() is None:
            self.process.kill()
            self.process.wait()
        self.process = None


# The background builds this process started, by key folder (one per key however many MPCs want it).
_BUILDS: dict[str, subprocess.Popen] = {}


def _locked(folder: Path) -> bool:
    """True if a process holds the build lock of the key folder ``folder`` (it is building that key)."""
    lock_path = Path(folder) / ".lock"
    if not lock_path.is_file():
        return False
    with open(lock_path, "a") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return True
        fcntl.flock(lock, fcntl.LOCK_UN)
    return False


def _lowest_priority() -> None:
    os.nice(19)


def _compile(spec: dict) -> None:
    """Compile the kept sources of ``spec`` into its key folder with its flags (the child's work)."""
    folder, flags, source = Path(spec["folder"]), tuple(spec["flags"]), Path(spec["source"])
    if spec["kind"] == "nlp":
        from wbmpc.solver import codegen

        def copy_c(tmp: Path) -> Path:
            shutil.copy(source, tmp / "wbmpc_nlp.c")
            shutil.copy(source.with_suffix(".h"), tmp / "wbmpc_nlp.h")
            return tmp / "wbmpc_nlp.c"

        codegen.build_in(folder, spec["key"], spec["description"], flags, copy_c, progress=True)
        return
    from wbmpc.solver.direct import build as direct_build

    def copy_sources(tmp: Path) -> list[Path]:
        copies = []
        for src in sorted(source.iterdir()):
            shutil.copy(src, tmp / src.name)
            copies.append(tmp / src.name)
        return copies

    direct_build.build_in(folder, spec["key"], spec["description"], flags, copy_sources, progress=True)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1:
        print("usage: python -m wbmpc.solver.release SPEC.json", file=sys.stderr)
        return 2
    spec = json.loads(Path(argv[0]).read_text())
    start = time.perf_counter()
    print(f"[wbmpc.solver.release] {spec['kind']} library, gcc {' '.join(spec['flags'])}", flush=True)
    _compile(spec)
    print(f"[wbmpc.solver.release] done in {time.perf_counter() - start:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
