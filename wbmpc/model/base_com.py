"""The base's centre of mass moved in a robot model: the model of a robot whose trunk mass sits elsewhere.

The B1's rear legs carry ~60 % of its weight standing, as if the trunk's centre of mass sat ~19 cm behind
the URDF's. :func:`shift_base_com` rebuilds the model with such an offset (identified from a standing log by
:func:`wbmpc.analysis.identify_com_offset`, stored in a calibration file by
:mod:`wbmpc.model.calibration`). The mass that moves is the heaviest link rigidly attached to the root
(:func:`base_com_link`), as the emulated robot moves it (:func:`wbmpc.model.urdf.offset_base_com`),
so an identified offset rebuilds that robot's model.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import replace

import numpy as np
import pinocchio as pin

__all__ = ["base_com_link", "shift_base_com"]


def base_com_link(robot) -> tuple[str, float]:
    """The link whose centre of mass a base offset moves and its mass [kg].

    The heaviest link rigidly attached (by fixed joints) to the URDF's root link (the B1's ``trunk``).

    Args:
        robot: A :class:`~wbmpc.model.robot.Robot` (its ``urdf_path`` is read).

    Returns:
        ``(link name, mass [kg])``.
    """
    root = ET.parse(robot.urdf_path).getroot()
    links = {link.get("name"): link for link in root.iter("link")}
    children = {c.get("link") for c in root.iter("child")}
    base = next(name for name in links if name not in children)
    rigid, stack = {base}, [base]
    while stack:
        parent = stack.pop()
        for joint in root.iter("joint"):
            if joint.get("type") == "fixed" and joint.find("parent").get("link") == parent:
                rigid.add(joint.find("child").get("link"))
                stack.append(joint.find("child").get("link"))

    def mass(name):
        element = links[name].find("inertial/mass")
        return 0.0 if element is None else float(element.get("value", 0.0))

    heavy = max(sorted(rigid), key=mass)
    return heavy, mass(heavy)


def shift_base_com(robot, offset, front_force_ratio: float | None = None):
    """A copy of ``robot`` whose base link's centre of mass moved by ``offset`` [m] (base frame).

    The mass ``m`` of :func:`base_com_link` moves: the base body's first moment changes by ``m offset`` and
    its rotational inertia by the link's parallel-axis terms (the dynamic parameters are linear in the mass
    distribution); the total mass is unchanged.

    Args:
        robot: The nominal :class:`~wbmpc.model.robot.Robot`.
        offset: Shift [m] (3,), base frame, x forward (assumes the link's frame is aligned with the base's).
        front_force_ratio: New share of the weight on the front feet in the force targets, in (0, 1)
            (``None``: kept).

    Returns:
        A new :class:`~wbmpc.model.robot.Robot` with a copied model (the original is unchanged).

    Raises:
        ValueError: if ``offset`` is not 3 finite numbers or ``front_force_ratio`` is not in (0, 1).
    """
    offset = np.asarray(offset, dtype=float)
    if offset.shape != (3,) or not np.all(np.isfinite(offset)):
        raise ValueError(f"the base CoM offset must be 3 finite numbers [m], got {offset}")
    if front_force_ratio is not None and not (0.0 < float(front_force_ratio) < 1.0):
        raise ValueError(f"front_force_ratio must be in (0, 1), got {front_force_ratio!r}")
    _, m = base_com_link(robot)
    model = robot.model.copy()
    body = model.inertias[1]
    old = pin.Inertia(m, body.lever, np.zeros((3, 3)))
    new = pin.Inertia(m, body.lever + offset, np.zeros((3, 3)))
    params = body.toDynamicParameters() - old.toDynamicParameters() + new.toDynamicParameters()
    model.inertias[1] = pin.Inertia.FromDynamicParameters(params)
    changes = {"model": model}
    if front_force_ratio is not None:
        changes["front_force_ratio"] = float(front_force_ratio)
    return replace(robot, **changes)
