"""The end-effector command of each solve, from an arm reference or a heading-frame hold point.

:class:`ArmCommander` turns a :class:`~wbmpc.control.command_schedule.CommandSchedule`'s arm fields into the
``ee_velocity`` command of a solve: with an ``arm_reference``, its velocity plus ``arm_kp`` feedback on the
measured end-effector position (one velocity per stage with ``arm_preview``); with
``ee_velocity_frame="heading"`` and no reference, a hold point carried by the heading frame and moving at
the commanded velocity; otherwise the commanded world velocity as it is.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pinocchio as pin

from wbmpc.control.arm_task import ArmReference, heading_frame, velocity_command
from wbmpc.ocp.time_grid import node_times

__all__ = ["ArmCommander"]


class ArmCommander:
    """The ``ee_velocity`` command of each solve of a run.

    Args:
        robot: The robot (its end-effector frame; a robot without an arm gets no command).
        commands: The run's command schedule (``arm_reference``, ``ee_velocity_frame``).
        q0: Initial configuration (nq,): the reference or the hold point is centred on the hand there.
        arm_kp: Position feedback gain [1/s].
        arm_preview: One velocity per MPC stage from the reference's future (True) or one held (False).
    """

    def __init__(self, robot, commands, q0: np.ndarray, arm_kp: float, arm_preview: bool):
        self.model = robot.model
        self.data = robot.model.createData()
        self.ee_id = robot.frame_id(robot.ee_frame) if robot.has_arm else None
        self.arm_kp = arm_kp
        self.arm_preview = arm_preview
        self.reference = commands.arm_reference
        self.hold = None  # the heading-frame hold point of an ``ee_velocity`` command: [position, time of it]
        self.ee_reference = np.full(3, np.nan)  # the reference position of the last command [m]
        if self.ee_id is not None and (self.reference is not None or commands.ee_velocity_frame == "heading"):
            pin.framesForwardKinematics(self.model, self.data, q0)
            if self.reference is None:
                self.hold = [
                    ArmReference.still().centered_at(q0, self.data.oMf[self.ee_id].translation).center,
                    0.0,
                ]
            elif self.reference.center is None:
                self.reference = self.reference.centered_at(q0, self.data.oMf[self.ee_id].translation)

    def command(
        self, q_meas: np.ndarray, t: float, cmd: dict, time_steps: Callable[[], np.ndarray], t_plan: float
    ) -> np.ndarray | None:
        """The end-effector velocity command [m/s], (3,) or (3, N-1), of a solve at ``t`` [s]; ``None``
        without an arm.

        Args:
            q_meas: The configuration the controller sees (nq,).
            t: Time of the measurement [s].
            cmd: The commands at ``t`` (:meth:`CommandSchedule.at`).
            time_steps: Returns the MPC's time steps [s] (called only for the per-stage preview).
            t_plan: Time the plan starts at [s] (``t`` without delay compensation).
        """
        if self.ee_id is None:
            return None
        model, data = self.model, self.data
        pin.framesForwardKinematics(model, data, q_meas)
        ee_pos = data.oMf[self.ee_id].translation.copy()
        if self.reference is None and self.hold is None:
            return cmd["ee_velocity"]
        local_velocity = None
        reference = self.reference
        hold = self.hold
        if hold is not None:  # the hold point moves at the commanded velocity (heading frame)
            hold[0] = tuple(np.asarray(hold[0]) + cmd["ee_velocity"] * (t - hold[1]))
            hold[1] = t
            reference, local_velocity = ArmReference.still(hold[0]), cmd["ee_velocity"]
        R_heading, _ = heading_frame(q_meas)
        stage_times = node_times(time_steps(), t_plan)[:-1] if self.arm_preview else None
        ee_cmd, self.ee_reference = velocity_command(
            reference,
            q_meas,
            ee_pos,
            t,
            R_heading @ cmd["base_velocity"],
            kp=self.arm_kp,
            node_times=stage_times,
            yaw_rate=cmd["base_yaw_rate"],
            local_velocity=local_velocity,
        )
        return ee_cmd
