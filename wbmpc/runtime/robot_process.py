"""The emulated robot on the wall clock, in a process of its own, behind a wire.

Every 2 ms (its own :class:`~wbmpc.runtime.clock.DeadlineLoop`) the robot takes the newest command from its
port, checks it like a motor driver (a non-finite value, negative gains, a setpoint beyond the joint's
position, rate or torque limits: refused and counted, the last safe command held), steps the PyBullet plant
(with the hardware profile's motors and CoM offset) for the period at the plant's rate with the drivers'
PD law evaluated at every step (:class:`~wbmpc.runtime.emulated.SimulatedRobot`), and publishes its
readings. Until the first accepted command it stands on its stand: the physics does not run (a robot is
powered on in a safe pose before a controller takes over).

The process keeps the true base state of every period (what only a simulation knows) and puts it with its
counters on the stats queue at the end; that is how a run knows whether the robot fell and how fast it
walked.
"""

from __future__ import annotations

import os
import time
import traceback
from dataclasses import dataclass, field

import numpy as np

__all__ = ["EmulatedRobotSpec", "RobotStats", "run_emulated_robot"]


@dataclass(frozen=True)
class EmulatedRobotSpec:
    """The emulated robot (picklable).

    Attributes:
        plant_dt: Physics step [s] (1 kHz: the drivers' PD law runs at this rate; the simulations use 0.5 ms,
            but on 2 cores the wall clock leaves the emulated robot half a core); period: the readings' and
            commands' period [s] (a multiple of it).
        phase: Offset [s] of its ticks on the monotonic clock's grid of periods (``None``: none; the
            controller ticks at :attr:`RuntimeConfig.controller_phase <wbmpc.runtime.run.RuntimeConfig>`).
        spin: How long before each tick the robot's loop stops sleeping and spins on the clock [s]
            (:class:`~wbmpc.runtime.clock.DeadlineLoop`). None by default: on the CPU it shares with the
            controller a spin takes the time the controller's tick needs, and an emulated robot's tick 0.1
            ms late does no harm.
        hardware: Use the default :class:`~wbmpc.sim.hardware.HardwareProfile` (friction, armature, CoM
            offset, latency, noisy sensors); False: the ideal robot.
        seed: Sensor-noise seed.
    """

    plant_dt: float = 0.001
    period: float = 0.002
    phase: float | None = 0.0
    spin: float = 0.0
    hardware: bool = True
    seed: int = 0

    def profile(self):
        from wbmpc.sim.hardware import HardwareProfile

        return HardwareProfile(seed=self.seed) if self.hardware else HardwareProfile.ideal(seed=self.seed)


@dataclass
class RobotStats:
    """The robot process's account of a run.

    Attributes:
        t, base: Time [s] since the physics started and the true base pose ``q[:7]`` of each period.
        commands, refused: Commands taken and refused; refusals: the first reasons.
        overruns: Periods the physics did not keep up with the wall clock; fell: whether it fell;
        errors: tracebacks.
    """

    t: list = field(default_factory=list)
    base: list = field(default_factory=list)
    commands: int = 0
    refused: int = 0
    refusals: list = field(default_factory=list)
    overruns: int = 0
    fell: bool = False
    errors: list = field(default_factory=list)


def run_emulated_robot(
    spec: EmulatedRobotSpec, port_factory, ready, stop, stats_path, q0=None, cpus=None
) -> None:
    """The robot process's body.

    Args:
        spec: The robot.
        port_factory: ``port_factory() -> port`` (in the child: shared memory or DDS) with ``publish`` and
            ``latest_command``.
        ready: Event set when the robot publishes; stop: event that ends it.
        stats_path: File the :class:`RobotStats` is written to at the end (:mod:`~wbmpc.runtime.accounts`).
        q0: Initial configuration (the robot's nominal pose by default).
        cpus: CPUs the robot may run on (``os.sched_setaffinity``), or ``None`` for any.
    """
    from wbmpc.model.robot import load_b1_z1
    from wbmpc.runtime.clock import DeadlineLoop
    from wbmpc.runtime.emulated import SimulatedRobot
    from wbmpc.sim.closed_loop import make_plant
    from wbmpc.sim.plant import fallen
    from wbmpc.sim.presets import hardware_config

    stats = RobotStats()
    parent = os.getppid()
    port = plant = None
    try:
        if cpus is not None:
            os.sched_setaffinity(0, cpus)
        robot = load_b1_z1()
        hardware = spec.profile()
        config = hardware_config(hardware)
        config.plant.dt = spec.plant_dt
        plant = make_plant(robot, config)
        state = plant.reset(robot.q_nominal if q0 is None else np.asarray(q0), np.zeros(robot.nv))
        sim = SimulatedRobot(robot, spec.plant_dt, spec.period, hardware)
        sim.reset(state)
        limits = (
            np.array([robot.model.lowerPositionLimit[7:], robot.model.upperPositionLimit[7:]]),
            np.asarray(robot.model.velocityLimit[6:], dtype=float),
            np.asarray(robot.joint_torque_limits, dtype=float),
        )
        substeps = round(spec.period / spec.plant_dt)
        port = port_factory()
        loop = DeadlineLoop(spec.period, phase_s=spec.phase, spin_s=spec.spin)
        started, t = False, 0.0
        while not stop.is_set() and os.getppid() == parent:
            tick = loop.wait_next()
            stats.overruns += tick.overrun
            command = port.latest_command()
            if command is not None:
                stats.commands += 1
                problem = command.problem(*limits)
                if problem:
                    stats.refused += 1
                    if len(stats.refusals) < 20:
                        stats.refusals.append(problem)
                else:
                    sim.write(command)
                    started = True
            if started and not stats.fell:
                for _ in range(substeps):
                    state = plant.step(sim.torque(state))
                t += spec.period
                stats.t.append(t)
                stats.base.append(state.q[:7].copy())
                stats.fell = bool(fallen(state))
            port.publish(sim.read(state, time.monotonic()))
            ready.set()
            loop.tick_done()
    except Exception:
        stats.errors.append(traceback.format_exc())
    finally:
        if port is not None:
            port.close()
        if plant is not None:
            plant.close()
        from wbmpc.runtime.accounts import write_account

        write_account(stats_path, stats)
