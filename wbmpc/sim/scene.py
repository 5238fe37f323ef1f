"""Objects of a PyBullet scene besides the robot: boxes, walls (or table tops) and payloads.

Plain validated descriptions (frozen dataclasses); :meth:`wbmpc.sim.pybullet_plant.PyBulletPlant.add`
creates the bodies, and :class:`~wbmpc.sim.loop_config.PlantConfig` ``scene`` lists them for a run.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wbmpc import checks

__all__ = ["Box", "Payload", "SceneObject", "Wall"]


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
