"""Scene bodies of the PyBullet plant: boxes, walls and payloads, carried or towed by the end effector.

:class:`SceneBodies` is the part of :class:`~wbmpc.sim.pybullet_plant.PyBulletPlant` that creates the scene
objects of :mod:`wbmpc.sim.scene` in the plant's client, names them, reads their poses and attaches payloads
to the end effector (a point-to-point constraint, or a tether: a spring that only pulls, applied every
step). It is a mixin: it uses the plant's client, robot body and end-effector link.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pybullet as p

from wbmpc import checks
from wbmpc.model.quaternion import cross3, quaternion_from_matrix, rotation_matrix
from wbmpc.sim.scene import Box, Payload, SceneObject, Wall

__all__ = ["SceneBodies", "scene_items"]


class SceneBodies:
    """Scene objects in a PyBullet plant (mixed into :class:`~wbmpc.sim.pybullet_plant.PyBulletPlant`).

    The plant sets ``_client``, ``_body``, ``_robot``, ``_ee_link``, ``_ee_offset`` and :meth:`ee_position`;
    :meth:`_init_scene` the body tables.
    """

    def _init_scene(self) -> None:
        self._bodies: dict[str, int] = {}
        self._payloads: dict[str, Payload] = {}
        self._constraints: dict[str, int] = {}
        self._tethers: dict[str, Payload] = {}

    def _apply_tethers(self) -> None:
        """The tethers' forces of this step (called before each simulation step)."""
        for name, payload in self._tethers.items():
            self._apply_tether(name, payload)

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


def scene_items(scene) -> list[tuple[str | None, SceneObject]]:
    if scene is None:
        return []
    if isinstance(scene, Mapping):
        return list(scene.items())
    if isinstance(scene, (Box, Wall, Payload)):
        return [(None, scene)]
    return [(None, obj) for obj in scene]
