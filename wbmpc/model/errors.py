"""The error of a robot description that cannot be used, and the warning of one PyBullet would change."""

from __future__ import annotations

__all__ = ["RobotModelError", "RobotModelWarning"]


class RobotModelError(ValueError):
    """Raised for a robot description that cannot be used (missing file, unknown joint, frame or pose,
    or a link mass or inertia that the simulator would not load as written)."""


class RobotModelWarning(UserWarning):
    """Issued by the loader for link masses or inertias that only PyBullet would change (a link without
    ``<inertial>``, an inertia tensor it zeroes, a massless root link): the MPC and the rigid plant use the
    model as written, the PyBullet plant refuses it with the same list (:mod:`wbmpc.model.inertials`)."""
