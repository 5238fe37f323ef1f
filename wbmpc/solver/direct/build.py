"""Generate, compile and cache the direct Fatrop driver of an OCP: one shared library per problem and flags.

The library holds the per-stage functions in Fatrop's layout (:mod:`wbmpc.solver.direct.problem`), one C
file per stage type compiled in parallel, a table that hands them to the driver, and the C++ driver
``wbmpc/solver/c/fatrop_direct.cpp`` compiled against the casadi wheel's Fatrop headers and linked against
its ``libfatrop.so`` and ``libblasfeo.so`` (no source build of a dependency). Cached like
:func:`wbmpc.solver.codegen.build`: the key is the codegen key of the OCP (robot model, settings, compiler,
casadi, wbmpc sources) plus the driver's own sources and flags; a file lock serialises builds of one key.

Without a compiled problem (:func:`build_vm`, :func:`functions_file`): the same driver built once per
machine with ``-DWBMPC_DIRECT_VM`` (a few seconds, no problem in it), which evaluates the stage functions
serialized from Python with CasADi's virtual machine through libcasadi's C API.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import shutil
import subprocess
import tempfile
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import casadi as ca

from wbmpc.ocp import OCP
from wbmpc.solver import codegen
from wbmpc.solver.direct.problem import (
    FUNCTIONS,
    KINDS,
    stage_layouts,
    stage_parameters_function,
    stage_problem,
)

DIRECT_VERSION = 2  # bump when the generated functions or the driver's ABI change meaning
DRIVER_SOURCE = Path(__file__).resolve().parents[1] / "c" / "fatrop_direct.cpp"
#: gcc flags of the generated stage functions (as the plugin path's library) and of the C++ driver.
DEFAULT_FLAGS = codegen.DEFAULT_FLAGS
DRIVER_FLAGS = ("-O2", "-std=c++17")
LIBRARY_NAME = "libwbmpc_direct.so"
VM_LIBRARY_NAME = "libwbmpc_direct_vm.so"
FUNCTIONS_NAME = "functions.casadi"
_CODEGEN_OPTIONS = {"with_header": False, "casadi_int": "long long int", "casadi_real": "double"}


@dataclass
class DirectLibrary:
    """A compiled direct-driver library in the cache, with its build record."""

    library: Path
    key: str
    build_s: float
    rebuilt: bool


def casadi_dir() -> Path:
    """Folder of the casadi wheel (``libfatrop.so``, ``libblasfeo.so``; headers under ``include``)."""
    return Path(ca.__file__).resolve().parent


def cache_key(ocp: OCP, flags: tuple[str, ...]) -> tuple[str, dict]:
    """Key of the direct library of ``ocp``: the codegen key plus this package's sources and the driver."""
    key, description = codegen.cache_key(ocp, tuple(flags))
    digest = hashlib.sha256()
    for path in (
        Path(__file__).parent / "problem.py",
        Path(__file__),
        DRIVER_SOURCE,
    ):  # what the library holds
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    description = {
        **description,
        "direct_version": DIRECT_VERSION,
        "driver_flags": list(DRIVER_FLAGS),
        "direct_sources_sha256": digest.hexdigest(),
        "codegen_key": key,
    }
    return hashlib.sha256(json.dumps(description, sort_keys=True).encode()).hexdigest()[:16], description


def build(
    ocp: OCP,
    flags: tuple[str, ...] = DEFAULT_FLAGS,
    directory: Path | None = None,
    progress: bool = True,
    force: bool = False,
) -> DirectLibrary:
    """Generate and compile the direct driver of ``ocp``, or reuse the cached library.

    Args:
        ocp: The problem.
        flags: gcc flags of the generated stage functions (part of the key).
        directory: Cache folder (default :func:`wbmpc.solver.codegen.cache_dir`).
        progress: Print what happens.
        force: Rebuild even if a valid library is cached.

    Raises:
        FileNotFoundError: the casadi wheel has no Fatrop headers or libraries.
        RuntimeError: a compiler error (the message holds its tail).
    """
    _check_toolchain(casadi_dir())
    key, description = cache_key(ocp, tuple(flags))
    folder = Path(directory or codegen.cache_dir()) / f"direct-{key}"

    def generate(tmp: Path) -> list[Path]:
        if progress:
            print(f"[wbmpc.solver.direct] generating the direct Fatrop driver ({key}) ...", flush=True)
        return _generate(ocp, tmp)

    return build_in(folder, key, description, tuple(flags), generate, progress, force)


def cached(ocp: OCP, flags: tuple[str, ...], directory: Path | None = None) -> DirectLibrary | None:
    """The valid cached direct library of ``ocp`` built with ``flags``, or ``None`` (nothing is built)."""
    key, _ = cache_key(ocp, tuple(flags))
    folder = Path(directory or codegen.cache_dir()) / f"direct-{key}"
    library, record = folder / LIBRARY_NAME, folder / "build.json"
    if not (library.is_file() and record.is_file()):
        return None
    info = json.loads(record.read_text())
    if info.get("library_sha256") != _sha256(library):
        return None
    return DirectLibrary(library, key, info["build_s"], False)


def build_vm(directory: Path | None = None, progress: bool = True, force: bool = False) -> DirectLibrary:
    """Compile (or reuse) the direct driver that evaluates serialized stage functions in CasADi's VM.

    It holds no problem: one library per driver source, casadi and compiler, for every OCP (the functions
    come from :func:`functions_file`). Linked against the wheel's ``libcasadi.so`` too.

    Raises:
        FileNotFoundError: no Fatrop or libcasadi in the casadi wheel, or no g++.
        RuntimeError: a compiler error (the message holds its tail).
    """
    lib_dir = casadi_dir()
    _check_toolchain(lib_dir, lib_dir / "libcasadi.so")
    description = {
        "direct_version": DIRECT_VERSION,
        "driver_flags": [*DRIVER_FLAGS, "-DWBMPC_DIRECT_VM"],
        "driver_sha256": _sha256(DRIVER_SOURCE),
        "casadi": ca.__version__,
        "compiler": codegen._compiler_version(),
    }
    key = hashlib.sha256(json.dumps(description, sort_keys=True).encode()).hexdigest()[:16]
    folder = Path(directory or codegen.cache_dir()) / f"direct-vm-{key}"

    def compile_into(tmp: Path) -> Path:
        if progress:
            print(f"[wbmpc.solver.direct] compiling the VM driver ({key}) ...", flush=True)
        include = lib_dir / "include"
        _run(
            [
                "g++",
                *description["driver_flags"],
                "-fPIC",
                "-shared",
                str(DRIVER_SOURCE),
                f"-I{include}",
                f"-I{include / 'blasfeo' / 'include'}",
                "-o",
                str(tmp / VM_LIBRARY_NAME),
                f"-L{lib_dir}",
                "-lcasadi",
                "-lfatrop",
                "-lblasfeo",
                f"-Wl,-rpath,{lib_dir}",
            ],
            tmp,
        )
        return tmp / VM_LIBRARY_NAME

    return _locked_build(folder / VM_LIBRARY_NAME, key, description, compile_into, progress, force)


def functions_file(ocp: OCP, directory: Path | None = None) -> Path:
    """The stage functions of ``ocp`` serialized for the VM driver (:func:`build_vm`), cached by the
    problem's key (:func:`cache_key`); written once, atomically."""
    key, _ = cache_key(ocp, ("vm",))
    folder = Path(directory or codegen.cache_dir()) / f"direct-functions-{key}"
    path = folder / FUNCTIONS_NAME
    if path.is_file():
        return path
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if path.is_file():
            return path
        functions = [*_stage_functions(ocp).values(), stage_parameters_function(ocp)]
        with tempfile.TemporaryDirectory(prefix=".write-", dir=folder) as tmp:
            written = Path(tmp) / FUNCTIONS_NAME
            serializer = ca.FileSerializer(str(written))
            serializer.pack(functions)
            del serializer  # closes the file
            os.replace(written, path)
    return path


def _stage_functions(ocp: OCP) -> dict[str, ca.Function]:
    """Every stage type's functions of ``ocp`` by name (``wbmpc_direct_<kind>_<which>``)."""
    return {f.name(): f for functions in _kind_functions(ocp).values() for f in functions.values()}


def _kind_functions(ocp: OCP) -> dict[str, dict[str, ca.Function]]:
    """The functions (:func:`stage_problem`) of each stage type the horizon uses, in ``KINDS`` order."""
    layouts = {}
    for layout in stage_layouts(ocp):
        layouts.setdefault(layout.kind, layout)
    return {kind: stage_problem(ocp, layouts[kind]) for kind in KINDS if kind in layouts}


def _check_toolchain(lib_dir: Path, *extra: Path) -> None:
    for needed in (lib_dir / "include" / "fatrop" / "fatrop.hpp", lib_dir / "libfatrop.so", *extra):
        if not needed.exists():
            raise FileNotFoundError(
                f"the casadi wheel has no {needed.name} at {needed}: the direct driver needs it"
            )
    if shutil.which("g++") is None or shutil.which("gcc") is None:
        raise FileNotFoundError("the direct Fatrop driver needs gcc and g++ on PATH")


def build_in(
    folder: Path,
    key: str,
    description: dict,
    flags: tuple[str, ...],
    generate,
    progress: bool = True,
    force: bool = False,
) -> DirectLibrary:
    """Compile the sources ``generate(tmp) -> [C files]`` writes, with the driver, into ``folder``.

    The part of :func:`build` that needs no OCP: the generated C is kept in ``folder/sources`` so that a
    background process can compile it again with other flags (:mod:`wbmpc.solver.release`).

    Raises:
        RuntimeError: a compiler error (the message holds its tail).
    """
    lib_dir = casadi_dir()
    folder = Path(folder)

    def compile_into(tmp: Path) -> Path:
        sources = [Path(src) for src in generate(tmp)]
        kept = folder / "sources"
        if kept.resolve() not in {src.parent.resolve() for src in sources}:
            shutil.rmtree(kept, ignore_errors=True)
            kept.mkdir()
            for src in sources:
                shutil.copy(src, kept / src.name)
        objects = _compile_all(sources, tmp, tuple(flags), lib_dir)
        _run(
            [
                "g++",
                "-shared",
                *[str(o) for o in objects],
                "-o",
                str(tmp / LIBRARY_NAME),
                f"-L{lib_dir}",
                "-lfatrop",
                "-lblasfeo",
                f"-Wl,-rpath,{lib_dir}",
            ],
            tmp,
        )
        return tmp / LIBRARY_NAME

    return _locked_build(folder / LIBRARY_NAME, key, description, compile_into, progress, force)


def _locked_build(library: Path, key: str, description: dict, compile_into, progress: bool, force: bool):
    """``library`` from the cache or built by ``compile_into(tmp) -> built file``
    (:func:`wbmpc.solver.codegen.locked_build`)."""

    def valid(library: Path, record: Path) -> bool:
        return (
            library.is_file()
            and record.is_file()
            and json.loads(record.read_text()).get("library_sha256") == _sha256(library)
        )

    info, rebuilt = codegen.locked_build(
        library, key, description, lambda tmp: (compile_into(tmp), {}), valid, force
    )
    if progress and rebuilt:
        print(f"[wbmpc.solver.direct] built {library} in {info['build_s']:.0f} s", flush=True)
    return DirectLibrary(library, key, info["build_s"], rebuilt)


def _generate(ocp: OCP, folder: Path) -> list[Path]:
    """Write one C file per stage type, the stage-parameter function and the table; their paths."""
    sources, table = [], {}
    for kind, functions in _kind_functions(ocp).items():
        index = KINDS.index(kind)
        generator = ca.CodeGenerator(f"wbmpc_direct_{kind}.c", _CODEGEN_OPTIONS)
        for which in FUNCTIONS:
            generator.add(functions[which])
            table[(index, FUNCTIONS.index(which))] = functions[which].name()
        generator.generate(str(folder) + os.sep)
        sources.append(folder / f"wbmpc_direct_{kind}.c")
    generator = ca.CodeGenerator("wbmpc_direct_stage_params.c", _CODEGEN_OPTIONS)
    stage_params = stage_parameters_function(ocp)
    generator.add(stage_params)
    generator.generate(str(folder) + os.sep)
    sources.append(folder / "wbmpc_direct_stage_params.c")
    names = sorted(set(table.values())) + [stage_params.name()]
    lines = [
        "/* Generated by wbmpc.solver.direct.build: the stage functions by (kind, which). */",
        "typedef long long int casadi_int;",
        "typedef int (*eval_fn)(const double**, double**, casadi_int*, double*, int);",
        "typedef int (*work_fn)(casadi_int*, casadi_int*, casadi_int*, casadi_int*);",
    ]
    for name in names:
        lines.append(f"int {name}(const double**, double**, casadi_int*, double*, int);")
        lines.append(f"int {name}_work(casadi_int*, casadi_int*, casadi_int*, casadi_int*);")
        lines.append(f"const casadi_int* {name}_sparsity_out(casadi_int);")
    lines.append("int wbmpc_direct_function(int kind, int which, eval_fn* eval, work_fn* work) {")
    sp = stage_params.name()
    lines.append(f"  if (which == -1) {{ *eval = {sp}; *work = {sp}_work; return 0; }}")
    for (kind, which), name in sorted(table.items()):
        lines.append(
            f"  if (kind == {kind} && which == {which}) {{ *eval = {name}; *work = {name}_work; return 0; }}"
        )
    # A stage type the horizon does not use (e.g. no plain node) takes another's: never called.
    fallback = next(iter(sorted(table.items())))[1]
    lines.append(f"  *eval = {fallback}; *work = {fallback}_work; return 0;")
    lines.append("}")
    # Output i's sparsity (CasADi's compressed-column format) of the same functions.
    lines.append("const casadi_int* wbmpc_direct_sparsity_out(int kind, int which, int i) {")
    lines.append(f"  if (which == -1) return {sp}_sparsity_out(i);")
    for (kind, which), name in sorted(table.items()):
        lines.append(f"  if (kind == {kind} && which == {which}) return {name}_sparsity_out(i);")
    lines.append(f"  return {fallback}_sparsity_out(i);")
    lines.append("}")
    (folder / "wbmpc_direct_table.c").write_text("\n".join(lines) + "\n")
    sources.append(folder / "wbmpc_direct_table.c")
    return sources


def _compile_all(sources: list[Path], folder: Path, flags: tuple[str, ...], lib_dir: Path) -> list[Path]:
    """Compile the generated C (``flags``) and the driver in parallel, one job per core."""
    jobs = [["gcc", *flags, "-fPIC", "-c", str(src), "-o", str(src.with_suffix(".o"))] for src in sources]
    driver = folder / "fatrop_direct.o"
    include = lib_dir / "include"
    jobs.append(
        [
            "g++",
            *DRIVER_FLAGS,
            "-fPIC",
            "-c",
            str(DRIVER_SOURCE),
            f"-I{include}",
            f"-I{include / 'blasfeo' / 'include'}",
            "-o",
            str(driver),
        ]
    )
    # The largest files first, so that the last job to start is a short one.
    jobs.sort(key=lambda job: -Path(job[-3] if job[0] == "gcc" else DRIVER_SOURCE).stat().st_size)
    with ThreadPoolExecutor(max_workers=max(1, os.cpu_count() or 1)) as pool:
        list(pool.map(lambda job: _run(job, folder), jobs))
    return [src.with_suffix(".o") for src in sources] + [driver]


def _run(command: list[str], cwd: Path) -> None:
    result = subprocess.run(command, cwd=cwd, capture_output=True, text=True)
    if result.returncode != 0:
        raise RuntimeError(f"{' '.join(command[:4])} ... failed:\n{result.stderr[-3000:]}")


def _sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()
