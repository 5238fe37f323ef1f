"""Code generation of the MPC's NLP for Fatrop, with code size independent of the number of nodes.

CasADi's ``nlpsol`` accepts a compiled library instead of symbolic expressions: it loads ``nlp`` and every
derivative function the solver needs (``nlp_f``, ``nlp_g``, ``nlp_grad_f``, ``nlp_jac_g``, ``nlp_hess_l``,
``nlp_grad``) by name, when the library provides them. wbmpc writes those functions itself:

* one set of SX functions per *stage type* (initial node, torque nodes, plain nodes, terminal node): the
  stage's cost and constraint rows, their gradient, Jacobian and Lagrangian Hessian, with the stage's
  variables ``(z_k = [x_k, u_k], x_{k+1})``, the shared parameters ``p`` and the per-stage parameters
  ``s_k = [dt_k, contact, swing_vz, force_des, ee_velocity]`` as inputs;
* thin MX functions that call them once per node and assemble the block-sparse NLP derivatives (the
  Hessian is block diagonal, the Jacobian has Fatrop's staircase structure).

The generated C holds each stage function once, so a 30-node problem has the same code as a 15-node one,
and gcc compiles small functions instead of one huge expression (the monolithic NLP did not compile in
13 minutes and 9 GB). Everything that was a runtime parameter stays one.

Everything else is a constant of the generated code: the numeric robot model (inertias, placements,
gravity, limits), the contact frames and the OCP settings. :func:`cache_key` fingerprints all of it, so
that a changed model gets its own library, and each build record says what it was built from.
"""

from __future__ import annotations

import dataclasses
import fcntl
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np
import pinocchio as pin

from wbmpc.ocp import OCP
from wbmpc.ocp.time_grid import symbolic_geometric_time_steps

NLP_FUNCTIONS = ("nlp", "nlp_f", "nlp_g", "nlp_grad_f", "nlp_jac_g", "nlp_hess_l", "nlp_grad")


def stage_kind(ocp: OCP, k: int) -> str:
    """Stage type of node ``k``: ``initial``, ``torque``, ``plain`` or ``terminal``."""
    if k == ocp.n_nodes - 1:
        return "terminal"
    if k == 0:
        return "initial"
    return "torque" if k < ocp.settings.n_tau_nodes else "plain"


def stage_functions(ocp: OCP, kind: str, k: int) -> dict[str, ca.Function]:
    """SX functions of one stage type, built from the OCP's own stage definition at node ``k``."""
    form = ocp.formulation
    p = ocp.params.symbols
    p_vec = ocp.params.vector
    has_input = kind != "terminal"
    st = form.stage(f"{kind}", p["q_hat"], has_input=has_input, torque_limited=kind in ("initial", "torque"))
    sizes = ocp.stage_parameter_sizes()
    s = ca.SX.sym("s", sum(sizes.values()))
    sp, i = {}, 0
    for name, n in sizes.items():
        sp[name] = s[i] if n == 1 else s[i : i + n]
        i += n
    x_next = ca.SX.sym("x_next", form.nx) if has_input else ca.SX(0, 1)
    cost, rows = ocp.stage_terms(k, st, x_next if has_input else None, p, sp if has_input else None)
    g = ca.vertcat(*[expr for _, expr, _, _ in rows])
    z = ocp.stage_decision_variables(k, st)
    w = ca.vertcat(z, x_next)
    lam_f, lam_g = ca.SX.sym("lam_f"), ca.SX.sym("lam_g", g.numel())
    gamma = lam_f * cost + ca.dot(lam_g, g)
    hess, grad_z = ca.hessian(gamma, z)
    ins = [z, x_next, p_vec, s]
    names = ["z", "x_next", "p", "s"]
    return {
        "fg": ca.Function(f"{kind}_fg", ins, [cost, g], names, ["f", "g"]),
        # The cost alone: the line search evaluates it without the dynamics rows.
        "f": ca.Function(f"{kind}_f", ins, [cost], names, ["f"]),
        "grad_f": ca.Function(f"{kind}_grad_f", ins, [ca.gradient(cost, z)], names, ["grad_f"]),
        "jac_g": ca.Function(f"{kind}_jac_g", ins, [g, ca.jacobian(g, w)], names, ["g", "jac_g"]),
        "hess": ca.Function(
            f"{kind}_hess",
            [*ins, lam_f, lam_g],
            [grad_z, ca.gradient(gamma, x_next), hess],
            [*names, "lam_f", "lam_g"],
            ["grad_z", "grad_x_next", "hess"],
        ),
        "grad_p": ca.Function(
            f"{kind}_grad_p",
            [*ins, lam_f, lam_g],
            [ca.gradient(gamma, p_vec), ca.gradient(gamma, s)],
            [*names, "lam_f", "lam_g"],
            ["grad_p", "grad_s"],
        ),
    }


def nlp_functions(ocp: OCP) -> list[ca.Function]:
    """The NLP functions CasADi's Fatrop interface loads from a library, assembled from stage functions."""
    n_x, n_p = ocp.n_variables, ocp.params.size
    kinds = {}
    for info in ocp.stages:
        kind = stage_kind(ocp, info.k)
        kinds.setdefault(kind, stage_functions(ocp, kind, info.k))

    X, P = ca.MX.sym("x", n_x), ca.MX.sym("p", n_p)
    lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", ocp.n_constraints)
    blocks = ocp.params.blocks
    dt_min = P[blocks["dt_min"][0]]
    dt_max = P[blocks["dt_max"][0]]
    dts = symbolic_geometric_time_steps(ocp.n_nodes, dt_min, dt_max)

    def stage_params(k):
        parts = [dts[k]]
        for name in ("contact", "swing_vz", "force_des", "ee_velocity"):
            start, (rows, _) = blocks[name]
            parts.append(P[start + k * rows : start + (k + 1) * rows])
        return ca.vertcat(*parts)

    f, f_only, g_parts, grad_f, jac_rows, hess_blocks, grad_x, grad_p = 0, 0, [], [], [], [], [], 0
    carry = None  # gradient of stage k-1 w.r.t. x_k
    for info in ocp.stages:
        fn = kinds[stage_kind(ocp, info.k)]
        nz = info.nx + info.nu
        z = X[info.x_offset : info.x_offset + nz]
        has_next = info.u_offset is not None
        nx_next = ocp.stages[info.k + 1].nx if has_next else 0
        xn = X[info.x_offset + nz : info.x_offset + nz + nx_next] if has_next else ca.MX(0, 1)
        s = stage_params(info.k) if has_next else ca.MX.zeros(fn["fg"].size1_in(3), 1)
        lg = lam_g[info.g_offset : info.g_offset + info.ng]
        ins = [z, xn, P, s]
        fk, gk = fn["fg"](*ins)
        f += fk
        f_only += fn["f"](*ins)
        g_parts.append(gk)
        grad_f.append(fn["grad_f"](*ins))
        _, jac = fn["jac_g"](*ins)
        width = nz + xn.numel()
        jac_rows.append(
            ca.horzcat(ca.MX(info.ng, info.x_offset), jac, ca.MX(info.ng, n_x - info.x_offset - width))
        )
        gz, gxn, hk = fn["hess"](*ins, lam_f, lg)
        hess_blocks.append(hk)
        if carry is not None:
            gz = gz + ca.vertcat(carry, ca.MX(info.nu, 1))
        grad_x.append(gz)
        carry = gxn if has_next else None
        gp, gs = fn["grad_p"](*ins, lam_f, lg)
        grad_p += gp
        if has_next:  # chain rule through s_k(p): slices and the geometric time step
            grad_p += ca.jtimes(s, P, gs, True)
    g = ca.vertcat(*g_parts)
    grad_f = ca.vertcat(*grad_f)
    jac_g = ca.vertcat(*jac_rows)
    hess = ca.diagcat(*hess_blocks)
    grad_x = ca.vertcat(*grad_x)
    return [
        ca.Function("nlp", [X, P], [f, g], ["x", "p"], ["f", "g"]),
        ca.Function("nlp_f", [X, P], [f_only], ["x", "p"], ["f"]),
        ca.Function("nlp_g", [X, P], [g], ["x", "p"], ["g"]),
        ca.Function("nlp_grad_f", [X, P], [grad_f], ["x", "p"], ["grad_f_x"]),
        ca.Function("nlp_jac_g", [X, P], [g, jac_g], ["x", "p"], ["g", "jac_g_x"]),
        ca.Function(
            "nlp_hess_l",
            [X, P, lam_f, lam_g],
            [grad_x, hess],
            ["x", "p", "lam_f", "lam_g"],
            ["grad_gamma_x", "hess_gamma_x_x"],
        ),
        ca.Function(
            "nlp_grad",
            [X, P, lam_f, lam_g],
            [f, g, grad_x, grad_p],
            ["x", "p", "lam_f", "lam_g"],
            ["f", "g", "grad_gamma_x", "grad_gamma_p"],
        ),
    ]


# --- building, caching and loading ------------------------------------------------------------------------
CODEGEN_VERSION = 2  # bump when the generated functions change meaning
DEFAULT_FLAGS = ("-O1",)
# The real-time build: 8 % faster solves than -O1 on the default problem (data/bench/real_time.json) for a
# 4x longer build (124 s and 0.93 GB against 29 s and 0.57 GB for N = 15 on a 2.5 GHz Xeon); `-march=native`
# ties the library to the CPU family it was built on (the flags are part of the cache key).
RELEASE_FLAGS = ("-O3", "-march=native")
# Modules whose code shapes the generated functions (every cpin module is added by glob).
# The wbmpc sources the generated code depends on (paths in the package), plus every file of wbmpc/cpin.
_SOURCES = ("solver/codegen.py", "ocp/builder.py", "ocp/formulations.py", "ocp/time_grid.py")
# Significant digits of the numeric fingerprint: reloading a model gives the same key on any platform.
FINGERPRINT_DIGITS = 12
# Temporary build folders start with this; older wbmpc versions used tempfile's default ``tmp``.
_TMP_PREFIX = ".build-"
_LEGACY_TMP_PREFIX = "tmp"


def cache_dir() -> Path:
    """Cache folder: ``$WBMPC_CACHE_DIR`` or ``<repo>/.wbmpc_cache`` (git-ignored)."""
    env = os.environ.get("WBMPC_CACHE_DIR")
    return Path(env) if env else Path(__file__).resolve().parents[2] / ".wbmpc_cache"


def _number(x) -> str:
    """Canonical text of a float: ``FINGERPRINT_DIGITS`` significant digits, no negative zero."""
    x = float(x)
    return "0" if x == 0.0 else f"{x:.{FINGERPRINT_DIGITS}g}"


def _rounded(x) -> float:
    return float(_number(x))


def _numbers(values) -> list[str]:
    return [_number(x) for x in np.asarray(values, dtype=float).ravel()]


def _placement(se3: pin.SE3) -> list[str]:
    return _numbers(se3.rotation) + _numbers(se3.translation)


def model_fingerprint(model: pin.Model) -> dict[str, dict[str, list]]:
    """Canonical description of every number of a Pinocchio model the generated code can depend on.

    Components (each ``{item name: canonical values}``): ``gravity``; ``joints`` (type, axis, parent,
    indices, placement in the parent joint); ``inertias`` (mass, centre of mass, rotational inertia);
    ``frames`` (parent joint, type, placement); ``limits`` (position, velocity and torque limits);
    ``armature`` (rotor inertia per degree of freedom, which RNEA, CRBA and ABA add). Floats are written
    with :data:`FINGERPRINT_DIGITS` significant digits. What the symbolic algorithms never read
    (friction, damping, geometry) is left out, so that it causes no rebuild.
    """
    joints, inertias, limits, armature = {}, {}, {}, {}
    for j in range(model.njoints):
        name = model.names[j]
        inertia = model.inertias[j]
        inertias[name] = _numbers([inertia.mass]) + _numbers(inertia.lever) + _numbers(inertia.inertia)
        if j == 0:
            continue  # the universe: no joint model, no placement, no limits
        joint = model.joints[j]
        axis = getattr(joint.extract(), "axis", None)  # unaligned revolute/prismatic joints
        joints[name] = [
            joint.shortname(),
            model.names[model.parents[j]],
            joint.idx_q,
            joint.idx_v,
            joint.nq,
            joint.nv,
            _numbers(axis) if axis is not None else None,
            _placement(model.jointPlacements[j]),
        ]
        q, v = slice(joint.idx_q, joint.idx_q + joint.nq), slice(joint.idx_v, joint.idx_v + joint.nv)
        limits[name] = [
            _numbers(model.lowerPositionLimit[q]),
            _numbers(model.upperPositionLimit[q]),
            _numbers(model.velocityLimit[v]),
            _numbers(model.effortLimit[v]),
        ]
        armature[name] = _numbers(model.armature[v])
    frames = {}
    for i, frame in enumerate(model.frames):
        name = frame.name if frame.name not in frames else f"{frame.name}#{i}"  # names may repeat
        frames[name] = [model.names[frame.parentJoint], str(frame.type), _placement(frame.placement)]
    gravity = {"linear": _numbers(model.gravity.linear), "angular": _numbers(model.gravity.angular)}
    return {
        "gravity": gravity,
        "joints": joints,
        "inertias": inertias,
        "frames": frames,
        "limits": limits,
        "armature": armature,
    }


def _digest(data, n: int) -> str:
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:n]


def _sources_sha256() -> str:
    package = Path(__file__).resolve().parents[1]
    files = [package / f for f in _SOURCES] + sorted((package / "cpin").glob("*.py"))
    digest = hashlib.sha256()
    for path in files:
        digest.update(str(path.relative_to(package)).encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()


def cache_key(ocp: OCP, flags: tuple[str, ...]) -> tuple[str, dict]:
    """Hash of everything that changes the generated code, and the description it was computed from.

    The key covers the numeric robot model (:func:`model_fingerprint`: every inertia, joint and frame
    placement, gravity, limits), the robot-level choices the OCP bakes in (contact frames, locked joints,
    foot radius, total mass), every field of the OCP settings, the compiler, its flags, CasADi and the
    wbmpc sources that generate the code. The reference poses are not part of it: the OCP takes the
    measured and desired configurations as parameters (the locked joints' values enter the reduced model
    and are keyed through it and ``locked_joints``).

    The description is what a build record shows: readable values for the robot and the settings, and a
    short digest per model component and per model item (joint, body, frame) so that comparing two records
    (:func:`describe_changes`) tells what changed.
    """
    robot = ocp.robot
    model = robot.model
    fingerprint = model_fingerprint(model)
    urdf = Path(robot.urdf_path)
    description = {
        "codegen_version": CODEGEN_VERSION,
        "ocp_settings": dataclasses.asdict(ocp.settings),
        "ocp_size": {
            "variables": ocp.n_variables,
            "constraints": ocp.n_constraints,
            "params": ocp.params.size,
        },
        "robot": robot.name,
        "urdf_sha256": hashlib.sha256(urdf.read_bytes()).hexdigest() if urdf.is_file() else None,
        "locked_joints": {name: _rounded(value) for name, value in robot.locked_joints.items()},
        "contact_frames": list(robot.contact_frames),
        "foot_frames": list(robot.foot_frames),
        "ee_frame": robot.ee_frame,
        "foot_radius": _rounded(robot.foot_radius),
        "mass": _rounded(robot.mass),
        "gravity": [_rounded(g) for g in model.gravity.linear],
        "model": {
            "nq": model.nq,
            "nv": model.nv,
            "njoints": model.njoints,
            "nframes": len(model.frames),
            "digests": {part: _digest(items, 12) for part, items in fingerprint.items()},
            "items": {
                part: {name: _digest(values, 8) for name, values in items.items()}
                for part, items in fingerprint.items()
                if part != "gravity"
            },
        },
        "flags": list(flags),
        "casadi": ca.__version__,
        "compiler": _compiler_version(),
        "wbmpc_sources_sha256": _sources_sha256(),
    }
    # The short digests are for reading; the key hashes the full canonical fingerprint.
    key = _digest([description, fingerprint], 16)
    return key, description


def describe_changes(old: dict, new: dict, prefix: str = "") -> list[str]:
    """Dotted paths of the entries that differ between two cache descriptions (or build records).

    Example: comparing the ``build.json`` of two keys after moving the tool frame gives
    ``["model.digests.frames", "model.items.frames.gripper_center"]`` (records also differ in timings).

    Args:
        old, new: Descriptions from :func:`cache_key`, or build records.
        prefix: Path of ``old`` and ``new`` inside an enclosing description.
    """
    if not (isinstance(old, dict) and isinstance(new, dict)):
        return [] if old == new else [prefix or "."]
    changes = []
    for name in sorted(set(old) | set(new), key=str):
        path = f"{prefix}.{name}" if prefix else str(name)
        if name not in old or name not in new:
            changes.append(path)
        else:
            changes += describe_changes(old[name], new[name], path)
    return changes


@dataclass
class CompiledNLP:
    """A compiled NLP library in the cache, with its build record."""

    library: Path
    key: str
    build_s: float
    build_peak_mb: float
    c_bytes: int
    rebuilt: bool


def build(
    ocp: OCP,
    flags: tuple[str, ...] = DEFAULT_FLAGS,
    directory: Path | None = None,
    progress: bool = True,
    force: bool = False,
) -> CompiledNLP:
    """Generate and compile the NLP functions of ``ocp``, or reuse the cached library.

    Safe when several processes build at once (a file lock serialises builds of the same key); a cached
    library whose checksum does not match its record, or that does not load, is rebuilt. Temporary folders
    of killed builds are removed on the way (:func:`remove_stale_builds`).

    Args:
        ocp: The problem.
        flags: Compiler flags (part of the cache key).
        directory: Cache folder (default :func:`cache_dir`).
        progress: Print what happens and show elapsed time while gcc runs.
        force: Rebuild even if a valid library is cached.
    """
    key, description = cache_key(ocp, tuple(flags))
    folder = Path(directory or cache_dir()) / key

    def generate(tmp: Path) -> Path:
        if progress:
            print(f"[wbmpc.solver.codegen] generating C for {ocp.n_nodes} nodes ({key}) ...", flush=True)
        generator = ca.CodeGenerator("wbmpc_nlp.c", {"with_header": True})
        for function in nlp_functions(ocp):
            generator.add(function)
        generator.generate(str(tmp) + os.sep)
        return tmp / "wbmpc_nlp.c"

    return build_in(folder, key, description, tuple(flags), generate, progress, force)


def cached(ocp: OCP, flags: tuple[str, ...], directory: Path | None = None) -> CompiledNLP | None:
    """The valid cached library of ``ocp`` built with ``flags``, or ``None`` (nothing is built)."""
    key, _ = cache_key(ocp, tuple(flags))
    folder = Path(directory or cache_dir()) / key
    library, record = folder / "libwbmpc_nlp.so", folder / "build.json"
    if not _valid(library, record):
        return None
    info = json.loads(record.read_text())
    return CompiledNLP(library, key, info["build_s"], info["build_peak_mb"], info["c_bytes"], False)


def build_in(
    folder: Path,
    key: str,
    description: dict,
    flags: tuple[str, ...],
    generate,
    progress: bool = True,
    force: bool = False,
) -> CompiledNLP:
    """Compile the C that ``generate(tmp) -> c_file`` writes into the key folder ``folder``, or reuse it.

    The part of :func:`build` that needs no OCP, so that a background process can compile the C an earlier
    build kept (``folder``'s ``wbmpc_nlp.c``) with other flags (:mod:`wbmpc.solver.release`).
    """
    folder = Path(folder)

    def compile_into(tmp: Path) -> tuple[Path, dict]:
        c_file = Path(generate(tmp))
        c_bytes = c_file.stat().st_size
        peak_mb = _compile(c_file, tmp / "lib.so", flags, progress, c_bytes)
        if c_file.resolve() != (folder / "wbmpc_nlp.c").resolve():
            shutil.copy(c_file, folder / "wbmpc_nlp.c")
            shutil.copy(c_file.with_suffix(".h"), folder / "wbmpc_nlp.h")
        return tmp / "lib.so", {"build_peak_mb": peak_mb, "c_bytes": c_bytes}

    info, rebuilt = locked_build(folder / "libwbmpc_nlp.so", key, description, compile_into, _valid, force)
    library = folder / "libwbmpc_nlp.so"
    if progress and rebuilt:
        print(
            f"[wbmpc.solver.codegen] built {library} in {info['build_s']:.0f} s "
            f"(gcc peak {info['build_peak_mb']:.0f} MB)",
            flush=True,
        )
    return CompiledNLP(library, key, info["build_s"], info["build_peak_mb"], info["c_bytes"], rebuilt)


def locked_build(
    library: Path, key: str, description: dict, compile_into, valid, force: bool = False
) -> tuple[dict, bool]:
    """``library`` from its cache folder, or built by ``compile_into(tmp) -> (built file, record fields)``
    and moved there atomically, under the folder's file lock (one build of a key at a time, also across
    processes; the lock goes with the process however it ends). Temporary folders of killed builds are
    removed on the way (:func:`remove_stale_builds`). Every compiled library of the cache is built here.

    Args:
        library: Where the library lives (its folder is the key folder, with ``build.json`` beside it).
        key, description: The cache key and what it was computed from (written into the record).
        compile_into: Builds into the temporary folder it is given; returns the built file and extra
            record fields.
        valid: ``valid(library, record) -> bool``: a cached library that can be used as it is.
        force: Rebuild even if a valid library is cached.

    Returns:
        The build record (``build_s`` [s], ``library_sha256``, the extra fields) and whether it was built now.
    """
    folder = Path(library).parent
    folder.mkdir(parents=True, exist_ok=True)
    record = folder / "build.json"
    with open(folder / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes, also when the process dies
        remove_stale_builds(folder.parent, locked=folder)
        if not force and valid(library, record):
            return json.loads(record.read_text()), False
        start = time.perf_counter()
        with tempfile.TemporaryDirectory(prefix=f"{_TMP_PREFIX}{os.getpid()}-", dir=folder) as tmp:
            built, extra = compile_into(Path(tmp))
            os.replace(built, library)  # atomic: readers never see a half-written library
        info = {
            **description,
            "key": key,
            "build_s": time.perf_counter() - start,
            **extra,
            "library_sha256": _sha256(library),
        }
        record.write_text(json.dumps(info, indent=2))
        return info, True


def remove_stale_builds(directory: Path | None = None, locked: Path | None = None) -> list[Path]:
    """Delete the temporary folders that killed builds left in the cache.

    A build creates its temporary folder inside its key folder while it holds that folder's lock, and the
    lock is released when the process ends, however it ends. So a temporary folder in a key folder whose
    lock can be taken belongs to a dead build; a live build's folder is never touched (its lock is held).

    Args:
        directory: Cache folder (default :func:`cache_dir`).
        locked: A key folder whose lock the caller already holds (its temporary folders are all stale).

    Returns:
        The folders removed.
    """
    root = Path(directory or cache_dir())
    removed = []
    for folder in sorted(root.iterdir()) if root.is_dir() else []:
        try:
            if not (folder / ".lock").is_file():
                continue  # not a key folder
            stale = [
                path
                for path in folder.iterdir()
                if path.is_dir() and path.name.startswith((_TMP_PREFIX, _LEGACY_TMP_PREFIX))
            ]
        except OSError:  # removed meanwhile by someone else
            continue
        if not stale:
            continue
        if locked is not None and folder.resolve() == Path(locked).resolve():
            removed += _remove(stale)
            continue
        with open(folder / ".lock", "a") as lock:
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                continue  # a build of this key is running
            removed += _remove(stale)
    return removed


def _remove(paths: list[Path]) -> list[Path]:
    for path in paths:
        shutil.rmtree(path, ignore_errors=True)
    return [path for path in paths if not path.exists()]


def _valid(library: Path, record: Path) -> bool:
    if not (library.is_file() and record.is_file()):
        return False
    try:
        if json.loads(record.read_text()).get("library_sha256") != _sha256(library):
            return False
        ca.external("nlp_hess_l", str(library))
    except (ValueError, RuntimeError, OSError):
        return False
    return True


def _compile(c_file: Path, output: Path, flags, progress: bool, c_bytes: int) -> float:
    """Run gcc, return its peak resident memory [MB] (from wait4); show elapsed time while it runs."""
    command = ["gcc", *flags, "-shared", "-fPIC", str(c_file), "-o", str(output)]
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    bar, start, last = None, time.perf_counter(), 0.0
    desc = f"gcc {' '.join(flags)} ({c_bytes / 1e6:.1f} MB of C)"
    if progress and sys.stderr.isatty():
        from tqdm.auto import tqdm

        bar = tqdm(desc=desc, bar_format="{desc}: {elapsed}")
    while True:
        pid, status, usage = os.wait4(process.pid, os.WNOHANG)
        if pid:
            break
        time.sleep(0.5)
        if bar is not None:
            bar.refresh()
        elif progress and time.perf_counter() - last > 15.0:  # no terminal: a line every 15 s
            last = time.perf_counter()
            print(f"[wbmpc.solver.codegen] {desc}: {last - start:.0f} s", flush=True)
    process.returncode = os.waitstatus_to_exitcode(status)
    stderr = process.stderr.read().decode(errors="replace")
    process.stderr.close()
    if bar is not None:
        bar.close()
    if process.returncode != 0:
        raise RuntimeError(f"compiling {c_file} failed:\n{stderr[-2000:]}")
    return usage.ru_maxrss / 1024  # kB on Linux


def _sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _compiler_version() -> str:
    try:
        return subprocess.run(
            ["gcc", "--version"], capture_output=True, text=True, check=True
        ).stdout.splitlines()[0]
    except (OSError, subprocess.CalledProcessError):
        return "gcc not found"
