"""The error of a robot description that cannot be used."""

from __future__ import annotations

__all__ = ["RobotModelError"]


class RobotModelError(ValueError):
    """Raised for a robot description that cannot be used (missing file, unknown joint, frame or pose,
    or a link mass or inertia that the simulator would not load as written)."""
