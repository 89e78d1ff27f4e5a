"""Typed samples: a dataclass to bytes and back through one precompiled ``struct``, checked both ways.

A teleoperation payload is a handful of numbers at a fixed layout. :class:`SampleCodec` ties a frozen
dataclass to such a layout, named field by field::

    @dataclass(frozen=True, slots=True)
    class JointCommand:
        sent_at: float
        q: tuple[float, ...]
        gripper: int

    codec = SampleCodec(JointCommand, sent_at="f64", q="f32[7]", gripper="u8")
    ep.send(codec.encode(JointCommand(tdtp.monotonic(), (0.0,) * 7, 1)))
    command = codec.decode(sample.payload)  # a JointCommand, or SampleFormatError

Field types: ``f32 f64`` (IEEE floats), ``i8 i16 i32 i64 u8 u16 u32 u64`` (integers), ``bool``, each
optionally an array of fixed length (``f32[7]``, a tuple in the dataclass). The byte order is
little-endian unless ``byte_order=">"``. The whole layout is one :class:`struct.Struct`, so encoding and
decoding cost one ``pack``/``unpack_from`` (about a microsecond for a 7-joint command); ``decode`` reads
from any buffer without copying it (a ``memoryview`` of a larger one included) and ``decode_values``
skips building the dataclass.

What is checked: on encode, every field is present, arrays have their length, integers fit, and (unless
``allow_non_finite=True``) floats are finite: a NaN joint angle is an application bug, not a sample. On
decode, the length (exactly the layout's size, or at least it with ``allow_trailing=True``) and,
unless allowed, that floats are finite: a payload from a peer is checked as strictly as one we send.
Errors are :class:`SampleFormatError` (a :class:`~tdtp.errors.TdtpError` and :class:`ValueError`)
naming the field.
"""

from __future__ import annotations

import dataclasses
import math
import re
import struct
from collections.abc import Sequence
from typing import Any, Final, Generic, TypeVar

from tdtp.errors import InvalidArgumentError

__all__ = ["SCALAR_TYPES", "SampleCodec", "SampleFormatError"]

T = TypeVar("T")


class SampleFormatError(InvalidArgumentError):
    """A sample does not fit its layout: a missing or extra field, a wrong length, a value out of
    range, or a float that is not finite."""


SCALAR_TYPES: Final[dict[str, str]] = {
    "f32": "f",
    "f64": "d",
    "i8": "b",
    "i16": "h",
    "i32": "i",
    "i64": "q",
    "u8": "B",
    "u16": "H",
    "u32": "I",
    "u64": "Q",
    "bool": "?",
}
"""The field types a layout may name, and their ``struct`` codes."""

_FIELD_TYPE: Final = re.compile(r"(?P<scalar>[a-z0-9]+)(?:\[(?P<count>[1-9][0-9]*)\])?")
_MAX_ARRAY: Final = 4096


@dataclasses.dataclass(frozen=True, slots=True)
class _Field:
    name: str
    code: str
    count: int  # 0: a scalar; n: a tuple of n

    @property
    def is_float(self) -> bool:
        return self.code in "fd"

    @property
    def width(self) -> int:
        return max(self.count, 1)


class SampleCodec(Generic[T]):
    """Encodes instances of a dataclass to its fixed layout and decodes them back."""

    __slots__ = ("_allow_non_finite", "_cls", "_fields", "_float_slots", "_struct", "size")

    def __init__(
        self,
        cls: type[T],
        *,
        byte_order: str = "<",
        allow_non_finite: bool = False,
        **layout: str,
    ) -> None:
        if not (isinstance(cls, type) and dataclasses.is_dataclass(cls)):
            raise SampleFormatError(f"SampleCodec needs a dataclass, got {cls!r}")
        if byte_order not in ("<", ">"):
            raise SampleFormatError(f'byte_order must be "<" or ">", got {byte_order!r}')
        names = [f.name for f in dataclasses.fields(cls) if f.init]
        if set(names) != set(layout):
            missing = [n for n in names if n not in layout]
            extra = [n for n in layout if n not in names]
            raise SampleFormatError(
                f"the layout of {cls.__name__} must name each of its fields once: "
                + "; ".join(
                    part
                    for part in (
                        f"missing {', '.join(missing)}" if missing else "",
                        f"not fields of it: {', '.join(extra)}" if extra else "",
                    )
                    if part
                )
            )
        fields = [_parse_field(name, layout[name]) for name in names]
        self._cls = cls
        self._fields = tuple(fields)
        self._struct = struct.Struct(
            byte_order + "".join(f"{f.count}{f.code}" if f.count else f.code for f in fields)
        )
        self._allow_non_finite = allow_non_finite
        slots: list[int] = []
        index = 0
        for f in fields:
            if f.is_float:
                slots.extend(range(index, index + f.width))
            index += f.width
        self._float_slots = tuple(slots)
        self.size: int = self._struct.size
        """Bytes of an encoded sample."""

    def __repr__(self) -> str:
        layout = ", ".join(f"{f.name}={_type_name(f)}" for f in self._fields)  # e.g. q=f32[7]
        return f"SampleCodec({self._cls.__name__}, {layout}; {self.size} bytes)"

    # ------------------------------------------------------------------ encoding

    def encode(self, sample: T) -> bytes:
        """The bytes of ``sample`` (an instance of the codec's dataclass)."""
        if not isinstance(sample, self._cls):
            raise SampleFormatError(f"expected a {self._cls.__name__}, got {type(sample).__name__}")
        return self.encode_values(*(getattr(sample, f.name) for f in self._fields))

    def encode_values(self, *values: Any) -> bytes:
        """The bytes of a sample given as its field values, in the dataclass's order."""
        if len(values) != len(self._fields):
            raise SampleFormatError(
                f"{self._cls.__name__} has {len(self._fields)} fields, got {len(values)} values"
            )
        flat: list[Any] = []
        for f, value in zip(self._fields, values, strict=True):
            if f.count:
                if not isinstance(value, Sequence) or len(value) != f.count:
                    raise SampleFormatError(
                        f"{self._cls.__name__}.{f.name} must be a sequence of {f.count} values, "
                        f"got {_describe(value)}"
                    )
                flat.extend(value)
            else:
                flat.append(value)
        if not self._allow_non_finite:
            for slot in self._float_slots:
                value = flat[slot]
                if isinstance(value, float) and not math.isfinite(value):
                    raise SampleFormatError(
                        f"{self._cls.__name__}.{self._field_at(slot)} is {value}: samples carry "
                        "finite numbers (allow_non_finite=True to send NaN or infinities)"
                    )
        try:
            return self._struct.pack(*flat)
        except struct.error as exc:
            raise SampleFormatError(
                f"{self._cls.__name__} does not fit its layout: {exc}"
            ) from None

    # ------------------------------------------------------------------ decoding

    def decode(self, payload: bytes | bytearray | memoryview, *, allow_trailing: bool = False) -> T:
        """The sample in ``payload``; :class:`SampleFormatError` if it does not fit the layout."""
        values = self.decode_values(payload, allow_trailing=allow_trailing)
        kwargs: dict[str, Any] = {}
        index = 0
        for f in self._fields:
            if f.count:
                kwargs[f.name] = values[index : index + f.count]
                index += f.count
            else:
                kwargs[f.name] = values[index]
                index += 1
        return self._cls(**kwargs)

    def decode_values(
        self, payload: bytes | bytearray | memoryview, *, allow_trailing: bool = False
    ) -> tuple[Any, ...]:
        """The layout's values in order, arrays flattened (no dataclass built)."""
        size = len(payload)
        if size != self.size and not (allow_trailing and size > self.size):
            raise SampleFormatError(
                f"a {self._cls.__name__} is {self.size} bytes, got {size}"
                + (" (allow_trailing=True accepts longer payloads)" if size > self.size else "")
            )
        values = self._struct.unpack_from(payload)
        if not self._allow_non_finite:
            for slot in self._float_slots:
                if not math.isfinite(values[slot]):
                    raise SampleFormatError(
                        f"{self._cls.__name__}.{self._field_at(slot)} is {values[slot]} in the "
                        "payload: not a finite number"
                    )
        return values

    def field_slots(self, *names: str) -> tuple[int, ...]:
        """Where the named fields sit in :meth:`decode_values`' flat tuple (arrays: every element):
        what :class:`~tdtp.teleop.deadband.DeadbandSender` groups are made of."""
        positions: dict[str, range] = {}
        index = 0
        for f in self._fields:
            positions[f.name] = range(index, index + f.width)
            index += f.width
        slots: list[int] = []
        for name in names:
            if name not in positions:
                raise SampleFormatError(f"{self._cls.__name__} has no field {name!r}")
            slots.extend(positions[name])
        return tuple(slots)

    def _field_at(self, slot: int) -> str:
        index = 0
        for f in self._fields:
            if slot < index + f.width:
                return f"{f.name}[{slot - index}]" if f.count else f.name
            index += f.width
        return "?"  # pragma: no cover - slots come from the fields


def _parse_field(name: str, spec: str) -> _Field:
    match = _FIELD_TYPE.fullmatch(spec) if isinstance(spec, str) else None
    if match is None or match["scalar"] not in SCALAR_TYPES:
        raise SampleFormatError(
            f"field {name!r}: unknown type {spec!r}; use one of {', '.join(SCALAR_TYPES)}, "
            "optionally with a length, e.g. f32[7]"
        )
    count = int(match["count"]) if match["count"] else 0
    if count > _MAX_ARRAY:
        raise SampleFormatError(f"field {name!r}: arrays hold at most {_MAX_ARRAY} values")
    return _Field(name, SCALAR_TYPES[match["scalar"]], count)


def _type_name(f: _Field) -> str:
    scalar = next(k for k, v in SCALAR_TYPES.items() if v == f.code)
    return f"{scalar}[{f.count}]" if f.count else scalar


def _describe(value: object) -> str:
    if isinstance(value, Sequence) and not isinstance(value, str | bytes):
        return f"{len(value)} values"
    return type(value).__name__
