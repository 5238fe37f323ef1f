"""Link masses and inertias of a URDF checked against what PyBullet loads as written.

PyBullet silently zeroes an inertia tensor that is not positive definite or breaks the triangle inequality,
and a link without an ``<inertial>`` gets a unit mass: the simulated plant would then not be the robot the
MPC models. :func:`read_inertials` parses every link's ``<inertial>`` and :func:`check_inertials` refuses the
tensors PyBullet would change (unless negligible), each problem named with the text to put in the URDF.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from wbmpc.model.errors import RobotModelError

__all__ = ["NEGLIGIBLE_INERTIA_RATIO", "check_inertials", "read_inertials"]

# An invalid inertia tensor whose largest principal moment is at most this share of the principal moments
# of the rigid body the link belongs to is a negligible placeholder (PyBullet zeroes it: no visible effect).
NEGLIGIBLE_INERTIA_RATIO = 1e-3
_INERTIA_KEYS = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
_ZERO_INERTIAL = (
    '<inertial><mass value="0"/><inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial>'
)


@dataclass(frozen=True)
class _Inertial:
    """A link's ``<inertial>`` as written: mass [kg] and rotational inertia [kg m^2] in the inertial frame."""

    mass: float
    inertia: np.ndarray  # (3, 3), symmetric


def read_inertials(urdf: Path, root: ET.Element) -> dict[str, _Inertial]:
    """Every link's inertial, read from the XML (Pinocchio cannot tell a missing one from a zero one).

    Raises:
        RobotModelError: listing every link without an ``<inertial>``, with a malformed one, with a
            negative mass, and a root link of zero mass.
    """
    links = root.findall("link")
    children = {
        joint.find("child").get("link") for joint in root.iter("joint") if joint.find("child") is not None
    }
    roots = {link.get("name") for link in links} - children
    inertials, problems = {}, []
    for link in links:
        name = link.get("name")
        element = link.find("inertial")
        if element is None:
            problems.append(
                f"link {name!r} has no <inertial>: Pinocchio makes it massless, but PyBullet gives it a mass "
                "of 1 kg and an inertia of diag(1, 1, 1) kg m^2. Add an <inertial> with the link's mass and "
                f"inertia, or, for a massless frame link on a fixed joint, {_ZERO_INERTIAL}"
            )
            continue
        try:
            inertial = _parse_inertial(element)
        except ValueError as exc:
            problems.append(f"link {name!r} has a malformed <inertial> ({exc}); PyBullet refuses to load it")
            continue
        if inertial.mass < 0.0:
            problems.append(f"link {name!r} has a negative mass ({inertial.mass:g} kg); give its real mass")
        elif inertial.mass == 0.0 and name in roots:
            problems.append(
                f"root link {name!r} has zero mass: PyBullet would weld it to the world (a fixed base). Give "
                'it a small mass and inertia, e.g. <mass value="0.001"/> <inertia ixx="1e-06" ixy="0" '
                'ixz="0" iyy="1e-06" iyz="0" izz="1e-06"/>'
            )
        inertials[name] = inertial
    if problems:
        raise RobotModelError(_problem_report(urdf, problems))
    return inertials


def _parse_inertial(element: ET.Element) -> _Inertial:
    """Mass and inertia of an ``<inertial>`` element; ``ValueError`` names what is missing or not a number."""
    mass_element, inertia_element = element.find("mass"), element.find("inertia")
    if mass_element is None or mass_element.get("value") is None:
        raise ValueError('no <mass value="...">')
    if inertia_element is None:
        raise ValueError("no <inertia>")
    missing = [key for key in _INERTIA_KEYS if inertia_element.get(key) is None]
    if missing:
        raise ValueError(f"<inertia> lacks {', '.join(missing)}")
    values = {"mass": mass_element.get("value")} | {key: inertia_element.get(key) for key in _INERTIA_KEYS}
    numbers = {}
    for key, text in values.items():
        try:
            numbers[key] = float(text)
        except ValueError:
            raise ValueError(f"{key}={text!r} is not a number") from None
        if not np.isfinite(numbers[key]):
            raise ValueError(f"{key}={text!r} is not finite")
    n = numbers
    inertia = np.array(
        [[n["ixx"], n["ixy"], n["ixz"]], [n["ixy"], n["iyy"], n["iyz"]], [n["ixz"], n["iyz"], n["izz"]]]
    )
    return _Inertial(n["mass"], inertia)


def _inertia_defect(inertia: np.ndarray) -> str | None:
    """Why PyBullet would reject a rotational inertia tensor (it then uses zero), or ``None`` if it is fine.

    A zero tensor is fine; otherwise the principal moments must be positive and satisfy the triangle
    inequalities (each at most the sum of the other two).
    """
    if not np.any(inertia):
        return None
    moments = np.linalg.eigvalsh(inertia)
    text = ", ".join(f"{m:.3g}" for m in moments)
    if moments[0] <= 0.0:
        return f"its principal moments ({text}) kg m^2 are not all positive"
    tolerance = 1e-9 * moments.sum()
    if moments[2] > moments[0] + moments[1] + tolerance:
        return (
            f"its principal moments ({text}) kg m^2 break the triangle inequality "
            f"{moments[0]:.3g} + {moments[1]:.3g} >= {moments[2]:.3g}"
        )
    return None


def check_inertials(urdf: Path, inertials: Mapping[str, _Inertial], model: pin.Model) -> None:
    """Check inertia tensors and the moving rigid bodies of ``model`` (fixed and locked links merged).

    Raises:
        RobotModelError: listing every link with an inertia tensor PyBullet would zero (unless negligible)
            and every moving rigid body without a positive mass and a positive-definite inertia.
    """
    body_links: dict[int, list[str]] = {}
    for frame in model.frames:
        if frame.type == pin.FrameType.BODY:
            body_links.setdefault(frame.parentJoint, []).append(frame.name)
    scale = {j: float(np.abs(np.linalg.eigvalsh(model.inertias[j].inertia)).max()) for j in body_links}
    problems = []
    for link, inertial in inertials.items():
        defect = _inertia_defect(inertial.inertia)
        if defect is None:
            continue
        joint = next((j for j, names in body_links.items() if link in names), None)
        size = float(np.abs(np.linalg.eigvalsh(inertial.inertia)).max())
        if joint is not None and size <= NEGLIGIBLE_INERTIA_RATIO * scale[joint]:
            continue  # a placeholder on a body that is much larger: zeroing it changes nothing visible
        problems.append(
            f"link {link!r} has inertia {_inertia_text(inertial.inertia)}: {defect}, so PyBullet replaces it "
            "with zero and would simulate a different link. Use the link's real inertia about its centre "
            "of mass (e.g. a solid box of mass m and sides a, b, c has ixx = m (b^2 + c^2) / 12, "
            "iyy = m (a^2 + c^2) / 12, izz = m (a^2 + b^2) / 12) and check the off-diagonal signs"
        )
    for joint, links in sorted(body_links.items()):
        if joint == 0:
            continue
        inertia = model.inertias[joint]
        moments = np.linalg.eigvalsh(inertia.inertia)
        if inertia.mass > 0.0 and moments[0] > 1e-9 * max(moments[2], 1e-300):
            continue
        what = "the floating base" if joint == 1 else f"the body moved by joint {model.names[joint]!r}"
        problems.append(
            f"{what} (links {', '.join(links)}) has mass {inertia.mass:g} kg and principal moments "
            f"({', '.join(f'{m:.3g}' for m in moments)}) kg m^2 about its centre of mass: a moving body "
            "needs a positive mass and a positive-definite inertia, else its dynamics are singular. Give "
            "its links their real masses and inertias (at least a small positive mass and inertia)"
        )
    if problems:
        raise RobotModelError(_problem_report(urdf, problems))


def _inertia_text(inertia: np.ndarray) -> str:
    values = (inertia[0, 0], inertia[0, 1], inertia[0, 2], inertia[1, 1], inertia[1, 2], inertia[2, 2])
    return "(" + ", ".join(f"{key}={value:g}" for key, value in zip(_INERTIA_KEYS, values, strict=True)) + ")"


def _problem_report(urdf: Path, problems: Sequence[str]) -> str:
    count = f"{len(problems)} problem" + ("s" if len(problems) > 1 else "")
    lines = "\n".join(f"  - {problem}" for problem in problems)
    return f"{urdf}: {count} with link masses or inertias (PyBullet would simulate another robot):\n{lines}"
