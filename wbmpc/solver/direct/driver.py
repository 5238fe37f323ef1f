"""The direct Fatrop driver loaded with ctypes: one call from parameters and a warm start to a solution.

:class:`DirectFatrop` builds (or reuses) the library of an OCP (:func:`wbmpc.solver.direct.build.build`),
creates Fatrop's algorithm once and solves with :meth:`DirectFatrop.solve`. The call runs entirely in C++
(ctypes releases the GIL for it). Inputs and outputs are in the NLP's order (``OCP.nlp``: the primal ``w``,
the constraint multipliers ``lam_g``), so the casadi-plugin path's vectors can be passed as they are; the
bound multipliers of the inequality rows (``z_l``, ``z_u``, Fatrop's own, which the plugin does not expose)
are in the order of :attr:`DirectFatrop.ineq_rows`.

Example:
    >>> solver = DirectFatrop(ocp)
    >>> result = solver.solve(p, w0)                    # cold duals, like the plugin
    >>> warm = solver.solve(p2, result.w, duals=result)  # primal-dual warm start
"""

from __future__ import annotations

import ctypes
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from wbmpc import checks
from wbmpc.ocp import OCP
from wbmpc.solver import blasfeo
from wbmpc.solver.direct import build as direct_build
from wbmpc.solver.direct.problem import KINDS, stage_layouts
from wbmpc.solver.statuses import FATROP_FLAGS

_DOUBLE_P = ctypes.POINTER(ctypes.c_double)
_INT_P = ctypes.POINTER(ctypes.c_int)
N_REPORT = 10
MAX_THREADS = 8  # fatrop_direct.cpp's MAX_THREADS


@dataclass
class DirectResult:
    """One solve of the direct driver.

    Attributes:
        w: Primal solution (n_variables,), the NLP's order.
        lam_g: Constraint multipliers (n_constraints,), the NLP's order and sign (as ``nlpsol``'s).
        z_l, z_u: Bound multipliers of the inequality rows (n_ineq,), :attr:`DirectFatrop.ineq_rows` order.
        g: Constraint values at ``w`` (n_constraints,).
        flag: Fatrop's return flag (``IpSolverReturnFlag``: 0 success, ...; -1 an exception).
        status, reason: Named status (:data:`wbmpc.solver.statuses.FATROP_FLAGS`) and its sentence.
        success: Converged to the tolerance with a finite primal.
        iterations: Fatrop's iteration count.
        mu: Barrier parameter at the end [-].
        timings: Seconds: ``wall`` (the C call), ``fatrop`` (Fatrop's optimize), ``initialization``,
            ``search_direction``, ``hessian``, ``jacobian``, ``residuals``, ``objective``.
    """

    w: np.ndarray
    lam_g: np.ndarray
    z_l: np.ndarray
    z_u: np.ndarray
    g: np.ndarray
    flag: int
    status: str
    reason: str
    success: bool
    iterations: int
    mu: float
    timings: dict


class DirectFatrop:
    """Fatrop driven directly over the OCP's stage functions, with a primal-dual warm start.

    Args:
        ocp: The problem (its stage definitions give the functions; its ``lbg``/``ubg`` the bounds).
        tol: Fatrop's convergence tolerance (the plugin path's ``tol``).
        max_iter: Iteration cap (>= 1).
        bound_push: Fatrop's ``bound_push`` (the plugin path's warm start uses 1e-7).
        flags: gcc flags of the generated stage functions (cache key).
        library: A built library (else :func:`wbmpc.solver.direct.build.build` builds or reuses one).
        progress: Print build progress.
        compiled: Compiled stage functions (generated C, built per problem and flags); False: the same
            functions serialized and evaluated by CasADi's virtual machine inside the driver
            (:func:`~wbmpc.solver.direct.build.build_vm`, built once in seconds: no problem to compile).
        threads: Threads that evaluate the stages' Hessians, Jacobians and residuals at once (1..8; 1 is
            the caller's thread only). The result does not depend on it.

    Raises:
        ValueError: not an OCP, flags that are not strings, a tolerance or bound push <= 0, an iteration
            cap < 1, threads outside 1..8, a library that does not load or a driver that cannot be
            created (the reason).
        FileNotFoundError, RuntimeError: the build's (no Fatrop in the wheel or no compiler; a compiler
            error).
    """

    def __init__(
        self,
        ocp: OCP,
        *,
        tol: float = 1e-3,
        max_iter: int = 30,
        bound_push: float = 1e-7,
        flags: tuple[str, ...] = direct_build.DEFAULT_FLAGS,
        library: Path | None = None,
        progress: bool = True,
        compiled: bool = True,
        threads: int = 1,
    ):
        if not isinstance(ocp, OCP):
            raise ValueError(f"ocp must be a wbmpc.ocp.OCP, got {ocp!r}")
        flags = checks.names("flags", flags, unique=False)
        checks.number("tol", tol, low=0.0, low_open=True)
        checks.integer("max_iter", max_iter, low=1)
        checks.number("bound_push", bound_push, low=0.0, low_open=True)
        checks.integer("threads", threads, low=1, high=MAX_THREADS)
        blasfeo.activate()  # the process's BLASFEO before libfatrop is mapped (as the plugin path)
        self.ocp = ocp
        self.compiled = bool(compiled)
        self.layouts = stage_layouts(ocp)
        built = None
        functions = b""
        if not self.compiled:
            functions = str(direct_build.functions_file(ocp)).encode()
        if library is None:
            if self.compiled:
                built = direct_build.build(ocp, tuple(flags), progress=progress)
            else:
                built = direct_build.build_vm(progress=progress)
            library = built.library
        self.built = built
        self.library_path = Path(library)
        try:
            self._lib = ctypes.CDLL(str(self.library_path))
        except OSError as exc:
            raise ValueError(f"the direct Fatrop library {library} does not load: {exc}") from None
        self._declare()
        self.n_w, self.n_g, self.n_p = ocp.n_variables, ocp.n_constraints, ocp.params.size
        lay = self.layouts
        ints = {
            name: np.array([getattr(s, name) for s in lay], dtype=np.intc)
            for name in ("nx", "nu", "n_dyn", "w_offset", "g_offset")
        }
        n_eq = np.array([s.eq_rows.size for s in lay], np.intc)
        n_ineq = np.array([s.ineq_rows.size for s in lay], np.intc)
        kind = np.array([KINDS.index(s.kind) for s in lay], np.intc)
        eq_rows = np.concatenate([s.eq_rows for s in lay]).astype(np.intc)
        self.ineq_rows = np.concatenate([s.ineq_rows for s in lay]).astype(np.intc)
        eq_const = np.ascontiguousarray(ocp.lbg[eq_rows], float)
        lower = np.ascontiguousarray(ocp.lbg[self.ineq_rows], float)
        upper = np.ascontiguousarray(ocp.ubg[self.ineq_rows], float)
        n_s = sum(ocp.stage_parameter_sizes().values())
        err = ctypes.create_string_buffer(512)
        self._keep = [ints, n_eq, n_ineq, kind, eq_rows, eq_const, lower, upper]  # alive for the call
        handle = self._lib.wbmpc_direct_create(
            len(lay),
            _ip(ints["nx"]),
            _ip(ints["nu"]),
            _ip(ints["n_dyn"]),
            _ip(n_eq),
            _ip(n_ineq),
            _ip(kind),
            _ip(ints["w_offset"]),
            _ip(ints["g_offset"]),
            _ip(eq_rows),
            _dp(eq_const),
            _ip(self.ineq_rows),
            _dp(lower),
            _dp(upper),
            self.n_w,
            self.n_g,
            self.n_p,
            n_s,
            functions,
            err,
            len(err),
        )
        if not handle:
            raise ValueError(f"the direct Fatrop driver could not be created: {err.value.decode()}")
        self._handle = ctypes.c_void_p(handle)
        self.n_ineq = int(self._lib.wbmpc_direct_n_ineq(self._handle))
        self.threads = 1
        self.set_threads(threads)
        self.tol, self.max_iter = float(tol), int(max_iter)
        self.options: dict[str, float | int] = {}  # what set_option last set
        self.set_option("tol", float(tol))
        self.set_option("max_iter", int(max_iter))
        self.set_option("bound_push", float(bound_push))
        # Output buffers, reused (the caller gets copies).
        self._w = np.zeros(self.n_w)
        self._lam = np.zeros(self.n_g)
        self._g = np.zeros(self.n_g)
        self._zl = np.zeros(self.n_ineq)
        self._zu = np.zeros(self.n_ineq)
        self._report = np.zeros(N_REPORT)
        #: The last converged result an owner keeps for its next warm start (wbmpc.solver.direct.adapter).
        self.last: DirectResult | None = None

    def _declare(self) -> None:
        lib = self._lib
        lib.wbmpc_direct_create.restype = ctypes.c_void_p
        lib.wbmpc_direct_create.argtypes = (
            [ctypes.c_int]
            + [_INT_P] * 9
            + [
                _DOUBLE_P,
                _INT_P,
                _DOUBLE_P,
                _DOUBLE_P,
                ctypes.c_int,
                ctypes.c_int,
                ctypes.c_int,
                ctypes.c_int,
                ctypes.c_char_p,
                ctypes.c_char_p,
                ctypes.c_int,
            ]
        )
        lib.wbmpc_direct_set_threads.argtypes = [ctypes.c_void_p, ctypes.c_int]
        lib.wbmpc_direct_set_option_double.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_double]
        lib.wbmpc_direct_set_option_int.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_int]
        lib.wbmpc_direct_n_ineq.argtypes = [ctypes.c_void_p]
        lib.wbmpc_direct_last_error.argtypes = [ctypes.c_void_p]
        lib.wbmpc_direct_last_error.restype = ctypes.c_char_p
        lib.wbmpc_direct_solve.argtypes = [
            ctypes.c_void_p,
            _DOUBLE_P,
            _DOUBLE_P,
            ctypes.c_double,
            ctypes.c_int,
        ] + [_DOUBLE_P] * 9
        lib.wbmpc_direct_solve.restype = ctypes.c_int
        lib.wbmpc_direct_destroy.argtypes = [ctypes.c_void_p]

    def set_threads(self, threads: int) -> None:
        """Evaluate the stages on ``threads`` threads (1..8) from the next solve on.

        Raises:
            ValueError: ``threads`` outside 1..8.
        """
        checks.integer("threads", threads, low=1, high=MAX_THREADS)
        if self._lib.wbmpc_direct_set_threads(self._handle, int(threads)):
            raise ValueError(self._lib.wbmpc_direct_last_error(self._handle).decode())
        self.threads = int(threads)

    def set_option(self, name: str, value: float | int) -> None:
        """Set one of Fatrop's options (``tol``, ``max_iter``, ``bound_push``, ``mu_init``, ...) or the warm
        start's ``mult_floor`` (the smallest bound multiplier it starts from).

        Raises:
            ValueError: an option Fatrop does not know, or a value of the wrong type.
        """
        is_int = isinstance(value, int | np.integer) and not isinstance(value, bool)
        setter = self._lib.wbmpc_direct_set_option_int if is_int else self._lib.wbmpc_direct_set_option_double
        if setter(self._handle, name.encode(), value if is_int else float(value)):
            raise ValueError(
                f"Fatrop option {name}={value!r}: {self._lib.wbmpc_direct_last_error(self._handle).decode()}"
            )
        self.options[name] = value
        if name == "max_iter":
            self.max_iter = int(value)

    def solve(
        self,
        p: np.ndarray,
        w0: np.ndarray,
        *,
        mu_init: float = 1e-4,
        duals: DirectResult | None = None,
        lam_g0: np.ndarray | None = None,
        z_l0: np.ndarray | None = None,
        z_u0: np.ndarray | None = None,
    ) -> DirectResult:
        """One solve from the parameters ``p`` and the initial primal ``w0``.

        Args:
            p: Parameter vector (``OCP.params.size``,).
            w0: Initial primal guess (``n_variables``,), the NLP's order.
            mu_init: Initial barrier parameter (> 0).
            duals: A previous result whose multipliers start this solve (equality, inequality and bound
                multipliers: no least-squares initialisation); or give ``lam_g0``, ``z_l0`` and ``z_u0``.
                None of them: Fatrop's default dual start (bound multipliers 1, least squares).

        Returns:
            The result; a failed solve has ``success`` False and a named status, never raises.

        Raises:
            ValueError: wrong shapes or non-finite inputs, ``mu_init`` <= 0, partial duals.
        """
        start = time.perf_counter()
        p = _vector("p", p, self.n_p)
        w0 = _vector("w0", w0, self.n_w)
        checks.number("mu_init", mu_init, low=0.0, low_open=True)
        if duals is not None:
            lam_g0, z_l0, z_u0 = duals.lam_g, duals.z_l, duals.z_u
        given = [v is not None for v in (lam_g0, z_l0, z_u0)]
        if any(given) and not all(given):
            raise ValueError("a dual warm start needs lam_g0, z_l0 and z_u0 together (or duals=result)")
        warm = all(given)
        if warm:
            lam_g0 = _vector("lam_g0", lam_g0, self.n_g)
            z_l0 = _vector("z_l0", z_l0, self.n_ineq)
            z_u0 = _vector("z_u0", z_u0, self.n_ineq)
        else:
            lam_g0, z_l0, z_u0 = self._lam, self._zl, self._zu  # unused by the driver
        flag = self._lib.wbmpc_direct_solve(
            self._handle,
            _dp(p),
            _dp(w0),
            float(mu_init),
            int(warm),
            _dp(lam_g0),
            _dp(z_l0),
            _dp(z_u0),
            _dp(self._w),
            _dp(self._lam),
            _dp(self._zl),
            _dp(self._zu),
            _dp(self._g),
            _dp(self._report),
        )
        wall = time.perf_counter() - start
        report = self._report
        if flag == -1:
            status = "solver_exception"
            reason = (
                f"the direct Fatrop driver raised: {self._lib.wbmpc_direct_last_error(self._handle).decode()}"
            )
        elif flag in FATROP_FLAGS:
            status, reason = FATROP_FLAGS[flag]
        else:
            status, reason = f"fatrop_status_{flag}", f"Fatrop returned the unknown flag {flag}."
        w = self._w.copy()
        success = flag == 0 and checks.all_finite(w)
        if flag == 0 and not success:
            status, reason = "non_finite_solution", "the solver returned NaN or inf"
        timings = {
            "wall": wall,
            "fatrop": float(report[3]),
            "initialization": float(report[4]),
            "search_direction": float(report[5]),
            "hessian": float(report[6]),
            "jacobian": float(report[7]),
            "residuals": float(report[8]),
            "objective": float(report[9]),
        }
        return DirectResult(
            w=w,
            lam_g=self._lam.copy(),
            z_l=self._zl.copy(),
            z_u=self._zu.copy(),
            g=self._g.copy(),
            flag=int(flag),
            status=status,
            reason="" if success else reason,
            success=success,
            iterations=int(report[1]) if flag != -1 else -1,
            mu=float(report[2]),
            timings=timings,
        )

    def __del__(self):
        handle = getattr(self, "_handle", None)
        if handle is not None and handle.value:
            self._lib.wbmpc_direct_destroy(handle)
            self._handle = None


def _vector(name: str, value, n: int) -> np.ndarray:
    array = np.ascontiguousarray(np.asarray(value, dtype=float).ravel())
    if array.shape != (n,):
        raise ValueError(f"{name} must have {n} entries, got shape {np.shape(value)}")
    if not checks.all_finite(array):
        raise ValueError(f"{name} contains NaN or inf")
    return array


def _dp(array: np.ndarray):
    return array.ctypes.data_as(_DOUBLE_P)


def _ip(array: np.ndarray):
    return array.ctypes.data_as(_INT_P)
