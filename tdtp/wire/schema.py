"""The TDTP wire format declared once with construct: the schema of record.

This declaration is the readable, checkable statement of the format; the hot path uses the hand-written
``struct`` codecs in ``header.py`` and ``control.py`` (49x faster to encode, 21x to decode a header: benchmarks/codec.py). The test suite
proves that the two agree byte for byte on every header value and every control body.
"""

from __future__ import annotations

from typing import Any

from construct import BitsInteger, BitStruct, Const, Int8ub, Int16ub, Int64ub, Struct, Switch

from tdtp.wire.control import ControlCode

Header: Any = BitStruct(
    "ptype" / BitsInteger(2),
    "seq" / BitsInteger(12),
    "ack" / BitsInteger(12),
    "sack" / BitsInteger(6),
    "hold" / BitsInteger(8),
)
"""The 5-byte base header, most significant bit first."""

OpenBody: Any = Struct(
    "version" / Int8ub,
    "flags" / Int8ub,
    "nonce" / Int64ub,
    "max_payload" / Int16ub,
)
CloseBody: Any = Struct("nonce" / Int64ub, "reason" / Int8ub)

ControlBody: Any = Struct(
    "code" / Int8ub,
    "body"
    / Switch(
        lambda ctx: ctx.code,
        {
            int(ControlCode.OPEN): OpenBody,
            int(ControlCode.OPEN_ACK): OpenBody,
            int(ControlCode.CLOSE): CloseBody,
            int(ControlCode.REJECT): CloseBody,
            int(ControlCode.KEEPALIVE): Const(b""),
        },
    ),
)
"""What follows the header in a CONTROL packet: a code byte, then a body that depends on the code."""
