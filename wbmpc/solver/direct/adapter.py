"""The direct driver behind :class:`~wbmpc.control.mpc.WholeBodyMPC`: an object called like its ``nlpsol``.

``SolverSettings(direct=True)`` (and the default in process) makes :meth:`WholeBodyMPC.make_solver` return
a :class:`DirectNlpsol` instead of the casadi-plugin ``nlpsol``. It takes the same keyword arguments
(``x0``, ``p``, ``lbg``, ``ubg``, ``lam_g0``), returns the same outputs (``x``, ``g``, ``lam_g``, ``f``)
and has a ``stats()`` in the plugin's format (``success``, ``return_status``, ``iter_count``,
``fatrop.return_flag`` and its timings), so the MPC's convergence test, named statuses
(:func:`wbmpc.solver.statuses.solver_status`), cold retry and fallbacks run unchanged.

The warm start the MPC passes (``lam_g0``, the last converged plan's multipliers) is completed here with
that solve's bound multipliers and final barrier parameter, which the plan does not carry: the cold,
warm and retry solvers of one MPC share one driver, and it remembers them for the ``lam_g`` it returned.
An ``lam_g0`` it did not return (another solver's) starts the duals as Fatrop does (as the plugin).

The plugin path stays the fallback: if the driver cannot be built (no g++, an unusable library), the MPC
gets the plugin's ``nlpsol`` (compiled or in process, as the settings say) with a warning; a solve in which
the driver raises is solved by the plugin.
"""

from __future__ import annotations

import warnings
import weakref

import numpy as np

from wbmpc.solver import codegen
from wbmpc.solver.direct.driver import DirectFatrop, DirectResult
from wbmpc.solver.nlpsol import make_nlpsol

#: Fatrop's default ``bound_push`` (``IpInitializer``), what the plugin's cold solves run with.
FATROP_BOUND_PUSH = 1e-2
# One driver per MPC, shared by its cold, warm and retry solvers (the Fatrop algorithm is built once).
_DRIVERS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


class DirectNlpsol:
    """One of an MPC's solvers (cold, warm or the cold retry) on the direct driver.

    Args:
        mpc: The MPC (its OCP, solver settings and options).
        name: Name (of the plugin fallback).
        cold: Cold-start settings (iteration cap, initial barrier parameter) instead of warm ones.
        max_iter: Iteration cap (default: the settings' for ``cold``).
        driver: The shared driver.
    """

    def __init__(self, mpc, name: str, cold: bool, max_iter: int | None, driver: DirectFatrop):
        # Fatrop's options of the plugin solver this one stands for (wbmpc.solver.nlpsol.solver_options).
        fatrop = mpc.solver_options(cold, max_iter)["fatrop"]
        self.mpc, self.name, self.cold = mpc, name, cold
        self.max_iter = int(fatrop["max_iter"])
        self.mu_init = float(fatrop["mu_init"])
        self.tol = float(fatrop["tol"])
        self.bound_push = float(fatrop.get("bound_push", FATROP_BOUND_PUSH))
        self.driver = driver
        self._plugin = None
        self._stats: dict = {}

    @classmethod
    def for_mpc(cls, mpc, name: str, cold: bool, max_iter: int | None = None):
        """The direct solver of ``mpc``, or its plugin ``nlpsol`` (with a warning) if the driver cannot be
        built."""
        driver = _DRIVERS.get(mpc)
        if driver is None:
            try:
                driver = _new_driver(mpc)
            except (OSError, RuntimeError, ValueError) as exc:
                warnings.warn(
                    f"the direct Fatrop driver is unavailable ({exc}); using the casadi plugin", stacklevel=3
                )
                return plugin_nlpsol(mpc, name, cold, max_iter)
            _DRIVERS[mpc] = driver
            if mpc.solver_settings.compiled:
                mpc.release.start()  # the release library, in the background (if wanted and not cached)
        return cls(mpc, name, cold, max_iter, driver)

    def __call__(self, *, x0, p, lbg=None, ubg=None, lam_g0=None, **_) -> dict:
        """Solve (``lbg``/``ubg`` are the OCP's constant bounds, compiled in; checked to be those)."""
        ocp, driver = self.mpc.ocp, self.driver
        for name, given, own in (("lbg", lbg, ocp.lbg), ("ubg", ubg, ocp.ubg)):
            if given is not None and not np.array_equal(np.asarray(given, float).ravel(), own):
                raise ValueError(
                    f"the direct Fatrop driver has the OCP's {name} compiled in; got other bounds"
                )
        for option in ("max_iter", "tol", "bound_push"):  # the shared driver holds the last solver's
            if driver.options.get(option) != getattr(self, option):
                driver.set_option(option, getattr(self, option))
        last: DirectResult | None = driver.last
        warm = (
            last is not None and lam_g0 is not None and np.array_equal(np.asarray(lam_g0).ravel(), last.lam_g)
        )
        if warm:  # the barrier parameter where that solve ended (not above the warm start's)
            result = driver.solve(p, x0, mu_init=min(max(last.mu, 1e-12), self.mu_init), duals=last)
        else:
            result = driver.solve(p, x0, mu_init=self.mu_init)
        if result.flag == -1:  # the driver raised: the plugin path solves this tick
            return self._solve_with_plugin(x0, p, lbg, ubg, lam_g0, result)
        if result.success:
            driver.last = result
        t = result.timings
        self._stats = {
            "success": result.success,
            "return_status": 0 if result.success else 1,
            "iter_count": result.iterations,
            "solver": "direct",
            "fatrop": {
                "return_flag": result.flag,
                "time_total": t["fatrop"],
                "compute_sd_time": t["search_direction"],
                "initialization_time": t["initialization"],
                "eval_hess_time": t["hessian"],
                "eval_jac_time": t["jacobian"],
                "eval_cv_time": t["residuals"],
                "warm_duals": warm,
            },
            # solver_timings() sums these as the derivative evaluations
            "t_wall_nlp_hess_l": t["hessian"],
            "t_wall_nlp_jac_g": t["jacobian"],
            "t_wall_nlp_g": t["residuals"],
            "t_wall_nlp_grad_f": t["objective"],
        }
        return {"x": result.w, "g": result.g, "lam_g": result.lam_g, "f": np.nan}

    def stats(self) -> dict:
        """The last call's statistics in the plugin's format."""
        return self._stats

    def _solve_with_plugin(self, x0, p, lbg, ubg, lam_g0, failed: DirectResult) -> dict:
        if self._plugin is None:
            self._plugin = plugin_nlpsol(self.mpc, self.name, self.cold, self.max_iter)
        args = {"x0": x0, "p": p, "lbg": self.mpc.ocp.lbg if lbg is None else lbg}
        args["ubg"] = self.mpc.ocp.ubg if ubg is None else ubg
        if lam_g0 is not None:
            args["lam_g0"] = lam_g0
        out = self._plugin(**args)
        self._stats = {**self._plugin.stats(), "solver": "plugin", "direct_failure": failed.reason}
        return {key: np.array(value).ravel() for key, value in out.items()}


def _new_driver(mpc) -> DirectFatrop:
    cfg = mpc.solver_settings
    flags = mpc.library_flags() if cfg.compiled else tuple(cfg.compile_flags)  # VM: nothing compiled per OCP
    return DirectFatrop(
        mpc.ocp,
        tol=cfg.tol,
        max_iter=cfg.max_iter,
        flags=flags,
        progress=mpc.verbose,
        compiled=cfg.compiled,
        threads=cfg.driver_threads,
    )


def switch_driver(mpc) -> DirectFatrop:
    """Give ``mpc`` a new driver on the library of its current flags (``mpc.library_flags()``: after the
    release library became ready), keeping the last solution's duals for the next warm start. The MPC's
    solvers must be made again (:meth:`~wbmpc.control.mpc.WholeBodyMPC.make_solver`)."""
    old = _DRIVERS.pop(mpc, None)
    driver = _DRIVERS[mpc] = _new_driver(mpc)
    if old is not None:
        driver.last = old.last
    return driver


def plugin_nlpsol(mpc, name: str, cold: bool, max_iter: int | None = None):
    """The casadi-plugin ``nlpsol`` of ``mpc`` (what ``make_solver`` builds without the driver): compiled
    with ``SolverSettings.compiled``, else in process."""
    cfg = mpc.solver_settings
    library = None
    if cfg.compiled:
        if mpc.compiled_nlp is None:
            mpc.compiled_nlp = codegen.build(mpc.ocp, tuple(cfg.compile_flags), progress=mpc.verbose)
        library = mpc.compiled_nlp.library
    options = mpc.solver_options(cold, max_iter)
    return make_nlpsol(name, "fatrop", mpc.ocp.nlp, options, library, n_nodes=mpc.ocp.n_nodes)
