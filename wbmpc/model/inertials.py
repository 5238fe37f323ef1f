"""Link masses and inertias of a URDF checked against what Pinocchio and PyBullet do with them.

Two kinds of problem, all found in one pass and listed together (:func:`inertial_problems`):

* **errors** make the model unusable for everyone: a malformed ``<inertial>``, a negative mass, a moving
  rigid body (links joined by fixed or locked joints) without a positive mass and a positive-definite
  inertia (its dynamics are singular). :func:`wbmpc.model.robot.load_robot` raises
  :class:`~wbmpc.model.errors.RobotModelError` for them;
* **PyBullet-only** problems change the simulated robot but not Pinocchio's: PyBullet gives a link without
  ``<inertial>`` a mass of 1 kg (Pinocchio: massless), welds a root link of zero mass to the world and
  zeroes an inertia tensor that is not positive definite or breaks the triangle inequality (unless it is
  a negligible placeholder). The loader only warns (:class:`~wbmpc.model.errors.RobotModelWarning`): the
  MPC and the rigid plant use the model as written. The PyBullet plant refuses them
  (:func:`check_for_pybullet`, called by :func:`wbmpc.model.urdf.preprocess_urdf`).

Each problem carries concrete fixes (:class:`InertialFix`) that make the link valid; :func:`apply_fixes`
writes them into the URDF text. A triangle-inequality break gets the smallest change of each inertia entry
that makes the tensor valid ("raise ixx by 0.016 (to 0.066), or bring |ixz| under 0.0997").
"""

from __future__ import annotations

import copy
import math
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from wbmpc.model.errors import RobotModelError

__all__ = [
    "NEGLIGIBLE_INERTIA_RATIO",
    "InertialFix",
    "InertialProblem",
    "apply_fixes",
    "check_for_pybullet",
    "check_inertials",
    "inertial_problems",
    "read_inertials",
]

# An invalid inertia tensor whose largest principal moment is at most this share of the principal moments
# of the rigid body the link belongs to is a negligible placeholder (PyBullet zeroes it: no visible effect).
NEGLIGIBLE_INERTIA_RATIO = 1e-3
_INERTIA_KEYS = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
_INDEX = {"ixx": (0, 0), "ixy": (0, 1), "ixz": (0, 2), "iyy": (1, 1), "iyz": (1, 2), "izz": (2, 2)}
_ZERO_INERTIAL = (
    '<inertial><mass value="0"/><inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial>'
)
_ROOT_PLACEHOLDER = (
    '<inertial><mass value="0.001"/>'
    '<inertia ixx="1e-06" ixy="0" ixz="0" iyy="1e-06" iyz="0" izz="1e-06"/></inertial>'
)
_DENSITY = 1000.0  # [kg/m^3] of the estimates from collision shapes (water: a placeholder, not the link)


@dataclass(frozen=True)
class _Inertial:
    """A link's ``<inertial>`` as written: mass [kg] and rotational inertia [kg m^2] in the inertial frame."""

    mass: float
    inertia: np.ndarray  # (3, 3), symmetric


@dataclass(frozen=True)
class InertialFix:
    """A concrete change of one link's ``<inertial>`` that removes a problem (:func:`apply_fixes`).

    Attributes:
        link: The link.
        text: What to do, as the message says it.
        inertial: A whole ``<inertial>`` element to put in the link (replacing any), or ``None``.
        values: Attributes to set, ``(("ixx", "0.066"),)`` (``"mass"``: the ``<mass value>``).
    """

    link: str
    text: str
    inertial: str | None = None
    values: tuple[tuple[str, str], ...] = ()


@dataclass(frozen=True)
class InertialProblem:
    """One defect of one link (or of a moving rigid body, ``link`` its first link).

    Attributes:
        link: The link named first.
        message: What is wrong and what the simulator does with it, followed by the fixes.
        fixes: Alternative fixes (any one of them removes the problem); empty if only the link's real
            values will do.
        pybullet_only: ``True`` if only PyBullet would simulate something else (Pinocchio's model is
            usable), ``False`` for a model nobody can use.
    """

    link: str
    message: str
    fixes: tuple[InertialFix, ...] = ()
    pybullet_only: bool = True

    def __str__(self) -> str:
        return self.message


# --- reading --------------------------------------------------------------------------------------------
def read_inertials(urdf: Path, root: ET.Element) -> dict[str, _Inertial]:
    """Every link's inertial, read from the XML (Pinocchio cannot tell a missing one from a zero one).

    Raises:
        RobotModelError: listing every link without an ``<inertial>``, with a malformed one or with a
            negative mass (all in one message).
    """
    inertials, problems = _read(root)
    if problems:
        raise RobotModelError(_problem_report(urdf, [p.message for p in problems.values()]))
    return inertials


def _read(root: ET.Element) -> tuple[dict[str, _Inertial], dict[str, InertialProblem]]:
    """Parsed inertials and, per link, the problem of reading it (missing, malformed, negative mass).

    A missing ``<inertial>`` gets its message and fixes later (:func:`_missing`: they depend on the body).
    """
    inertials, problems = {}, {}
    for link in root.findall("link"):
        name = link.get("name")
        element = link.find("inertial")
        if element is None:
            problems[name] = InertialProblem(name, "missing")
            continue
        try:
            inertial = _parse_inertial(element)
        except ValueError as exc:
            problems[name] = InertialProblem(
                name,
                f"link {name!r} has a malformed <inertial> ({exc}); Pinocchio and PyBullet cannot load it: "
                'write <mass value="..."/> and all six <inertia> attributes as finite numbers',
                pybullet_only=False,
            )
            continue
        if inertial.mass < 0.0:
            problems[name] = InertialProblem(
                name,
                f"link {name!r} has a negative mass ({inertial.mass:g} kg); give its real mass",
                pybullet_only=False,
            )
        inertials[name] = inertial
    return inertials, problems


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


def loadable_urdf_text(root: ET.Element) -> str | None:
    """URDF text Pinocchio can parse when some ``<inertial>`` is malformed or has a negative mass (those
    replaced by zero ones, to find every other problem in the same pass); ``None`` if none is."""
    _, problems = _read(root)
    bad = {name for name, problem in problems.items() if not problem.pybullet_only}
    if not bad:
        return None
    root = copy.deepcopy(root)
    for link in root.findall("link"):
        if link.get("name") in bad:
            for element in link.findall("inertial"):
                link.remove(element)
            link.insert(0, ET.fromstring(_ZERO_INERTIAL))
    return ET.tostring(root, encoding="unicode")


# --- checking -------------------------------------------------------------------------------------------
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


def check_inertials(
    urdf: Path, inertials: Mapping[str, _Inertial], model: pin.Model, root: ET.Element | None = None
) -> list[InertialProblem]:
    """Every problem of the URDF's masses and inertias on the (reduced) ``model``, in one pass.

    Args:
        urdf: The URDF file (named in messages; read when ``root`` is not given).
        inertials: The parsed inertials (:func:`_read`), as written.
        model: Pinocchio's model of the URDF with its locked joints removed (fixed and locked links merged
            into rigid bodies).
        root: The URDF's XML root (``None``: parsed from ``urdf``).

    Returns:
        The problems in link order, then those of moving rigid bodies (empty: the URDF is fine).
    """
    if root is None:
        root = ET.parse(urdf).getroot()
    _, read_problems = _read(root)
    links = {link.get("name"): link for link in root.findall("link")}
    children = {j.find("child").get("link") for j in root.iter("joint") if j.find("child") is not None}
    roots = set(links) - children
    body_links: dict[int, list[str]] = {}
    for frame in model.frames:
        if frame.type == pin.FrameType.BODY:
            body_links.setdefault(frame.parentJoint, []).append(frame.name)
    body_of = {link: joint for joint, names in body_links.items() for link in names}
    scale = {j: float(np.abs(np.linalg.eigvalsh(model.inertias[j].inertia)).max()) for j in body_links}
    problems = []
    for name, element in links.items():
        body = body_of.get(name)
        body_mass = model.inertias[body].mass if body is not None else 0.0
        problem = read_problems.get(name)
        if problem is not None and problem.message == "missing":
            problems.append(_missing(name, element, name in roots, body_mass))
            continue
        if problem is not None:
            problems.append(problem)
            continue
        inertial = inertials[name]
        if inertial.mass == 0.0 and name in roots:
            problems.append(_massless_root(name, element, body_mass))
            continue
        defect = _inertia_defect(inertial.inertia)
        if defect is None:
            continue
        size = float(np.abs(np.linalg.eigvalsh(inertial.inertia)).max())
        if body is not None and size <= NEGLIGIBLE_INERTIA_RATIO * scale[body]:
            continue  # a placeholder on a body that is much larger: zeroing it changes nothing visible
        fixes = _tensor_fixes(name, inertial.inertia)
        advice = (
            "The smallest changes that make it valid (any one): " + ", or ".join(f.text for f in fixes)
            if fixes
            else "No single entry can make it valid"
        )
        problems.append(
            InertialProblem(
                name,
                f"link {name!r} has inertia {_inertia_text(inertial.inertia)}: {defect}, so PyBullet "
                f"replaces it with zero and would simulate a different link. {advice}. Better: the link's "
                "real inertia about its centre of mass (a solid box of mass m and sides a, b, c has ixx = "
                "m (b^2 + c^2) / 12, iyy = m (a^2 + c^2) / 12, izz = m (a^2 + b^2) / 12); check the "
                "off-diagonal signs",
                fixes,
            )
        )
    for joint, names in sorted(body_links.items()):
        if joint == 0:
            continue
        inertia = model.inertias[joint]
        moments = np.linalg.eigvalsh(inertia.inertia)
        if inertia.mass > 0.0 and moments[0] > 1e-9 * max(moments[2], 1e-300):
            continue
        if any(n in read_problems and not read_problems[n].pybullet_only for n in names):
            continue  # a malformed inertial or a negative mass, already listed, is the cause
        what = "the floating base" if joint == 1 else f"the body moved by joint {model.names[joint]!r}"
        listed = [n for n in names if n in {p.link for p in problems}]
        if listed:
            advice = f"fix {', '.join(repr(n) for n in listed)} as suggested above"
            fixes = ()
        else:
            advice = "give its links their real masses and inertias (at least a small positive mass)"
            fixes = _estimate_fixes(names[0], links[names[0]])
        problems.append(
            InertialProblem(
                names[0],
                f"{what} (links {', '.join(names)}) has mass {inertia.mass:g} kg and principal moments "
                f"({', '.join(f'{m:.3g}' for m in moments)}) kg m^2 about its centre of mass: a moving body "
                f"needs a positive mass and a positive-definite inertia, else its dynamics are singular: "
                f"{advice}" + "".join(f"; or {fix.text}" for fix in fixes),
                fixes,
                pybullet_only=False,
            )
        )
    return problems


def _missing(name: str, link: ET.Element, is_root: bool, body_mass: float) -> InertialProblem:
    """A link without ``<inertial>``: what PyBullet does, and an inertial that makes it load."""
    text = (
        f"link {name!r} has no <inertial>: Pinocchio makes it massless, but PyBullet gives it a mass of 1 kg "
        "and an inertia of diag(1, 1, 1) kg m^2"
    )
    if is_root and body_mass > 0.0:
        fix = InertialFix(name, f"add {_ROOT_PLACEHOLDER}", _ROOT_PLACEHOLDER)
        why = (
            "It is the root link: PyBullet welds a root link of zero mass to the world, so a massless frame "
            "here needs a small positive mass (the links fixed to it carry the body's mass)"
        )
        fixes = (fix,)
    elif body_mass > 0.0:
        fix = InertialFix(name, f"add {_ZERO_INERTIAL}", _ZERO_INERTIAL)
        why = "It moves with links that carry mass: if it is a massless frame, an explicit zero inertial does"
        fixes = (fix,)
    else:
        fixes = _estimate_fixes(name, link)
        why = "It is a moving body of its own: it needs its real mass and inertia"
    return InertialProblem(name, f"{text}. {why}: " + " or ".join(f.text for f in fixes), fixes)


def _massless_root(name: str, link: ET.Element, body_mass: float) -> InertialProblem:
    text = f"root link {name!r} has zero mass: PyBullet would weld it to the world (a fixed base)"
    if body_mass > 0.0:
        fixes = (InertialFix(name, f"put {_ROOT_PLACEHOLDER} instead", _ROOT_PLACEHOLDER),)
        why = "A massless frame link here needs a small positive mass (the links fixed to it carry the mass)"
    else:
        fixes = _estimate_fixes(name, link)
        why = "Give it its real mass and inertia"
    return InertialProblem(name, f"{text}. {why}: " + " or ".join(f.text for f in fixes), fixes)


def _estimate_fixes(name: str, link: ET.Element) -> tuple[InertialFix, ...]:
    """An ``<inertial>`` estimated from the link's first primitive collision shape (solid, density of
    water), or a 0.1 kg, 5 cm cube: both load, neither is the link's real value."""
    for collision in link.findall("collision"):
        geometry = collision.find("geometry")
        estimate = _primitive_inertia(geometry) if geometry is not None else None
        if estimate is None:
            continue
        mass, moments, shape = estimate
        origin = collision.find("origin")
        xml = _inertial_xml(mass, moments, origin)
        return (
            InertialFix(
                name, f"put {xml} (a solid {shape} of water's density: replace by the real values)", xml
            ),
        )
    xml = _inertial_xml(0.1, (0.1 * 0.05**2 / 6,) * 3, None)
    return (InertialFix(name, f"put {xml} (a 0.1 kg, 5 cm cube: replace by the real values)", xml),)


def _primitive_inertia(geometry: ET.Element) -> tuple[float, tuple[float, float, float], str] | None:
    try:
        if (box := geometry.find("box")) is not None:
            a, b, c = (float(x) for x in box.get("size").split())
            m = _DENSITY * a * b * c
            return m, (m * (b * b + c * c) / 12, m * (a * a + c * c) / 12, m * (a * a + b * b) / 12), "box"
        if (cylinder := geometry.find("cylinder")) is not None:
            r, h = float(cylinder.get("radius")), float(cylinder.get("length"))
            m = _DENSITY * math.pi * r * r * h
            side = m * (3 * r * r + h * h) / 12
            return m, (side, side, m * r * r / 2), "cylinder"
        if (sphere := geometry.find("sphere")) is not None:
            r = float(sphere.get("radius"))
            m = _DENSITY * 4 / 3 * math.pi * r**3
            return m, (0.4 * m * r * r,) * 3, "sphere"
    except (AttributeError, TypeError, ValueError):
        return None
    return None


def _inertial_xml(mass: float, moments: Sequence[float], origin: ET.Element | None) -> str:
    origin_xml = ""
    if origin is not None:
        origin_xml = f'<origin xyz="{origin.get("xyz", "0 0 0")}" rpy="{origin.get("rpy", "0 0 0")}"/>'
    ixx, iyy, izz = (f"{m:.4g}" for m in moments)
    return (
        f'<inertial>{origin_xml}<mass value="{mass:.4g}"/><inertia ixx="{ixx}" ixy="0" ixz="0" iyy="{iyy}" '
        f'iyz="0" izz="{izz}"/></inertial>'
    )


# --- the smallest change of one entry that makes a tensor valid ------------------------------------------
def _validity(inertias: np.ndarray) -> np.ndarray:
    """For tensors (n, 3, 3): min(smallest principal moment, smallest (I1 + I2 - I3) / 2) [kg m^2]; a
    tensor is valid (positive definite, triangle inequalities) where this is > 0."""
    moments = np.linalg.eigvalsh(inertias)
    trace = np.trace(inertias, axis1=1, axis2=2)
    # The eigenvalues of tr(I)/2 E - I are the (I_j + I_k - I_i) / 2: the triangle inequalities.
    spread = np.linalg.eigvalsh(0.5 * trace[:, None, None] * np.eye(3) - inertias)
    return np.minimum(moments[:, 0], spread[:, 0])


def _tensor_fixes(link: str, inertia: np.ndarray, limit: int = 3) -> tuple[InertialFix, ...]:
    """For each inertia entry, the smallest change of that entry alone that makes ``inertia`` valid (with
    a margin of 0.1 % of its largest moment, rounded so the written number is still valid); the ``limit``
    smallest relative to the entry's size, smallest first."""
    size = max(float(np.abs(np.linalg.eigvalsh(inertia)).max()), 1e-12)
    margin = 1e-3 * size
    trace = float(np.abs(np.diag(inertia)).sum())
    options = []
    for key in _INERTIA_KEYS:
        i, j = _INDEX[key]
        unit = np.zeros((3, 3))
        unit[i, j] = unit[j, i] = 1.0
        x = float(inertia[i, j])
        if i == j:
            low, high = -x, 2.0 * trace + 2.0 * size
        else:
            low, high = -trace - x, trace - x
        t_grid = np.linspace(low, high, 4001)
        g = _validity(inertia[None] + t_grid[:, None, None] * unit)
        best = int(np.argmax(g))
        if g[best] <= 2 * margin:
            continue  # this entry alone cannot make the tensor valid

        def valid(t, unit=unit):
            return float(_validity((inertia + t * unit)[None])[0])

        inside, outside = float(t_grid[best]), 0.0
        for _ in range(80):  # the valid set of t is an interval (concave validity): bisect its edge
            mid = 0.5 * (inside + outside)
            inside, outside = (mid, outside) if valid(mid) >= margin else (inside, mid)
        fix = _rounded_fix(link, key, x, inside, float(np.sign(t_grid[best] - inside)), valid, margin)
        if fix is not None:
            options.append((abs(inside) / max(abs(x), size), fix))
    options.sort(key=lambda item: item[0])
    return tuple(fix for _, fix in options[:limit])


def _rounded_fix(link, key, x, t, inward, valid, margin) -> InertialFix | None:
    """The change ``t`` of entry ``key`` (now ``x``) written with the fewest significant digits (2 to 8)
    that stay valid, rounded towards the inside of the valid interval (direction ``inward``)."""
    for digits in range(2, 9):
        target_text = f"{_round_towards(x + t, digits, inward):.{digits}g}"
        delta = float(target_text) - x
        if valid(delta) < 0.5 * margin:
            continue
        if key[1] == key[2]:  # a diagonal entry: raise or lower it
            text = f"{'raise' if delta > 0 else 'lower'} {key} by {abs(delta):.6g} (to {target_text})"
        elif abs(float(target_text)) < abs(x):
            text = f"bring |{key}| under {abs(float(target_text)):.{digits}g} ({key}={target_text})"
        else:
            text = f"set {key} to {target_text}"
        return InertialFix(link, text, values=((key, target_text),))
    return None


def _round_towards(value: float, digits: int, direction: float) -> float:
    """``value`` rounded to ``digits`` significant digits, up if ``direction`` > 0, down otherwise."""
    if value == 0.0:
        return 0.0
    step = 10.0 ** (math.floor(math.log10(abs(value))) - digits + 1)
    return (math.ceil(value / step) if direction > 0 else math.floor(value / step)) * step


# --- whole files -----------------------------------------------------------------------------------------
def inertial_problems(
    urdf: str | Path, locked_joints: Mapping[str, float] | None = None
) -> list[InertialProblem]:
    """Every mass and inertia problem of a URDF file, in one pass (see the module docstring).

    Args:
        urdf: The URDF file.
        locked_joints: ``{joint: value}`` of the joints made fixed (their links merge into one body).
    """
    urdf = Path(urdf)
    try:
        root = ET.parse(urdf).getroot()
    except (ET.ParseError, OSError) as exc:
        raise RobotModelError(f"{urdf} cannot be read as a URDF: {exc}") from exc
    inertials, _ = _read(root)
    model = _reduced_model(urdf, root, locked_joints or {})
    return check_inertials(urdf, inertials, model, root)


def _reduced_model(urdf: Path, root: ET.Element, locked_joints: Mapping[str, float]) -> pin.Model:
    text = loadable_urdf_text(root)
    if text is None:
        full = pin.buildModelFromUrdf(str(urdf), pin.JointModelFreeFlyer())
    else:
        full = pin.buildModelFromXML(text, pin.JointModelFreeFlyer())
    if not locked_joints:
        return full
    q = pin.neutral(full)
    ids = []
    for name, value in locked_joints.items():
        if not full.existJointName(name):
            raise RobotModelError(f"locked joint {name!r} is not in {urdf}")
        joint = full.joints[full.getJointId(name)]
        if joint.nq == 1:
            q[joint.idx_q] = value
        elif joint.nq == 2:
            q[joint.idx_q : joint.idx_q + 2] = math.cos(value), math.sin(value)
        ids.append(full.getJointId(name))
    return pin.buildReducedModel(full, ids, q)


def check_for_pybullet(urdf: str | Path, locked_joints: Mapping[str, float] | None = None) -> None:
    """Refuse a URDF whose masses or inertias PyBullet would not simulate as written.

    Raises:
        RobotModelError: listing every problem (:func:`inertial_problems`) with its fixes.
    """
    problems = inertial_problems(urdf, locked_joints)
    if problems:
        raise RobotModelError(
            _problem_report(urdf, [p.message for p in problems])
            + "\nThe PyBullet plant needs them fixed; the rigid plant (ContactPlant, demo --plant rigid) "
            "and the MPC use Pinocchio's model and can run as it is."
        )


def apply_fixes(urdf_text: str, fixes: Iterable[InertialFix]) -> str:
    """URDF text with each fix written into its link's ``<inertial>``.

    Raises:
        RobotModelError: a fix names a link the URDF does not have, or sets values of a link without
            ``<inertial>``.
    """
    root = ET.fromstring(urdf_text)
    links = {link.get("name"): link for link in root.iter("link")}
    for fix in fixes:
        link = links.get(fix.link)
        if link is None:
            raise RobotModelError(f"no link {fix.link!r} to fix")
        if fix.inertial is not None:
            for element in link.findall("inertial"):
                link.remove(element)
            link.insert(0, ET.fromstring(fix.inertial))
        inertial = link.find("inertial")
        for key, value in fix.values:
            if inertial is None:
                raise RobotModelError(f"link {fix.link!r} has no <inertial> to set {key} in")
            if key == "mass":
                inertial.find("mass").set("value", value)
            else:
                inertial.find("inertia").set(key, value)
    return ET.tostring(root, encoding="unicode")


def _inertia_text(inertia: np.ndarray) -> str:
    values = (inertia[0, 0], inertia[0, 1], inertia[0, 2], inertia[1, 1], inertia[1, 2], inertia[2, 2])
    return "(" + ", ".join(f"{key}={value:g}" for key, value in zip(_INERTIA_KEYS, values, strict=True)) + ")"


def _problem_report(urdf: str | Path, problems: Sequence[str]) -> str:
    count = f"{len(problems)} problem" + ("s" if len(problems) > 1 else "")
    lines = "\n".join(f"  - {problem}" for problem in problems)
    return f"{urdf}: {count} with link masses or inertias:\n{lines}"


def report(urdf: str | Path, problems: Sequence[InertialProblem]) -> str:
    """The message listing ``problems``: errors say nobody can use the model, PyBullet-only ones what
    PyBullet would do and that the rigid plant and the MPC are unaffected."""
    text = _problem_report(urdf, [p.message for p in problems])
    if any(not p.pybullet_only for p in problems):
        return text
    return (
        text + "\nOnly PyBullet would simulate another robot: the MPC and the rigid plant use the model as "
        "written; the PyBullet plant refuses this URDF until these are fixed."
    )
