"""Deployment artefact: the whole Fatrop solve as a C shared library, a header and a layout description.

:func:`export` writes, into one folder:

* ``libwbmpc_nlp.so`` / ``wbmpc_nlp.h``: the compiled NLP functions (:mod:`wbmpc.solver.codegen`, cached);
* ``wbmpc_solver.c`` / ``.h`` / ``libwbmpc_solver.so``: CasADi's generated Fatrop solver calling them,
  linked against the Fatrop and Blasfeo libraries shipped in the casadi wheel;
* ``layout.json``: the solver inputs (``x0, p, lbx, ubx, lbg, ubg, lam_x0, lam_g0``) and outputs with their
  sizes, the parameter blocks (offset, shape, column-major), the per-stage variable layout and the
  constant constraint bounds: everything a C/C++ caller needs to fill the inputs;
* ``solve_once.c``: a small C program that reads the inputs from a binary file, solves and writes ``x``.

Everything that is a runtime parameter in Python stays one in C: weights, commands, schedule, time steps,
initial state and the primal warm start.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import casadi as ca
import numpy as np

from wbmpc.ocp import OCP
from wbmpc.solver import codegen
from wbmpc.solver.nlpsol import TOL, WARM_MAX_ITER, WARM_MU_INIT, make_nlpsol, solver_options

SOLVER_NAME = "wbmpc_solver"


def casadi_dir() -> Path:
    """Folder of the casadi wheel (Fatrop/Blasfeo libraries; headers under ``include``)."""
    return Path(ca.__file__).resolve().parent


def layout(ocp: OCP, solver: ca.Function) -> dict:
    """Machine-readable description of the solver's inputs, outputs and the OCP layout."""
    blocks = [
        {"name": name, "offset": start, "rows": rows, "cols": cols, "order": "column-major"}
        for name, (start, (rows, cols)) in ocp.params.blocks.items()
    ]
    form = ocp.formulation
    stages = []
    for s in ocp.stages:
        entry = {
            "node": s.k,
            "x_offset": s.x_offset,
            "nx": s.nx,
            "nu": s.nu,
            # Node 0's state is the measurement (parameters q_hat, v_hat) unless the layout pins it.
            "x": _ranges(form.state_blocks()) if s.nx else {},
        }
        if s.u_offset is not None:
            entry["u_offset"] = s.u_offset
            entry["u"] = _ranges(form.input_blocks(s.has_torque))
        stages.append(entry)
    return {
        "solver": SOLVER_NAME,
        "robot": ocp.robot.name,
        "formulation": ocp.settings.formulation,
        "nodes": ocp.n_nodes,
        "n_tau_nodes": ocp.settings.n_tau_nodes,
        "n_variables": ocp.n_variables,
        "n_constraints": ocp.n_constraints,
        "n_parameters": ocp.params.size,
        "inputs": [{"name": solver.name_in(i), "size": solver.numel_in(i)} for i in range(solver.n_in())],
        "outputs": [{"name": solver.name_out(i), "size": solver.numel_out(i)} for i in range(solver.n_out())],
        "parameters": blocks,
        "stages": stages,
        "contact_frames": list(ocp.robot.contact_frames),
        "joint_names": ocp.robot.joint_names,
        "lbg": [float(v) if np.isfinite(v) else None for v in ocp.lbg],
        "ubg": [float(v) if np.isfinite(v) else None for v in ocp.ubg],
        "units": "SI: m, rad, s, N, N m; forces on the robot in world axes",
    }


def _ranges(blocks: list[tuple[str, int]]) -> dict[str, list[int]]:
    """``{block: [start, stop]}`` offsets within a stage's state or input vector."""
    out, i = {}, 0
    for name, n in blocks:
        out[name] = [i, i + n]
        i += n
    return out


def export(
    ocp: OCP,
    directory: Path,
    options: dict | None = None,
    flags: tuple[str, ...] = ("-O1",),
    nlp_flags: tuple[str, ...] = codegen.DEFAULT_FLAGS,
) -> Path:
    """Write the deployment folder of an OCP's Fatrop solve and build ``libwbmpc_solver.so``.

    Args:
        ocp: The OCP (:class:`~wbmpc.ocp.OCP`).
        directory: Output folder (created).
        options: Fatrop's ``nlpsol`` options (:func:`wbmpc.solver.nlpsol.solver_options`); ``None``: the
            warm start of the MPC's defaults (those of an MPC: ``mpc.solver_options(cold=False)``).
        flags: gcc flags of the solver library.
        nlp_flags: gcc flags of the compiled NLP functions (:func:`wbmpc.solver.codegen.build`, cached; an
            MPC's are ``mpc.solver_settings.compile_flags``).

    Returns:
        The folder.

    Raises:
        ValueError: options of another solver than Fatrop.
    """
    if options is None:
        options = solver_options(
            "fatrop", tol=TOL, max_iter=WARM_MAX_ITER, mu_init=WARM_MU_INIT, warm=True, equality=ocp.equality
        )
    if "fatrop" not in options:
        raise ValueError(f"export needs Fatrop's options (solver_options('fatrop', ...)), got {options!r}")
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    nlp = codegen.build(ocp, tuple(nlp_flags), progress=False).library
    solver = make_nlpsol(SOLVER_NAME, "fatrop", ocp.nlp, options, nlp, n_nodes=ocp.n_nodes)
    shutil.copy(nlp, directory / "libwbmpc_nlp.so")
    shutil.copy(nlp.parent / "wbmpc_nlp.h", directory / "wbmpc_nlp.h")
    cwd = os.getcwd()
    try:  # CodeGenerator writes into the current folder
        os.chdir(directory)
        solver.generate(f"{SOLVER_NAME}.c", {"with_header": True})
    finally:
        os.chdir(cwd)
    shutil.copy(Path(__file__).parent / "c" / "solve_once.c", directory / "solve_once.c")
    (directory / "layout.json").write_text(json.dumps(layout(ocp, solver), indent=1))
    lib_dir = casadi_dir()
    _run(
        [
            "gcc",
            *flags,
            "-shared",
            "-fPIC",
            f"{SOLVER_NAME}.c",
            "-o",
            f"lib{SOLVER_NAME}.so",
            f"-I{lib_dir / 'include'}",
            "-L.",
            "-lwbmpc_nlp",
            f"-L{lib_dir}",
            "-lfatrop",
            "-lblasfeo",
            f"-Wl,-rpath,$ORIGIN:{lib_dir}",
        ],
        directory,
    )
    return directory


def build_example(directory: Path) -> Path:
    """Compile ``solve_once.c`` against the exported solver; returns the executable."""
    directory = Path(directory)
    _run(
        [
            "gcc",
            "-O1",
            "solve_once.c",
            "-I.",
            "-L.",
            f"-l{SOLVER_NAME}",
            "-o",
            "solve_once",
            "-Wl,-rpath,$ORIGIN",
        ],
        directory,
    )
    return directory / "solve_once"


def write_inputs(path: Path, values: list[np.ndarray]) -> None:
    """Write solver inputs as consecutive float64 arrays (the format ``solve_once`` reads)."""
    np.concatenate([np.ravel(np.asarray(v, dtype=float)) for v in values]).tofile(path)


def _run(command: list[str], cwd: Path) -> None:
    result = subprocess.run(command, cwd=cwd, capture_output=True, text=True)
    if result.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed:\n{result.stderr[-3000:]}")
