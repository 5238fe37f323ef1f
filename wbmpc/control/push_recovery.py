"""Push recovery of the whole-body MPC: swings aborted after a push, and the contact plan they give.

A trot keeps one diagonal pair on the ground for a whole swing (0.4 s at a 0.8 s period): a line contact
across which the base is an inverted pendulum that cannot be slowed. A push at a lift-off leaves the robot
on that line for the whole swing and it falls. :class:`PushRecovery` watches the measured base velocity;
when it jumps off the last converged plan's by more than ``MPCConfig.kick_recovery`` [m/s] (a push, not a
commanded speed-up), every swing still in its first ``kick_recovery_phase`` is aborted: the foot is brought
down and planned in stance until its nominal touchdown.

While recovering (after a push, until the base velocity is back near the command), the end-effector
velocity reference is released (``MPCConfig.kick_ee_release``, :meth:`PushRecovery.ee_release`): the OCP
holds the hand's world velocity to its reference as a hard equality from node 1 on, and a pushed base
carries the arm with it; holding the hand still at once made every solve after a forward push fail.

The aborted swings change the contact plan, and that plan is the one the closed loop uses too
(:meth:`PushRecovery.contact`): the rigid plant's contacts and the logs'. Without a push every method
returns its input unchanged (undisturbed walking is not affected).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from wbmpc.model.robot import heading
from wbmpc.model.statics import default_force_distribution
from wbmpc.ocp.time_grid import interp_row, node_times

#: An aborted swing's descent aims this far below the ground [m], so that the foot reaches it.
TOUCHDOWN_DEPTH = 0.005
#: Fastest planned descent of an aborted swing [m/s].
MAX_TOUCHDOWN_SPEED = 1.0


class PushRecovery:
    """The swing-abort state of one MPC (reset with the MPC).

    It holds no reference to its MPC: every call receives what it reads (the MPC's configuration, its
    last converged plan, the node times of the solve), so configuration changes apply at once.

    Args:
        robot: The MPC's robot (feet, end effector, mass).

    Attributes:
        aborted: Foot index to the interval ``(landing, end)`` [s] of its aborted swing: the foot is brought
            down until ``landing`` and in stance from then until ``end`` (its nominal touchdown).
        recovering: True after a push until the base velocity is back near the command.
        pushed_at: Time [s] of the last detected push (``None``: none yet).
        swing_aborts: Swings aborted since the last :meth:`reset`.
    """

    def __init__(self, robot):
        self.robot = robot
        self.aborted: dict[int, tuple[float, float]] = {}
        self.landing: dict[
            int, float
        ] = {}  # foot -> landing time [s] fixed at the first solve after its abort
        self.recovering = False
        self.pushed_at: float | None = None
        self.swing_aborts = 0

    def reset(self) -> None:
        """Forget every aborted swing and the recovery state."""
        self.aborted = {}
        self.landing = {}
        self.recovering = False
        self.pushed_at = None
        self.swing_aborts = 0

    # --- detection ------------------------------------------------------------------------------------------
    def update(self, q_hat: np.ndarray, v_hat: np.ndarray, t: float, commands, cfg, previous, gait) -> bool:
        """Detect a push at time ``t`` [s] and abort the early swings; returns whether a push was detected.

        A push is a measured horizontal base velocity (base frame, as ``v_hat[0:2]``) more than
        ``cfg.kick_recovery`` [m/s] away from the last converged plan's (``previous``, an
        :class:`~wbmpc.control.config.MPCSolution` or ``None``) at ``t``. ``gait``: the gait walked.
        """
        robot = self.robot
        self.aborted = {i: span for i, span in self.aborted.items() if t < span[1] - 1e-9}
        self.landing = {i: tl for i, tl in self.landing.items() if i in self.aborted}
        if cfg.kick_recovery is None:
            return False
        pushed = False
        if previous is not None:
            v_plan = interp_row(t, previous.node_times, previous.v)
            pushed = bool(np.linalg.norm(v_hat[0:2] - v_plan[0:2]) > cfg.kick_recovery)
        if not (pushed or self.recovering):
            return False  # the every-tick case: nothing more to compute
        # Recovering until the base velocity is back near the command (a commanded speed-up is no push).
        R_base = pin.Quaternion(q_hat[3:7]).normalized().toRotationMatrix()
        R_heading = pin.rpy.rpyToMatrix(0.0, 0.0, heading(q_hat))
        error = np.linalg.norm((R_base @ v_hat[0:3] - R_heading @ commands.base_linear_velocity)[0:2])
        self.recovering = error > cfg.kick_recovery
        if pushed:
            self.pushed_at = t
        if pushed or (self.recovering and cfg.kick_recovery_hold):
            now = gait.sample(np.array([t]))
            for i in range(robot.n_feet):
                phase = now.swing_phase[i, 0]
                if now.contact[i, 0] or phase >= cfg.kick_recovery_phase or i in self.aborted:
                    continue
                end = t + (1.0 - phase) * now.swing_duration[i, 0]
                self.aborted[i] = (t, end)  # landing set by parameters() from the foot height
                self.swing_aborts += 1
        return pushed

    # --- the contact plan -----------------------------------------------------------------------------------
    def contact(self, times, gait) -> np.ndarray:
        """Contact flags (4, n) at ``times`` [s]: ``gait`` (a gait or schedule) with the aborted swings
        (stance from their landing to their nominal touchdown); the gait's own when no swing is aborted."""
        times = np.atleast_1d(np.asarray(times, dtype=float))
        contact = gait.sample(times).contact.copy()
        for i, (landing, end) in self.aborted.items():
            contact[i, (times >= landing - 1e-9) & (times < end - 1e-9)] = True
        return contact

    def parameters(
        self, params: dict, q_hat: np.ndarray, v_hat: np.ndarray, t: float, commands, cfg, time_steps
    ) -> dict:
        """The stage parameters after a push: aborted swings (feet brought down at ``touchdown_speed`` and
        planned in stance until their nominal touchdown) and, while recovering, the released end-effector
        velocity (:meth:`ee_release`); ``params`` itself when neither applies. ``cfg``: the MPC's
        configuration; ``time_steps``: the solve's time steps [s] (N-1,)."""
        params = self.ee_release(params, q_hat, v_hat, t, cfg, time_steps)
        if not self.aborted:
            return params
        robot = self.robot
        t_nodes = node_times(time_steps, t)[:-1]
        contact = params["contact"] > 0.5
        swing_vz = np.array(params["swing_vz"], dtype=float)
        heights = self._foot_heights(q_hat)
        for i, (_, end) in list(self.aborted.items()):
            # The landing time is fixed at the first solve after the abort (re-planning it from the measured
            # height at every solve kept a foot hovering a few millimetres up, its landing always 30 ms
            # ahead); the descent aims TOUCHDOWN_DEPTH below the ground so that the foot does reach it, and a
            # foot still in the air at its landing keeps descending one more node.
            height = heights[i]
            if i not in self.landing:
                self.landing[i] = (
                    t + max(cfg.touchdown_time, height / cfg.touchdown_speed) if height > 2e-3 else t
                )
            landing = self.landing[i]
            if t >= landing - 1e-9 and height > 2e-3:
                landing = t + t_nodes[1] - t_nodes[0]
            self.aborted[i] = (landing, end)
            down = (t_nodes < landing - 1e-9) & (t_nodes < end - 1e-9)
            stance = (t_nodes >= landing - 1e-9) & (t_nodes < end - 1e-9)
            speed = (max(height, 0.0) + TOUCHDOWN_DEPTH) / max(landing - t, 1e-3)
            contact[i, down], swing_vz[i, down] = False, -min(speed, MAX_TOUCHDOWN_SPEED)
            contact[i, stance], swing_vz[i, stance] = True, 0.0
        ratio = robot.front_force_ratio if cfg.front_force_ratio is None else cfg.front_force_ratio
        weight = robot.mass * robot.gravity - commands.ee_force[2]
        force_des = default_force_distribution(contact, weight / robot.gravity, robot.gravity, ratio)
        return {**params, "contact": contact.astype(float), "swing_vz": swing_vz, "force_des": force_des}

    def ee_release(
        self, params: dict, q_hat: np.ndarray, v_hat: np.ndarray, t: float, cfg, time_steps
    ) -> dict:
        """While recovering, the end-effector velocity reference starts at the measured one and ramps to the
        command over ``MPCConfig.kick_ee_release`` [s]; ``params`` itself otherwise.

        The OCP holds the end-effector velocity (world) equal to its reference from node 1 on, a hard
        equality. A push moves the base and the arm with it: holding the hand still in the world 10 ms later
        asks the arm for a velocity jump its joint velocity and torque limits cannot give, and every solve
        fails (measured: a 0.8 m/s forward kick fails every solve, warm and cold, until the fall).
        """
        release = cfg.kick_ee_release
        robot = self.robot
        if release is None or not self.recovering or not robot.has_arm:
            return params
        data = robot.model.createData()
        pin.forwardKinematics(robot.model, data, q_hat, v_hat)
        v_ee = pin.getFrameVelocity(
            robot.model, data, robot.frame_id(robot.ee_frame), pin.LOCAL_WORLD_ALIGNED
        ).linear
        t_nodes = node_times(time_steps, t)[:-1]
        weight = np.clip(1.0 - (t_nodes - t) / release, 0.0, 1.0)  # 1 at the measurement, 0 after release
        command = np.asarray(params["ee_velocity"], dtype=float)
        ee_velocity = command + (v_ee[:, None] - command) * weight[None, :]
        return {**params, "ee_velocity": ee_velocity}

    def _foot_heights(self, q: np.ndarray) -> np.ndarray:
        """Height [m] of each foot's sole above the ground (z = 0) at configuration ``q``."""
        robot = self.robot
        data = robot.model.createData()
        pin.framesForwardKinematics(robot.model, data, q)
        return np.array(
            [data.oMf[robot.frame_id(f)].translation[2] - robot.foot_radius for f in robot.foot_frames]
        )
