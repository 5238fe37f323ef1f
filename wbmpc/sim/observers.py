"""Observers of the closed loop: what watches a run without steering it (logs, failure reports, progress).

A :class:`LoopObserver` is called by :class:`wbmpc.sim.closed_loop.ClosedLoop` at fixed points of each plant
step (Crocoddyl's callbacks, Drake's loggers): :meth:`~LoopObserver.on_step` at the start of every plant
step, :meth:`~LoopObserver.on_solve` after every MPC solve, :meth:`~LoopObserver.on_tick` at every
low-level tick (after the torques are computed, before the plant steps), and
:meth:`~LoopObserver.summary` for its entries of the run summary. It reads the loop's public attributes
(``loop.t``, ``loop.state``, ``loop.q_meas``, ``loop.tau``, ``loop.commands``, ``loop.plant``, ...) and never
changes them. Pass extra observers to :func:`~wbmpc.sim.closed_loop.run_closed_loop` (``observers=``).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from wbmpc.control.config import MPCSolution
from wbmpc.sim.failure_reporter import FailureReporter
from wbmpc.sim.loop_log import ClosedLoopLog

__all__ = ["FailureObserver", "LogRecorder", "LoopObserver", "ProgressBar"]


class LoopObserver:
    """Hooks of the closed loop; every one does nothing by default (override the ones you need)."""

    def on_step(self, loop, step: int) -> None:
        """At the start of plant step ``step`` (before anything of the step ran)."""

    def on_solve(self, loop, plan: MPCSolution, apply_t: float) -> None:
        """After a solve: ``plan`` reaches the low level at ``apply_t`` [s] (``loop.t`` is the solve's)."""

    def on_tick(self, loop) -> None:
        """At a low-level tick, after the torques were computed and before the plant steps."""

    def summary(self) -> dict:
        """Entries this observer adds to the run summary."""
        return {}

    def close(self) -> None:
        """At the end of the run (also after an error)."""


class LogRecorder(LoopObserver):
    """Fills a :class:`~wbmpc.sim.loop_log.ClosedLoopLog`: every low-level tick and every solve.

    Args:
        log: The log (in memory or streamed, :meth:`ClosedLoopLog.streaming`).
        keep_plans: Keep every plan (memory heavy; for replays of the predictions).
    """

    def __init__(self, log: ClosedLoopLog, keep_plans: bool = False):
        self.log = log
        self.keep_plans = keep_plans
        self._data = None

    def on_step(self, loop, step: int) -> None:
        self.log.tick(step)  # a streamed log writes a chunk to disk and empties its lists

    def on_solve(self, loop, plan: MPCSolution, apply_t: float) -> None:
        log = self.log
        if loop.ee_command is not None:
            cmd = loop.ee_command
            log.ee_command.append(cmd if cmd.ndim == 1 else cmd[:, 0])
        log.solve_t.append(plan.t)
        log.apply_t.append(apply_t)
        log.plan_q.append(plan.q[:2].copy())
        log.plan_v.append(plan.v[:2].copy())
        log.plan_tau.append(plan.tau[0].copy())
        log.plan_forces.append(plan.forces[0].copy())
        log.plan_contact.append(np.asarray(plan.contact[:, 0], bool))
        log.hold.append(bool(plan.hold))
        log.solve_time.append(plan.solve_time)
        log.iterations.append(plan.iterations)
        log.success.append(plan.success)
        log.fallback.append(plan.fallback)
        log.violation.append(plan.constraint_violation)
        log.status.append(plan.status)
        log.reason.append(plan.reason)
        log.timings.append(plan.timings)
        if self.keep_plans:
            log.plans.append(plan)

    def on_tick(self, loop) -> None:
        log, plant, robot = self.log, loop.plant, loop.robot
        q, v, cmd = loop.state.q, loop.state.v, loop.commands
        log.t.append(loop.t)
        log.q.append(q.copy())
        log.v.append(v.copy())
        log.q_meas.append(loop.q_meas.copy())
        log.v_meas.append(loop.v_meas.copy())
        log.tau.append(loop.tau.copy())
        log.tau_ff.append(loop.low.last_reference.tau_ff)
        log.contact.append(loop.contact)
        log.contact_sim.append(plant.foot_contacts(loop.contact))
        log.foot_forces.append(plant.contact_forces())
        log.foot_height.append(plant.foot_positions[:, 2] - robot.foot_radius)
        log.base_velocity_cmd.append(cmd["base_velocity"])
        log.base_yaw_rate_cmd.append(cmd["base_yaw_rate"])
        log.ee_force_cmd.append(cmd["ee_force"])
        if loop.ee_id is not None:  # only the end-effector frame is needed here
            model = robot.model
            if self._data is None:
                self._data = model.createData()
            pin.forwardKinematics(model, self._data, q)
            log.ee_position.append(pin.updateFramePlacement(model, self._data, loop.ee_id).translation.copy())
            log.ee_force_sim.append(plant.ee_contact_force())
        else:
            log.ee_position.append(np.full(3, np.nan))
            log.ee_force_sim.append(np.zeros(3))
        log.ee_reference.append(loop.ee_reference.copy())
        if loop.scene_names:
            log.scene_positions.append(np.array([plant.body_pose(name)[0] for name in loop.scene_names]))


class FailureObserver(LoopObserver):
    """Reports failed solves and precheck findings (one line per new reason, then counts), for the summary.

    Args:
        reporter: The reporter (default: one printing ``[closed loop] ...`` lines).
    """

    def __init__(self, reporter: FailureReporter | None = None):
        self.reporter = reporter or FailureReporter(prefix="[closed loop]")

    def on_solve(self, loop, plan: MPCSolution, apply_t: float) -> None:
        if plan.fallback:
            kept = "static hold applied" if plan.hold else "previous plan kept"
            self.reporter.report(loop.t, plan.status, f"{plan.reason} ({kept})")
        if plan.findings:
            self.reporter.report_findings(loop.t, plan.findings)

    def summary(self) -> dict:
        return {"diagnostics": self.reporter.summary()}


class ProgressBar(LoopObserver):
    """A tqdm bar of the solves, with the last solve's iterations and time.

    Args:
        total: Expected number of solves.
    """

    def __init__(self, total: int):
        from tqdm.auto import tqdm

        self.bar = tqdm(total=total, desc="MPC", unit="solve")

    def on_solve(self, loop, plan: MPCSolution, apply_t: float) -> None:
        self.bar.update(1)
        self.bar.set_postfix(iters=plan.iterations, ms=f"{1e3 * plan.solve_time:.0f}")

    def close(self) -> None:
        self.bar.close()
