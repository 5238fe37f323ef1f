"""The whole-body MPC: commands and measured state in, a warm-started Fatrop (or IPOPT) solve, a plan out.

:class:`WholeBodyMPC` owns one :class:`wbmpc.ocp.OCP` and its solver. Everything a user changes between
solves (state, commands, gait and swing parameters, weights, time steps, friction) is a runtime parameter:
changing it never rebuilds anything. A failed or non-converged solve never raises inside a loop: the
result says so, the failure is counted, and :meth:`WholeBodyMPC.solve` returns the previous plan shifted
in time (the fallback) so a controller can keep interpolating it.
"""

from __future__ import annotations

import time
from dataclasses import replace

import casadi as ca
import numpy as np
import pinocchio as pin

from wbmpc import checks
from wbmpc.control import guesses
from wbmpc.control.config import (
    DT_BOUNDS,
    SOLVERS,
    Commands,
    MPCConfig,
    MPCSolution,
    SolverSettings,
    default_weights,
)
from wbmpc.control.prechecks import Prechecks
from wbmpc.control.push_recovery import PushRecovery
from wbmpc.model.robot import FOOT_NAMES, Robot, heading
from wbmpc.model.statics import default_force_distribution, static_equilibrium
from wbmpc.ocp import OCP, OCPSettings
from wbmpc.ocp.gait import (
    Gait,
    GaitSchedule,
    swing_vertical_velocity,
)
from wbmpc.ocp.time_grid import geometric_time_steps, node_times
from wbmpc.solver import codegen
from wbmpc.solver.nlpsol import make_nlpsol, solver_options
from wbmpc.solver.release import ReleaseUpgrade
from wbmpc.solver.statuses import exception_status, solver_status
from wbmpc.solver.timings import solver_timings

__all__ = [
    "DT_BOUNDS",
    "SOLVERS",
    "Commands",
    "MPCConfig",
    "MPCSolution",
    "SolverSettings",
    "WholeBodyMPC",
    "default_weights",
    "heading",
    "solver_timings",
]

# Unbalanced base wrench [N, N m] below which a scheduled stance holds the measured pose statically.
HOLD_RESIDUAL = 1e-6
# Precheck findings that make the problem ill-posed: refused before any work (the others ride on the plan).
REFUSED_FINDINGS = ("ee_force_lifts_robot", "arm_command_without_arm")


class WholeBodyMPC:
    """Whole-body inverse-dynamics MPC (build once, solve many times).

    One class on purpose (about 490 lines): the solve's parts (parameters from the commands, warm and cold
    guesses, the solver calls with the cold retry, the failed-solve rule, the static hold) share the last
    converged plan and the statistics, and the failed-solve rule is only checkable as a whole; push recovery
    (:mod:`wbmpc.control.push_recovery`) and the prechecks (:mod:`wbmpc.control.prechecks`) are objects of
    their own.

    Args:
        robot: The robot.
        settings: Structural OCP settings (nodes, torque nodes, formulation).
        config: Runtime configuration (weights, gait, time steps, fallbacks; may change between solves).
        solver: How the NLP is solved (solver, compiled or not, tolerance, iteration caps); fixed.

    Raises:
        ValueError: On a robot without four feet or arguments of the wrong type.
    """

    def __init__(
        self,
        robot: Robot,
        settings: OCPSettings | None = None,
        config: MPCConfig | None = None,
        solver: SolverSettings | None = None,
    ):
        if not isinstance(robot, Robot):
            raise ValueError(f"robot must be a wbmpc.model.robot.Robot (see load_robot), got {robot!r}")
        if robot.n_feet != len(FOOT_NAMES):
            raise ValueError(
                f"robot {robot.name!r} has {robot.n_feet} foot frames {list(robot.foot_frames)}; the MPC's "
                f"gaits schedule 4 feet in the order {FOOT_NAMES} (front-left, front-right, rear-left, "
                "rear-right): give load_robot four foot_frames"
            )
        if settings is not None and not isinstance(settings, OCPSettings):
            raise ValueError(f"settings must be an OCPSettings, got {settings!r}")
        if config is not None and not isinstance(config, MPCConfig):
            raise ValueError(f"config must be an MPCConfig, got {config!r}")
        if solver is not None and not isinstance(solver, SolverSettings):
            raise ValueError(f"solver must be a SolverSettings (wbmpc.control.mpc), got {solver!r}")
        self.robot = robot
        self.config = config or MPCConfig()
        self.solver_settings = solver or SolverSettings()
        self.ocp = OCP(robot, settings)
        self.n_nodes = self.ocp.n_nodes
        self._solvers = {}
        self.previous: MPCSolution | None = None
        self.stats = {"solves": 0, "failures": 0, "exceptions": 0, "cold_retries": 0, "holds": 0}
        self.stats["swing_aborts"] = 0
        self.stats["library_switches"] = 0
        self.push_recovery = PushRecovery(robot)  # swings aborted after a push (MPCConfig.kick_recovery)
        self.prechecks = Prechecks(robot)  # physical checks of each solve request, with their own data
        # Of the model the OCP was built from (the Robot properties walk the model on every call).
        self._mass, self._gravity = robot.mass, robot.gravity
        self._time_steps = None  # ((dt_min, dt_max), steps) of the last time_steps()
        self._default_weights = default_weights(robot)
        self.compiled_nlp = None
        self.release: ReleaseUpgrade | None = None  # the compiled library's flags, its release build
        self.last_inputs: dict | None = None
        self.verbose = True

    # --- solver construction --------------------------------------------------------------------------------
    def _solver(self, cold: bool, max_iter: int | None = None) -> ca.Function:
        """The solver for cold or warm starts (built on first use)."""
        key = (cold, max_iter)
        if key not in self._solvers:
            self._solvers[key] = self.make_solver(f"wbmpc_{self.solver_settings.solver}", cold, max_iter)
        return self._solvers[key]

    def prepare(self) -> None:
        """Build every solver a control loop may call (warm start, cold start, cold retry) now.

        They are otherwise built on first use, which costs a compile-cache lookup and about 30 ms of
        ``nlpsol`` construction each on a 2-vCPU machine: inside the first solves, and inside the first
        failed warm solve (its cold retry), where a loop that measures its delay can least afford it. Call it
        before the clock starts, as a robot's start-up does (:func:`~wbmpc.sim.closed_loop.run_closed_loop`
        does); calling it again does nothing.
        """
        self._solver(True)
        self._solver(False)
        self._solver(True, self.solver_settings.retry_max_iter)

    def solver_options(self, cold: bool, max_iter: int | None = None) -> dict:
        """The ``casadi.nlpsol`` options of this MPC's cold- or warm-start solves
        (:func:`wbmpc.solver.nlpsol.solver_options`; ``max_iter`` overrides the settings' iteration cap)."""
        cfg = self.solver_settings
        if max_iter is None:
            max_iter = cfg.cold_max_iter if cold else cfg.max_iter
        return solver_options(
            cfg.solver,
            tol=cfg.tol,
            max_iter=max_iter,
            mu_init=cfg.mu_init_cold if cold else cfg.mu_init_warm,
            warm=not cold,
            equality=self.ocp.equality,
        )

    def make_solver(self, name: str, cold: bool, max_iter: int | None = None) -> ca.Function:
        """A new ``casadi.nlpsol`` for this problem with the cold- or warm-start options of the settings
        (``max_iter`` overrides their iteration cap); compiled (cached) with ``SolverSettings.compiled``; the
        direct driver's stand-in (:class:`wbmpc.solver.direct.adapter.DirectNlpsol`) with ``direct``."""
        cfg = self.solver_settings
        if cfg.direct_driver:  # called like an nlpsol; the plugin path is its fallback
            from wbmpc.solver.direct.adapter import DirectNlpsol

            return DirectNlpsol.for_mpc(self, name, cold, max_iter)
        library = None
        if cfg.compiled:
            if self.compiled_nlp is None:
                self.compiled_nlp = codegen.build(self.ocp, self.library_flags(), progress=self.verbose)
                self.release.start()  # the release library, in the background (if wanted and not cached)
            library = self.compiled_nlp.library
        options = self.solver_options(cold, max_iter)
        return make_nlpsol(name, cfg.solver, self.ocp.nlp, options, library, n_nodes=self.ocp.n_nodes)

    def library_flags(self) -> tuple[str, ...]:
        """The gcc flags of the compiled library in use: ``SolverSettings.release_flags`` once that library
        is cached, else ``compile_flags`` (:class:`wbmpc.solver.release.ReleaseUpgrade`)."""
        if self.release is None:
            cfg = self.solver_settings
            kind = "direct" if cfg.direct_driver else "nlp"
            self.release = ReleaseUpgrade(
                self.ocp, kind, cfg.compile_flags, cfg.release_flags, build=cfg.release_build
            )
        return self.release.flags

    def _switch_to_release(self) -> float:
        """Rebuild the solvers on the release library once its background build is done; the time [s]."""
        if self.release is None or not self.release.poll():
            return 0.0
        start = time.perf_counter()
        built = list(self._solvers)
        self._solvers.clear()
        self.compiled_nlp = None
        if self.solver_settings.direct_driver:
            from wbmpc.solver.direct.adapter import switch_driver

            switch_driver(self)  # the warm duals carry over
        for cold, max_iter in built:
            self._solver(cold, max_iter)
        self.stats["library_switches"] += 1
        return time.perf_counter() - start

    # --- parameters -----------------------------------------------------------------------------------------
    def time_steps(self) -> np.ndarray:
        """The solve's geometric time steps [s] (N-1,) from ``config.dt_min`` to ``config.dt_max``."""
        key = (self.config.dt_min, self.config.dt_max)
        if self._time_steps is None or self._time_steps[0] != key:  # several calls per tick
            self._time_steps = key, geometric_time_steps(self.n_nodes, *key)
        return self._time_steps[1].copy()

    def desired_configuration(self, q_hat: np.ndarray, commands: Commands) -> np.ndarray:
        """Nominal pose at the measured base x, y and heading, level base at the nominal height, or at the
        commanded ``base_height`` with the leg joints that keep the feet where the nominal pose has them
        (:meth:`pose_at_height`)."""
        q_des = (
            self.robot.q_nominal
            if commands.base_height is None
            else self.pose_at_height(commands.base_height)
        )
        yaw = heading(q_hat)
        q_des[0:2] = q_hat[0:2]
        q_des[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(0.0, 0.0, yaw)).coeffs()
        return q_des

    def pose_at_height(self, height: float) -> np.ndarray:
        """The nominal pose with the base at ``height`` [m] and the leg joints that keep every foot at its
        nominal position (Gauss-Newton on the feet's positions over the leg joints, within the joint
        limits; the arm keeps its joints). Cached per height (0.1 mm).

        Without it a height command changes only the base's row of the posture cost while every leg joint
        is still pulled to its nominal angle, which at another height would lift the feet or push them in:
        the leg weights win and the base barely moves.
        """
        key = round(float(height), 4)
        cache = self.__dict__.setdefault("_height_poses", {})
        if key not in cache:
            robot, model = self.robot, self.robot.model
            data = model.createData()
            q = robot.q_nominal
            ids = [robot.frame_id(f) for f in robot.foot_frames]
            pin.framesForwardKinematics(model, data, q)
            targets = np.concatenate([data.oMf[i].translation for i in ids])
            legs = np.ones(model.nv, bool)
            legs[:6] = False
            legs[[robot.joint_index_v(n) for n in robot.arm_joint_names]] = False
            q[2] = key
            lower, upper = model.lowerPositionLimit, model.upperPositionLimit
            for _ in range(30):
                pin.computeJointJacobians(model, data, q)
                pin.framesForwardKinematics(model, data, q)
                error = targets - np.concatenate([data.oMf[i].translation for i in ids])
                if np.max(np.abs(error)) < 1e-8:
                    break
                J = np.vstack(
                    [pin.getFrameJacobian(model, data, i, pin.LOCAL_WORLD_ALIGNED)[:3] for i in ids]
                )
                step = np.zeros(model.nv)
                step[legs] = np.linalg.lstsq(J[:, legs], error, rcond=None)[0]
                q = pin.integrate(model, q, step)
                q[7:] = np.clip(q[7:], lower[7:], upper[7:])
            cache[key] = q
        out = cache[key].copy()
        out[2] = float(height)  # the legs of the nearest 0.1 mm, the base at the height asked for
        return out

    def parameters(self, q_hat: np.ndarray, v_hat: np.ndarray, t: float, commands: Commands) -> dict:
        """Numeric values of every OCP parameter block for a solve at time ``t`` [s]."""
        cfg, robot = self.config, self.robot
        dts = self.time_steps()
        t_nodes = node_times(dts, t)[:-1]
        sample = self.gait(commands).sample(t_nodes)
        contact = sample.contact.astype(float)
        swing_vz = np.zeros_like(sample.swing_phase)
        swinging = ~sample.contact
        for duration in np.unique(sample.swing_duration[swinging]):  # one per gait of a schedule
            mask = swinging & (sample.swing_duration == duration)
            swing_vz[mask] = swing_vertical_velocity(
                sample.swing_phase[mask],
                duration,
                cfg.swing.height,
                cfg.swing.v_liftoff,
                cfg.swing.v_touchdown,
            )
        ratio = robot.front_force_ratio if cfg.front_force_ratio is None else cfg.front_force_ratio
        # The vertical targets carry the weight plus the commanded end-effector load.
        gravity = self._gravity
        weight = self._mass * gravity - commands.ee_force[2]
        force_des = default_force_distribution(sample.contact, weight / gravity, gravity, ratio)
        R_base = pin.Quaternion(q_hat[3:7]).normalized().toRotationMatrix()
        R_heading = pin.rpy.rpyToMatrix(0.0, 0.0, heading(q_hat))
        v_des = np.zeros(robot.nv)
        v_des[0:3] = R_base.T @ R_heading @ commands.base_linear_velocity
        v_des[3:6] = R_base.T @ R_heading @ commands.base_angular_velocity
        Q, R = self.weights()
        return {
            "q_hat": q_hat,
            "v_hat": v_hat,
            "dq_des": pin.difference(robot.model, q_hat, self.desired_configuration(q_hat, commands)),
            "v_des": v_des,
            "dt_min": cfg.dt_min,
            "dt_max": cfg.dt_max,
            "contact": contact,
            "swing_vz": swing_vz,
            "force_des": force_des,
            "ee_velocity": np.broadcast_to(commands.ee_velocity.reshape(3, -1), (3, self.n_nodes - 1))
            if commands.ee_velocity.ndim == 1
            else commands.ee_velocity,
            "ee_force": commands.ee_force,
            "mu": cfg.mu,
            "Q": Q,
            "R": R,
        }

    def weights(self) -> tuple[np.ndarray, np.ndarray]:
        """The diagonal weights ``Q`` (2 nv,) and ``R`` of this solve: the config's, or the defaults."""
        out = []
        for name, default in zip(("Q", "R"), self._default_weights, strict=True):
            value = getattr(self.config, name)
            if value is None:
                out.append(default)
                continue
            value = np.asarray(value, dtype=float)
            if value.shape != default.shape or not np.all(np.isfinite(value)) or np.any(value < 0):
                raise ValueError(
                    f"MPCConfig.{name} must hold {default.size} finite weights >= 0 for this robot and "
                    f"formulation, got shape {value.shape}" + (f", min {value.min()}" if value.size else "")
                )
            out.append(value)
        return out[0], out[1]

    # --- initial guesses ---------------------------------------------------------------------------------
    def cold_guess(self, q_hat: np.ndarray, v_hat: np.ndarray, params: dict) -> np.ndarray:
        """:func:`wbmpc.control.guesses.cold_guess` of this MPC."""
        return guesses.cold_guess(self.ocp, self.robot, q_hat, v_hat, params)

    def shifted_guess(self, previous: MPCSolution, q_hat: np.ndarray, t: float, params: dict) -> np.ndarray:
        """:func:`wbmpc.control.guesses.shifted_guess` of this MPC, on its node times from ``t`` [s]."""
        return guesses.shifted_guess(self.ocp, self.robot, self.time_steps(), previous, q_hat, t, params)

    # --- solve ----------------------------------------------------------------------------------------------
    def solve(
        self,
        q_hat: np.ndarray,
        v_hat: np.ndarray,
        t: float = 0.0,
        commands: Commands | None = None,
        warm_start: bool = True,
    ) -> MPCSolution:
        """Solve the OCP from the measured state.

        Args:
            q_hat: Measured configuration (nq,).
            v_hat: Measured velocity (nv,).
            t: Time [s] (sets the gait phase).
            commands: Tracking commands; zero velocities and forces by default.
            warm_start: Start from the previous plan if there is one (else a cold start).

        Returns:
            The new plan, or the previous one shifted in time with ``fallback=True`` if the solve failed;
            a measured state no robot can be in (:func:`wbmpc.control.prechecks.absurd_measurement`) is
            such a failure, status ``absurd_measurement``, its reason naming the measurement (not solved).

        Raises:
            ValueError: wrong shape or NaN in the state or the commands, a zero quaternion, an upward
                end-effector force the stance feet cannot balance (bad input, not a solver failure).
        """
        switch_s = self._switch_to_release()  # between two solves, as a robot's loop would see it
        start = time.perf_counter()
        t = checks.number("t", t, unit="s")
        if commands is not None and not isinstance(commands, Commands):
            raise ValueError(f"commands must be a Commands (wbmpc.control.mpc) or None, got {commands!r}")
        q_hat = checks.array("q_hat", q_hat, self.robot.nq)
        v_hat = checks.array("v_hat", v_hat, self.robot.nv)
        q_hat = q_hat.copy()
        norm = np.linalg.norm(q_hat[3:7])
        if norm < 1e-6:
            raise ValueError(
                f"q_hat[3:7] is the base quaternion (x, y, z, w) and must not be zero, got {q_hat[3:7]}"
            )
        # A state no robot can be in (a sensor fault) is not solved: a failed solve that names it.
        measured = tuple(self.prechecks.absurd_measurement(q_hat, v_hat))
        absurd = tuple(f for f in measured if f.severity == "error")
        q_hat[3:7] /= norm
        commands = (commands or Commands()).validated()
        # Cheap physical checks (~0.1 ms): explain a failure before it happens; refuse ill-posed commands.
        gait = self.gait(commands)
        gait = gait.gait_at(t) if isinstance(gait, GaitSchedule) else gait  # the gait in force now
        findings = measured + tuple(self.prechecks.run(q_hat, v_hat, commands, gait))
        for finding in findings:
            if finding.code in REFUSED_FINDINGS:
                raise ValueError(f"command refused: {finding.message}")
        params = self.parameters(q_hat, v_hat, t, commands)
        params = self.recovery_parameters(params, q_hat, v_hat, t, commands)  # swings aborted after a push
        p = self.ocp.params.pack(params)
        # self.previous is always the last converged plan (fallbacks are not stored).
        cold = not warm_start or self.previous is None
        x0 = None if cold else self.shifted_guess(self.previous, q_hat, t, params)
        if x0 is None or not np.isfinite(x0).all():  # Fatrop does not return from a NaN guess
            x0, cold = self.cold_guess(q_hat, v_hat, params), True
        args = {"x0": x0, "p": p, "lbg": self.ocp.lbg, "ubg": self.ocp.ubg}
        if not cold and self.config.dual_warm_start and self.previous.lam_g is not None:
            args["lam_g0"] = self.previous.lam_g
        self.last_inputs = args  # what the solver was called with (for replays, exports, debugging)
        self.stats["solves"] += 1
        if absurd:
            reason = "; ".join(f.message for f in absurd) + " (solve skipped, the controller falls back)"
            w, lam_g = None, None
            report = {"success": False, "status": "absurd_measurement", "reason": reason, "iterations": -1}
            report |= {"solve_time": 0.0, "constraint_violation": np.inf, "timings": {}}
        else:
            w, lam_g, report = self._run_solver(self._solver(cold), args)
        if not report["success"] and not cold and self.config.cold_retry and not absurd:
            # A warm start far from the new state (e.g. after a push) can stall; a cold start from the
            # measured state often converges. Its time adds to this solve's.
            self.stats["cold_retries"] += 1
            args = {**args, "x0": self.cold_guess(q_hat, v_hat, params)}
            args.pop("lam_g0", None)
            w2, lam_g2, report2 = self._run_solver(
                self._solver(True, self.solver_settings.retry_max_iter), args
            )
            report2["solve_time"] += report["solve_time"]
            # -1 is "no iteration count" (the solver raised): the total counts the iterations that ran.
            counts = [n for n in (report["iterations"], report2["iterations"]) if n >= 0]
            report2["iterations"] = sum(counts) if counts else -1
            # Where the time of both solves went (each entry summed), whichever report is kept below.
            both = {k: report["timings"].get(k, 0.0) + t for k, t in report2["timings"].items()}
            report2["timings"] = {**report["timings"], **both, "cold_retry": 1.0}
            if not report2["success"]:
                report2["reason"] = f"warm start: {report['status']}; cold retry: {report2['reason']}"
            if report2["success"] or w is None:
                w, lam_g, report = w2, lam_g2, report2
            else:
                report["solve_time"], report["iterations"] = report2["solve_time"], report2["iterations"]
                report["reason"] = report2["reason"]  # both failures, not the warm one alone
                report["timings"] = report2["timings"]
        report["findings"] = findings
        if not report["success"]:
            self.stats["failures"] += 1
            # Only converged plans reach the low level or become the warm start.
            if self.previous is not None:
                plan = replace(self.previous, fallback=True, hold=False, **report)
            else:
                self.stats["holds"] += 1
                plan = self.hold_plan(q_hat, t, params, report)
        else:
            plan = self.previous = self._solution(w, lam_g, q_hat, t, p, params, report)
        # The whole call, Python included (solve_time is the solver's share).
        plan.timings = {**plan.timings, "total": time.perf_counter() - start}
        if switch_s:
            plan.timings["library_switch"] = switch_s
        return plan

    def hold_plan(self, q_hat: np.ndarray, t: float, params: dict, report: dict | None = None) -> MPCSolution:
        """The safe command while no converged plan exists: hold the measured pose at rest.

        Every node is the measured configuration with zero velocity and acceleration; the torques are the
        static-equilibrium torques of that pose on the scheduled stance feet, or on all four feet when those
        cannot hold it: no stance foot, a base wrench they leave
        unbalanced (a trot diagonal), or a foot that would have to pull; with the commanded end-effector
        force.
        """
        robot, N = self.robot, self.n_nodes
        ee_force = params["ee_force"] if robot.has_arm else None
        stance = params["contact"][:, 0] > 0.5
        try:
            eq = static_equilibrium(robot, q_hat, stance, ee_force=ee_force)
            # A stance that leaves the base unbalanced (a trot diagonal) or needs a pulling foot cannot hold.
            holds = eq.residual_norm < HOLD_RESIDUAL and np.all(eq.forces[:, 2] >= 0.0)
        except ValueError:  # no stance foot
            holds = False
        if not holds:
            eq = static_equilibrium(robot, q_hat, np.ones(robot.n_feet, bool), ee_force=ee_force)
        forces = eq.forces if not robot.has_arm else np.vstack([eq.forces, params["ee_force"]])
        report = report or {}
        return MPCSolution(
            t=t,
            dts=self.time_steps(),
            q=np.tile(q_hat, (N, 1)),
            v=np.zeros((N, robot.nv)),
            a=np.zeros((N - 1, robot.nv)),
            forces=np.tile(forces, (N - 1, 1, 1)),
            tau=np.tile(eq.tau, (self.ocp.settings.n_tau_nodes, 1)),
            contact=params["contact"] > 0.5,
            success=False,
            iterations=report.get("iterations", -1),
            solve_time=report.get("solve_time", 0.0),
            status=report.get("status", "hold"),
            reason=report.get("reason", ""),
            findings=report.get("findings", ()),
            constraint_violation=report.get("constraint_violation", np.inf),
            fallback=True,
            hold=True,
            timings=report.get("timings", {}),
        )

    def _run_solver(
        self, solver: ca.Function, args: dict
    ) -> tuple[np.ndarray | None, np.ndarray | None, dict]:
        """One solver call: primal and dual solution (``None`` if it raised) and a report."""
        start = time.perf_counter()
        try:
            out = solver(**args)
            stats = solver.stats()
            elapsed = time.perf_counter() - start
            w = np.array(out["x"]).ravel()
            g = np.array(out["g"]).ravel()
            violation = float(np.max(np.maximum(0.0, np.maximum(self.ocp.lbg - g, g - self.ocp.ubg))))
            success = bool(stats.get("success", False)) and bool(np.isfinite(w).all())
            status, reason = solver_status(self.solver_settings.solver, stats)
            if not success and status == "success":  # a non-finite iterate
                status, reason = "non_finite_solution", "the solver returned NaN or inf"
            iterations = int(stats.get("iter_count", -1))
            lam_g = np.array(out["lam_g"]).ravel()
            timings = solver_timings(stats, elapsed)
        except RuntimeError as exc:  # the solver raised (e.g. NaN in an evaluation): counted, not fatal
            elapsed = time.perf_counter() - start
            self.stats["exceptions"] += 1
            status, reason = exception_status(exc)
            success, iterations, violation = False, -1, np.inf
            w = lam_g = None
            timings = {"wall": elapsed}
        report = {
            "success": bool(success),
            "status": status,
            "reason": "" if success else reason,
            "iterations": iterations,
            "solve_time": elapsed,
            "constraint_violation": violation,
            "timings": timings,
        }
        return w, lam_g, report

    def _solution(self, w, lam_g, q_hat, t, p, params, report: dict) -> MPCSolution:
        plan = self.ocp.plan(w, p)
        model = self.robot.model
        q = np.array([pin.integrate(model, q_hat, d) for d in plan["dq"]])
        n_c = len(self.robot.contact_frames)
        return MPCSolution(
            t=t,
            dts=self.time_steps(),
            q=q,
            v=plan["v"],
            a=plan["a"],
            forces=plan["forces"].reshape(-1, n_c, 3),
            tau=plan["tau"],
            contact=params["contact"] > 0.5,
            w=w,
            lam_g=lam_g,
            **report,
        )

    def reset(self) -> None:
        """Forget the previous plan (the next solve is a cold start) and any aborted swing."""
        self.previous = None
        self.push_recovery.reset()

    def recovery_parameters(
        self, params: dict, q_hat: np.ndarray, v_hat: np.ndarray, t: float, commands: Commands
    ) -> dict:
        """The stage parameters after a push (see :mod:`wbmpc.control.push_recovery`): aborted swings
        (``MPCConfig.kick_recovery``) and, while recovering, the released end-effector velocity
        (``MPCConfig.kick_ee_release``); ``params`` itself when neither acts (no push detected)."""
        recovery = self.push_recovery
        aborts = recovery.swing_aborts
        recovery.update(q_hat, v_hat, t, commands, self.config, self.previous, self.gait(commands))
        self.stats["swing_aborts"] += recovery.swing_aborts - aborts
        return recovery.parameters(params, q_hat, v_hat, t, commands, self.config, self.time_steps())

    def gait(self, commands: Commands | None = None) -> Gait | GaitSchedule:
        """The gait of a solve: the commands' (a command schedule's) if they carry one, else the config's."""
        if commands is not None and commands.gait is not None:
            return commands.gait
        return self.config.gait

    def contact_plan(self, times, gait: Gait | GaitSchedule | None = None) -> np.ndarray:
        """Contact flags (4, n) at ``times`` [s]: ``gait`` (default: the configured one) with any aborted
        swing (the one plan the closed loop's plant, state estimator and logs share with the MPC)."""
        return self.push_recovery.contact(times, self.config.gait if gait is None else gait)

    @property
    def aborted_swings(self) -> dict[int, float]:
        """Foot -> nominal touchdown time [s] of its aborted swing."""
        return {i: span[1] for i, span in self.push_recovery.aborted.items()}

    @property
    def recovering(self) -> bool:
        """After a push, until the base velocity is back near the command."""
        return self.push_recovery.recovering
