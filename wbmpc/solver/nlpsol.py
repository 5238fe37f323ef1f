"""The NLP solvers: Fatrop's and IPOPT's options for cold and warm starts, an OCP's ``casadi.nlpsol``.

Both the MPC (:class:`~wbmpc.control.mpc.WholeBodyMPC`) and the deployment artefact
(:func:`wbmpc.solver.deploy.export`) build their solvers here, so a deployed solver has the options of the
one the MPC runs.
"""

from __future__ import annotations

from pathlib import Path

import casadi as ca

from wbmpc import checks
from wbmpc.solver import blasfeo

__all__ = [
    "SOLVERS",
    "TOL",
    "WARM_MAX_ITER",
    "WARM_MU_INIT",
    "check_library",
    "make_nlpsol",
    "solver_options",
]

SOLVERS = ("fatrop", "ipopt")
#: Defaults of a warm-started solve (the MPC's :class:`~wbmpc.control.config.MPCConfig` takes them from here).
TOL = 1e-3  # the paper's tolerance
WARM_MAX_ITER = 30
WARM_MU_INIT = 1e-4


def solver_options(
    solver: str, *, tol: float, max_iter: int, mu_init: float, warm: bool, equality=None
) -> dict:
    """``casadi.nlpsol`` options of a cold or warm-started solve.

    Args:
        solver: ``"fatrop"`` or ``"ipopt"``.
        tol: Convergence tolerance (the paper's 1e-3).
        max_iter: Iteration cap (>= 1).
        mu_init: Initial barrier parameter (> 0): small for a warm start that is already near the optimum.
        warm: Warm-start options (Fatrop: bound push 1e-7; IPOPT: ``warm_start_init_point`` with its
            pushes at 1e-7), else cold-start ones.
        equality: Fatrop only: the per-constraint equality flags of the OCP (``OCP.equality``), for its
            structure detection.

    Returns:
        The options dict (printing off).

    Raises:
        ValueError: an unknown solver, a tolerance or barrier parameter <= 0, an iteration cap < 1.
    """
    if solver not in SOLVERS:
        raise ValueError(f"solver must be one of {SOLVERS}, got {solver!r}")
    checks.number("tol", tol, low=0.0, low_open=True)
    checks.number("mu_init", mu_init, low=0.0, low_open=True)
    checks.integer("max_iter", max_iter, low=1)
    if solver == "fatrop":
        inner = {"print_level": 0, "tol": tol, "max_iter": int(max_iter), "mu_init": mu_init}
        if warm:
            # The casadi 3.8.2 Fatrop plugin accepts bound_push but not the warm_start_* options.
            inner["bound_push"] = 1e-7
        opts = {"structure_detection": "auto", "print_time": False, "fatrop": inner}
        if equality is not None:
            opts["equality"] = equality
        return opts
    ipopt = {"print_level": 0, "tol": tol, "max_iter": int(max_iter), "mu_init": mu_init, "sb": "yes"}
    if warm:
        ipopt |= {
            "warm_start_init_point": "yes",
            "warm_start_bound_push": 1e-7,
            "warm_start_mult_bound_push": 1e-7,
        }
    return {"print_time": False, "ipopt": ipopt}


def make_nlpsol(
    name: str, solver: str, nlp, options: dict, library: Path | None = None, n_nodes: int | None = None
) -> ca.Function:
    """The ``casadi.nlpsol`` of an NLP, in process or from its compiled library.

    The process's BLASFEO is chosen first (:func:`wbmpc.solver.blasfeo.activate`), before casadi opens its
    Fatrop plugin.

    Args:
        name: Function name.
        solver: ``"fatrop"`` or ``"ipopt"``.
        nlp: The CasADi NLP dict (``OCP.nlp``); expanded to SX when solved in process.
        options: :func:`solver_options`.
        library: The compiled NLP functions (:func:`wbmpc.solver.codegen.build`), or ``None`` to solve in
            process.
        n_nodes: The horizon of ``nlp`` (named when ``library`` was compiled for another one).

    Raises:
        ValueError: ``library`` does not load, or was compiled for an NLP of other sizes (another horizon,
            robot or settings); the message names the file, both horizons and how to rebuild.
    """
    if solver == "fatrop":
        blasfeo.activate()
    if library is not None:
        check_library(library, nlp, n_nodes)
        return ca.nlpsol(name, solver, str(library), options)
    return ca.nlpsol(name, solver, nlp, {**options, "expand": True})


def check_library(library: Path, nlp, n_nodes: int | None = None) -> None:
    """Check that a compiled NLP library holds the functions of ``nlp`` (same variable, parameter and
    constraint counts), before CasADi meets the mismatch as an option-length error.

    The horizon the library was built for is read from the build record next to it (``build.json``,
    :func:`wbmpc.solver.codegen.build`), when there is one.

    Raises:
        ValueError: naming the file, the cached and the requested horizon, and the fix.
    """
    library = Path(library)
    if not library.is_file():
        raise FileNotFoundError(
            f"no compiled NLP library at {library}: build it with wbmpc.solver.codegen.build(ocp) "
            "(SolverSettings(compiled=True) does)"
        )
    try:
        compiled = ca.external("nlp", str(library))
    except RuntimeError as exc:
        raise ValueError(
            f"the compiled NLP library {library} does not load ({str(exc).strip().splitlines()[-1]}): "
            "rebuild it (wbmpc.solver.codegen.build(ocp, force=True)) or delete its cache folder"
        ) from None
    sizes = {"x": compiled.numel_in(0), "p": compiled.numel_in(1), "g": compiled.numel_out(1)}
    wanted = {key: int(nlp[key].numel()) for key in sizes}
    if sizes == wanted:
        return
    cached = _recorded_nodes(library)
    names = {"x": "variables", "p": "parameters", "g": "constraints"}
    differ = ", ".join(
        f"{sizes[k]} {names[k]} (this OCP: {wanted[k]})" for k in sizes if sizes[k] != wanted[k]
    )
    horizon = f"N = {cached} nodes" if cached is not None else "another problem (no build.json beside it)"
    requested = f"N = {n_nodes} nodes" if n_nodes is not None else "this OCP"
    raise ValueError(
        f"the compiled NLP library {library} was built for {horizon}, not for {requested}: it has {differ}. "
        "Rebuild it for this OCP (wbmpc.solver.codegen.build(ocp, force=True); SolverSettings(compiled=True) "
        f"builds its own), or clear the cache (delete {library.parent}; the cache is "
        "$WBMPC_CACHE_DIR or <repo>/.wbmpc_cache)"
    )


def _recorded_nodes(library: Path) -> int | None:
    import json

    try:
        return int(json.loads((library.parent / "build.json").read_text())["ocp_settings"]["n_nodes"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
