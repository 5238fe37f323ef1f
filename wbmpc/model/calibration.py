"""Calibration file of a robot: what a lab identifies once and every later run loads with the model.

A :class:`Calibration` holds the parameters the nominal URDF model gets wrong on the real robot: the base
link's centre-of-mass offset and the front/rear force split (:func:`wbmpc.analysis.identify_com_offset`),
and per joint the motor friction and the reflected rotor inertia (armature)
(:func:`wbmpc.estimation.identification.identify_joint_friction`). ``python -m wbmpc.studies.calibrate``
writes one from a log; :func:`wbmpc.model.robot.load_robot` (``calibration=``) applies one
(:meth:`Calibration.apply`): the base CoM moved (:func:`wbmpc.model.base_com.shift_base_com`), the front
force ratio set and the armature written to ``model.armature`` (which Pinocchio's and the CasADi mirror's
RNEA, CRBA and ABA include). The friction is not part of the rigid-body model: the low-level controller
compensates it (:meth:`Calibration.joint_friction`, ``LowLevelController(friction=...)``).

File format (YAML, ``.yaml`` / ``.yml``; or the same keys in JSON, ``.json``), units in the key names::

    format_version: 1                       # this module reads up to FORMAT_VERSION
    robot: Unitree B1 + Z1                  # optional: the robot's display name (informative)
    source: runs/stand_trot_bag             # optional: the log it was identified from (informative)
    base_com_offset_m: [-0.19, 0.0, 0.0]    # base link CoM shift [m], base frame (x forward)
    front_force_ratio: 0.40                 # share of the weight on the front feet; null: the model's
    friction_velocity_radps: 0.05           # v_s [rad/s] of the Coulomb term c tanh(qdot / v_s)
    joints:                                 # any subset of the robot's actuated joints, by name
      FL_hip_joint: {coulomb_nm: 1.0, viscous_nms_per_rad: 0.2, armature_kgm2: 0.02}
      ...
    identification: {...}                   # optional: free-form diagnostics of the identification

Joints the file does not list keep the nominal values (no friction, no armature). :meth:`Calibration.load`
checks every field and names the file and the field in its errors; :meth:`Calibration.apply` rejects joint
names the robot does not have.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from wbmpc.model.friction import JointFriction

__all__ = ["FORMAT_VERSION", "Calibration", "CalibrationError", "JointParameters"]

FORMAT_VERSION = 1
_JOINT_KEYS = {"coulomb": "coulomb_nm", "viscous": "viscous_nms_per_rad", "armature": "armature_kgm2"}
_TOP_KEYS = (
    "format_version",
    "robot",
    "source",
    "base_com_offset_m",
    "front_force_ratio",
    "friction_velocity_radps",
    "joints",
    "identification",
)
_SUFFIXES = (".yaml", ".yml", ".json")


class CalibrationError(ValueError):
    """A calibration file or value that cannot be used; the message names the file and the field."""


@dataclass(frozen=True)
class JointParameters:
    """One joint's calibration: Coulomb friction [N m], viscous friction [N m s/rad], armature [kg m^2]."""

    coulomb: float = 0.0
    viscous: float = 0.0
    armature: float = 0.0


@dataclass
class Calibration:
    """The identified parameters of one robot (see the module doc for the file format).

    Attributes:
        base_com_offset: Shift of the base link's centre of mass [m] (3,), base frame, x forward.
        front_force_ratio: Share of the weight on the front feet in the MPC's force targets, in (0, 1);
            ``None``: the robot's own.
        friction_velocity: Smoothing joint rate ``v_s`` [rad/s] of the Coulomb friction, > 0.
        joints: ``{joint name: JointParameters}``.
        robot: Display name of the robot it was identified on (informative).
        source: The log it was identified from (informative).
        identification: Free-form diagnostics (JSON-ready values).
        path: The file it was loaded from or last saved to (``None``: built in memory); names the origin
            in error messages.

    Raises:
        CalibrationError: for a value of the wrong type or out of range (see :meth:`from_dict`).
    """

    base_com_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    front_force_ratio: float | None = None
    friction_velocity: float = 0.05
    joints: dict[str, JointParameters] = field(default_factory=dict)
    robot: str | None = None
    source: str | None = None
    identification: dict = field(default_factory=dict)
    path: Path | None = field(default=None, compare=False)

    def __post_init__(self):
        checked = Calibration.from_dict(self.to_dict(), where=self._where())
        self.base_com_offset = checked.base_com_offset
        self.joints = checked.joints
        self.friction_velocity = checked.friction_velocity

    def _where(self) -> str:
        return str(self.path) if self.path is not None else "calibration"

    # ------------------------------------------------------------------------------------------- files
    def to_dict(self) -> dict:
        """The file's content as plain values (the keys of the module doc)."""
        joints = {}
        for name, p in self.joints.items():
            if not isinstance(p, JointParameters):
                raise CalibrationError(
                    f"{self._where()}: joints[{name!r}] must be a JointParameters, got {type(p).__name__}"
                )
            joints[name] = {key: getattr(p, attr) for attr, key in _JOINT_KEYS.items()}
        return {
            "format_version": FORMAT_VERSION,
            "robot": self.robot,
            "source": self.source,
            "base_com_offset_m": list(self.base_com_offset) if _is_sequence(self.base_com_offset) else None,
            "front_force_ratio": self.front_force_ratio,
            "friction_velocity_radps": self.friction_velocity,
            "joints": joints,
            "identification": self.identification,
        }

    @classmethod
    def from_dict(cls, data, where: str = "calibration") -> Calibration:
        """A calibration from the file's content, every field checked.

        Args:
            data: Mapping with the keys of the module doc.
            where: Name of the origin (the file) used in error messages.

        Raises:
            CalibrationError: naming ``where`` and the field, for a missing ``format_version``, ``joints``
                or ``base_com_offset_m``, a newer format version, an unknown key, or a value of the wrong
                type or out of range.
        """
        if not isinstance(data, dict):
            raise CalibrationError(
                f"{where}: a calibration is a mapping of fields, got {type(data).__name__}"
            )
        unknown = sorted(set(data) - set(_TOP_KEYS))
        if unknown:
            raise CalibrationError(f"{where}: unknown fields {unknown}; known fields: {list(_TOP_KEYS)}")
        for key in ("format_version", "base_com_offset_m", "joints"):
            if key not in data:
                raise CalibrationError(f"{where}: field {key!r} is missing")
        version = data["format_version"]
        if isinstance(version, bool) or not isinstance(version, int) or version < 1:
            raise CalibrationError(
                f"{where}: field 'format_version' must be an integer >= 1, got {version!r}"
            )
        if version > FORMAT_VERSION:
            raise CalibrationError(
                f"{where}: format_version {version} is newer than this wbmpc reads (up to {FORMAT_VERSION})"
            )
        for key in ("robot", "source"):
            if data.get(key) is not None and not isinstance(data[key], str):
                raise CalibrationError(f"{where}: field {key!r} must be a string or null, got {data[key]!r}")
        offset = data["base_com_offset_m"]
        if not _is_sequence(offset) or len(offset) != 3:
            raise CalibrationError(
                f"{where}: field 'base_com_offset_m' must be 3 numbers [m], got {offset!r}"
            )
        offset = tuple(_number(where, f"base_com_offset_m[{i}]", x) for i, x in enumerate(offset))
        ratio = data.get("front_force_ratio")
        if ratio is not None:
            ratio = _number(where, "front_force_ratio", ratio)
            if not 0.0 < ratio < 1.0:
                raise CalibrationError(f"{where}: field 'front_force_ratio' must be in (0, 1), got {ratio}")
        velocity = _number(where, "friction_velocity_radps", data.get("friction_velocity_radps", 0.05))
        if velocity <= 0.0:
            raise CalibrationError(f"{where}: field 'friction_velocity_radps' must be > 0, got {velocity}")
        joints_in = data["joints"]
        if not isinstance(joints_in, dict):
            raise CalibrationError(
                f"{where}: field 'joints' must map joint names to their parameters, got {joints_in!r}"
            )
        joints = {}
        for name, entry in joints_in.items():
            if not isinstance(name, str):
                raise CalibrationError(f"{where}: field 'joints' has a key {name!r} that is not a joint name")
            if not isinstance(entry, dict):
                raise CalibrationError(
                    f"{where}: field 'joints.{name}' must be a mapping with keys "
                    f"{list(_JOINT_KEYS.values())}, got {entry!r}"
                )
            extra = sorted(set(entry) - set(_JOINT_KEYS.values()))
            if extra:
                raise CalibrationError(
                    f"{where}: field 'joints.{name}' has unknown keys {extra}; "
                    f"known: {list(_JOINT_KEYS.values())}"
                )
            values = {}
            for attr, key in _JOINT_KEYS.items():
                if key not in entry:
                    raise CalibrationError(f"{where}: field 'joints.{name}.{key}' is missing")
                values[attr] = _number(where, f"joints.{name}.{key}", entry[key])
                if values[attr] < 0.0:
                    raise CalibrationError(
                        f"{where}: field 'joints.{name}.{key}' must be >= 0, got {entry[key]}"
                    )
            joints[name] = JointParameters(**values)
        diagnostics = data.get("identification") or {}
        if not isinstance(diagnostics, dict):
            raise CalibrationError(f"{where}: field 'identification' must be a mapping, got {diagnostics!r}")
        out = object.__new__(cls)  # checked values: no second round of checks in __post_init__
        out.base_com_offset, out.front_force_ratio, out.friction_velocity = offset, ratio, velocity
        out.joints, out.robot, out.source = joints, data.get("robot"), data.get("source")
        out.identification, out.path = dict(diagnostics), None
        return out

    def save(self, path: str | Path) -> Path:
        """Write the calibration to ``path`` (YAML for ``.yaml``/``.yml``, JSON for ``.json``).

        Returns:
            The path written (also stored in :attr:`path`).

        Raises:
            CalibrationError: for another suffix.
            OSError: if the file cannot be written.
        """
        path = Path(path)
        if path.suffix.lower() not in _SUFFIXES:
            raise CalibrationError(f"{path}: a calibration file ends with one of {list(_SUFFIXES)}")
        data = _plain(self.to_dict())
        path.parent.mkdir(parents=True, exist_ok=True)
        if path.suffix.lower() == ".json":
            path.write_text(json.dumps(data, indent=2) + "\n")
        else:
            _write_yaml(path, data)
        self.path = path
        return path

    @classmethod
    def load(cls, path: str | Path) -> Calibration:
        """Read a calibration file written by :meth:`save` (or by hand, in the format of the module doc).

        Raises:
            FileNotFoundError: if there is no file at ``path``.
            CalibrationError: for another suffix, a file that is not valid YAML/JSON, or a field that is
                missing, unknown, of the wrong type or out of range (naming the file and the field).
        """
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"no calibration file at {path}")
        suffix = path.suffix.lower()
        if suffix not in _SUFFIXES:
            raise CalibrationError(f"{path}: a calibration file ends with one of {list(_SUFFIXES)}")
        text = path.read_text()
        try:
            if suffix == ".json":
                data = json.loads(text)
            else:
                from ruamel.yaml import YAML, YAMLError

                try:
                    data = YAML(typ="safe").load(text)
                except YAMLError as exc:
                    raise ValueError(str(exc)) from None
        except ValueError as exc:
            kind = "JSON" if suffix == ".json" else "YAML"
            raise CalibrationError(f"{path}: not valid {kind}: {exc}") from None
        out = cls.from_dict(data, where=str(path))
        out.path = path
        return out

    # ----------------------------------------------------------------------------------------- robots
    def check_joints(self, robot) -> None:
        """Every joint the calibration names must be an actuated joint of ``robot``.

        Raises:
            CalibrationError: naming the file, the field and the unknown joints.
        """
        unknown = [name for name in self.joints if name not in robot.joint_names]
        if unknown:
            raise CalibrationError(
                f"{self._where()}: field 'joints' names joints {unknown} that robot {robot.name!r} does not "
                f"have (a calibration of another robot?); its joints: {robot.joint_names}"
            )

    def _per_joint(self, robot, attr: str) -> np.ndarray:
        self.check_joints(robot)
        return np.array([getattr(self.joints.get(n, JointParameters()), attr) for n in robot.joint_names])

    def armature(self, robot) -> np.ndarray:
        """Armature [kg m^2] (nj,) in the robot's joint order (0 for the joints not listed)."""
        return self._per_joint(robot, "armature")

    def joint_friction(self, robot) -> JointFriction:
        """The friction of every joint of ``robot`` (0 for the joints not listed).

        Raises:
            CalibrationError: for joint names the robot does not have.
        """
        return JointFriction(
            self._per_joint(robot, "coulomb"), self._per_joint(robot, "viscous"), self.friction_velocity
        )

    def apply(self, robot):
        """A copy of ``robot`` with this calibration: base CoM moved, front force ratio, ``model.armature``.

        The returned robot's ``calibration`` attribute is this calibration (its friction is for the low
        level: :meth:`joint_friction`).

        Raises:
            CalibrationError: for joint names the robot does not have.
        """
        from dataclasses import replace

        from wbmpc.model.base_com import shift_base_com

        armature = self.armature(robot)
        out = shift_base_com(robot, self.base_com_offset, self.front_force_ratio)
        out.model.armature[6:] = armature
        return replace(out, calibration=self)


def _is_sequence(value) -> bool:
    return isinstance(value, list | tuple | np.ndarray)


def _number(where: str, name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise CalibrationError(f"{where}: field {name!r} must be a number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise CalibrationError(f"{where}: field {name!r} must be finite, got {value}")
    return value


def _plain(value):
    """NumPy scalars and arrays, tuples and paths as plain YAML/JSON values."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple | np.ndarray):
        return [_plain(v) for v in value]
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None  # JSON has no NaN
    if isinstance(value, Path):
        return str(value)
    return value


def _write_yaml(path: Path, data: dict) -> None:
    """YAML with a header comment, one flow-style line per joint."""
    from ruamel.yaml import YAML
    from ruamel.yaml.comments import CommentedMap, CommentedSeq

    def flow(items):
        out = CommentedMap(items) if isinstance(items, dict) else CommentedSeq(items)
        out.fa.set_flow_style()
        return out

    def flow_lists(value):
        """Mappings as blocks, lists of plain values on one line."""
        if isinstance(value, dict):
            return CommentedMap((k, flow_lists(v)) for k, v in value.items())
        if isinstance(value, list):
            items = [flow_lists(v) for v in value]
            return flow(items) if not any(isinstance(v, dict | list) for v in value) else CommentedSeq(items)
        return value

    doc = CommentedMap()
    for key, value in data.items():
        if key == "joints":
            doc[key] = CommentedMap((name, flow(p)) for name, p in value.items())
        else:
            doc[key] = flow_lists(value)
    doc.yaml_set_start_comment(
        "wbmpc robot calibration (wbmpc.model.calibration): base CoM offset [m, base frame], front force\n"
        "ratio [-], friction smoothing velocity [rad/s]; per joint Coulomb friction [N m], viscous friction\n"
        "[N m s/rad], armature (reflected rotor inertia) [kg m^2]."
    )
    yaml = YAML()
    yaml.width = 110
    with path.open("w") as stream:
        yaml.dump(doc, stream)
