"""One MPC tick, apart from when its plan applies: the commands, the state to plan from, the solve.

:class:`Planner` is shared by the simulated loop (:class:`wbmpc.sim.closed_loop.ClosedLoop`, which decides
when a plan reaches the low level in simulated time) and the runtime's MPC worker
(:mod:`wbmpc.runtime.mpc_worker`, where a plan reaches the controller when the solve returns), so that
both plan from the same inputs the same way:

1. the commands of the :class:`~wbmpc.control.command_schedule.CommandSchedule` at the measurement time
   ``t``, through the velocity ramp if the schedule has one;
2. with delay compensation, the time the plan will apply, ``t_plan = t + ceil(d / dt) dt`` for the
   expected computation delay ``d`` (:class:`~wbmpc.control.delay.DelayEstimate`), and the state predicted
   there along the plan in use (:func:`~wbmpc.control.delay.predict_state`);
3. the arm's end-effector velocity command (:class:`~wbmpc.sim.arm_commander.ArmCommander`);
4. :meth:`WholeBodyMPC.solve <wbmpc.control.mpc.WholeBodyMPC.solve>`, whose whole call time feeds the
   delay estimate.
"""

from __future__ import annotations

import math

import numpy as np

from wbmpc.control.command_ramp import CommandRamp
from wbmpc.control.delay import DelayEstimate, predict_state
from wbmpc.control.mpc import Commands, MPCSolution, WholeBodyMPC
from wbmpc.sim.arm_commander import ArmCommander
from wbmpc.sim.loop_config import ClosedLoopConfig

__all__ = ["Planner"]


class Planner:
    """The MPC side of a run: commands in, plans out.

    Args:
        mpc: The MPC (its configuration is not changed).
        config: The run's settings: the command schedule, ``delay``, ``delay_compensation``, the plant
            step ``plant.dt`` [s] (plan times are whole plant steps), the arm gains.
        q0: The initial configuration (the arm's hold point).

    Attributes:
        gait: The gait walked (the schedule's, else the MPC's).
        arm: The arm's commander.
        commands: The commands of the last :meth:`plan` (:meth:`CommandSchedule.at`, ramped).
        ee_command: Its end-effector velocity command [m/s] (``None`` without an arm);
        ee_reference: the arm's reference position [m].
        last_plan_time: When the last plan applies [s] (:meth:`plan_time` of its measurement).
    """

    def __init__(self, mpc: WholeBodyMPC, config: ClosedLoopConfig, q0: np.ndarray):
        self.mpc, self.config = mpc, config
        self.schedule = config.commands
        self.gait = self.schedule.gait if self.schedule.gait is not None else mpc.config.gait
        self.arm = ArmCommander(mpc.robot, self.schedule, q0, config.arm_kp, config.arm_preview)
        self.ee_command, self.ee_reference = None, self.arm.ee_reference
        self.commands = self.schedule.at(0.0, self.gait)
        self.last_plan_time = 0.0
        self.reset()

    def reset(self) -> None:
        """Forget the delay measured and the ramp's state (a new run)."""
        ramp = self.schedule.ramp
        self._ramp = None if ramp is None else CommandRamp(*ramp)
        delay = self.config.delay
        self.expected_delay = DelayEstimate(None if delay in ("off", "measured") else float(delay))

    def plan_time(self, t: float, plan_in_use: MPCSolution | None) -> float:
        """When a plan made from the measurement at ``t`` [s] applies: ``t`` itself, or with delay
        compensation (and a plan in use to bridge the gap) ``t`` plus the expected delay in whole plant
        steps."""
        config = self.config
        if config.delay_compensation and config.delay != "off" and plan_in_use is not None:
            dt = config.plant.dt
            return t + math.ceil(self.expected_delay.expected() / dt - 1e-9) * dt
        return t

    def plan(
        self,
        q_meas: np.ndarray,
        v_meas: np.ndarray,
        t: float,
        plan_in_use: MPCSolution | None,
        record_delay: bool = True,
    ) -> MPCSolution:
        """Solve from the measured state ``(q_meas, v_meas)`` at ``t`` [s].

        Args:
            plan_in_use: The plan the low level interpolates now (the state prediction follows it).
            record_delay: Count this solve's call time in the delay estimate (not for the cold first
                solve, before the robot moves: it says nothing of the next ones).
        """
        mpc = self.mpc
        cmd = self.commands = self.schedule.at(t, self.gait)
        if self._ramp is not None:
            cmd["base_velocity"], cmd["base_yaw_rate"] = self._ramp(
                t, cmd["base_velocity"], cmd["base_yaw_rate"]
            )
        t_plan = self.last_plan_time = self.plan_time(t, plan_in_use)
        commands = Commands(
            base_linear_velocity=cmd["base_velocity"],
            base_angular_velocity=np.array([0, 0, cmd["base_yaw_rate"]]),
            ee_force=cmd["ee_force"],
            gait=self.schedule.gait,
        )
        self.ee_command = self.arm.command(q_meas, t, cmd, mpc.time_steps, t_plan)
        self.ee_reference = self.arm.ee_reference
        if self.ee_command is not None:
            commands.ee_velocity = self.ee_command
        q_plan, v_plan = q_meas, v_meas
        if t_plan > t:  # plan from where the robot will be when the plan arrives
            q_plan, v_plan = predict_state(mpc.robot.model, plan_in_use, q_meas, v_meas, t, t_plan)
        plan = mpc.solve(q_plan, v_plan, t_plan, commands)
        if record_delay:
            self.expected_delay.record(plan.timings.get("total", plan.solve_time))
        return plan
