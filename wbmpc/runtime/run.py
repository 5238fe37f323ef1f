"""A runtime run on the wall clock: the robot, the MPC worker and the 500 Hz controller, each a process.

:func:`run_runtime` starts the robot (the emulated robot in its own process, behind shared memory or DDS)
and the MPC worker (:mod:`wbmpc.runtime.mpc_worker`), waits until both are ready and the first plan is in,
then runs the controller loop in this process on absolute 2 ms deadlines (:class:`DeadlineLoop`):

1. read the newest robot observation; estimate (:class:`~wbmpc.runtime.controller.RuntimeController`);
2. take the newest plan from the worker if there is one (stale, out-of-order and other-epoch plans are
   refused by the channel and counted);
3. command the robot at the tick's time from the plan in use, or in damping mode once the watchdog tripped
   (no new plan for ``max_plan_age`` seconds, ``max_overruns`` overruns in a row, the worker dead, an
   observation that is not finite, no observation for ``max_observation_gap`` of loop ticks); the reason is
   said once;
4. publish the estimate for the worker; record the tick (:class:`~wbmpc.runtime.metrics.RuntimeMetrics`).

The run writes its log (``runtime_log.npz``: per tick the time, estimate, command, plan in use), the same
as a ROS 2 bag (``bag/``: the estimate as joint states and odometry, the commanded feed-forward torques),
and a summary JSON with the metrics, the worker's and the robot's accounts, and the robot's true forward
speed.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from wbmpc.runtime.accounts import read_account
from wbmpc.runtime.faults import Faults
from wbmpc.runtime.mpc_worker import MPCRecipe, run_worker
from wbmpc.runtime.priority import check_priority, realtime_priority
from wbmpc.runtime.robot_process import EmulatedRobotSpec, run_emulated_robot

__all__ = ["CPU_LAYOUTS", "RuntimeConfig", "cpu_sets", "run_runtime"]

#: :attr:`RuntimeConfig.cpu_layout` values: who gets a CPU to itself ("split": the worker), or nobody.
CPU_LAYOUTS = ("split", "controller", "robot", "any")


@dataclass
class RuntimeConfig:
    """One runtime run.

    Attributes:
        duration: Wall-clock length of the controlled run [s] (stand 2 s, trot, stand 2 s).
        speed: Forward speed command of the trot [m/s].
        robot: ``"emulated"`` (the emulated robot behind shared memory) or ``"dds"`` (behind DDS,
            ``rt/lowcmd`` / ``rt/lowstate``).
        domain, interface: DDS domain and network interface (``robot="dds"``).
        period: Controller period [s]; mpc_rate: the planner's nominal rate [Hz] (the worker runs free, a
            solve starting when the last one returned; a multiple of the robot's 1 ms step).
        max_plan_age: Watchdog limit on the age of the plan in use [s]; max_overruns: overrun ticks in a row
            that trip it; max_observation_gap: time without a robot observation that trips it [s],
            counted in the loop's own ticks (a stall of the whole machine is not the robot's silence).
        nodes, compiled: The MPC; max_iter: its warm solves' iteration cap (a failed solve is not
            published; no cold retry on the wall clock); direct: the worker solves with the direct Fatrop
            driver (:mod:`wbmpc.solver.direct`; compiled or, without ``compiled``, its in-process build, on
            one thread beside the loops); ``None`` (default): True. Its whole tick is about
            half the plugin's, which keeps the plan age at use within two MPC periods on 2 cores (p95
            20 ms over DDS, 60 s, 2026-12-04; the plugin's solves alone take 13-15 ms).
        faults: Faults to inject (:class:`~wbmpc.runtime.faults.Faults`), for tests.
        gait_schedule: The gait schedule (e.g. ``"stand:1,trot@0.2:3"``; the run lasts it, ``duration`` is
            replaced); ``None``: stand 2 s, trot at ``speed``, stand 2 s over ``duration``.
        ready_timeout: Seconds to wait for the worker's MPC (a first compile takes minutes).
        controller_phase: Offset [s] of the controller's ticks on the monotonic clock's grid of periods,
            where the emulated robot ticks at offset 0 (:attr:`EmulatedRobotSpec.phase`); ``None``: the
            loop starts when it starts. Half a period by default: the robot's physics and the controller's
            tick then take turns on the CPU they share and each command is computed from a reading half a
            period old (when they woke together, a fifth of the controller's ticks waited 0.6-0.8 ms for
            the robot's physics and the loop period's p99 was 2.84 ms). A real robot keeps its own time:
            the offset to its readings is then whatever it happens to be.
        realtime_priority: ``SCHED_FIFO`` priority of the controller's loop
            (:func:`~wbmpc.runtime.priority.realtime_priority`; where the system refuses it, the loop runs at
            the ordinary priority and the summary's ``scheduling`` says why), or ``None``.
        arm_motion: The arm's end effector moves up and down (the default
            :class:`~wbmpc.control.arm_task.ArmReference`, 15 cm over 5 s) instead of being held still in
            the heading frame (the default: a stand-trot-stand run tests the legs and the wire).
        cpu_layout: Who gets a CPU to itself (``os.sched_setaffinity``, :func:`cpu_sets`): ``"split"``
            the MPC worker (the controller and the robot share the others; a solve otherwise takes turns
            with both fast loops), ``"controller"`` or ``"robot"``; ``"any"``: the kernel places every
            process.
    """

    duration: float = 10.0
    speed: float = 0.2
    robot: str = "emulated"
    domain: int = 42
    interface: str = "lo"
    period: float = 0.002
    mpc_rate: float = 100.0
    max_plan_age: float = 0.15
    max_overruns: int = 5
    max_observation_gap: float = 0.02
    nodes: int = 15
    compiled: bool = True
    max_iter: int = 15
    direct: bool | None = None
    faults: Faults = field(default_factory=Faults)
    ready_timeout: float = 900.0
    gait_schedule: str | None = None
    cpu_layout: str = "split"
    arm_motion: bool = False
    controller_phase: float | None = 0.001
    realtime_priority: int | None = 50

    def __post_init__(self):
        if self.cpu_layout not in CPU_LAYOUTS:
            layout = self.cpu_layout
            raise ValueError(f"RuntimeConfig.cpu_layout must be one of {CPU_LAYOUTS}, got {layout!r}")
        if not isinstance(self.faults, Faults):
            raise ValueError(f"RuntimeConfig.faults must be a Faults, got {self.faults!r}")
        check_priority(self.realtime_priority, "RuntimeConfig.realtime_priority")
        if self.direct is None:
            self.direct = True
        if self.controller_phase is not None and not 0.0 <= self.controller_phase < self.period:
            raise ValueError(
                f"RuntimeConfig.controller_phase must be in [0, period = {self.period}) s or None, "
                f"got {self.controller_phase!r}"
            )
        if self.robot not in ("emulated", "dds"):
            raise ValueError(f"RuntimeConfig.robot must be 'emulated' or 'dds', got {self.robot!r}")
        if self.robot == "dds":
            from wbmpc.runtime.dds import check_domain, check_interface

            check_domain(self.domain)
            check_interface(self.interface)
        if self.gait_schedule is not None:
            from wbmpc.ocp.gait import parse_gait_schedule

            # raises on a bad schedule, before anything starts; the run lasts the schedule
            self.duration = float(parse_gait_schedule(self.gait_schedule).duration)
        elif not (np.isfinite(self.duration) and self.duration >= 4.5):
            raise ValueError(
                f"RuntimeConfig.duration must be >= 4.5 s (stand 2, trot, stand 2), got {self.duration}"
            )
        if not (np.isfinite(self.speed) and abs(self.speed) <= 1.0):
            raise ValueError(f"RuntimeConfig.speed must be within +-1 m/s, got {self.speed}")

    @property
    def gait(self) -> str:
        if self.gait_schedule is not None:
            return self.gait_schedule
        return f"stand:2,trot@{self.speed:g}:{self.duration - 4:g},stand:2"


def cpu_sets(layout: str, available: set[int] | None = None) -> dict[str, set[int] | None]:
    """The CPUs of the ``"controller"``, the ``"worker"`` and the ``"robot"`` for a
    :attr:`RuntimeConfig.cpu_layout` (``None``: not pinned).

    With at least two CPUs available the named process gets the highest-numbered one to itself and the
    other two share the rest (``"split"`` is the worker's layout); with one CPU, or ``"any"``, nothing is
    pinned.
    """
    available = set(os.sched_getaffinity(0)) if available is None else set(available)
    names = ("controller", "worker", "robot")
    if layout == "any" or len(available) < 2:
        return dict.fromkeys(names)
    alone = "worker" if layout == "split" else layout
    own, rest = {max(available)}, available - {max(available)}
    return {name: own if name == alone else rest for name in names}


def _loop_config(config: RuntimeConfig, hardware):
    from wbmpc.control.command_schedule import CommandSchedule
    from wbmpc.ocp.gait import parse_gait_schedule
    from wbmpc.sim.presets import hardware_config

    schedule = parse_gait_schedule(config.gait)
    from wbmpc.control.arm_task import ArmReference

    arm = ArmReference() if config.arm_motion else ArmReference.still()
    commands = CommandSchedule(ee_velocity_frame="heading", gait=schedule, arm_reference=arm)
    loop = hardware_config(
        hardware, commands=commands, delay="measured", duration=config.duration, mpc_rate=config.mpc_rate
    )
    loop.plant.dt = EmulatedRobotSpec.plant_dt  # the planner rounds plan times to the robot's step
    loop.check()
    return loop


def run_runtime(config: RuntimeConfig, output: str | Path | None = None) -> dict:
    """Run the robot, the MPC worker and the controller on the wall clock; returns the summary.

    Raises:
        RuntimeError: the worker or the robot did not come up (their error is in the message).
    """
    from wbmpc.control.push_recovery import PushRecovery
    from wbmpc.model.robot import load_b1_z1
    from wbmpc.ocp.gait import parse_gait_schedule
    from wbmpc.runtime.control_loop import ControlLoop
    from wbmpc.runtime.controller import RuntimeController
    from wbmpc.runtime.shared import ObservationChannel, PlanChannel
    from wbmpc.runtime.wire import Wire

    robot = load_b1_z1()
    spec = EmulatedRobotSpec()
    loop_config = _loop_config(config, spec.profile())
    recipe = MPCRecipe(
        gait=config.gait,
        nodes=config.nodes,
        compiled=config.compiled,
        max_iter=config.max_iter,
        cold_retry=False,
        direct=config.direct,
    )
    ctx = mp.get_context("spawn")
    stop, worker_ready = ctx.Event(), ctx.Event()
    accounts = Path(tempfile.mkdtemp(prefix="wbmpc-runtime-"))  # the children's accounts (accounts.py)
    worker_stats, robot_stats = str(accounts / "worker.pickle"), str(accounts / "robot.pickle")
    plans = PlanChannel.create(recipe.plan_layout(robot))
    observations = ObservationChannel.create(robot.nq, robot.nv)
    wire, state_slot, command_slot = Wire.create(robot.nj)
    faults = config.faults
    stall = None if faults.stall_at is None else (faults.stall_at, faults.stall_for)
    worker_args = (recipe, loop_config, robot.q_nominal, observations.description, plans.description)
    cpus = cpu_sets(config.cpu_layout)
    worker = ctx.Process(
        target=run_worker,
        args=(*worker_args, worker_ready, stop, worker_stats, stall, 0, cpus["worker"]),
        name="wbmpc-mpc-worker",
        daemon=True,
    )
    robots: list = []

    def start_robot():
        ready = ctx.Event()
        process = ctx.Process(
            target=run_emulated_robot,
            args=(spec, _PortFactory(config, wire), ready, stop, robot_stats, None, cpus["robot"]),
            name="wbmpc-emulated-robot",
            daemon=True,
        )
        process.start()
        robots.append(process)
        return ready, process

    def restart_robot():
        robots[-1].kill()  # the robot's computer reboots: its state and tick counter start over
        robots[-1].join(5)
        start_robot()

    worker.start()
    robot_ready, robot_process = start_robot()
    own_cpus = os.sched_getaffinity(0)
    client = None
    log: dict = {}
    summary: dict = {}
    try:
        _wait(worker_ready, worker, worker_stats, config.ready_timeout, "MPC worker")
        _wait(robot_ready, robot_process, robot_stats, 60.0, "emulated robot")
        client = _client(config, wire, robot)
        gait = parse_gait_schedule(config.gait)
        contacts = PushRecovery(robot)
        controller = RuntimeController(
            robot,
            loop_config,
            lambda times: contacts.contact(times, gait),
            seq_step=getattr(client, "seq_step", 1),
        )
        loop = ControlLoop(config, robot, client, controller, plans, observations, worker, restart_robot)
        log = loop.log
        if cpus["controller"] is not None:
            os.sched_setaffinity(0, cpus["controller"])
        with realtime_priority(config.realtime_priority) as scheduling:
            summary = loop.run()
        summary["scheduling"] = scheduling
    finally:
        os.sched_setaffinity(0, own_cpus)
        stop.set()
        for process in (worker, *robots):
            process.join(10)
            if process.is_alive():
                process.kill()
        if client is not None:
            client.close()
        for slot in (plans, observations, state_slot, command_slot):
            slot.close()
            slot.unlink()
        if output is not None and log:  # the log up to a fault or an error is kept
            output = Path(output)
            output.mkdir(parents=True, exist_ok=True)
            np.savez_compressed(output / "runtime_log.npz", **{k: np.asarray(v) for k, v in log.items()})
            summary["bag"] = _write_bag(log, output / "bag", robot)
    from wbmpc.sim.summary import machine_description

    summary["machine"] = machine_description()  # timing depends on it: name the CPU
    worker_account = read_account(worker_stats)
    solves = {
        "worker_solve_s": np.asarray(worker_account.pop("solve_times", []), dtype=float),
        "worker_iterations": np.asarray(worker_account.pop("iterations", []), dtype=int),
    }
    summary["worker"] = worker_account | _solve_statistics(*solves.values())
    robot_account = read_account(robot_stats)
    truth = (np.asarray(robot_account.get("t", [])), np.asarray(robot_account.get("base", [])))
    summary["robot"] = _robot_summary(robot_account, config)
    if log and log["t"] and len(truth[0]):
        from wbmpc.runtime.metrics import estimate_error

        # the robot's physics starts at the first command: the controller's first tick
        summary["estimate_error"] = estimate_error(
            log["t"], log["q_hat"], log["damping"], *truth, true_start=log["t"][0]
        )
    if output is not None and log and len(truth[0]):  # what only a simulated robot knows, for the plots
        np.savez_compressed(Path(output) / "robot_truth.npz", t=truth[0], base=truth[1])
    if output is not None:
        np.savez_compressed(Path(output) / "worker_solves.npz", **solves)
    shutil.rmtree(accounts, ignore_errors=True)
    if output is not None:
        (Path(output) / "summary.json").write_text(json.dumps(summary, indent=1, default=_json))
    return summary


def _write_bag(log: dict, path: Path, robot) -> str:
    """The run as a ROS 2 bag (:func:`wbmpc.io.rosbag.write_bag`): the controller's estimate as the joint
    states and odometry, the commanded feed-forward torques; returns the folder, or why none was written
    (the summary and the npz log are kept either way)."""
    from wbmpc.io.logs import RunLog
    from wbmpc.io.rosbag import write_bag

    try:
        signals = {
            "t": np.asarray(log["t"], dtype=float),
            "q_meas": np.asarray(log["q_hat"], dtype=float),
            "v_meas": np.asarray(log["v_hat"], dtype=float),
            "tau_ff": np.asarray(log["tau_cmd"], dtype=float),
        }
        if path.exists():
            shutil.rmtree(path)
        return str(write_bag(RunLog(signals=signals, meta={"source": "wbmpc.runtime"}), path, robot))
    except Exception as exc:  # a bag is a convenience: never lose the run's summary to it
        return f"not written: {type(exc).__name__}: {exc}"


class _PortFactory:
    """Builds the robot's port in the robot's process (picklable)."""

    def __init__(self, config: RuntimeConfig, wire):
        self.kind, self.domain, self.interface, self.wire = (
            config.robot,
            config.domain,
            config.interface,
            wire,
        )

    def __call__(self):
        from wbmpc.runtime.wire import SharedMemoryPort

        if self.kind == "emulated":
            return SharedMemoryPort(self.wire)
        from wbmpc.runtime.dds_robot import DdsRobotPort

        return DdsRobotPort(self.domain, self.interface)


def _client(config: RuntimeConfig, wire, robot):
    from wbmpc.runtime.wire import SharedMemoryRobot

    if config.robot == "emulated":
        return SharedMemoryRobot(wire, robot.joint_names)
    from wbmpc.runtime.dds_robot import DdsRobot

    return DdsRobot(robot, config.domain, config.interface)


def _wait(event, process, account: str, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not event.wait(0.1):
        if not process.is_alive() or time.monotonic() > deadline:
            alive = process.is_alive()
            if alive:
                process.kill()
            process.join(5)
            errors = "\n".join(read_account(account).get("errors", []))
            why = f"did not start within {timeout:g} s" if alive else f"exited (code {process.exitcode})"
            raise RuntimeError(f"the {what} {why} before it was ready:\n{errors}")


def _solve_statistics(times: np.ndarray, iterations: np.ndarray) -> dict:
    """The worker's solve times [ms] and iterations, summarised (the per-solve series go to
    ``worker_solves.npz``)."""
    if not len(times):
        return {"solve_ms": None, "iterations": None}
    ms = times * 1e3
    counts = np.bincount(np.maximum(iterations, 0))
    return {
        "solve_ms": {
            "mean": float(ms.mean()),
            **{f"p{q}": float(np.percentile(ms, q)) for q in (50, 95, 99)},
            "max": float(ms.max()),
        },
        "iterations": {
            "mean": float(iterations.mean()),
            "max": int(iterations.max()),
            "histogram": {str(n): int(c) for n, c in enumerate(counts) if c},
        },
    }


def _robot_summary(stats: dict, config: RuntimeConfig) -> dict:
    t, base = np.asarray(stats.pop("t", [])), np.asarray(stats.pop("base", []))
    out = dict(stats)
    if len(t) > 10:
        trot = (t > 2.5) & (t < config.duration - 2.0)
        if trot.sum() > 10:
            ts, xs = t[trot], base[trot, 0]
            out["forward_speed_mps"] = float(np.polyfit(ts, xs, 1)[0])
        out["final_base"] = base[-1].tolist()
    return out


def _json(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return str(value)
