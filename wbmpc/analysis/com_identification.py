"""The base's centre-of-mass offset from the leg torques of a standing robot, and how much a run leans.

:func:`foot_forces_from_torques` (foot forces through the leg Jacobians), :func:`identify_com_offset`
(their centre of pressure against the model's centre of mass), :func:`standing_mask` (the quiet standing
samples it uses), :func:`lean` (pitch and rear-leg share, before and after a model edit such as
:func:`wbmpc.model.base_com.shift_base_com`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from wbmpc.model.base_com import base_com_link
from wbmpc.model.robot import heading


def standing_mask(
    log,
    t_min: float = 0.3,
    t_max: float | None = None,
    max_speed: float = 0.05,
    max_joint_speed: float | None = 0.03,
) -> np.ndarray:
    """Samples of quiet standing.

    Every foot scheduled in stance, ``t`` in ``[t_min, t_max]`` [s], base speed below ``max_speed`` [m/s]
    (odometry: ``v_meas``, else ``v``) and every joint slower than ``max_joint_speed`` [rad/s] (``v``, the
    encoders). The last one matters: a joint that moves carries its motor's friction torque, which the
    logged command does not contain (1 N m on a calf is ~3 N at the foot); still joints carry none on
    average.
    """
    t = np.asarray(log["t"], float)
    contact = np.asarray(log["contact"], bool)
    v = np.asarray(log["v_meas"] if "v_meas" in log.signals else log["v"], float)
    mask = contact.all(axis=1) & (t >= t_min) & (np.linalg.norm(v[:, :3], axis=1) < max_speed)
    if max_joint_speed is not None:
        mask &= np.abs(np.asarray(log["v"], float)[:, 6:]).max(axis=1) < max_joint_speed
    if t_max is not None:
        mask &= t <= t_max
    return mask


def _legs(robot) -> list[tuple[int, np.ndarray]]:
    """Per foot: its frame id and the velocity indices of the joints between the base and the foot."""
    model = robot.model
    out = []
    for name in robot.foot_frames:
        fid = robot.frame_id(name)
        joints = [j for j in model.supports[model.frames[fid].parentJoint] if j > 1]  # skip universe, base
        out.append((fid, np.array([model.joints[j].idx_v for j in joints])))
    return out


def foot_forces_from_torques(robot, q: np.ndarray, tau: np.ndarray, v=None, a=None) -> np.ndarray:
    """Ground forces on the feet [N] (T, n_feet, 3), world axes, from the leg joint torques.

    The leg rows of the equations of motion, ``tau_leg = rnea_leg(q, v, a) - J_leg^T F`` (with ``v = a = 0``:
    ``tau_leg = g_leg(q) - J_leg^T F``), solved for the force ``F`` at the foot's contact point (the bottom
    of the foot sphere) through the 3 x 3 Jacobian of the leg's joints. A leg's rows involve only the links
    below its hip, so the base's mass distribution does not enter.

    Args:
        robot: The robot model (:class:`~wbmpc.model.robot.Robot`).
        q: Configurations (T, nq); tau: joint torques (T, nj) [N m].
        v, a: Optional velocities and accelerations (T, nv) for the dynamic terms.
    """
    model, data = robot.model, robot.model.createData()
    q, tau = np.atleast_2d(q), np.atleast_2d(tau)
    legs = _legs(robot)
    lever = pin.skew(np.array([0.0, 0.0, robot.foot_radius]))  # contact point = frame - r e_z
    zero = np.zeros(model.nv)
    forces = np.zeros((len(q), len(legs), 3))
    for k in range(len(q)):
        vk = zero if v is None else v[k]
        ak = zero if a is None else a[k]
        h = pin.rnea(model, data, q[k], vk, ak)
        pin.computeJointJacobians(model, data, q[k])
        pin.updateFramePlacements(model, data)
        for i, (fid, idx) in enumerate(legs):
            J = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
            Jc = J[:3] + lever @ J[3:]
            forces[k, i] = np.linalg.solve(Jc[:, idx].T, h[idx] - tau[k, idx - 6])
    return forces


@dataclass
class ComIdentification:
    """The base's centre-of-mass offset identified from a standing log.

    Attributes:
        offset: Shift [m] (3,) of the base link's CoM in the base frame (x forward) that explains the centre
            of pressure, in the convention of :attr:`wbmpc.sim.hardware.HardwareProfile.base_com_offset`
            (the heaviest rigidly attached link, mass ``link_mass``, moves). ``z`` is 0: statics on flat
            ground cannot see a vertical shift.
        body_offset: The same as a shift of the whole rigid base body's CoM (mass ``body_mass``) [m].
        com_shift: Whole-robot CoM minus the model's [m] (3,), heading frame (z = 0).
        cop: Centre of pressure minus the model's CoM [m] per sample (n, 2), heading frame.
        foot_forces: Estimated foot forces [N] (n, n_feet, 3), world axes.
        rear_share: Share of the vertical force on the rear feet.
        front_force_ratio: ``1 - rear_share``: the force targets' front share for the MPC.
        samples: Samples used; window_s: their time span [s].
        link_mass: Mass of the moved link [kg]; body_mass: of the rigid base body in the model [kg].
    """

    offset: np.ndarray
    body_offset: np.ndarray
    com_shift: np.ndarray
    cop: np.ndarray
    foot_forces: np.ndarray
    rear_share: float
    front_force_ratio: float
    samples: int
    window_s: tuple[float, float]
    link_mass: float
    body_mass: float

    def summary(self) -> dict:
        return {
            "offset_m": self.offset.tolist(),
            "body_offset_m": self.body_offset.tolist(),
            "com_shift_m": self.com_shift.tolist(),
            "cop_std_m": self.cop.std(axis=0).tolist(),
            "rear_share": self.rear_share,
            "front_force_ratio": self.front_force_ratio,
            "samples": self.samples,
            "window_s": list(self.window_s),
        }


def identify_com_offset(
    log, robot, mask: np.ndarray | None = None, dynamic: bool = True, rear: tuple[int, ...] = (2, 3)
) -> ComIdentification:
    """The base's centre-of-mass offset from the leg torques of a standing robot.

    Foot forces come from the torques (:func:`foot_forces_from_torques`). In static balance on the ground
    the moments about the whole robot's CoM ``c`` vanish: with contact points ``p_i`` and forces ``F_i``,
    ``c_x = (sum x_i F_zi - sum (z_i - c_z) F_xi) / sum F_zi`` (and ``y`` alike), the centre of pressure
    corrected for the horizontal forces. Its difference to the model's CoM at the same configuration is the
    CoM shift; the base link (mass ``m_b`` of a robot of mass ``M``) moved by ``M / m_b`` times it.

    Args:
        log: Run log with ``t``, ``q`` (base pose from odometry or ground truth), ``v``, ``tau``, ``contact``.
        robot: The nominal model.
        mask: Samples to use (T,); ``None``: :func:`standing_mask`.
        dynamic: Include the legs' velocity and acceleration terms (acceleration from finite differences).
        rear: Indices of the rear feet.

    Returns:
        :class:`ComIdentification`.
    """
    t = np.asarray(log["t"], float)
    mask = standing_mask(log) if mask is None else np.asarray(mask, bool)
    if mask.sum() < 10:
        raise ValueError(f"only {int(mask.sum())} standing samples: need a log with quiet standing")
    q, tau = np.asarray(log["q"], float)[mask], np.asarray(log["tau"], float)[mask]
    v = a = None
    if dynamic:
        v_all = np.asarray(log["v"], float)
        a = np.gradient(v_all, t, axis=0)[mask]
        v = v_all[mask]
    forces = foot_forces_from_torques(robot, q, tau, v, a)
    model, data = robot.model, robot.model.createData()
    r = robot.foot_radius
    ids = [robot.frame_id(f) for f in robot.foot_frames]
    cop = np.zeros((len(q), 2))
    for k in range(len(q)):
        c = pin.centerOfMass(model, data, q[k])
        pin.framesForwardKinematics(model, data, q[k])
        p = np.array([data.oMf[i].translation - [0.0, 0.0, r] for i in ids])
        F = forces[k]
        fz = F[:, 2].sum()
        cx = (np.dot(p[:, 0], F[:, 2]) - np.dot(p[:, 2] - c[2], F[:, 0])) / fz
        cy = (np.dot(p[:, 1], F[:, 2]) - np.dot(p[:, 2] - c[2], F[:, 1])) / fz
        yaw = heading(q[k])
        R = np.array([[np.cos(yaw), np.sin(yaw)], [-np.sin(yaw), np.cos(yaw)]])  # world -> heading
        cop[k] = R @ (np.array([cx, cy]) - c[:2])
    shift = np.r_[cop.mean(axis=0), 0.0]
    _, link_mass = base_com_link(robot)
    body_mass = float(model.inertias[1].mass)
    share = float(forces[:, list(rear), 2].sum() / forces[:, :, 2].sum())
    return ComIdentification(
        offset=robot.mass / link_mass * shift,
        body_offset=robot.mass / body_mass * shift,
        com_shift=shift,
        cop=cop,
        foot_forces=forces,
        rear_share=share,
        front_force_ratio=1.0 - share,
        samples=int(mask.sum()),
        window_s=(float(t[mask][0]), float(t[mask][-1])),
        link_mass=link_mass,
        body_mass=body_mass,
    )


def lean(
    log, mask: np.ndarray | None = None, robot=None, rear: tuple[int, ...] = (2, 3), samples: int = 400
) -> dict:
    """How much a run leans: base pitch and the rear feet's share of the vertical force.

    Args:
        log: Run log (``q``; ``plan_forces`` and ``solve_t`` for the planned share; ``tau`` with ``robot``).
        mask: Samples to use (T,); ``None``: every sample.
        robot: The model, to estimate the forces from the leg torques (:func:`foot_forces_from_torques`,
            static terms) on up to ``samples`` evenly spread samples; ``None``: skipped.
        rear: Indices of the rear feet.

    Returns:
        ``pitch_mean_rad``, ``pitch_std_rad`` (positive: nose down), ``rear_share_torques`` (from the leg
        torques, ``None`` without ``robot``), ``rear_share_measured`` (``foot_forces``, a simulator's, if
        logged), ``rear_share_planned`` (the MPC's first-stage forces of the solves in the same time span).
    """
    t = np.asarray(log["t"], float)
    mask = np.ones(t.shape, bool) if mask is None else np.asarray(mask, bool)
    q = np.asarray(log["q"], float)[mask]
    rot = [pin.Quaternion(qk[3:7]).normalized().toRotationMatrix() for qk in q]
    pitch = np.array([pin.rpy.matrixToRpy(R)[1] for R in rot])
    out = {"pitch_mean_rad": float(pitch.mean()), "pitch_std_rad": float(pitch.std())}

    def share(fz):
        return float(fz[:, list(rear)].sum() / fz[:, :4].sum()) if fz.size else None

    out["rear_share_torques"] = None
    if robot is not None:
        pick = np.linspace(0, len(q) - 1, min(samples, len(q))).astype(int)
        tau = np.asarray(log["tau"], float)[mask][pick]
        out["rear_share_torques"] = share(foot_forces_from_torques(robot, q[pick], tau)[:, :, 2])
    forces = log.signals.get("foot_forces")
    out["rear_share_measured"] = (
        share(np.asarray(forces, float)[mask][:, :, 2]) if forces is not None else None
    )
    out["rear_share_planned"] = None
    if "plan_forces" in log.solves and len(log["plan_forces"]):
        st = np.asarray(log["solve_t"], float)
        span = (st >= t[mask][0]) & (st <= t[mask][-1])
        out["rear_share_planned"] = share(np.asarray(log["plan_forces"], float)[span][:, :4, 2])
    return out
