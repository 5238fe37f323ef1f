"""PyBullet plant: the robot and interface of :class:`wbmpc.sim.plant.ContactPlant`, with physical contacts.

:class:`PyBulletPlant` loads the MPC's own URDF (``robot.urdf_path``) into a private PyBullet client
(DIRECT mode, so several plants can coexist) on a flat ground plane, drives every actuated joint in torque
mode and converts the state to and from Pinocchio's conventions. Contacts are no longer scheduled: they come
from PyBullet's collision detection and its unilateral, friction-limited contact solver, so the closed loop
can swap :class:`~wbmpc.sim.plant.ContactPlant` for this plant to test the MPC against a physics engine.

What the plant does to the URDF (a temporary, preprocessed copy is loaded; the original is untouched):

* ``<visual>`` elements are dropped: DIRECT mode never renders, and parsing the Collada visual meshes took
  ~5 s per load. Collision meshes (the Z1 gripper STLs) keep their geometry; ``package://`` URIs are
  rewritten to absolute paths (``example-robot-data`` is located through its installed distribution, other
  packages by searching the folders above the URDF).
* Locked joints (``robot.locked_joints``, e.g. ``joint5, joint6, jointGripper``) are rewritten as *fixed*
  joints whose origin includes the rotation by the locked angle. This is exactly what Pinocchio's
  ``buildReducedModel`` does, so the two models have the same rigid bodies; a stiff position motor or a
  fixed constraint would instead add compliance, drift and solver load.
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

Emulated-hardware options (all off by default; :class:`wbmpc.sim.hardware.HardwareProfile` sets them), model
errors the MPC does not know about:

* Motor friction ``tau_f = -(c tanh(qdot / v_s) + b qdot)`` per joint (``coulomb_friction`` c [N m],
  ``viscous_friction`` b [N m s/rad], smoothed over ``friction_velocity`` v_s [rad/s]), added to the
  motor torque (after its clipping), on top of the URDF joint damping and friction above.
* Rotor inertia (``armature`` I_a [kg m^2], reflected through the gearbox): PyBullet has no armature
  (``changeDynamics`` has no such option, its URDF parser ignores it), so the plant adds the reflected
  inertia torque ``-I_a qddot`` with ``qddot`` the mean of the last two finite differences of the joint
  rates. One-step-old estimates are unstable once I_a exceeds a joint's effective link inertia (the B1
  calf ~0.04 kg m^2, the Z1 wrist ~0.009); the two-step mean is stable up to twice it, and the error
  decays within a few steps.
* Base centre-of-mass offset (``base_com_offset`` [m], base frame): the base link's inertial origin in the
  loaded URDF moves by it; the state conversion follows (it reads the inertial frame back).
* Torque-command latency (``torque_latency`` [s]): a delay line of ``round(latency / dt)`` steps between
  :meth:`PyBulletPlant.step`'s torques and the motors (the first command fills it after :meth:`reset`).

Example:
    >>> robot = load_b1_z1()
    >>> with PyBulletPlant(robot, scene=[Box((0.3, 0.3, 0.3), (1.0, 0.0, 0.15), mass=5.0)]) as plant:
    ...     state = plant.reset(robot.q_nominal, np.zeros(robot.nv))
    ...     state = plant.step(np.zeros(robot.nj))
    ...     plant.contact_forces()  # (4, 3) world ground reaction forces on FL, FR, RL, RR [N]
"""

from __future__ import annotations

import tempfile
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin
import pybullet as p

from wbmpc import checks
from wbmpc.model.quaternion import (
    cross3,
    quaternion_conjugate,
    quaternion_from_matrix,
    quaternion_multiply,
    rotation_matrix,
)
from wbmpc.model.robot import Robot, RobotModelError
from wbmpc.model.urdf import offset_base_com, preprocess_urdf
from wbmpc.sim.plant import Plant, PlantState
from wbmpc.sim.plant import fallen as _fallen

__all__ = ["Box", "Payload", "PyBulletPlant", "Wall"]

_VIOLATION_KINDS = ("pulling", "slipping", "penetrating")
#: A foot counts as slipping when its friction force reaches this share of mu * normal force (PyBullet's
#: default friction cone clamps the friction force at mu f_n when the contact slides).
_SLIP_RATIO = 0.99
#: Contact distance below which a foot counts as penetrating the ground [m] (standing, PyBullet's feet sink
#: ~1e-5 m into the ground).
_PENETRATION_TOL = 2e-3


# ---------------------------------------------------------------------------------------------- scene
@dataclass(frozen=True)
class Box:
    """An axis-aligned (up to yaw) box.

    Attributes:
        size: Full edge lengths (x, y, z) [m].
        position: Centre in the world [m].
        mass: Mass [kg]; 0 makes the box static.
        friction: Lateral friction coefficient (against the robot; against the ground it is multiplied by
            the ground friction).
        yaw: Rotation about the world z axis [rad].
    """

    size: tuple[float, float, float]
    position: tuple[float, float, float]
    mass: float = 0.0
    friction: float = 0.8
    yaw: float = 0.0

    def __post_init__(self):
        size = checks.vector("Box.size", self.size, 3, unit="m")
        if np.any(size <= 0):
            raise ValueError(f"Box.size must be 3 edge lengths > 0 [m], got {self.size!r}")
        checks.vector("Box.position", self.position, 3, unit="m")
        checks.number("Box.mass", self.mass, low=0.0, unit="kg (0: static)")
        checks.number("Box.friction", self.friction, low=0.0)
        checks.number("Box.yaw", self.yaw, unit="rad")


@dataclass(frozen=True)
class Wall:
    """A static slab whose contact face is centred at ``position`` and faces ``normal``.

    Attributes:
        position: Centre of the contact face in the world [m].
        normal: Outward normal of the contact face (towards the robot); normalised internally.
        size: Face extent (width, height) [m]: height along the world z axis projected on the face (for a
            horizontal face, e.g. a table top, along the world x axis), width across it.
        thickness: Slab thickness behind the face [m].
        friction: Lateral friction coefficient (against the robot).
    """

    position: tuple[float, float, float]
    normal: tuple[float, float, float]
    size: tuple[float, float] = (2.0, 2.0)
    thickness: float = 0.1
    friction: float = 0.5

    def __post_init__(self):
        checks.vector("Wall.position", self.position, 3, unit="m")
        normal = checks.vector("Wall.normal", self.normal, 3)
        if np.linalg.norm(normal) < 1e-9:
            raise ValueError(f"Wall.normal must be a non-zero direction (to the robot), got {self.normal!r}")
        size = checks.vector("Wall.size", self.size, 2, unit="m")
        if np.any(size <= 0):
            raise ValueError(f"Wall.size must be (width, height) > 0 [m], got {self.size!r}")
        checks.number("Wall.thickness", self.thickness, low=0.0, low_open=True, unit="m")
        checks.number("Wall.friction", self.friction, low=0.0)


@dataclass(frozen=True)
class Payload:
    """A sphere that can be attached to the end effector (carried or towed).

    Attributes:
        mass: Mass [kg].
        position: Initial centre in the world [m]; required unless ``attach="rigid"`` (the payload then
            hangs from the end effector).
        radius: Sphere radius [m].
        friction: Lateral friction coefficient.
        attach: ``None`` (free), ``"rigid"`` (point-to-point constraint between the end-effector point and
            the top of the sphere: the gripper holds it) or ``"tether"`` (a rope: a unilateral spring
            between the end-effector point and the sphere centre, for pulling-load experiments).
        tether_length: Rest length of the tether [m].
        tether_stiffness: Tether stiffness [N/m].
        tether_damping: Tether damping along the rope [N s/m] (only while taut).
        rolling_friction: Rolling (and spinning) friction coefficient [m]; a large value (e.g. 1) makes
            the sphere slide like a sled instead of rolling (a dragged load).
    """

    mass: float
    position: tuple[float, float, float] | None = None
    radius: float = 0.05
    friction: float = 0.8
    attach: str | None = None
    tether_length: float = 1.0
    tether_stiffness: float = 5000.0
    tether_damping: float = 100.0
    rolling_friction: float = 0.0

    def __post_init__(self):
        checks.number("Payload.mass", self.mass, low=0.0, low_open=True, unit="kg")
        if self.position is not None:
            checks.vector("Payload.position", self.position, 3, unit="m")
        checks.number("Payload.radius", self.radius, low=0.0, low_open=True, unit="m")
        if self.attach not in (None, "rigid", "tether"):
            raise ValueError(f"Payload.attach must be None, 'rigid' or 'tether', got {self.attach!r}")
        if self.position is None and self.attach != "rigid":
            raise ValueError("Payload.position is required unless attach='rigid'")
        checks.number("Payload.tether_length", self.tether_length, low=0.0, low_open=True, unit="m")
        for key in ("friction", "tether_stiffness", "tether_damping", "rolling_friction"):
            checks.number(f"Payload.{key}", getattr(self, key), low=0.0)


SceneObject = Box | Wall | Payload


# ---------------------------------------------------------------------------------------------- plant
class PyBulletPlant(Plant):
    """The robot in PyBullet, with the :class:`~wbmpc.sim.plant.ContactPlant` interface.

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
        coulomb_friction: Motor Coulomb friction [N m], scalar or (nj,) (see the module doc).
        viscous_friction: Motor viscous friction [N m s/rad], scalar or (nj,).
        friction_velocity: Joint rate [rad/s] over which the Coulomb friction rises (tanh smoothing).
        armature: Reflected rotor inertia [kg m^2], scalar or (nj,), emulated by a torque.
        base_com_offset: Shift of the base link's centre of mass [m] (3,), base frame; ``None``: none.
        torque_latency: Delay [s] of the torque commands (rounded to whole steps).

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
        coulomb_friction: float | np.ndarray = 0.0,
        viscous_friction: float | np.ndarray = 0.0,
        friction_velocity: float = 0.02,
        armature: float | np.ndarray = 0.0,
        base_com_offset: np.ndarray | None = None,
        torque_latency: float = 0.0,
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
        nj = robot.nj
        self._coulomb = _joint_values(coulomb_friction, nj, "coulomb_friction")
        self._viscous = _joint_values(viscous_friction, nj, "viscous_friction")
        self._armature = _joint_values(armature, nj, "armature")
        if not (np.isfinite(friction_velocity) and friction_velocity > 0.0):
            raise ValueError(f"friction_velocity must be > 0 [rad/s], got {friction_velocity}")
        self._friction_velocity = float(friction_velocity)
        com_offset = base_com_offset
        if com_offset is not None:
            com_offset = checks.array("base_com_offset", com_offset, 3)
        if not (np.isfinite(torque_latency) and torque_latency >= 0.0):
            raise ValueError(f"torque_latency must be >= 0 [s], got {torque_latency}")
        self._latency_steps = round(torque_latency / self._dt)
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

        self._bodies: dict[str, int] = {}
        self._payloads: dict[str, Payload] = {}
        self._constraints: dict[str, int] = {}
        self._tethers: dict[str, Payload] = {}
        self._t0 = 0.0
        self._steps = 0
        n = robot.n_feet
        self._forces = np.zeros((n, 3))
        self._in_contact = np.zeros(n, dtype=bool)
        self._ee_force = np.zeros(3)
        self._violations = {k: np.zeros(n, dtype=bool) for k in _VIOLATION_KINDS}
        self._counts = {k: np.zeros(n, dtype=np.int64) for k in _VIOLATION_KINDS}
        self._clip_counts = np.zeros(robot.nj, dtype=np.int64)
        self._tau_limits = robot.joint_torque_limits
        self._tau_queue: list[np.ndarray] = []  # torque delay line, oldest first
        self._v_joint_history: list[np.ndarray] = []  # last three joint rates, for the armature torque
        self._motor_torque = np.zeros(robot.nj)
        self._extra_torque = np.zeros(robot.nj)
        self._q = robot.q_nominal
        self._v = np.zeros(robot.nv)
        self.reset(robot.q_nominal, np.zeros(robot.nv))
        for name, obj in _scene_items(scene):
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
    def contact(self) -> np.ndarray:
        """Feet touching the ground after the last step, shape (n_feet,) bool."""
        return self._in_contact.copy()

    @property
    def last_contact_forces(self) -> np.ndarray:
        """Same as :meth:`contact_forces` (the name used by :class:`~wbmpc.sim.plant.ContactPlant`)."""
        return self._forces.copy()

    @property
    def last_violations(self) -> dict[str, np.ndarray]:
        """Per-foot flags of the last step, each shape (n_feet,) bool.

        * ``pulling``: always False (PyBullet contacts are unilateral); kept for key-by-key comparisons with
          :class:`~wbmpc.sim.plant.ContactPlant`.
        * ``slipping``: a foot whose friction force reached the friction limit (the contact slides).
        * ``penetrating``: a foot deeper than 2 mm into the ground.
        """
        return {k: flags.copy() for k, flags in self._violations.items()}

    @property
    def violation_counts(self) -> dict[str, np.ndarray]:
        """Cumulative per-foot number of steps with each of :attr:`last_violations` since :meth:`reset`."""
        return {k: counts.copy() for k, counts in self._counts.items()}

    @property
    def motor_torque(self) -> np.ndarray:
        """Motor torques [N m] (nj,) of the last step: the clipped command, ``torque_latency`` late."""
        return self._motor_torque.copy()

    @property
    def friction_torque(self) -> np.ndarray:
        """Motor friction plus armature torques [N m] (nj,) added in the last step (0 without them)."""
        return self._extra_torque.copy()

    @property
    def torque_clip_counts(self) -> np.ndarray:
        """Per-joint number of steps whose commanded torque exceeded the limit since :meth:`reset`, (nj,)."""
        return self._clip_counts.copy()

    # ------------------------------------------------------------------ state conversion
    def _read_state(self) -> tuple[np.ndarray, np.ndarray]:
        cid, body = self._client, self._body
        pos_c, quat_c = p.getBasePositionAndOrientation(body, physicsClientId=cid)
        vel_c, omega = p.getBaseVelocity(body, physicsClientId=cid)
        states = p.getJointStates(body, self._joint_ids, physicsClientId=cid)
        quat = quaternion_multiply(quat_c, self._q_il)
        if quat @ self._q[3:7] < 0.0:
            quat = -quat  # same rotation; stay in the previous state's hemisphere (no sign jumps in logs)
        R = rotation_matrix(quat)
        r_c = R @ self._r_li  # base origin -> centre of mass, world
        omega = np.array(omega)
        q = np.empty(self._model.nq)
        v = np.empty(self._model.nv)
        q[:3] = np.subtract(pos_c, r_c)
        q[3:7] = quat
        q[7:] = [s[0] for s in states]
        v[:3] = (np.subtract(vel_c, cross3(omega, r_c))) @ R
        v[3:6] = omega @ R
        v[6:] = [s[1] for s in states]
        return q, v

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
        self._write_state(q, v)
        self._q, self._v = self._read_state()
        self._t0, self._steps = float(t), 0
        self._forces[:] = 0.0
        self._in_contact[:] = False
        self._ee_force[:] = 0.0
        for k in _VIOLATION_KINDS:
            self._violations[k][:] = False
            self._counts[k][:] = 0
        self._clip_counts[:] = 0
        self._tau_queue.clear()
        self._v_joint_history.clear()
        self._motor_torque[:] = 0.0
        self._extra_torque[:] = 0.0
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
        tau = checks.array("tau_joints", tau_joints, self._robot.nj)
        clipped = np.abs(tau) > self._tau_limits
        if clipped.any():
            self._clip_counts += clipped
            tau = np.clip(tau, -self._tau_limits, self._tau_limits)
        tau = self._motor_dynamics(tau)
        wrench = None if external_wrench is None else checks.array("external_wrench", external_wrench, 6)
        p.setJointMotorControlArray(body, self._joint_ids, p.TORQUE_CONTROL, forces=tau, physicsClientId=cid)
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
        for name, payload in self._tethers.items():
            self._apply_tether(name, payload)
        p.stepSimulation(physicsClientId=cid)
        q, v = self._read_state()
        if not (np.isfinite(q).all() and np.isfinite(v).all()):
            raise FloatingPointError(f"PyBullet state became non-finite at t={self.time + self._dt:.6f} s")
        self._q, self._v = q, v
        self._steps += 1
        self._read_contacts()
        return self.state

    def _motor_dynamics(self, tau: np.ndarray) -> np.ndarray:
        """Joint torques [N m] reaching the links: the command delayed, plus friction and armature torques."""
        if self._latency_steps:
            if not self._tau_queue:
                self._tau_queue.extend(tau.copy() for _ in range(self._latency_steps))
            self._tau_queue.append(tau.copy())
            tau = self._tau_queue.pop(0)
        self._motor_torque = tau
        qd = self._v[6:]
        extra = -(self._coulomb * np.tanh(qd / self._friction_velocity) + self._viscous * qd)
        if self._armature.any():
            history = self._v_joint_history
            history.append(qd.copy())
            del history[:-3]
            if len(history) == 3:  # mean acceleration over the last two steps
                extra -= self._armature * (history[2] - history[0]) / (2.0 * self._dt)
        self._extra_torque = extra
        return tau + extra

    def _read_contacts(self) -> None:
        n = self._robot.n_feet
        forces = [[0.0, 0.0, 0.0] for _ in range(n)]
        ee = [0.0, 0.0, 0.0]
        depth = [0.0] * n
        friction = [0.0] * n  # largest friction force / (mu f_n) over the foot's contact points
        ground, robot, feet, gripper = self._ground, self._body, self._foot_of_link, self._gripper_links
        # Plain-float arithmetic: this runs every step and numpy is slow on 3-vectors.
        for c in p.getContactPoints(bodyA=robot, physicsClientId=self._client):
            other, link = c[2], c[3]
            if other == robot:
                continue
            # c[7] is the normal on B pointing towards A: these forces act on A, the robot.
            fn, n_b, f1, d1, f2, d2 = c[9], c[7], c[10], c[11], c[12], c[13]
            f = [fn * n_b[i] + f1 * d1[i] + f2 * d2[i] for i in range(3)]
            foot = feet.get(link)
            if foot is not None:
                acc = forces[foot]
                for i in range(3):
                    acc[i] += f[i]
                if other != ground:
                    continue  # a box or a wall: its friction differs, no slip or depth check
                depth[foot] = min(depth[foot], c[8])
                if fn > 0.0 and self._mu > 0.0:
                    friction[foot] = max(friction[foot], (f1 * f1 + f2 * f2) ** 0.5 / (self._mu * fn))
            elif link in gripper:
                for i in range(3):
                    ee[i] += f[i]
        self._forces = np.array(forces)
        self._ee_force = np.array(ee)
        self._in_contact = self._forces[:, 2] > 0.0
        self._violations["slipping"] = self._in_contact & (np.array(friction) >= _SLIP_RATIO)
        self._violations["penetrating"] = np.array(depth) < -_PENETRATION_TOL
        for k in ("slipping", "penetrating"):
            self._counts[k] += self._violations[k]

    # ------------------------------------------------------------------ measurements
    def contact_forces(self) -> np.ndarray:
        """World contact forces on the feet during the last step [N], shape (n_feet, 3).

        Sum over the foot's contact points (with the ground or any scene body) of the normal force and the
        two friction forces; zero rows for feet in the air (and for all feet after :meth:`reset`).
        """
        return self._forces.copy()

    def foot_contacts(self, scheduled: np.ndarray | None = None) -> np.ndarray:
        """Feet pushed upwards by a contact after the last step, shape (n_feet,) bool (``scheduled`` is
        ignored: the contacts come from the physics)."""
        return self._in_contact.copy()

    def ee_contact_force(self) -> np.ndarray:
        """World force [N] of everything except the robot itself on the gripper links (``gripperStator``,
        ``gripperMover``; the end-effector link for other arms) during the last step, shape (3,)."""
        if self._ee_link is None:
            raise ValueError(f"robot {self._robot.name!r} has no end effector")
        return self._ee_force.copy()

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
        return self.state

    # ------------------------------------------------------------------ scene
    def add(self, obj: SceneObject, name: str | None = None) -> int:
        """Add a :class:`Box`, :class:`Wall` or :class:`Payload`; returns its PyBullet body id.

        Raises:
            ValueError: On an unknown object type, a duplicate name or an invalid attachment.
        """
        kinds = {Box: "box", Wall: "wall", Payload: "payload"}
        if type(obj) not in kinds:
            raise ValueError(f"scene objects must be Box, Wall or Payload, got {type(obj).__name__}")
        if name is None:
            prefix = kinds[type(obj)]
            name = f"{prefix}{sum(n.startswith(prefix) for n in self._bodies)}"
        if name in self._bodies:
            raise ValueError(f"a scene body is already named {name!r}")
        cid = self._client
        if isinstance(obj, Box):
            half = 0.5 * checks.array("Box.size", obj.size, 3)
            shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=cid)
            body = p.createMultiBody(
                obj.mass,
                shape,
                basePosition=checks.array("Box.position", obj.position, 3),
                baseOrientation=p.getQuaternionFromEuler((0.0, 0.0, obj.yaw)),
                physicsClientId=cid,
            )
        elif isinstance(obj, Wall):
            n = checks.array("Wall.normal", obj.normal, 3)
            n = n / np.linalg.norm(n)
            up = np.array([0.0, 0.0, 1.0]) if abs(n[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
            up = up - (up @ n) * n
            up /= np.linalg.norm(up)
            R = np.column_stack([n, np.cross(up, n), up])  # box x = normal, z = "up" on the face
            width, height = obj.size
            shape = p.createCollisionShape(
                p.GEOM_BOX, halfExtents=[0.5 * obj.thickness, 0.5 * width, 0.5 * height], physicsClientId=cid
            )
            centre = checks.array("Wall.position", obj.position, 3) - 0.5 * obj.thickness * n
            body = p.createMultiBody(
                0.0,
                shape,
                basePosition=centre,
                baseOrientation=quaternion_from_matrix(R),
                physicsClientId=cid,
            )
        else:
            if obj.attach not in (None, "rigid", "tether"):
                raise ValueError(f"Payload.attach must be None, 'rigid' or 'tether', got {obj.attach!r}")
            if obj.attach is not None and self._ee_link is None:
                raise ValueError(f"robot {self._robot.name!r} has no end effector to attach a payload to")
            if obj.position is None and obj.attach != "rigid":
                raise ValueError("Payload.position is required unless attach='rigid'")
            if obj.position is None:
                position = self.ee_position() - [0.0, 0.0, obj.radius]
            else:
                position = checks.array("Payload.position", obj.position, 3)
            shape = p.createCollisionShape(p.GEOM_SPHERE, radius=obj.radius, physicsClientId=cid)
            body = p.createMultiBody(obj.mass, shape, basePosition=position, physicsClientId=cid)
            self._payloads[name] = obj
        p.changeDynamics(body, -1, lateralFriction=obj.friction, physicsClientId=cid)
        if isinstance(obj, Payload) and obj.rolling_friction > 0:
            p.changeDynamics(
                body,
                -1,
                rollingFriction=obj.rolling_friction,
                spinningFriction=obj.rolling_friction,
                physicsClientId=cid,
            )
        self._bodies[name] = body
        if isinstance(obj, Payload) and obj.attach is not None:
            self.attach_payload(name, obj.attach)
        return body

    @property
    def body_names(self) -> list[str]:
        """Names of the scene bodies, in the order they were added."""
        return list(self._bodies)

    def body(self, name: str) -> int:
        """PyBullet body id of a scene object."""
        if name not in self._bodies:
            raise KeyError(f"no scene body named {name!r}; known: {sorted(self._bodies)}")
        return self._bodies[name]

    def body_pose(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """World position [m] (centre of mass) and quaternion (x, y, z, w) of a scene body."""
        pos, quat = p.getBasePositionAndOrientation(self.body(name), physicsClientId=self._client)
        return np.array(pos), np.array(quat)

    def body_velocity(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """World linear [m/s] and angular [rad/s] velocity of a scene body."""
        lin, ang = p.getBaseVelocity(self.body(name), physicsClientId=self._client)
        return np.array(lin), np.array(ang)

    def attach_payload(self, name: str, mode: str = "rigid") -> None:
        """Attach a payload to the end effector.

        ``"rigid"`` moves the payload under the end-effector point and adds a ``JOINT_POINT2POINT``
        constraint between that point and the top of the sphere (collisions between the payload and the
        robot are disabled, the gripper encloses it). ``"tether"`` adds a rope of the payload's
        ``tether_length``: a spring that only pulls, applied every step between the end-effector point and
        the sphere centre.
        """
        if name not in self._payloads:
            raise KeyError(f"no payload named {name!r}; known: {sorted(self._payloads)}")
        if self._ee_link is None:
            raise ValueError(f"robot {self._robot.name!r} has no end effector to attach a payload to")
        self.detach_payload(name)
        payload, cid = self._payloads[name], self._client
        if mode == "rigid":
            body = self._bodies[name]
            for link in range(-1, p.getNumJoints(self._body, physicsClientId=cid)):
                p.setCollisionFilterPair(self._body, body, link, -1, 0, physicsClientId=cid)
            # Constraint frames are given in the link's inertial frame, not its URDF frame.
            info = p.getDynamicsInfo(self._body, self._ee_link, physicsClientId=cid)
            pivot = rotation_matrix(np.array(info[4])).T @ (self._ee_offset.translation - np.array(info[3]))
            constraint = p.createConstraint(
                self._body,
                self._ee_link,
                body,
                -1,
                p.JOINT_POINT2POINT,
                [0.0, 0.0, 0.0],
                pivot.tolist(),
                [0.0, 0.0, payload.radius],
                physicsClientId=cid,
            )
            p.changeConstraint(constraint, maxForce=1e5, physicsClientId=cid)
            self._constraints[name] = constraint
            self._place_payload_at_ee(name)
        elif mode == "tether":
            self._tethers[name] = payload
        else:
            raise ValueError(f"mode must be 'rigid' or 'tether', got {mode!r}")

    def detach_payload(self, name: str) -> None:
        """Release a payload (no-op if it is not attached); collisions with the robot are restored."""
        cid = self._client
        constraint = self._constraints.pop(name, None)
        if constraint is not None:
            p.removeConstraint(constraint, physicsClientId=cid)
            for link in range(-1, p.getNumJoints(self._body, physicsClientId=cid)):
                p.setCollisionFilterPair(self._body, self._bodies[name], link, -1, 1, physicsClientId=cid)
        self._tethers.pop(name, None)

    def _place_payload_at_ee(self, name: str) -> None:
        payload = self._payloads[name]
        top = self.ee_position()
        p.resetBasePositionAndOrientation(
            self._bodies[name], top - [0.0, 0.0, payload.radius], [0, 0, 0, 1], physicsClientId=self._client
        )
        p.resetBaseVelocity(
            self._bodies[name], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], physicsClientId=self._client
        )

    def _apply_tether(self, name: str, payload: Payload) -> None:
        cid = self._client
        s = p.getLinkState(
            self._body,
            self._ee_link,
            computeLinkVelocity=True,
            computeForwardKinematics=True,
            physicsClientId=cid,
        )
        R = rotation_matrix(np.array(s[5]))
        r = R @ self._ee_offset.translation
        p_ee = np.array(s[4]) + r
        v_ee = np.array(s[6]) + cross3(s[7], r - np.subtract(s[0], s[4]))
        body = self._bodies[name]
        pos, _ = p.getBasePositionAndOrientation(body, physicsClientId=cid)
        vel, _ = p.getBaseVelocity(body, physicsClientId=cid)
        d = np.array(pos) - p_ee
        length = np.linalg.norm(d)
        if length <= payload.tether_length or length < 1e-9:
            return
        u = d / length
        stretch_rate = u @ (np.array(vel) - v_ee)
        tension = max(
            0.0,
            payload.tether_stiffness * (length - payload.tether_length)
            + payload.tether_damping * stretch_rate,
        )
        p.applyExternalForce(body, -1, -tension * u, pos, p.WORLD_FRAME, physicsClientId=cid)
        p.applyExternalForce(self._body, self._ee_link, tension * u, p_ee, p.WORLD_FRAME, physicsClientId=cid)

    # ------------------------------------------------------------------ lifetime
    def close(self) -> None:
        """Disconnect the PyBullet client (idempotent)."""
        if getattr(self, "_client", -1) >= 0:
            try:
                p.disconnect(physicsClientId=self._client)
            finally:
                self._client = -1

    def __enter__(self) -> PyBulletPlant:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # interpreter shutdown: pybullet may already be gone
            pass


# ---------------------------------------------------------------------------------------------- helpers
def _joint_values(x, nj: int, name: str) -> np.ndarray:
    """A per-joint parameter >= 0: scalar or (nj,), as an (nj,) array."""
    arr = np.broadcast_to(np.asarray(x, dtype=float), (nj,)).copy() if np.ndim(x) == 0 else None
    arr = checks.array(name, x, nj) if arr is None else arr
    if not np.isfinite(arr).all() or np.any(arr < 0):
        raise ValueError(f"{name} must be finite and >= 0, got {x!r}")
    return arr


def _scene_items(scene) -> list[tuple[str | None, SceneObject]]:
    if scene is None:
        return []
    if isinstance(scene, Mapping):
        return list(scene.items())
    if isinstance(scene, (Box, Wall, Payload)):
        return [(None, scene)]
    return [(None, obj) for obj in scene]
