"""The controller's 500 Hz loop on the wall clock (the process that talks to the robot).

Each tick of :class:`ControlLoop` (absolute deadlines, :class:`~wbmpc.runtime.clock.DeadlineLoop`):

1. read the newest observation (``None``: none arrived; the estimate stands) and estimate;
2. take the newest plan of the current epoch from the worker, if one came; a plan made with delay
   compensation starts in the future (at its measurement time plus the expected delay): it waits until
   then and the plan in use goes on, as in the simulated loop (:class:`~wbmpc.sim.closed_loop.ClosedLoop`
   delivers a plan at its start). Used early, its first interval would be extrapolated backwards (the
   feed-forward by up to a whole 10 ms step) and the arm, light and stiffly controlled, rings;
3. the watchdog: a trip (no new plan for ``max_plan_age``, ``max_overruns`` overruns in a row, the worker
   dead, an unusable observation, a restarted robot, no observation for ``max_observation_gap`` of loop
   ticks) puts the controller in the damping mode for good; the reason is printed and recorded once;
4. command the robot at the tick's time; publish the estimate for the worker (not in damping: nothing more
   is planned);
5. record the tick (:class:`~wbmpc.runtime.metrics.RuntimeMetrics`) and the log row.

Before the first tick the loop waits for the robot's first observation (the estimator starts at the
nominal base pose with the measured joints) and for the first plan, so the robot is never commanded before
there is a plan.
"""

from __future__ import annotations

import gc
import time

import numpy as np

from wbmpc.runtime.clock import DeadlineLoop
from wbmpc.runtime.faults import FaultyRobot
from wbmpc.runtime.metrics import RuntimeMetrics
from wbmpc.runtime.watchdog import Watchdog

__all__ = ["ControlLoop"]

#: Fields of the runtime log, one row per tick.
LOG_FIELDS = (
    "t",
    "q_hat",
    "v_hat",
    "q_cmd",
    "dq_cmd",
    "tau_cmd",
    "damping",
    "plan_seq",
    "lateness",
    "compute",
    "plan_age",
    "plan_obs_t",
)


class ControlLoop:
    """The loop of one run (built by :func:`wbmpc.runtime.run.run_runtime`).

    Args:
        config: The :class:`~wbmpc.runtime.run.RuntimeConfig`.
        robot: The robot model; client: the robot (:class:`~wbmpc.runtime.robot.Robot`).
        controller: The :class:`~wbmpc.runtime.controller.RuntimeController`.
        plans, observations: The channels from and to the worker; worker: its process.
        restart_robot: Called once at ``faults.restart_robot_at`` (fault injection).

    Attributes:
        log: Field -> list of per-tick values (:data:`LOG_FIELDS`), kept up to a fault or an error.
        metrics: The run's :class:`RuntimeMetrics`; watchdog: its :class:`Watchdog`.
    """

    def __init__(self, config, robot, client, controller, plans, observations, worker, restart_robot):
        self.config, self.robot, self.controller = config, robot, controller
        self.plans, self.observations, self.worker = plans, observations, worker
        self.restart_robot = restart_robot
        self.t0 = time.monotonic()
        faults = config.faults
        self.client = FaultyRobot(client, faults, self.now) if faults.observation_faults else client
        self.metrics = RuntimeMetrics()
        self.watchdog = Watchdog(config.max_plan_age, config.max_overruns)
        self.log = {key: [] for key in LOG_FIELDS}
        self.epoch = 1
        self.plan_seq, self.plan_meta = 0, None  # the newest plan received
        self.used_seq, self.used_obs_t = 0, 0.0  # the plan in use and its measurement time
        self.pending: list = []  # (plan, seq, measurement time) received, not started yet, oldest first
        self._said: set[str] = set()
        self.later_causes: list[tuple[float, str]] = []

    def now(self) -> float:
        """The run's clock [s]."""
        return time.monotonic() - self.t0

    def run(self) -> dict:
        """Run ``config.duration`` seconds of ticks; returns the summary (metrics, counters)."""
        # No garbage collection while the loop runs: a full collection of this process's heap pauses it
        # for several ticks (five overruns in a row, seen). The loop makes no reference cycles; whatever
        # piles up is collected after it.
        gc.collect()
        gc.freeze()
        gc.disable()
        try:
            return self._run()
        finally:
            gc.enable()
            gc.unfreeze()

    def _run(self) -> dict:
        config, robot, controller = self.config, self.robot, self.controller
        first = self._first_observation(5.0)
        q0 = robot.q_nominal.copy()
        q0[7:] = first.q
        controller.reset(q0, np.zeros(robot.nv))
        self.t0 = time.monotonic()
        self.observations.publish(0.0, q0, np.zeros(robot.nv), epoch=self.epoch)
        self._first_plan(60.0)
        return self._ticks(DeadlineLoop(config.period, phase_s=config.controller_phase))

    def _ticks(self, loop: DeadlineLoop) -> dict:
        config, controller = self.config, self.controller
        faults = config.faults
        killed = restarted = False
        last_wake, silent_ticks = None, 0
        # The robot's silence is counted in the loop's own ticks: when the whole machine stalls (a
        # virtual machine's host took both CPUs for 50 ms, seen), the robot and the controller stop
        # together and the first tick after it comes before the robot's next reading; a robot that stops
        # publishing is still caught after max_observation_gap of ticks.
        max_silent = round(config.max_observation_gap / config.period)
        while True:  # for ``duration`` seconds of the wall clock (skipped ticks do not lengthen the run)
            tick = loop.wait_next()
            now = tick.wake_ns / 1e9 - self.t0
            if now >= config.duration:
                loop.tick_done()
                break
            if faults.kill_worker_at is not None and not killed and now >= faults.kill_worker_at:
                self.worker.kill()  # SIGKILL: no clean-up, no last words
                killed = True
            if faults.restart_robot_at is not None and not restarted and now >= faults.restart_robot_at:
                self.restart_robot()
                restarted = True
            observation = self.client.read()
            silent_ticks += 1
            if observation is not None:
                observation.stamp -= self.t0  # the run's clock (both on CLOCK_MONOTONIC)
                problem = controller.estimate(observation)
                if "not finite" in problem or "restarted" in problem:
                    self._trip(f"the robot sent an unusable observation: {problem}", now)
                elif not problem:
                    silent_ticks = 0
            if silent_ticks > max_silent:
                gap = silent_ticks * config.period
                self._trip(f"no observation from the robot for {silent_ticks} ticks ({gap:.3f} s)", now)
            got = self.plans.latest(self.plan_seq, self.epoch)
            if got is not None:
                self.plan_seq, self.plan_meta = got[1].seq, got[1]
                self.metrics.plan_received(self.plan_seq, self.plan_meta.observation_time)
                self.pending.append((got[0], got[1].seq, got[1].observation_time))
            self._start_due_plans(now)
            if not self.worker.is_alive():
                self._trip("the MPC worker died", now)
            state = self.watchdog.check(now, self.plan_meta.observation_time, tick.overrun)
            if state.tripped:
                self._trip(state.reason, now)
            command = controller.command(now)
            self.client.write(command)
            if not command.damping:
                self.metrics.plan_used(self.used_seq, now)
                self.observations.publish(now, controller.q_hat, controller.v_hat, epoch=self.epoch)
            compute = loop.tick_done()
            age = None if command.damping else now - self.used_obs_t  # of the plan in use
            period = None if last_wake is None else (tick.wake_ns - last_wake) / 1e9
            last_wake = tick.wake_ns
            self.metrics.tick(
                lateness_s=tick.lateness_s,
                overrun=tick.overrun,
                compute_s=compute,
                period_s=period,
                plan_age_s=age,
                skipped=tick.skipped,
            )
            self._record(now, command, tick.lateness_s, compute, age)
        return self._summary()

    def _start_due_plans(self, now: float) -> None:
        """Hand the newest pending plan whose start time has come to the controller (older pending plans
        are superseded by it and dropped)."""
        due = [i for i, (plan, *_) in enumerate(self.pending) if plan.t <= now + 1e-9]
        if due:
            plan, self.used_seq, self.used_obs_t = self.pending[due[-1]]
            self.controller.offer(plan)
            del self.pending[: due[-1] + 1]

    def _trip(self, reason: str, now: float) -> None:
        """Damping from now on; say why once (the first cause; later ones are only listed in the summary's
        ``later_causes``)."""
        self.watchdog.trip(reason, now)
        self.controller.enter_damping()
        if not self._said:
            self.metrics.watchdog_event(now, reason)
            print(f"[wbmpc.runtime] t={now:.3f} s: damping mode: {reason}", flush=True)
        elif reason not in self._said and len(self._said) < 20:
            self.later_causes.append((now, reason))
        self._said.add(reason)

    def _record(self, now: float, command, lateness: float, compute: float, plan_age: float | None) -> None:
        log, controller = self.log, self.controller
        row = (now, controller.q_hat, controller.v_hat, command.q, command.dq, command.tau)
        for key, value in zip(LOG_FIELDS[:6], row, strict=True):
            log[key].append(value)
        log["damping"].append(command.damping)
        log["plan_seq"].append(self.used_seq)
        log["lateness"].append(lateness)
        log["compute"].append(compute)
        log["plan_age"].append(np.nan if plan_age is None else plan_age)
        log["plan_obs_t"].append(self.used_obs_t)

    def _first_observation(self, timeout: float):
        deadline = time.monotonic() + timeout
        while (observation := self.client.read()) is None:
            if time.monotonic() > deadline:
                raise RuntimeError(f"no observation from the robot within {timeout:g} s")
            time.sleep(0.001)
        return observation

    def _first_plan(self, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while (got := self.plans.latest(self.plan_seq, self.epoch)) is None:
            if time.monotonic() > deadline or not self.worker.is_alive():
                raise RuntimeError(f"no first plan from the MPC worker within {timeout:g} s")
            time.sleep(0.001)
        self.controller.offer(got[0])  # made from the robot at rest at t = 0: it starts at once
        self.plan_seq, self.plan_meta = got[1].seq, got[1]
        self.used_seq = self.plan_seq
        self.metrics.plan_received(self.plan_seq, self.plan_meta.observation_time)

    def _summary(self) -> dict:
        from dataclasses import asdict

        metrics, controller = self.metrics, self.controller
        metrics.plan_rejected("stale", self.plans.rejected_stale)
        metrics.plan_rejected("epoch", self.plans.rejected_epoch)
        summary = metrics.summary()
        summary["config"] = asdict(self.config)
        summary["controller_problems"] = [reason for _, reason in controller.problems[:20]]
        summary["controller_problem_count"] = len(controller.problems)
        summary["clipped"] = dict(controller.clipped)
        summary["held_periods"] = controller.held_periods
        summary["damping"] = bool(controller.damping)
        summary["later_causes"] = [{"time_s": t, "reason": r} for t, r in self.later_causes]
        damped = np.flatnonzero(self.log["damping"])
        summary["damping_from_s"] = float(self.log["t"][damped[0]]) if damped.size else None
        if isinstance(self.client, FaultyRobot):
            summary["injected"] = dict(self.client.injected)
        return summary
