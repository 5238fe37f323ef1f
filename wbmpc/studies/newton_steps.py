"""Study: a fixed number of Fatrop iterations per tick (real-time iteration) against the converged solve.

Issue 22, item 3. Three parts, the variants taking turns in one run (the order rotates tick by tick or
case by case, so drift hits them alike):

1. Recorded ticks (:func:`recorded_ticks`): a closed loop of the default benchmark (B1 + Z1, N = 15, trot,
   rigid plant, the direct driver converged in the loop) is recorded (:func:`wbmpc.studies.direct_fatrop.
   record_ticks`); per tick the direct driver solves from the recorded primal guess and the previous tick's
   converged duals, converged and with 1 and 2 fixed iterations
   (:func:`wbmpc.solver.direct.fixed_steps.fixed_step_solve`). Node 0's torques [N m] and contact forces
   [N] against the converged solution, the constraint residuals (transition, inverse-dynamics (RNEA)
   rows, other equalities, inequalities), time per call [ms]. Then each MPC's own chain: a
   :class:`~wbmpc.control.fixed_steps.FixedStepMPC` and the converged direct MPC call ``solve()`` on
   the recorded observations (each warm-started from its own previous plan): node 0 against the converged
   MPC's plan of the same observation, and the whole tick [ms].
2. Closed loops (:func:`closed_loops`): the converged direct MPC and the 1- and 2-step MPCs on (a) kicks of
   the push grid's 0.6-0.8 m/s rows (:func:`wbmpc.studies.sweeps.cases.robustness_case`, PyBullet), (b)
   arm end-effector tracking while trotting (:func:`~wbmpc.studies.sweeps.cases.nodes_case`), (c) base
   velocity commands on the rigid plant, (d) the emulated robot
   (:func:`wbmpc.analysis.record_emulated_run`, measured delay, estimated state).
3. CasADi's ``sqpmethod`` with the ``hpipm`` QP plugin on the same ticks (:func:`sqp_ticks`).

Run (writes ``data/bench/newton_steps.json``)::

    python -m wbmpc.studies.newton_steps            # --quick: the short version (tests, notebooks)
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from wbmpc.control.fixed_steps import FixedStepMPC
from wbmpc.quick import pick
from wbmpc.solver.direct.fixed_steps import fixed_step_solve
from wbmpc.studies.direct_fatrop import cpu_name, record_ticks

REPO_ROOT = Path(__file__).resolve().parents[2]
OUTPUT = REPO_ROOT / "data" / "bench" / "newton_steps.json"
STEPS = (1, 2)
#: Residual groups reported (the OCP's row groups, :class:`wbmpc.ocp.inspection.ConstraintInspector`).
EQUALITY_GROUPS = ("transition", "dynamics")
# Outcomes kept from the experiments' case functions.
KICK_KEYS = ("fell", "max_tilt_rad", "peak_speed_along_kick", "recovery_time_s")
ARM_KEYS = ("fell", "ee_rms_cm", "ee_max_error_cm", "speed_m_per_s")


def _last_p(mpc) -> np.ndarray:
    return np.asarray(mpc.last_inputs["p"], float).ravel()  # the parameters of its last solve


def _stats(values) -> dict:
    a = np.asarray(values, float)
    if a.size == 0:
        return {"mean": None, "p95": None, "max": None, "n": 0}
    return {"mean": float(a.mean()), "p95": float(np.percentile(a, 95)), "max": float(a.max()), "n": a.size}


class NodeZero:
    """Node 0's torques and contact forces, and the residuals of the constraint groups, of a primal point.

    Args:
        ocp: The :class:`wbmpc.ocp.OCP`.
    """

    def __init__(self, ocp):
        from wbmpc.ocp.inspection import ConstraintInspector

        self.ocp = ocp
        inspector = ConstraintInspector(ocp)
        equality = ~inspector.inequality
        self.groups = {name: inspector.groups[name] for name in EQUALITY_GROUPS if name in inspector.groups}
        named = np.concatenate(list(self.groups.values()))
        other = np.setdiff1d(np.nonzero(equality)[0], named)
        self.groups["other_equalities"] = other
        self.inequality_rows = np.nonzero(inspector.inequality)[0]

    def torques_forces(self, w: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Node 0's joint torques [N m] and contact forces [N] (flattened) of ``w``."""
        plan = self.ocp.plan_function(w=w, p=p)
        return np.array(plan["tau"]).T[0], np.array(plan["forces"]).T[0]

    def residuals(self, g: np.ndarray) -> dict:
        """Largest violation per group of the constraint values ``g``: equalities ``|g - lbg|``,
        inequalities ``max(lbg - g, g - ubg, 0)`` (rows in their units: N m, rad, rad/s; limits scaled)."""
        lbg, ubg = self.ocp.lbg, self.ocp.ubg
        out = {name: float(np.max(np.abs(g[rows] - lbg[rows]))) if rows.size else 0.0
               for name, rows in self.groups.items()}  # fmt: skip
        rows = self.inequality_rows
        out["inequalities"] = float(
            np.max(np.maximum(0.0, np.maximum(lbg[rows] - g[rows], g[rows] - ubg[rows])))
        )
        return out


def recorded_ticks(direct, ticks, steps=STEPS, mu_warm: float = 1e-4) -> dict:
    """Part 1 on recorded ticks, the driver's calls (see the module doc).

    Args:
        direct: A :class:`~wbmpc.solver.direct.driver.DirectFatrop` of the ticks' OCP.
        ticks: :func:`~wbmpc.studies.direct_fatrop.record_ticks`'s (cold ones skipped).
        steps: Fixed iteration counts.
        mu_warm: The warm start's barrier parameter cap (``SolverSettings.mu_init_warm``).

    Returns:
        ``{"per_variant": {name: summary}, "from_converged": ...}``; a summary has ``solve_ms``,
        ``iterations_mean``, ``flags`` (count per Fatrop flag), ``tau0_diff_Nm`` / ``force0_diff_N`` (max abs
        per tick, statistics over ticks), ``primal_diff``, ``residuals`` (per group, statistics); and
        ``from_converged``: 1 iteration from a tick's converged solution and duals (largest primal change).
    """
    node0 = NodeZero(direct.ocp)
    names = ["converged"] + [f"steps_{k}" for k in steps]
    rec = {n: {"ms": [], "it": [], "flags": {}, "tau": [], "force": [], "w": [], "res": []} for n in names}
    from_converged = []
    previous = None
    warm = [tick for tick in ticks if not tick.cold]
    for i, tick in enumerate(warm):
        if previous is None:
            previous = direct.solve(tick.p, tick.x0, mu_init=mu_warm)
            continue
        mu = min(max(previous.mu, 1e-12), mu_warm)
        results = {}
        for name in names[i % len(names) :] + names[: i % len(names)]:  # rotating order
            if name == "converged":
                results[name] = direct.solve(tick.p, tick.x0, mu_init=mu, duals=previous)
            else:
                k = int(name.split("_")[1])
                results[name] = fixed_step_solve(direct, tick.p, tick.x0, k, mu_init=mu, duals=previous)
        conv = results["converged"]
        if not conv.success:  # no reference on this tick; the next one starts as the driver's default
            previous = None
            continue
        tau_c, force_c = node0.torques_forces(conv.w, tick.p)
        for name, r in results.items():
            entry = rec[name]
            entry["ms"].append(1e3 * r.timings["wall"])
            entry["it"].append(r.iterations)
            entry["flags"][r.status] = entry["flags"].get(r.status, 0) + 1
            if np.all(np.isfinite(r.w)):
                tau, force = node0.torques_forces(r.w, tick.p)
                entry["tau"].append(float(np.max(np.abs(tau - tau_c))))
                entry["force"].append(float(np.max(np.abs(force - force_c))))
                entry["w"].append(float(np.max(np.abs(r.w - conv.w))))
                entry["res"].append(node0.residuals(r.g))
        again = fixed_step_solve(
            direct, tick.p, conv.w, 1, mu_init=min(max(conv.mu, 1e-12), mu_warm), duals=conv
        )
        from_converged.append(float(np.max(np.abs(again.w - conv.w))))
        previous = conv
    summary = {}
    for name, entry in rec.items():
        groups = entry["res"][0].keys() if entry["res"] else ()
        summary[name] = {
            "solve_ms": _stats(entry["ms"]),
            "iterations_mean": float(np.mean(entry["it"])) if entry["it"] else None,
            "flags": entry["flags"],
            "tau0_diff_Nm": _stats(entry["tau"]),
            "force0_diff_N": _stats(entry["force"]),
            "primal_diff": _stats(entry["w"]),
            "residuals": {g: _stats([r[g] for r in entry["res"]]) for g in groups},
        }
    return {"per_variant": summary, "from_converged_max_primal_change": max(from_converged, default=None)}


def make_mpcs(robot, steps=STEPS, settings=None, config=None, flags=None) -> dict:
    """The converged direct MPC and one :class:`FixedStepMPC` per step count, built and prepared.

    Args:
        robot: The robot; settings: :class:`~wbmpc.ocp.OCPSettings` (default N = 15); config:
            :class:`~wbmpc.control.mpc.MPCConfig`; flags: gcc flags (default the default build's).
    """
    from wbmpc.control.mpc import MPCConfig, SolverSettings, WholeBodyMPC
    from wbmpc.ocp import OCPSettings

    settings = settings or OCPSettings(n_nodes=15)
    solver = SolverSettings(compiled=True, direct=True, release_flags=None)  # one library for the whole run
    if flags is not None:
        solver = replace(solver, compile_flags=tuple(flags))
    mpcs = {"converged": WholeBodyMPC(robot, settings, config or MPCConfig(), solver)}
    for k in steps:
        mpcs[f"steps_{k}"] = FixedStepMPC(robot, settings, config or MPCConfig(), solver, steps=k)
    for mpc in mpcs.values():
        mpc.verbose = False
        mpc.prepare()
    return mpcs


def mpc_chains(mpcs: dict, ticks) -> dict:
    """Part 1, each MPC's own warm-start chain: ``solve()`` on the recorded observations (turns rotate per
    tick); node 0 against the converged MPC's plan of the same observation, whole tick [ms], statuses, and
    whether any applied plan had a non-finite value."""
    node0 = NodeZero(mpcs["converged"].ocp)
    for mpc in mpcs.values():
        mpc.reset()
    names = list(mpcs)
    rec = {n: {"ms": [], "tau": [], "force": [], "status": {}, "non_finite_plans": 0} for n in names}
    for i, tick in enumerate(ticks):
        plans = {}
        for name in names[i % len(names) :] + names[: i % len(names)]:
            plans[name] = mpcs[name].solve(tick.q_hat, tick.v_hat, tick.t, tick.commands)
        if i == 0:
            continue  # the cold start
        ref = plans["converged"]
        for name, plan in plans.items():
            entry = rec[name]
            entry["ms"].append(1e3 * plan.timings["total"])
            entry["status"][plan.status] = entry["status"].get(plan.status, 0) + 1
            finite = all(np.all(np.isfinite(x)) for x in (plan.tau, plan.forces, plan.q, plan.v))
            entry["non_finite_plans"] += int(not finite)
            if ref.success and plan.success and finite:
                tau, force = node0.torques_forces(plan.w, _last_p(mpcs[name]))
                tau_c, force_c = node0.torques_forces(ref.w, _last_p(mpcs["converged"]))
                entry["tau"].append(float(np.max(np.abs(tau - tau_c))))
                entry["force"].append(float(np.max(np.abs(force - force_c))))
    return {
        name: {
            "tick_ms": _stats(e["ms"]),
            "tau0_diff_Nm": _stats(e["tau"]),
            "force0_diff_N": _stats(e["force"]),
            "status": e["status"],
            "non_finite_plans": e["non_finite_plans"],
        }
        for name, e in rec.items()
    }


# --------------------------------------------------------------------------------------------- closed loops
@contextlib.contextmanager
def experiments_mpc(mpc, robot, nodes: int = 15):
    """Make the PyBullet experiments' case functions (:mod:`wbmpc.studies.sweeps.cases`, which build their
    MPC through :func:`wbmpc.studies.experiments.common._mpc`) run ``mpc`` instead of their own: it is put in
    that cache under the key the cases look up (their robot, ``nodes``, ``SolverSettings(compiled=True)``)
    for the ``with`` block, and the entry restored afterwards."""
    from wbmpc.control.mpc import SolverSettings
    from wbmpc.studies.experiments.common import mpc_in_use
    from wbmpc.studies.sweeps.cases import use_robot

    use_robot(robot)
    with mpc_in_use(mpc, nodes, SolverSettings(compiled=True)):
        yield mpc


def _loop_numbers(result, mpc, stats_before: dict) -> dict:
    """Solver numbers of a closed loop: time per solve [ms], iterations, statuses, failures, cold retries,
    and the plans applied with a non-finite value."""
    log = result.log
    statuses = {}
    for status in log.status:
        statuses[status] = statuses.get(status, 0) + 1
    applied = np.asarray(log.tau, float)
    return {
        "solve_ms": _stats([1e3 * t for t in log.solve_time[1:]]),
        "iterations_mean": float(np.mean(log.iterations[1:])) if len(log.iterations) > 1 else None,
        "status": statuses,
        "failures": int(mpc.stats["failures"] - stats_before["failures"]),
        "cold_retries": int(mpc.stats["cold_retries"] - stats_before["cold_retries"]),
        "non_finite_torques": int(np.sum(~np.isfinite(applied).all(axis=-1))) if applied.size else 0,
    }


def _case_with_result(case_function, case: dict) -> tuple[dict, object]:
    """Run one of the experiments' case functions and keep the closed loop's result it ran (its
    ``run_closed_loop`` call, through :mod:`wbmpc.studies.experiments.common`, is recorded)."""
    from wbmpc.studies.experiments import common

    captured = {}
    run = common.run_closed_loop

    def recording(*args, **kwargs):
        captured["result"] = run(*args, **kwargs)
        return captured["result"]

    common.run_closed_loop = recording
    try:
        out = case_function(case)
    finally:
        common.run_closed_loop = run
    return out, captured["result"]


def _rigid_command(mpc, command, stand: float, trot: float):
    """Base velocity command on the rigid plant: stand, trot with ``command`` (forward, left [m/s], yaw
    rate [rad/s]); the achieved velocity of the trot segment (heading frame, after 1 s of settling)."""
    from wbmpc.ocp.gait import parse_gait_schedule
    from wbmpc.sim.closed_loop import ClosedLoopConfig, run_closed_loop
    from wbmpc.sim.loop_config import CommandSchedule, PlantConfig

    vx, vy, wz = command
    schedule = parse_gait_schedule(f"stand:{stand:g},trot@{vx:g}/{vy:g}/{wz:g}:{trot:g}")
    mpc.config = replace(mpc.config, gait=schedule)
    mpc.reset()
    config = ClosedLoopConfig(
        duration=schedule.duration,
        plant=PlantConfig(kind="rigid"),
        commands=CommandSchedule(arm_reference=None),
    )
    result = run_closed_loop(mpc, config, progress=False)
    moving = [seg for seg in result.summary["tracking"] if any(abs(c) > 0 for c in seg["commanded"])]
    achieved = moving[0]["achieved"] if moving else [float("nan")] * 3
    return {"fell": bool(result.fell), "commanded": list(command), "achieved": achieved}, result


def closed_loops(robot, mpcs: dict, emulated_mpcs: dict | None, quick: bool = False) -> dict:
    """Part 2 (see the module doc): every scenario with each MPC in turn (the order rotates per case).

    Args:
        robot: The robot of ``mpcs`` (the experiments' cases run on it).
        mpcs: :func:`make_mpcs`'s (default OCP settings, N = 15).
        emulated_mpcs: The same on the emulated robot's OCP settings (``None``: that scenario skipped).
        quick: Short runs (one kick, short arm and command runs).

    Returns:
        ``{scenario: [{"case": ..., name: {outcome and solver numbers}}, ...]}``.
    """
    from wbmpc.analysis import record_emulated_run
    from wbmpc.studies.sweeps.cases import nodes_case, robustness_case

    base_config = mpcs["converged"].config
    kicks = [
        {"magnitude": m, "direction": d, "phase": ph, "after": 1.0 if not quick else 0.4}
        for m in ((0.6, 0.7, 0.8) if not quick else (0.8,))
        for d in (("lateral", "forward") if not quick else ("lateral",))
        for ph in ((0.0, 0.25) if not quick else (0.0,))
    ]
    scenarios = {
        "push": [("kick", case) for case in kicks],
        "arm_tracking": [("arm", {"nodes": 15, "duration": 2.0 if not quick else 0.5})],
        "command_tracking_rigid": [
            ("command", {"command": c, "stand": 1.0, "trot": 2.5 if not quick else 1.2})
            for c in (((0.5, 0.0, 0.0), (0.0, 0.0, 0.3)) if not quick else ((0.5, 0.0, 0.0),))
        ],
    }
    if emulated_mpcs is not None:
        scenarios["emulated"] = [("emulated", {"gait": f"stand:1,trot@0.2:{1 if quick else 2.5:g}"})]
    out: dict[str, list] = {}
    turn = 0
    for scenario, runs in scenarios.items():
        out[scenario] = []
        for kind, case in runs:
            row = {"case": dict(case)}
            pool = emulated_mpcs if kind == "emulated" else mpcs
            names = list(pool)
            for name in names[turn % len(names) :] + names[: turn % len(names)]:
                mpc = pool[name]
                mpc.config = base_config if kind != "emulated" else mpc.config
                before = dict(mpc.stats)
                start = time.perf_counter()
                if kind == "kick":
                    with experiments_mpc(mpc, robot):
                        outcome, result = _case_with_result(robustness_case, case)
                    outcome = {k: outcome[k] for k in KICK_KEYS}
                elif kind == "arm":
                    with experiments_mpc(mpc, robot):
                        outcome, result = _case_with_result(nodes_case, case)
                    outcome = {k: outcome[k] for k in ARM_KEYS}
                elif kind == "command":
                    outcome, result = _rigid_command(mpc, case["command"], case["stand"], case["trot"])
                else:
                    mpc.reset()
                    result, _ = record_emulated_run(gait=case["gait"], robot=robot, mpc=mpc)
                    s = result.summary
                    moving = [seg for seg in s["tracking"] if any(abs(c) > 0 for c in seg["commanded"])]
                    forward = moving[0]["achieved"][0] if moving else None
                    outcome = {"fell": bool(result.fell), "max_tilt_rad": s["max_tilt_rad"]}
                    outcome["achieved_forward_m_per_s"] = forward
                row[name] = outcome | _loop_numbers(result, mpc, before)
                row[name]["wall_s"] = time.perf_counter() - start
            turn += 1
            out[scenario].append(row)
        for mpc in mpcs.values():
            mpc.config = base_config
    return out


# ------------------------------------------------------------------------------------ sqpmethod with hpipm
def sqp_solver(ocp, qpsol: str = "hpipm", max_iter: int = 15, convexify: str | None = "regularize"):
    """CasADi's ``sqpmethod`` over the OCP's NLP (in-process SX functions), the QP solved by ``qpsol``.

    For ``hpipm`` the QP's OCP structure comes from :meth:`wbmpc.ocp.OCP.stage_sizes` (``N`` = nodes - 1,
    per stage ``nx``, ``nu``, ``ng``: node 0's split as Fatrop's detection makes it), which the wheel's
    interface accepts. Tolerances as the MPC's (dual 1e-3), primal 1e-6. ``convexify``: sqpmethod's
    ``convexify_strategy`` (the exact Hessian is indefinite here).
    """
    import casadi as ca

    qp_options: dict = {"error_on_fail": False}
    if qpsol == "hpipm":
        sizes = ocp.stage_sizes()
        qp_options |= {"N": len(sizes["nx"]) - 1, "nx": sizes["nx"], "nu": sizes["nu"], "ng": sizes["ng"]}
    elif qpsol == "qrqp":
        qp_options |= {"print_iter": False, "print_header": False}
    options = {"qpsol": qpsol, "qpsol_options": qp_options, "max_iter": max_iter, "tol_pr": 1e-6}
    options |= {"tol_du": 1e-3} | dict.fromkeys(
        ("print_time", "print_header", "print_iteration", "print_status", "error_on_fail"), False
    )
    if convexify:
        options["convexify_strategy"] = convexify
    return ca.nlpsol("wbmpc_sqp", "sqpmethod", ocp.nlp, options)


def sqp_ticks(ocp, direct, ticks, n_ticks: int, variants: dict | None = None) -> dict:
    """Part 3: ``sqpmethod`` on the first ``n_ticks`` warm recorded ticks, from the recorded primal guess,
    with the previous tick's converged Fatrop multipliers (``lam_g0``) or without; against the direct
    driver's converged solution of the tick. Per variant: statuses, iterations, time [ms] (in-process SX
    evaluations, not compiled), primal difference to Fatrop's."""
    variants = variants or {
        "hpipm, regularized Hessian, Fatrop's duals": ("hpipm", "regularize", True),
        "hpipm, regularized Hessian, zero duals": ("hpipm", "regularize", False),
        "hpipm, exact Hessian, Fatrop's duals": ("hpipm", None, True),
    }
    warm = [t for t in ticks if not t.cold][: n_ticks + 1]
    previous = direct.solve(warm[0].p, warm[0].x0)
    references = []
    for tick in warm[1:]:
        reference = direct.solve(tick.p, tick.x0, duals=previous)
        references.append((tick, previous, reference))
        previous = reference
    out = {}
    for label, (qpsol, convexify, with_duals) in variants.items():
        try:
            solver = sqp_solver(ocp, qpsol, convexify=convexify)
        except RuntimeError as exc:
            out[label] = {"error": str(exc).strip().splitlines()[-1][:500]}
            continue
        rec = {"status": {}, "iterations": [], "ms": [], "diff": []}
        for tick, before, reference in references:
            args = {"x0": tick.x0, "p": tick.p, "lbg": ocp.lbg, "ubg": ocp.ubg}
            if with_duals:
                args["lam_g0"] = before.lam_g
            start = time.perf_counter()
            sol = solver(**args)  # error_on_fail off: a failed solve returns with its status
            rec["ms"].append(1e3 * (time.perf_counter() - start))
            stats = solver.stats()
            status = str(stats.get("return_status"))
            rec["status"][status] = rec["status"].get(status, 0) + 1
            rec["iterations"].append(int(stats.get("iter_count", -1)))
            rec["diff"].append(float(np.max(np.abs(np.array(sol["x"]).ravel() - reference.w))))
        out[label] = {
            "status": rec["status"],
            "iterations_mean": float(np.mean(rec["iterations"])) if rec["iterations"] else None,
            "solve_ms": _stats(rec["ms"]),
            "primal_diff_to_fatrop": _stats(rec["diff"]),
            "fatrop_iterations_mean": float(np.mean([r.iterations for _, _, r in references])),
        }
    return out


# ------------------------------------------------------------------------------------------------- the run
def run(quick: bool | None = None, emulated: bool = True, progress: bool = True) -> dict:
    """The whole study (sizes by :func:`wbmpc.quick.pick` unless ``quick`` is given); returns the result
    that :func:`main` writes."""
    from wbmpc.analysis.emulated_runs import EMULATED_TORQUE_FRACTION
    from wbmpc.model.robot import load_b1_z1
    from wbmpc.ocp import OCPSettings
    from wbmpc.solver.direct import DirectFatrop

    quick = pick(False, True) if quick is None else quick
    robot = load_b1_z1()
    say = print if progress else (lambda *a, **k: None)
    mpcs = make_mpcs(robot)
    converged = mpcs["converged"]
    cfg = converged.solver_settings
    direct = DirectFatrop(converged.ocp, tol=cfg.tol, max_iter=cfg.max_iter, progress=False)
    ticks = record_ticks(converged, 0.4 if quick else 1.5)
    say(f"{len(ticks)} ticks recorded")
    started = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
    load_before = list(os.getloadavg())
    result = {
        "what": "fixed Fatrop iterations per tick (real-time iteration) vs the converged direct solve; "
        "sqpmethod + hpipm",
        "problem": "B1 + Z1, N = 15, default settings, trot closed loop (rigid plant), 80 Hz ticks",
        "cpu": cpu_name(),
        "started_utc": started,
        "load_average_before": load_before,
        "quick": quick,
        "ticks": len(ticks),
        "flags": list(cfg.compile_flags),
    }
    result["recorded_ticks"] = recorded_ticks(direct, ticks, mu_warm=cfg.mu_init_warm)
    say("recorded ticks done")
    result["mpc_chains"] = mpc_chains(mpcs, ticks)
    say("MPC chains done")
    emulated_mpcs = None
    if emulated:
        settings = OCPSettings(n_nodes=15, torque_limit_fraction=EMULATED_TORQUE_FRACTION)
        emulated_mpcs = make_mpcs(robot, settings=settings)
    result["closed_loops"] = closed_loops(robot, mpcs, emulated_mpcs, quick=quick)
    say("closed loops done")
    result["sqp"] = sqp_ticks(converged.ocp, direct, ticks, 2 if quick else 10)
    result["load_average_after"] = list(os.getloadavg())
    return result


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(
        prog="python -m wbmpc.studies.newton_steps", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--quick", action="store_true", help="the short version (also with WBMPC_QUICK=1)")
    parser.add_argument("--no-emulated", action="store_true", help="skip the emulated robot")
    parser.add_argument("--output", type=Path, default=OUTPUT)
    args = parser.parse_args(argv)
    result = run(quick=True if args.quick else None, emulated=not args.no_emulated)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=1, default=float) + "\n")
    print(summary_tables(result))
    return result


def summary_tables(result: dict) -> str:
    """Markdown tables of a result: recorded ticks, MPC chains, closed loops, sqpmethod."""
    lines = [
        "| variant | call mean / p95 [ms] | iterations | node-0 torque diff mean / max [N m] "
        "| node-0 force diff mean / max [N] | RNEA residual max | transition residual max "
        "| inequality violation max |",
        "|---|---|---|---|---|---|---|---|",
    ]
    f = _fmt
    for name, s in result["recorded_ticks"]["per_variant"].items():
        res = s["residuals"]
        lines.append(
            f"| {name} | {f(s['solve_ms']['mean'])} / {f(s['solve_ms']['p95'])} | {f(s['iterations_mean'])} "
            f"| {f(s['tau0_diff_Nm']['mean'], 'e')} / {f(s['tau0_diff_Nm']['max'], 'e')} "
            f"| {f(s['force0_diff_N']['mean'], 'e')} / {f(s['force0_diff_N']['max'], 'e')} "
            f"| {f(res['dynamics']['max'], 'e')} | {f(res['transition']['max'], 'e')} "
            f"| {f(res['inequalities']['max'], 'e')} |"
        )
    lines += [
        "",
        "| MPC (own chain) | whole tick mean / p95 [ms] | node-0 torque diff mean / max [N m] "
        "| node-0 force diff mean / max [N] | statuses | non-finite plans |",
        "|---|---|---|---|---|---|",
    ]
    for name, s in result["mpc_chains"].items():
        lines.append(
            f"| {name} | {f(s['tick_ms']['mean'])} / {f(s['tick_ms']['p95'])} "
            f"| {f(s['tau0_diff_Nm']['mean'], 'e')} / {f(s['tau0_diff_Nm']['max'], 'e')} "
            f"| {f(s['force0_diff_N']['mean'], 'e')} / {f(s['force0_diff_N']['max'], 'e')} "
            f"| {s['status']} | {s['non_finite_plans']} |"
        )
    lines += [
        "",
        "| scenario | case | MPC | fell | outcome | solve mean / p95 [ms] | failures |",
        "|---|---|---|---|---|---|---|",
    ]
    for scenario, rows in result["closed_loops"].items():
        for row in rows:
            case = ", ".join(f"{k}={v}" for k, v in row["case"].items())
            for name, r in row.items():
                if name == "case":
                    continue
                keys = [k for k in r if k not in ("fell", "solve_ms", "status", "failures", "wall_s")]
                keys = [k for k in keys if k not in ("iterations_mean", "cold_retries", "non_finite_torques")]
                outcome = ", ".join(f"{k} {f(r[k])}" for k in keys)
                lines.append(
                    f"| {scenario} | {case} | {name} | {r['fell']} | {outcome} "
                    f"| {f(r['solve_ms']['mean'])} / {f(r['solve_ms']['p95'])} | {r['failures']} |"
                )
    lines += [
        "",
        "| sqpmethod variant | statuses | iterations | time mean [ms] | primal diff to Fatrop max |",
        "|---|---|---|---|---|",
    ]
    for name, s in result["sqp"].items():
        if "error" in s:
            lines.append(f"| {name} | error: {s['error']} | | | |")
            continue
        lines.append(
            f"| {name} | {s['status']} | {f(s['iterations_mean'])} | {f(s['solve_ms']['mean'])} "
            f"| {f(s['primal_diff_to_fatrop']['max'], 'e')} |"
        )
    return "\n".join(lines)


def _fmt(value, kind: str = "f") -> str:
    if value is None:
        return "-"
    if isinstance(value, bool | str):
        return str(value)
    if isinstance(value, list):
        return "[" + ", ".join(_fmt(v, kind) for v in value) + "]"
    return f"{value:.2e}" if kind == "e" else f"{value:.2f}"


if __name__ == "__main__":
    main()
