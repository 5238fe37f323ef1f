"""The MPC worker: a process of its own that plans from the latest observation, as fast as it can.

The controller publishes its state estimate at every tick (:class:`~wbmpc.runtime.shared.ObservationChannel`);
the worker takes the newest one, plans from it (:class:`wbmpc.sim.planner.Planner`: the command schedule,
delay compensation with the measured solve times, the arm's command, the solve) and publishes the plan
(:class:`~wbmpc.runtime.shared.PlanChannel`) tagged with the observation it was made from. Older
observations are skipped, never queued: OCS2's MPC/MRT split. A failed solve is counted and not published
(the controller keeps the plan it has; its watchdog sees the age grow).

The worker builds its MPC itself from an :class:`MPCRecipe` (a spawned process shares no objects), compiled
Fatrop by default, and announces when it is ready. It runs until its stop event is set, or until its
parent dies.
"""

from __future__ import annotations

import os
import time
import traceback
from dataclasses import dataclass, field, replace

import numpy as np

__all__ = ["MPCRecipe", "WorkerStats", "run_worker"]

#: Solves from the nominal standing pose before the worker says it is ready (warm start, caches).
WARMUP_SOLVES = 3


@dataclass(frozen=True)
class MPCRecipe:
    """How to build the worker's MPC (picklable).

    Attributes:
        gait: Gait schedule of the run (:func:`wbmpc.ocp.gait.parse_gait_schedule`, e.g.
            ``"stand:2,trot@0.2:56,stand:2"``).
        nodes: MPC nodes.
        compiled: Compiled Fatrop (cached library) or in-process.
        base_com_offset: Shift [m] of the MPC model's base CoM (the identified offset of the robot,
            :func:`wbmpc.model.base_com.shift_base_com`), or ``None``.
        torque_limit_fraction: Share of the torque limits the MPC plans with (the drives add damping).
        max_iter: Iteration cap of a warm-started solve; ``None``: the solver's default
            (:class:`~wbmpc.control.config.SolverSettings`). On the wall clock a solve past the cap is not
            worth finishing: its plan would be too old (the next solve starts from a newer state).
        cold_retry: Retry a failed warm solve from a cold start in the same tick
            (:attr:`MPCConfig.cold_retry <wbmpc.control.config.MPCConfig.cold_retry>`); off by default on
            the wall clock, where it makes a failed tick last a second.
        direct: Solve with the direct primal-dual warm-started Fatrop driver
            (:attr:`SolverSettings.direct <wbmpc.control.config.SolverSettings.direct>`).
    """

    gait: str = "stand:2,trot@0.2:6,stand:2"
    nodes: int = 15
    compiled: bool = True
    base_com_offset: tuple[float, float, float] | None = (-0.19, 0.0, 0.0)
    torque_limit_fraction: float = 0.9
    max_iter: int | None = None
    cold_retry: bool = True
    direct: bool = False

    def robot(self):
        """The MPC's robot model."""
        from wbmpc.model.base_com import shift_base_com
        from wbmpc.model.robot import load_b1_z1

        robot = load_b1_z1()
        if self.base_com_offset is not None:
            robot = shift_base_com(robot, np.asarray(self.base_com_offset, dtype=float))
        return robot

    def schedule(self):
        from wbmpc.ocp.gait import parse_gait_schedule

        return parse_gait_schedule(self.gait)

    def plan_layout(self, robot):
        """The :class:`~wbmpc.runtime.shared.PlanLayout` of this MPC's plans for ``robot``."""
        from wbmpc.ocp import OCPSettings
        from wbmpc.runtime.shared import PlanLayout

        n_tau = OCPSettings(n_nodes=self.nodes).n_tau_nodes
        return PlanLayout(
            self.nodes, robot.nq, robot.nv, robot.nj, n_tau, len(robot.contact_frames), robot.n_feet
        )

    def build(self):
        """The MPC (prepared: its solver built or loaded from the cache)."""
        from wbmpc.control.mpc import MPCConfig, SolverSettings, WholeBodyMPC
        from wbmpc.ocp import OCPSettings

        settings = OCPSettings(n_nodes=self.nodes, torque_limit_fraction=self.torque_limit_fraction)
        # The release library if it is cached, but no background build on the wall clock: gcc would take a
        # core from the loops mid-run.
        # One evaluation thread: the controller and the robot have the other cores.
        solver = SolverSettings(compiled=self.compiled, direct=self.direct, release_build=False, threads=1)
        if self.max_iter is not None:
            solver = replace(solver, max_iter=self.max_iter)
        config = MPCConfig(gait=self.schedule(), cold_retry=self.cold_retry)
        mpc = WholeBodyMPC(self.robot(), settings, config, solver)
        mpc.verbose = False
        mpc.prepare()
        return mpc


@dataclass
class WorkerStats:
    """What the worker did (the parent reads it from the stats queue at the end).

    Attributes:
        solves: Solves run; failed: solves that did not converge (not published); published: plans sent;
        skipped: observations superseded before the worker took them; solve_times: whole call [s] per
        solve; iterations: per solve; errors: tracebacks of exceptions (the worker stops on one);
        solver: what solved (``direct`` driver or plugin, the compiled library's gcc ``flags``).
    """

    solves: int = 0
    failed: int = 0
    published: int = 0
    skipped: int = 0
    solve_times: list = field(default_factory=list)
    iterations: list = field(default_factory=list)
    reasons: list = field(default_factory=list)
    errors: list = field(default_factory=list)
    solver: dict = field(default_factory=dict)


def run_worker(
    recipe: MPCRecipe,
    loop_config,
    q0,
    observations,
    plans,
    ready,
    stop,
    stats_path,
    stall=None,
    nice=0,
    cpus=None,
):
    """The worker process's body (the target of a spawned ``multiprocessing.Process``).

    Args:
        recipe: The MPC to build.
        loop_config: The run's :class:`~wbmpc.sim.loop_config.ClosedLoopConfig` (commands, delay
            compensation, arm gains, plant step).
        q0: Initial configuration (the arm's hold point).
        observations: The :class:`~wbmpc.runtime.shared.ObservationChannel` to read.
        plans: The :class:`~wbmpc.runtime.shared.PlanChannel` to write.
        ready: Event set once the MPC is built; stop: event that ends the loop.
        stats_path: File the :class:`WorkerStats` is written to at the end (:mod:`~wbmpc.runtime.accounts`).
        stall: Optional ``(start_s, duration_s)``: the solver stalls once, for fault tests.
        nice: Niceness added to the worker (needs no privilege). 0 by default: on 2 cores with the emulated
            robot beside it, +5 made the solves slower (50 against 42 ms mean, one 8 s run each) without
            steadier ticks.
        cpus: CPUs the worker may run on (``os.sched_setaffinity``), or ``None`` for any.
    """
    from wbmpc.runtime.shared import ObservationChannel, PlanChannel, SlotDescription
    from wbmpc.sim.planner import Planner

    if isinstance(observations, SlotDescription):
        observations = ObservationChannel.attach(observations)
    if isinstance(plans, SlotDescription):
        plans = PlanChannel.attach(plans)
    stats = WorkerStats()
    parent = os.getppid()
    try:
        if cpus is not None:
            os.sched_setaffinity(0, cpus)
        if nice:
            os.nice(nice)  # the controller's loop must get a core the moment it wakes
        mpc = recipe.build()
        settings = mpc.solver_settings
        stats.solver = {"direct": settings.direct_driver, "compiled": bool(settings.compiled)}
        if settings.compiled:
            stats.solver["flags"] = list(mpc.library_flags())
        q0 = np.asarray(q0, dtype=float)
        planner = Planner(mpc, loop_config, q0)
        v0 = np.zeros(mpc.robot.nv)
        for _ in range(WARMUP_SOLVES):  # the first solves of a process are slow (caches, pages, warm start)
            planner.plan(q0, v0, 0.0, None, record_delay=False)
        ready.set()
        last_seq, epoch, plan_in_use, first = 0, None, None, True
        stalled = False
        while not stop.is_set():
            if os.getppid() != parent:
                break  # the controller died: nobody reads our plans
            observation = observations.latest(after_seq=last_seq)
            if observation is None:
                time.sleep(0.0002)
                continue
            stats.skipped += max(0, observation.seq - last_seq - 1)
            last_seq = observation.seq
            if observation.epoch != epoch:  # the controller (re)started
                if epoch is not None:
                    mpc.reset()  # a reset: the last plan says nothing of the new state
                epoch, plan_in_use, first = observation.epoch, None, True
                planner.reset()
            if stall is not None and not stalled and observation.t >= stall[0]:
                stalled = True
                time.sleep(stall[1])
            start = time.perf_counter()
            plan = planner.plan(
                observation.q, observation.v, observation.t, plan_in_use, record_delay=not first
            )
            stats.solves += 1
            stats.solve_times.append(time.perf_counter() - start)
            stats.iterations.append(int(plan.iterations))
            first = False
            if not plan.success or plan.fallback:
                stats.failed += 1
                stats.reasons.append(plan.reason or plan.status)
                continue
            plans.publish(plan, epoch=epoch, observation_seq=observation.seq, observation_time=observation.t)
            stats.published += 1
            plan_in_use = plan
    except Exception:  # reported to the parent, which falls back to damping when plans stop
        stats.errors.append(traceback.format_exc())
    finally:
        from wbmpc.runtime.accounts import write_account

        write_account(stats_path, stats)
