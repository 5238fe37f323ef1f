"""PyBullet plant: the robot and interface of :class:`wbmpc.sim.plant.ContactPlant`, with physical contacts.

:class:`PyBulletPlant` loads the MPC's own URDF (``robot.urdf_path``) into a private PyBullet client
(DIRECT mode, so several plants can coexist) on a flat ground plane, drives every actuated joint in torque
mode and converts the state to and from Pinocchio's conventions. Contacts are no longer scheduled: they come
from PyBullet's collision detection and its unilateral, friction-limited contact solver, so the closed loop
can swap :class:`~wbmpc.sim.plant.ContactPlant` for this plant to test the MPC against a physics engine.

The plant loads a temporary copy of the URDF rewritten by :func:`wbmpc.model.urdf.preprocess_urdf` (no
visuals, absolute mesh paths, locked joints made fixed: the same rigid bodies as Pinocchio's reduced model).

* The root link frame is the base: PyBullet reports the base *inertial* frame (its centre of mass, principal
  axes), the plant converts to the URDF root link frame with the inertial frame returned by
  ``getDynamicsInfo`` (position and orientation both matter: PyBullet diagonalises the inertia tensor).

Physics choices:

* Actuated joints: PyBullet's default velocity motors are disabled (``VELOCITY_CONTROL`` with zero force),
  then ``TORQUE_CONTROL`` is set every step. Torques are clipped to ``robot.joint_torque_limits`` and the
  clips are counted (:attr:`PyBulletPlant.torque_clip_counts`).
* Joint damping and friction (``joint_damping=True``): PyBullet reads ``<dynamics damping>`` from the URDF
  and applies the viscous torque ``-d qdot`` itself every step; the URDF ``friction`` is parsed but never
  applied, so the plant adds it as Coulomb friction: a velocity motor with target 0 whose force is capped
  at the friction torque. With ``joint_damping=False`` both are zero (the rigid-body model the MPC uses).
  Only the Z1 arm joints have non-zero values (damping 1-2 N m s/rad, friction 1-2 N m).
* PyBullet's default linear/angular *body* damping of multibodies (0.04, a non-physical drag) is set to 0.
* Effective friction and restitution of a contact are the products of the two bodies' coefficients, so the
  robot's links are given friction 1 and restitution 1 and the ground carries ``ground_friction`` and
  ``restitution``; a box's ``friction`` is then its friction against the robot.

Motor effects (friction, rotor inertia, torque latency) are not the plant's: :class:`wbmpc.sim.actuators.
ActuatedPlant` puts them in front of any plant. The one model error the plant itself carries is the base
centre-of-mass offset (``base_com_offset`` [m], base frame, :class:`wbmpc.sim.hardware.HardwareProfile`): the
base link's inertial origin in the loaded URDF moves by it, and the state conversion follows (it reads the
inertial frame back).

Example:
    >>> robot = load_b1_z1()
    >>> with PyBulletPlant(robot, scene=[Box((0.3, 0.3, 0.3), (1.0, 0.0, 0.15), mass=5.0)]) as plant:
    ...     state = plant.reset(robot.q_nominal, np.zeros(robot.nv))
    ...     state = plant.step(np.zeros(robot.nj))
    ...     plant.contact_forces()  # (4, 3) world ground reaction forces on FL, FR, RL, RR [N]
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np
import pinocchio as pin
import pybullet as p

from wbmpc import checks
from wbmpc.model.quaternion import (
    cross3,
    quaternion_conjugate,
    quaternion_multiply,
    rotation_matrix,
)
from wbmpc.model.robot import Robot, RobotModelError
from wbmpc.model.urdf import offset_base_com, preprocess_urdf
from wbmpc.sim.plant import Plant, PlantState
from wbmpc.sim.plant import fallen as _fallen
from wbmpc.sim.pybullet_contacts import VIOLATION_KINDS, ContactReadings
from wbmpc.sim.pybullet_scene import SceneBodies, scene_items
from wbmpc.sim.scene import Box, Payload, SceneObject, Wall

__all__ = ["Box", "Payload", "PyBulletPlant", "Wall"]


def _quaternion_product(a, b) -> list[float]:
    """:func:`wbmpc.model.quaternion.quaternion_multiply` of two sequences of floats, as a list."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return [
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ]


def _rotation_rows(x: float, y: float, z: float, w: float) -> list[list[float]]:
    """The rows of :func:`wbmpc.model.quaternion.rotation_matrix` of a unit quaternion (x, y, z, w)."""
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]


def _cross(a, b) -> list[float]:
    """:func:`wbmpc.model.quaternion.cross3` of two sequences of floats, as a list."""
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


# ---------------------------------------------------------------------------------------------- plant
class PyBulletPlant(SceneBodies, ContactReadings, Plant):
    """The robot in PyBullet, with the :class:`~wbmpc.sim.plant.ContactPlant` interface.

    The scene bodies and the contact readings are mixins of their own modules; what stays here (about 450
    lines) is one PyBullet body's set-up, its state conversion to Pinocchio's conventions, the step, frame
    placements and kicks, which all share the link maps and inertial-frame offsets built at set-up.

    Args:
        robot: The robot (its URDF, locked joints, joint order, foot and end-effector frames are used).
        dt: Simulation step [s].
        ground_friction: Friction coefficient between the feet (and any robot link) and the ground.
        restitution: Restitution coefficient of the ground contacts (0: inelastic).
        joint_damping: Apply the URDF joint damping (viscous) and friction (Coulomb); see the module doc.
        scene: Extra bodies: a sequence of :class:`Box`, :class:`Wall`, :class:`Payload`, or a mapping
            ``{name: object}`` (names default to ``box0``, ``wall0``, ``payload0``, ...).
        physics_params: Extra keyword arguments for ``pybullet.setPhysicsEngineParameter`` (e.g.
            ``{"numSolverIterations": 100}``).
        base_com_offset: Shift of the base link's centre of mass [m] (3,), base frame; ``None``: none.
        clip_torques: Clip the torques to the robot's limits (counted in :attr:`torque_clip_counts`);
            False behind motors that saturate first (:class:`wbmpc.sim.actuators.ActuatedPlant`).

    Raises:
        ValueError: On a non-positive ``dt`` or a negative friction or restitution.
        RobotModelError: If the URDF lacks a joint or frame of the robot model.
    """

    def __init__(
        self,
        robot: Robot,
        dt: float = 0.001,
        ground_friction: float = 0.8,
        restitution: float = 0.0,
        joint_damping: bool = True,
        scene: Iterable[SceneObject] | Mapping[str, SceneObject] | None = None,
        physics_params: Mapping[str, object] | None = None,
        base_com_offset: np.ndarray | None = None,
        clip_torques: bool = True,
    ) -> None:
        if not (np.isfinite(dt) and dt > 0.0):
            raise ValueError(f"dt must be > 0 [s], got {dt}")
        if not (np.isfinite(ground_friction) and ground_friction >= 0.0):
            raise ValueError(f"ground_friction must be >= 0, got {ground_friction}")
        if not (np.isfinite(restitution) and 0.0 <= restitution <= 1.0):
            raise ValueError(f"restitution must be in [0, 1], got {restitution}")
        self._robot = robot
        self._model = robot.model
        self._dt = float(dt)
        self._foot_names = tuple(robot.foot_frames)
        self._mu = float(ground_friction)
        self._clip_torques = bool(clip_torques)
        com_offset = base_com_offset
        if com_offset is not None:
            com_offset = checks.array("base_com_offset", com_offset, 3)
        self._client = p.connect(p.DIRECT)
        if self._client < 0:
            raise RuntimeError("could not start a PyBullet DIRECT client")
        cid = self._client
        try:
            p.setGravity(0.0, 0.0, -robot.gravity, physicsClientId=cid)
            p.setTimeStep(self._dt, physicsClientId=cid)
            if physics_params:
                p.setPhysicsEngineParameter(**physics_params, physicsClientId=cid)
            plane = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=cid)
            self._ground = p.createMultiBody(0.0, plane, physicsClientId=cid)
            p.changeDynamics(
                self._ground, -1, lateralFriction=self._mu, restitution=restitution, physicsClientId=cid
            )
            with tempfile.TemporaryDirectory(prefix="wbmpc_pybullet_") as tmp:
                urdf = Path(tmp) / Path(robot.urdf_path).name
                text = preprocess_urdf(robot.urdf_path, robot.locked_joints)
                urdf.write_text(text if com_offset is None else offset_base_com(text, com_offset))
                self._body = p.loadURDF(
                    str(urdf),
                    flags=p.URDF_USE_INERTIA_FROM_FILE,
                    useFixedBase=False,
                    physicsClientId=cid,
                )
            self._setup_robot(joint_damping)
        except BaseException:
            self.close()
            raise

        self._init_scene()
        self._t0 = 0.0
        self._steps = 0
        n = robot.n_feet
        self._forces = np.zeros((n, 3))
        self._in_contact = np.zeros(n, dtype=bool)
        self._ee_force = np.zeros(3)
        self._violations = {k: np.zeros(n, dtype=bool) for k in VIOLATION_KINDS}
        self._counts = {k: np.zeros(n, dtype=np.int64) for k in VIOLATION_KINDS}
        self._clip_counts = np.zeros(robot.nj, dtype=np.int64)
        self._tau_limits = robot.joint_torque_limits
        self._nq, self._nj = robot.model.nq, robot.nj
        self._q = robot.q_nominal
        self._v = np.zeros(robot.nv)
        self.reset(robot.q_nominal, np.zeros(robot.nv))
        for name, obj in scene_items(scene):
            self.add(obj, name)

    # ------------------------------------------------------------------ setup
    def _setup_robot(self, joint_damping: bool) -> None:
        cid, body, robot = self._client, self._body, self._robot
        link_index = {p.getBodyInfo(body, physicsClientId=cid)[0].decode(): -1}
        joint_index = {}
        friction = {}
        for j in range(p.getNumJoints(body, physicsClientId=cid)):
            info = p.getJointInfo(body, j, physicsClientId=cid)
            link_index[info[12].decode()] = j
            if info[2] != p.JOINT_FIXED:
                joint_index[info[1].decode()] = j
                friction[j] = info[7]
        missing = [name for name in robot.joint_names if name not in joint_index]
        if missing:
            raise RobotModelError(f"joints {missing} of the model are not movable joints of the URDF")
        extra = sorted(set(joint_index) - set(robot.joint_names))
        if extra:
            raise RobotModelError(f"URDF joints {extra} are neither in the model nor locked")
        self._link_index = link_index
        self._joint_ids = [joint_index[name] for name in robot.joint_names]

        # Base link frame <- base inertial frame, as PyBullet reports the base pose in the latter.
        info = p.getDynamicsInfo(body, -1, physicsClientId=cid)
        self._r_li = np.array(info[3])
        self._q_li = np.array(info[4])
        self._q_il = quaternion_conjugate(self._q_li)
        self._q_il_list = self._q_il.tolist()

        for link in range(-1, p.getNumJoints(body, physicsClientId=cid)):
            p.changeDynamics(
                body,
                link,
                lateralFriction=1.0,
                restitution=1.0,
                linearDamping=0.0,
                angularDamping=0.0,
                physicsClientId=cid,
            )
        if not joint_damping:
            for j in self._joint_ids:
                p.changeDynamics(body, j, jointDamping=0.0, physicsClientId=cid)
        p.setJointMotorControlArray(
            body,
            self._joint_ids,
            p.VELOCITY_CONTROL,
            forces=[0.0] * len(self._joint_ids),
            physicsClientId=cid,
        )
        coulomb = [j for j in self._joint_ids if friction[j] > 0.0] if joint_damping else []
        if coulomb:
            p.setJointMotorControlArray(
                body,
                coulomb,
                p.VELOCITY_CONTROL,
                targetVelocities=[0.0] * len(coulomb),
                forces=[friction[j] for j in coulomb],
                physicsClientId=cid,
            )

        self._foot_links = []
        self._foot_offsets = []
        for frame in robot.foot_frames:
            link, offset = self._link_of_frame(frame)
            self._foot_links.append(link)
            self._foot_offsets.append(offset)
        self._foot_of_link = {link: i for i, link in enumerate(self._foot_links)}
        if robot.ee_frame is not None:
            self._ee_link, self._ee_offset = self._link_of_frame(robot.ee_frame)
            gripper = [name for name in ("gripperStator", "gripperMover") if name in link_index]
            self._gripper_links = {link_index[name] for name in gripper} or {self._ee_link}
        else:
            self._ee_link, self._ee_offset, self._gripper_links = None, None, set()

    def _link_of_frame(self, frame: str) -> tuple[int, pin.SE3]:
        """PyBullet link index carrying a Pinocchio frame and the frame placement in that link's URDF frame.

        A frame named like a URDF link is that link; any other frame (e.g. ``gripper_center``) is placed on
        the most distal URDF link rigidly attached to the same Pinocchio joint.
        """
        model = self._model
        if frame in self._link_index and model.existFrame(frame):
            return self._link_index[frame], pin.SE3.Identity()
        if not model.existFrame(frame):
            raise RobotModelError(f"unknown frame {frame!r}")
        f = model.frames[model.getFrameId(frame)]
        candidates = [
            other
            for other in model.frames
            if other.parentJoint == f.parentJoint
            and other.type == pin.FrameType.BODY
            and other.name in self._link_index
        ]
        if not candidates:
            raise RobotModelError(f"frame {frame!r} is not rigidly attached to any URDF link")
        link = candidates[-1]
        return self._link_index[link.name], link.placement.actInv(f.placement)

    # ------------------------------------------------------------------ properties
    @property
    def client(self) -> int:
        """PyBullet physics client id (pass it as ``physicsClientId`` for direct PyBullet calls)."""
        return self._client

    @property
    def body_id(self) -> int:
        """PyBullet body id of the robot."""
        return self._body

    @property
    def ground_id(self) -> int:
        """PyBullet body id of the ground plane."""
        return self._ground

    @property
    def time(self) -> float:
        """Simulated time [s] (``t0 + steps * dt``)."""
        return self._t0 + self._steps * self._dt

    @property
    def state(self) -> PlantState:
        """Copy of the current state."""
        return PlantState(self._q.copy(), self._v.copy(), self.time)

    @property
    def joint_velocities(self) -> np.ndarray:
        """Joint rates [rad/s] (nj,) of the current state (``state.v[6:]``, a copy, without the state's)."""
        return self._v[6:].copy()

    @property
    def torque_clip_counts(self) -> np.ndarray:
        """Per-joint number of steps whose commanded torque exceeded the limit since :meth:`reset`, (nj,)."""
        return self._clip_counts.copy()

    # ------------------------------------------------------------------ state conversion
    def _read_state(self) -> tuple[np.ndarray, np.ndarray]:
        # Plain-float arithmetic in numpy's order of operations (the quaternion product, the rotation matrix
        # and the cross product of wbmpc.model.quaternion) and numpy's BLAS for the matrix products, batched.
        cid, body = self._client, self._body
        pos_c, quat_c = p.getBasePositionAndOrientation(body, physicsClientId=cid)
        vel_c, omega = p.getBaseVelocity(body, physicsClientId=cid)
        states = p.getJointStates(body, self._joint_ids, physicsClientId=cid)
        quat = _quaternion_product(quat_c, self._q_il_list)
        x, y, z, w = self._quat_prev  # self._q[3:7] (|q . q_prev| ~ 1: its sign decides)
        if quat[0] * x + quat[1] * y + quat[2] * z + quat[3] * w < 0.0:
            quat = [-a for a in quat]  # same rotation; stay in the previous hemisphere (no sign jumps)
        self._quat_read = quat
        R = np.array(_rotation_rows(*quat))
        r_c = (R @ self._r_li).tolist()  # base origin -> centre of mass, world
        turn = _cross(omega, r_c)
        lin = [vel_c[0] - turn[0], vel_c[1] - turn[1], vel_c[2] - turn[2]]
        (lin,), (ang,) = np.matmul(np.array([[lin], [omega]]), R).tolist()  # v R, omega R: base axes
        joint_q, joint_v = (list(zip(*states, strict=True)) or [(), ()])[:2]  # positions, rates
        values = [pos_c[0] - r_c[0], pos_c[1] - r_c[1], pos_c[2] - r_c[2], *quat, *joint_q, *lin, *ang]
        values += joint_v
        self._finite = math.isfinite(sum(values))  # (or the sum overflows: step checks each value then)
        both = np.array(values)  # one conversion: q and v are views of it
        return both[: self._nq], both[self._nq :]

    def _write_state(self, q: np.ndarray, v: np.ndarray) -> None:
        cid, body = self._client, self._body
        R = rotation_matrix(q[3:7])
        r_c = R @ self._r_li
        omega = R @ v[3:6]
        p.resetBasePositionAndOrientation(
            body, q[:3] + r_c, quaternion_multiply(q[3:7], self._q_li), physicsClientId=cid
        )
        p.resetBaseVelocity(body, R @ v[:3] + cross3(omega, r_c), omega, physicsClientId=cid)
        p.resetJointStatesMultiDof(
            body,
            self._joint_ids,
            [[x] for x in q[7:]],
            targetVelocities=[[x] for x in v[6:]],
            physicsClientId=cid,
        )

    # ------------------------------------------------------------------ simulation
    def reset(self, q: np.ndarray, v: np.ndarray, t: float = 0.0) -> PlantState:
        """Set the robot state (scene bodies stay where they are) and clear the counters.

        Args:
            q: Configuration (nq,): base position [m], quaternion (x, y, z, w) (normalised here), joint
                angles [rad].
            v: Velocity (nv,): base linear [m/s] and angular [rad/s] velocity in the base frame, joint
                rates [rad/s].
            t: Simulated time [s].

        Returns:
            The state read back from PyBullet.

        Raises:
            ValueError: On a wrong shape or a non-finite value in ``q``, ``v`` or ``t``.
        """
        q = checks.array("q", q, self._model.nq).copy()
        v = checks.array("v", v, self._model.nv)
        if not np.isfinite(t):
            raise ValueError(f"t must be finite, got {t}")
        norm = np.linalg.norm(q[3:7])
        if norm < 1e-12:
            raise ValueError("q: the base quaternion has zero norm")
        q[3:7] /= norm
        self._q = q  # reference hemisphere of the quaternion read back
        self._quat_prev = q[3:7].tolist()
        self._write_state(q, v)
        self._q, self._v = self._read_state()
        self._quat_prev = self._quat_read
        self._t0, self._steps = float(t), 0
        self._forces[:] = 0.0
        self._in_contact[:] = False
        self._ee_force[:] = 0.0
        for k in VIOLATION_KINDS:
            self._violations[k][:] = False
            self._counts[k][:] = 0
        self._clip_counts[:] = 0
        for name in self._constraints:
            # Carried payloads move with the robot; a constraint error would otherwise yank them.
            self._place_payload_at_ee(name)
        return self.state

    def step(
        self,
        tau_joints: np.ndarray,
        contact: np.ndarray | None = None,
        external_wrench: np.ndarray | None = None,
        ee_force: np.ndarray | None = None,
    ) -> PlantState:
        """Advance the simulation by one step ``dt`` with the joint torques held constant.

        Args:
            tau_joints: Actuated joint torques [N m], shape (nj,), Pinocchio joint order; clipped to the
                torque limits (counted in :attr:`torque_clip_counts`).
            contact: Ignored (accepted for interface compatibility: contacts come from the physics).
            external_wrench: Optional disturbance on the base, shape (6,): force [N] then torque [N m], world
                axes, applied at (and taken about) the base link origin.
            ee_force: Optional disturbance force [N] (3,), world axes, at the end-effector frame origin
                (a push on the gripper).

        Returns:
            The state after the step (a copy).

        Raises:
            ValueError: On a wrong shape or a non-finite value in ``tau_joints``, ``external_wrench`` or
                ``ee_force``.
            FloatingPointError: If PyBullet returns a non-finite state.
        """
        del contact
        cid, body = self._client, self._body
        tau = tau_joints  # read only: no copy of a valid array (the motors' torques, every step)
        exact = type(tau) is np.ndarray and tau.dtype == np.float64 and tau.shape == (self._nj,)
        if not (exact and checks.all_finite(tau)):
            tau = checks.array("tau_joints", tau_joints, self._nj)
        if self._clip_torques:
            clipped = np.abs(tau) > self._tau_limits
            if clipped.any():
                self._clip_counts += clipped
                tau = np.clip(tau, -self._tau_limits, self._tau_limits)
        wrench = None if external_wrench is None else checks.array("external_wrench", external_wrench, 6)
        # The same values as a list: pybullet reads it faster than an array.
        p.setJointMotorControlArray(
            body, self._joint_ids, p.TORQUE_CONTROL, forces=tau.tolist(), physicsClientId=cid
        )
        if wrench is not None:
            p.applyExternalForce(body, -1, wrench[:3], self._q[:3], p.WORLD_FRAME, physicsClientId=cid)
            p.applyExternalTorque(body, -1, wrench[3:], p.WORLD_FRAME, physicsClientId=cid)
        if ee_force is not None:
            if self._ee_link is None:
                raise ValueError(f"robot {self._robot.name!r} has no end effector to push")
            force = checks.array("ee_force", ee_force, 3)
            p.applyExternalForce(
                body, self._ee_link, force, self.ee_position(), p.WORLD_FRAME, physicsClientId=cid
            )
        self._apply_tethers()
        p.stepSimulation(physicsClientId=cid)
        q, v = self._read_state()
        if not (self._finite or (np.isfinite(q).all() and np.isfinite(v).all())):
            raise FloatingPointError(f"PyBullet state became non-finite at t={self.time + self._dt:.6f} s")
        self._q, self._v = q, v
        self._quat_prev = self._quat_read
        self._steps += 1
        self._read_contacts()
        return self.state

    # ------------------------------------------------------------------ measurements
    def frame_placement(self, frame: str) -> pin.SE3:
        """World placement of a Pinocchio frame (a foot, the end effector, any link), read from PyBullet."""
        link, offset = self._link_of_frame(frame)
        return self._link_placement(link) * offset

    def frame_velocity(self, frame: str) -> np.ndarray:
        """World-aligned velocity of a Pinocchio frame read from PyBullet, shape (6,).

        Linear velocity of the frame origin [m/s] then angular velocity [rad/s], both in world axes
        (Pinocchio's ``LOCAL_WORLD_ALIGNED`` frame velocity).
        """
        cid = self._client
        link, offset = self._link_of_frame(frame)
        if link == -1:
            com, _ = p.getBasePositionAndOrientation(self._body, physicsClientId=cid)
            vel, omega = p.getBaseVelocity(self._body, physicsClientId=cid)
        else:
            s = p.getLinkState(
                self._body, link, computeLinkVelocity=True, computeForwardKinematics=True, physicsClientId=cid
            )
            com, vel, omega = s[0], s[6], s[7]
        origin = (self._link_placement(link) * offset).translation
        return np.concatenate([np.add(vel, cross3(omega, origin - np.array(com))), omega])

    @property
    def foot_positions(self) -> np.ndarray:
        """World positions of the foot frames read from PyBullet [m], shape (n_feet, 3) (a property, as in
        :class:`~wbmpc.sim.plant.ContactPlant`)."""
        return np.array(
            [
                (self._link_placement(link) * offset).translation
                for link, offset in zip(self._foot_links, self._foot_offsets, strict=True)
            ]
        )

    def ee_position(self) -> np.ndarray:
        """World position of the end-effector frame [m], shape (3,)."""
        if self._ee_link is None:
            raise ValueError(f"robot {self._robot.name!r} has no end effector")
        return (self._link_placement(self._ee_link) * self._ee_offset).translation

    def _link_placement(self, link: int) -> pin.SE3:
        """World placement of a link's URDF frame (not its inertial frame)."""
        cid = self._client
        if link == -1:
            pos, quat = p.getBasePositionAndOrientation(self._body, physicsClientId=cid)
            quat = quaternion_multiply(np.array(quat), quaternion_conjugate(self._q_li))
            R = rotation_matrix(quat)
            return pin.SE3(R, np.array(pos) - R @ self._r_li)
        s = p.getLinkState(self._body, link, computeForwardKinematics=True, physicsClientId=cid)
        return pin.SE3(rotation_matrix(np.array(s[5])), np.array(s[4]))

    def fallen(self, state: PlantState | None = None, **kwargs) -> bool:
        """:func:`wbmpc.sim.plant.fallen` on ``state`` (default: the current state); kwargs are passed on."""
        return _fallen(self.state if state is None else state, **kwargs)

    # ------------------------------------------------------------------ disturbances
    def apply_base_velocity_kick(self, delta_v_world: np.ndarray) -> PlantState:
        """Add a velocity jump to the base (an impulsive push).

        Args:
            delta_v_world: World-frame change of the base origin's linear velocity [m/s], shape (3,), or of
                the linear and angular velocity [m/s, rad/s], shape (6,).

        Returns:
            The new state.

        Raises:
            ValueError: On a wrong shape or a non-finite value.
        """
        dv = np.asarray(delta_v_world, dtype=float)
        if dv.shape not in ((3,), (6,)):
            raise ValueError(f"delta_v_world must have shape (3,) or (6,), got {dv.shape}")
        dv = checks.array("delta_v_world", dv, dv.size)
        q, v = self._read_state()
        R = rotation_matrix(q[3:7])
        v[:3] += R.T @ dv[:3]
        if dv.size == 6:
            v[3:6] += R.T @ dv[3:]
        self._write_state(q, v)
        self._q, self._v = self._read_state()
        self._quat_prev = self._quat_read
        return self.state

    # ------------------------------------------------------------------ lifetime
    def close(self) -> None:
        """Disconnect the PyBullet client (idempotent)."""
        if getattr(self, "_client", -1) >= 0:
            try:
                p.disconnect(physicsClientId=self._client)
            finally:
                self._client = -1

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # interpreter shutdown: pybullet may already be gone
            pass
