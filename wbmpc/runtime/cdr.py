"""Fast fixed-layout (de)serialization of final, fixed-size IDL structs (Unitree's ``LowCmd_``/``LowState_``).

Why. cyclonedds-python serializes a sample by walking its IDL machine one member at a time in Python:
about 400 us to serialize or deserialize a ``LowCmd_``, 400 / 560 us a ``LowState_``, on the development
machine (2 cores, loaded), far too much for a 2 ms control tick that writes two commands and reads two
states. A struct that is ``@final`` and has no strings, sequences or optional members has a fixed byte
layout, so it can be encoded in one :mod:`struct` call (the hooked methods below: about 11 / 23 us for a
``LowCmd_``, 13 / 30 us for a ``LowState_``, most of it building or reading the Python objects), or,
better, copied between a numpy record and the wire with one fancy-indexed byte copy (:meth:`FixedCdr.
encode` / :meth:`FixedCdr.decode`: 4 to 9 us).

Two layouts of the same members (both little endian, IDL member order):

* the C/C++ struct (:func:`struct_dtype`: natural alignment, each struct padded to its own alignment):
  what Unitree's CRC is computed over, and a convenient numpy record (``rec["motor_cmd"]["q"]`` is a
  (20,) float32 view);
* the CDR stream cyclonedds-python puts on the wire for these types (XCDR version 1, "PLAIN_CDR" little
  endian, its default for final types; ``DataWriter._use_version_2`` is False with our QoS): the 4-byte
  encapsulation header ``00 01 00 00``, then every primitive aligned to its own size (at most 8) counted
  from the end of the header, and no padding at the end of a struct (so an array of structs need not
  repeat its element's padding: the ``LowState_``'s first ``MotorState_`` starts right after the IMU's
  one-byte temperature).

Both are lists of the same primitive runs at different offsets; :class:`FixedCdr` precomputes the byte
permutation between them, and the :mod:`struct` format of each.

The hook. ``DataWriter.write(sample)`` calls ``sample.serialize(use_version_2=...)`` and
``DataReader.take()`` / ``read()`` call ``data_type.deserialize(data)`` (cyclonedds 11, ``pub.py`` and
``sub.py``); the type support itself (``cls.__idl__``, the XTypes type information, the type name) is
separate. :func:`install` replaces only the class's ``serialize`` and ``deserialize`` methods, so the
type's identity on the wire (its name, XTypes ids and type objects, computed from ``__idl__``) is untouched
and cyclonedds's own serializer stays available as ``cls.__idl__.serialize`` / ``.deserialize``. Anything
the fast path does not cover (XCDR2, big endian, a caller's buffer, a sample without the expected header)
falls back to it. Faster still, :meth:`FixedCdr.encode` / :meth:`FixedCdr.decode` turn numpy records
into wire bytes and back without building any Python objects; :mod:`wbmpc.runtime.dds` writes and takes
such bytes directly (``write_serialized``, ``take_serialized``).
"""

from __future__ import annotations

import struct
import sys
import typing

import numpy as np
from cyclonedds.idl import IdlStruct, types

__all__ = ["CDR_LE_HEADER", "FixedCdr", "install", "struct_dtype"]

CDR_LE_HEADER = b"\x00\x01\x00\x00"  # encapsulation PLAIN_CDR (XCDR1), little endian, options 0

_PRIMITIVES = {"byte": "u1", "uint8": "u1", "int8": "i1", "int16": "<i2", "uint16": "<u2"}
_PRIMITIVES.update(int32="<i4", uint32="<u4", float32="<f4")
# member kinds: a scalar, an array of scalars, a struct, an array of structs
_SCALAR, _SCALARS, _STRUCT, _STRUCTS = range(4)


def _members(cls: type) -> list[tuple[str, int, object, int, bool]]:
    """(name, kind, element (numpy dtype or IDL class), array length or 1, is an octet) of each member, in
    IDL order. Raises TypeError for a member that is not a fixed-size primitive, struct or array of them."""
    hints = typing.get_type_hints(cls, include_extras=True)
    out = []
    for name in cls.__dataclass_fields__:
        args = typing.get_args(hints[name])
        array = args[1] if len(args) == 2 and isinstance(args[1], types.array) else None
        element = array.subtype if array else hints[name]
        octet = False
        if isinstance(element, type) and issubclass(element, IdlStruct):
            kind = _STRUCTS if array else _STRUCT
        else:
            kind = _SCALARS if array else _SCALAR
            primitive = typing.get_args(element)[1] if typing.get_args(element) else None
            if primitive not in _PRIMITIVES:
                raise TypeError(f"{cls.__name__}.{name}: not a fixed-size primitive ({hints[name]})")
            octet = primitive == "byte"
            element = np.dtype(_PRIMITIVES[primitive])
        out.append((name, kind, element, array.length if array else 1, octet))
    return out


def struct_dtype(cls: type) -> np.dtype:
    """The C/C++ layout of an IDL struct as a numpy dtype: members in IDL order, natural alignment.

    ``align=True`` does what a C compiler does: each member at a multiple of its own alignment, the struct
    padded to a multiple of its largest member's alignment.
    """
    fields = []
    for name, kind, element, length, _ in _members(cls):
        dtype = struct_dtype(element) if kind in (_STRUCT, _STRUCTS) else element
        fields.append((name, dtype, (length,)) if kind in (_SCALARS, _STRUCTS) else (name, dtype))
    return np.dtype(fields, align=True)


def struct_format(dtype: np.dtype) -> str:
    """The :mod:`struct` format of a structured dtype, its padding spelled out as pad bytes (``x``)."""
    parts, position = [], 0
    for name in dtype.names:
        member, offset = dtype.fields[name][:2]
        base, shape = member.subdtype if member.subdtype else (member, ())
        count = int(np.prod(shape))
        parts.append("x" * (offset - position))
        parts.append((struct_format(base) if base.names else base.char) * count)
        position = offset + member.itemsize
    return "".join(parts) + "x" * (dtype.itemsize - position)


def _bad_length(path: str, value, length: int):
    raise ValueError(f"{path} has {len(value)} elements, not {length}")


def _with_fields(cls: type, fields: dict):
    obj = object.__new__(cls)
    obj.__dict__ = fields
    return obj


def _compile(cls: type):
    """Generated code (as :mod:`dataclasses` does) for an IDL class's flat value tuple, in IDL order:

    * ``flatten(obj) -> tuple``: the values of an instance (ValueError for an array of the wrong length);
    * ``build(values) -> obj``: the instance of ``values[4:]`` (the first four are the CDR header's bytes),
      octet arrays as ``bytes`` and other arrays as lists, as cyclonedds's deserializer makes them.

    Straight-line code with constant indices is several times faster than walking the members.
    """
    namespace = {"_bad": _bad_length, "_obj": _with_fields}
    lines, values, counter = [], [], iter(range(1 << 30))

    def flatten(cls: type, ref: str, path: str) -> None:
        for name, kind, element, length, _ in _members(cls):
            if kind == _SCALAR:
                values.append(f"{ref}.{name}")
                continue
            local = f"_{next(counter)}"
            lines.append(f"    {local} = {ref}.{name}")
            if kind == _STRUCT:
                flatten(element, local, f"{path}.{name}")
                continue
            lines.append(f"    if len({local}) != {length}: _bad({path + '.' + name!r}, {local}, {length})")
            if kind == _SCALARS:
                values.append("*" + local)
            else:
                for k in range(length):
                    flatten(element, f"{local}[{k}]", f"{path}.{name}[{k}]")

    def build(cls: type, i: int) -> tuple[str, int]:
        key = f"C{next(counter)}"
        namespace[key] = cls
        items = []
        for name, kind, element, length, octet in _members(cls):
            if kind == _SCALAR:
                expr, i = f"v[{i}]", i + 1
            elif kind == _SCALARS:
                expr, i = f"{'bytes' if octet else 'list'}(v[{i}:{i + length}])", i + length
            elif kind == _STRUCT:
                expr, i = build(element, i)
            else:
                elements = []
                for _ in range(length):
                    element_expr, i = build(element, i)
                    elements.append(element_expr)
                expr = "[" + ", ".join(elements) + "]"
            items.append(f"{name!r}: {expr}")
        return f"_obj({key}, {{{', '.join(items)}}})", i

    flatten(cls, "o", cls.__name__)
    source = "def flatten(o):\n" + "\n".join(lines) + f"\n    return ({', '.join(values)},)\n"
    source += f"def build(v):\n    return {build(cls, 4)[0]}\n"
    exec(compile(source, f"<wbmpc.runtime.cdr {cls.__name__}>", "exec"), namespace)
    return namespace["flatten"], namespace["build"]


def _cdr_runs(cls: type, position: int = 0, align_max: int = 8) -> tuple[list[tuple[int, int, str]], int]:
    """The primitive runs ``(offset, bytes, struct format)`` of ``cls`` in its XCDR1 stream, offsets from
    the end of the encapsulation header, starting at ``position``; and the position after it."""
    runs = []
    for _, kind, element, length, _ in _members(cls):
        if kind in (_SCALAR, _SCALARS):
            alignment = min(element.itemsize, align_max)
            position = -(-position // alignment) * alignment
            runs.append((position, element.itemsize * length, element.char * length))
            position += element.itemsize * length
        else:
            for _ in range(length):
                sub, position = _cdr_runs(element, position, align_max)
                runs.extend(sub)
    return runs, position


def _c_runs(dtype: np.dtype, base: int = 0) -> list[tuple[int, int]]:
    """The primitive runs ``(offset, bytes)`` of a C-layout structured dtype, in member order."""
    runs = []
    for name in dtype.names:
        member, offset = dtype.fields[name][:2]
        element, shape = member.subdtype if member.subdtype else (member, ())
        count = int(np.prod(shape))
        if element.names:
            for k in range(count):
                runs.extend(_c_runs(element, base + offset + k * element.itemsize))
        else:
            runs.append((base + offset, element.itemsize * count))
    return runs


class FixedCdr:
    """The XCDR1 little-endian codec of one final, fixed-size IDL struct, and its C-layout numpy record.

    Args:
        data_type: The IDL class (an ``IdlStruct`` whose members are primitives, structs and arrays of
            them; extensibility final).

    Attributes:
        data_type: The class; dtype: its C layout (:func:`struct_dtype`); size: bytes of a serialized
            sample, header included, as ``serialize()`` returns it (``DataWriter.write`` and
            :func:`~wbmpc.runtime.dds.write_serialized` pad it to a multiple of 4; 812 for a ``LowCmd_``,
            1180 for a ``LowState_``, already are).

    Raises:
        TypeError: a member of variable size, or a type whose default XCDR version is not 1.
    """

    def __init__(self, data_type: type):
        self.data_type = data_type
        idl = data_type.__idl__
        idl.populate()
        if idl.default_version != 1:
            raise TypeError(f"{data_type.__name__} is not serialized as XCDR1 by default (not final?)")
        self.dtype = struct_dtype(data_type)
        runs, payload = _cdr_runs(data_type)
        c_runs = _c_runs(self.dtype)
        assert [n for _, n, _ in runs] == [n for _, n in c_runs]
        self.size = len(CDR_LE_HEADER) + payload
        # byte i of the C record goes to byte dst[i] of the wire (both lists cover the data bytes only)
        self._src = np.concatenate([np.arange(o, o + n) for o, n in c_runs])
        self._dst = np.concatenate([np.arange(o, o + n) for o, n, _ in runs]) + len(CDR_LE_HEADER)
        self._template = np.zeros(self.size, np.uint8)
        self._template[: len(CDR_LE_HEADER)] = np.frombuffer(CDR_LE_HEADER, np.uint8)
        fmt, position = [], 0
        for offset, n, chars in runs:
            fmt.append("x" * (offset - position) + chars)
            position = offset + n
        padding = "x" * (self.size - len(CDR_LE_HEADER) - position)
        self._cdr = struct.Struct("<4B" + "".join(fmt) + padding)  # the header's 4 bytes, then the payload
        self._c = struct.Struct("<" + struct_format(self.dtype))
        self._flatten, self._build = _compile(data_type)

    # numpy records <-> wire bytes, no Python objects

    def zeros(self) -> np.ndarray:
        """A zeroed 0-d record of :attr:`dtype` (padding zero, as the SDK's value-initialised structs)."""
        return np.zeros((), self.dtype)

    def encode(self, record: np.ndarray) -> bytes:
        """The serialized sample (header included) of a C-layout record (0-d or (1,) array of
        :attr:`dtype`), byte-equal to cyclonedds's ``serialize()`` of the same values."""
        raw = np.frombuffer(record, np.uint8)  # the record's memory (a view; 3 times faster than .view)
        out = self._template.copy()
        out[self._dst] = raw[self._src]
        return out.tobytes()

    def decode(self, data, out: np.ndarray | None = None) -> np.ndarray:
        """The C-layout record of a serialized sample (into ``out`` if given: its padding is left as is).

        A sample that is not XCDR1 little endian of the expected length (another DDS implementation's
        XCDR2 or big-endian encoding) is decoded by cyclonedds's own deserializer instead.
        """
        if out is None:
            out = self.zeros()
        raw = np.frombuffer(out, np.uint8)
        if len(data) >= self.size and data[:2] == CDR_LE_HEADER[:2]:
            raw[self._src] = np.frombuffer(data, np.uint8, self.size)[self._dst]
        else:
            raw[:] = np.frombuffer(self.pack(self.data_type.__idl__.deserialize(data)), np.uint8)
        return out

    # Python objects <-> C layout

    def pack(self, obj) -> bytes:
        """The C struct bytes of an instance (ValueError for a field out of its type's range)."""
        try:
            return self._c.pack(*self._flatten(obj))
        except (struct.error, OverflowError) as exc:
            raise ValueError(f"{type(obj).__name__} has a field out of its IDL type's range: {exc}") from exc

    def from_object(self, obj) -> np.ndarray:
        """The C-layout record of an instance."""
        return np.frombuffer(bytearray(self.pack(obj)), self.dtype).reshape(())

    def to_object(self, record: np.ndarray):
        """An instance holding the values of a C-layout record."""
        return self._build((0, 1, 0, 0) + self._c.unpack(record.tobytes()))

    # Python objects <-> wire bytes: the methods install() puts on the class

    def serialize(self, obj, buffer=None, endianness=None, use_version_2=None) -> bytes:
        """``obj.serialize()``: the fast path for XCDR1 little endian, cyclonedds's serializer otherwise."""
        if buffer is not None or use_version_2 or (endianness is not None and endianness.name != "Little"):
            return self.data_type.__idl__.serialize(
                obj, buffer=buffer, endianness=endianness, use_version_2=use_version_2
            )
        try:
            return self._cdr.pack(0, 1, 0, 0, *self._flatten(obj))
        except (struct.error, OverflowError) as exc:
            raise ValueError(f"{type(obj).__name__} has a field out of its IDL type's range: {exc}") from exc

    def deserialize(self, data, has_header: bool = True, use_version_2=None):
        """``cls.deserialize(data)``: the fast path for an XCDR1 little-endian sample with its header,
        cyclonedds's deserializer otherwise."""
        fast = has_header and use_version_2 is None and isinstance(data, bytes | bytearray | memoryview)
        if not (fast and len(data) >= self.size and data[:2] == CDR_LE_HEADER[:2]):
            idl = self.data_type.__idl__
            return idl.deserialize(data, has_header=has_header, use_version_2=use_version_2)
        return self._build(self._cdr.unpack_from(data, 0))


def install(data_type: type) -> FixedCdr:
    """Make ``data_type.serialize`` / ``data_type.deserialize`` (hence ``DataWriter.write`` and
    ``DataReader.take``/``read``) use a :class:`FixedCdr`; returns the codec.

    The type's ``__idl__`` (its name and XTypes information, cyclonedds's own serializer) is left as is.
    On a big-endian host nothing is installed (the codec's layout is little endian).
    """
    codec = FixedCdr(data_type)
    if sys.byteorder != "little":
        return codec

    def serialize(self, buffer=None, endianness=None, use_version_2=None) -> bytes:
        return codec.serialize(self, buffer, endianness, use_version_2)

    def deserialize(cls, data, has_header: bool = True, use_version_2=None):
        return codec.deserialize(data, has_header, use_version_2)

    serialize.__doc__ = deserialize.__doc__ = f"Fast XCDR1 codec of {data_type.__name__} (wbmpc.runtime.cdr)."
    data_type.serialize = serialize
    data_type.deserialize = classmethod(deserialize)
    return codec
