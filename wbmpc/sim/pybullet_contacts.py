"""Contact readings of the PyBullet plant: foot and gripper forces, slip and penetration, from PyBullet's
contact points after each step.

:class:`ContactReadings` is mixed into :class:`~wbmpc.sim.pybullet_plant.PyBulletPlant` (it uses the plant's
client, robot and ground bodies and its foot and gripper link maps).
"""

from __future__ import annotations

import numpy as np
import pybullet as p

__all__ = ["VIOLATION_KINDS", "ContactReadings"]

VIOLATION_KINDS = ("pulling", "slipping", "penetrating")
#: A foot counts as slipping when its friction force reaches this share of mu * normal force (PyBullet's
#: default friction cone clamps the friction force at mu f_n when the contact slides).
_SLIP_RATIO = 0.99
#: Contact distance below which a foot counts as penetrating the ground [m] (standing, PyBullet's feet sink
#: ~1e-5 m into the ground).
_PENETRATION_TOL = 2e-3


class ContactReadings:
    """The plant's contact measurements of the last step (mixed into the PyBullet plant)."""

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

    def _read_contacts(self) -> None:
        n = self._robot.n_feet
        forces = [[0.0, 0.0, 0.0] for _ in range(n + 1)]  # the feet's, then the gripper's
        depth = [0.0] * n
        friction = [0.0] * n  # largest friction force / (mu f_n) over the foot's contact points
        ground, robot, feet, gripper = self._ground, self._body, self._foot_of_link, self._gripper_links
        mu = self._mu
        # Plain-float arithmetic: this runs every step and numpy is slow on 3-vectors.
        for c in p.getContactPoints(bodyA=robot, physicsClientId=self._client):
            other, link = c[2], c[3]
            if other == robot:
                continue
            foot = feet.get(link)
            if foot is None and link not in gripper:
                continue
            # c[7] is the normal on B pointing towards A: these forces act on A, the robot.
            (nx, ny, nz), fn, f1, (ax, ay, az), f2, (bx, by, bz) = c[7], c[9], c[10], c[11], c[12], c[13]
            acc = forces[n if foot is None else foot]
            acc[0] += fn * nx + f1 * ax + f2 * bx
            acc[1] += fn * ny + f1 * ay + f2 * by
            acc[2] += fn * nz + f1 * az + f2 * bz
            if foot is None or other != ground:
                continue  # the gripper; or a box or a wall: its friction differs, no slip or depth check
            if c[8] < depth[foot]:
                depth[foot] = c[8]
            if fn > 0.0 and mu > 0.0:
                ratio = (f1 * f1 + f2 * f2) ** 0.5 / (mu * fn)
                if ratio > friction[foot]:
                    friction[foot] = ratio
        in_contact = [f[2] > 0.0 for f in forces[:n]]
        slipping = [c and s >= _SLIP_RATIO for c, s in zip(in_contact, friction, strict=True)]
        penetrating = [d < -_PENETRATION_TOL for d in depth]
        self._ee_force = np.array(forces.pop())
        self._forces = np.array(forces).reshape(n, 3)
        flags = np.array(in_contact + slipping + penetrating, dtype=bool)  # one conversion, three views
        self._in_contact = flags[:n]
        self._violations["slipping"], self._violations["penetrating"] = flags[n : 2 * n], flags[2 * n :]
        if any(slipping):
            self._counts["slipping"] += self._violations["slipping"]
        if any(penetrating):
            self._counts["penetrating"] += self._violations["penetrating"]

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
