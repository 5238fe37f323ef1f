"""The controller's tick: an observation in, a motor command out (paper, Sec. V-B, on the robot's side).

At every low-level tick (500 Hz) :class:`RuntimeController`

1. checks the observation (a non-finite field or a wrong shape never reaches the estimator: the tick
   reports it and the controller keeps its last estimate);
2. runs the state estimator (:class:`wbmpc.estimation.StateEstimator`, the contacts of the gait schedule)
   over every sample period the observation stands for (its ``seq`` gap): a reading that superseded
   older ones is held over the missing periods (:meth:`EstimatedState.update
   <wbmpc.sim.hardware.EstimatedState.update>`; fed only the newest readings, over DDS on two shared cores
   where 28 % of the ticks found two, the estimated forward position gained 77 % of the true one);
3. interpolates the latest plan at the tick's time (:class:`wbmpc.control.low_level.LowLevelController`);
4. returns the command for the motor drivers: setpoints, feed-forward and gains
   (``joint_pd="drive"``: the drivers close the PD loop), or the whole torque with zero gains
   (``joint_pd="controller"``: the PD law at 500 Hz on the estimate);
5. checks the command: one that is not finite is never returned (the damping mode goes out instead, for
   good, and the reason is kept); setpoints beyond the joints' position, rate or torque limits are clipped
   to them (and counted), since the robot's drivers refuse such a command.

The same object runs in the lockstep loop (:mod:`wbmpc.runtime.lockstep`, deterministic) and in the
wall-clock controller process.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from wbmpc import checks
from wbmpc.control.config import MPCSolution
from wbmpc.runtime.robot import MotorCommand, Observation
from wbmpc.sim.closed_loop import joint_level
from wbmpc.sim.hardware import EstimatedState, PlannedContacts
from wbmpc.sim.loop_config import ClosedLoopConfig

__all__ = ["RuntimeController"]

#: A tick this far behind the last one is a restarted robot, not a message out of order.
RESTART_WINDOW = 50

#: Most sample periods a reading is held over (a longer silence trips the watchdog's observation gap).
MAX_HELD_PERIODS = 10

#: Damping [N m s/rad] of the damping mode (Unitree's own examples damp with kd of 1-5).
DAMPING_KD = 3.0


class RuntimeController:
    """Estimator, plan interpolation and the motor command of one robot.

    Args:
        robot: The MPC's robot model (:class:`wbmpc.model.robot.Robot`).
        config: The run's settings (low-level gains and rate, ``joint_pd``, the sensing's estimator and
            velocity filter, the hardware profile's estimator tuning).
        contacts: The contact plan, ``contacts(times) -> (n_feet, n)`` flags (the MPC's
            :meth:`~wbmpc.control.mpc.WholeBodyMPC.contact_plan` with the run's gait).
        damping_kd: Damping of the damping mode [N m s/rad] (> 0).
        seq_step: How much an observation's ``seq`` advances per sample period of the robot (1 for a
            message counter; a robot whose tick counts milliseconds at 500 Hz says 2).

    Attributes:
        low: The plan interpolation (its ``plan`` is the plan in use).
        q_hat, v_hat: The last estimate (nq,), (nv,).
        last_command: The last command returned; damping: True once the damping mode is on.
        problems: ``(stamp, reason)`` of every observation or command refused.
        held_periods: Sample periods bridged by holding a newer reading (readings superseded or lost).
        clipped: Ticks at which the setpoints ``q``, ``dq`` or ``tau`` were clipped to the joint limits.
    """

    def __init__(
        self,
        robot,
        config: ClosedLoopConfig,
        contacts: Callable[[np.ndarray], np.ndarray],
        damping_kd: float = DAMPING_KD,
        seq_step: int = 1,
    ):
        self.robot, self.config = robot, config
        self.seq_step = checks.integer("seq_step", seq_step, low=1)
        self.held_periods = 0
        _, _, per_low = config.steps()
        self.dt = per_low * config.plant.dt
        self.low, _ = joint_level(robot, config)
        nj = robot.nj
        self.kp = np.broadcast_to(np.asarray(self.low.kp, dtype=float), (nj,)).copy()
        self.kd = np.broadcast_to(np.asarray(self.low.kd, dtype=float), (nj,)).copy()
        self.zero_gains = np.zeros(nj)
        self.drive_pd = config.low_level.joint_pd == "drive"
        self.estimator = EstimatedState(
            robot,
            PlannedContacts(contacts),
            self.dt,
            config.plant.hardware,
            config.sensing.velocity_cutoff_hz,
        )
        self.damping_command = MotorCommand.damping_mode(nj, damping_kd)
        lower = robot.model.lowerPositionLimit[7:]
        upper = robot.model.upperPositionLimit[7:]
        self.position_limits = np.array([lower, upper])
        self.velocity_limits = np.asarray(robot.model.velocityLimit[6:], dtype=float)
        self.torque_limits = np.asarray(robot.joint_torque_limits, dtype=float)
        self.q_hat = self.v_hat = None
        self.last_command: MotorCommand | None = None
        self.damping = False
        self.problems: list[tuple[float, str]] = []
        self.clipped = {"q": 0, "dq": 0, "tau": 0}
        self._last_seq: int | None = None

    def reset(self, q0: np.ndarray, v0: np.ndarray) -> None:
        """Start the estimator at the robot's state ``(q0, v0)`` (the robot at rest, before the run)."""
        self.q_hat, self.v_hat = self.estimator.reset(q0, v0)
        self._last_seq = None
        self.damping = False

    def offer(self, plan: MPCSolution) -> None:
        """Use ``plan`` from now on (the newest plan; the channel has already refused stale ones)."""
        self.low.update(plan)

    def estimate(self, observation: Observation) -> str:
        """Feed one observation to the estimator; returns why it was refused, or ``""``.

        Refused: a non-finite field or a wrong shape, a sequence number not newer than the last one (a
        duplicate or a message out of order), one more than :data:`RESTART_WINDOW` behind it (the robot
        restarted: the reason says so).
        """
        problem = observation.problem()
        last = self._last_seq
        if not problem and last is not None and observation.seq < last - RESTART_WINDOW:
            problem = f"the robot restarted: its tick went back from {last} to {observation.seq}"
        elif not problem and last is not None and observation.seq <= last:
            problem = f"observation seq {observation.seq} not newer than {last} (stale)"
        if problem:
            self.problems.append((observation.stamp, problem))
            return problem
        periods = 1
        if last is not None:
            periods = min(max(round((observation.seq - last) / self.seq_step), 1), MAX_HELD_PERIODS)
        self._last_seq = observation.seq
        self.held_periods += periods - 1
        self.q_hat, self.v_hat = self.estimator.update(
            observation.imu(), observation.joints(), observation.stamp, periods
        )
        return ""

    def command(self, t: float) -> MotorCommand:
        """The command at time ``t`` [s] from the plan in use and the last estimate; the damping mode when
        it is on, when there is no plan yet, or when the command would be unsafe (reason kept)."""
        if self.damping or self.low.plan is None:
            return self._send(self.damping_command)
        if self.drive_pd:
            ref = self.low.last_reference = self.low.reference(t)
            command = MotorCommand(ref.q_des, ref.v_des, ref.tau_ff, self.kp, self.kd)
        else:  # the PD law here, on the estimate; the drives apply the torque as it is
            tau = self.low.torque(t, self.q_hat, self.v_hat)
            ref = self.low.last_reference
            command = MotorCommand(ref.q_des, ref.v_des, tau, self.zero_gains, self.zero_gains)
        problem = command.problem()
        if problem:  # not finite: nothing of it may reach the motors
            self.problems.append((t, problem))
            self.enter_damping()
            return self._send(self.damping_command)
        return self._send(self._within_limits(command))

    def tick(self, observation: Observation | None, t: float) -> MotorCommand:
        """One low-level tick at ``t`` [s]: estimate from ``observation`` (``None``: none arrived; the
        last estimate stands), then :meth:`command`."""
        if observation is not None:
            self.estimate(observation)
        return self.command(t)

    def enter_damping(self) -> None:
        """Switch to the damping mode for good (latched until :meth:`reset`)."""
        self.damping = True

    def _within_limits(self, command: MotorCommand) -> MotorCommand:
        """The command with setpoints clipped to the joint's position, rate and torque limits (each clip
        counted in ``clipped``): the robot refuses a command beyond them."""
        low, high = self.position_limits
        clipped = (  # minimum(maximum()) is np.clip for finite values, without its Python wrapper
            np.minimum(np.maximum(command.q, low), high),
            np.minimum(np.maximum(command.dq, -self.velocity_limits), self.velocity_limits),
            np.minimum(np.maximum(command.tau, -self.torque_limits), self.torque_limits),
        )
        before = (command.q, command.dq, command.tau)
        for name, old, new in zip(("q", "dq", "tau"), before, clipped, strict=True):
            if np.any(new != old):
                self.clipped[name] += 1
        command.q, command.dq, command.tau = clipped
        return command

    def _send(self, command: MotorCommand) -> MotorCommand:
        self.last_command = command
        return command
