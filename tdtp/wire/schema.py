"""The TDTP wire format declared once with construct: the schema of record.

This declaration is the readable, checkable statement of the format; the hot path uses the hand-written
``struct`` codecs in ``header.py`` and ``control.py`` (49x faster to encode, 21x to decode a header:
benchmarks/codec.py). The test suite proves that the two agree byte for byte on every header value, every
control body and the keyed packet layout.
"""

from __future__ import annotations

from typing import Any

from construct import (
    BitsInteger,
    BitStruct,
    Bytes,
    GreedyBytes,
    GreedyRange,
    If,
    Int8ub,
    Int16ub,
    Int32ub,
    Struct,
    Switch,
    this,
)
from construct.core import stream_size, stream_tell

from tdtp.wire.control import (
    COOKIE_SIZE,
    KEY_ID_SIZE,
    MP_TOKEN_SIZE,
    NONCE_SIZE,
    PATH_TOKEN_SIZE,
    RESET_ECHO_SIZE,
    RESET_TAG_SIZE,
    ControlCode,
    OpenFlags,
)
from tdtp.wire.protected import TAG_SIZE

Header: Any = BitStruct(
    "ptype" / BitsInteger(2),
    "seq" / BitsInteger(12),
    "ack" / BitsInteger(12),
    "sack" / BitsInteger(6),
    "hold" / BitsInteger(8),
)
"""The 5-byte base header, most significant bit first."""

_KEYED = int(OpenFlags.KEYED)

OpenBody: Any = Struct(
    "version" / Int8ub,
    "flags" / Int8ub,
    "suite" / Int8ub,
    "max_payload" / Int16ub,
    "attempt" / Int16ub,
    "nonce" / Bytes(NONCE_SIZE),
    "key_id" / Bytes(KEY_ID_SIZE),
    "cookie" / Bytes(COOKIE_SIZE),
    "tag" / If(this.flags & _KEYED, Bytes(TAG_SIZE)),
)
"""OPEN: a keyed one (flag KEYED) ends in a tag over the header and everything before the tag."""

OpenAckBody: Any = Struct(
    "version" / Int8ub,
    "flags" / Int8ub,
    "suite" / Int8ub,
    "max_payload" / Int16ub,
    "packet_number" / Int16ub,
    "nonce" / Bytes(NONCE_SIZE),
    "slave_nonce" / Bytes(NONCE_SIZE),
    "tag" / If(this.flags & _KEYED, Bytes(TAG_SIZE)),
)
CookieBody: Any = Struct(
    "version" / Int8ub, "nonce" / Bytes(NONCE_SIZE), "cookie" / Bytes(COOKIE_SIZE)
)
CloseBody: Any = Struct("nonce" / Bytes(NONCE_SIZE), "reason" / Int8ub)
ResetBody: Any = Struct(
    "echo" / Bytes(RESET_ECHO_SIZE),
    "tags" / GreedyRange(Bytes(RESET_TAG_SIZE)),
)
"""RESET: the first 16 bytes of the datagram that found no session, then (keyed) 16-byte tags."""
KeepaliveBody: Any = Struct("nonce" / Bytes(NONCE_SIZE))
PathChallengeBody: Any = Struct("token" / Bytes(PATH_TOKEN_SIZE))
PathResponseBody: Any = Struct("token" / Bytes(PATH_TOKEN_SIZE), "nonce" / Bytes(NONCE_SIZE))
MessageBody: Any = Struct(
    "nonce" / Bytes(NONCE_SIZE), "seq" / Int16ub, "ack" / Int16ub, "data" / GreedyBytes
)
"""MESSAGE (the reliable control channel): the master's nonce, the message's number and the
cumulative acknowledgement of the peer's messages (both their low 16 bits), then the message itself
(at least one byte)."""
MessageAckBody: Any = Struct("nonce" / Bytes(NONCE_SIZE), "ack" / Int16ub)
TimestampBody: Any = Struct("time" / Int32ub)
"""TIMESTAMP: the sender's clock (microseconds, low 32 bits) when it left."""
TimedDataBody: Any = Struct("time" / Int32ub, "payload" / GreedyBytes)
"""TIMED_DATA: the sender's clock as TIMESTAMP's, then the sample (at least one byte)."""
MpChallengeBody: Any = Struct(
    "nonce" / Bytes(NONCE_SIZE), "path_id" / Int8ub, "token" / Bytes(MP_TOKEN_SIZE)
)
"""MP_CHALLENGE (multipath): the master's nonce (in the clear even when keyed), the path's id, a
random token the answer echoes on the same path."""
MpResponseBody: Any = Struct(
    "nonce" / Bytes(NONCE_SIZE),
    "path_id" / Int8ub,
    "echo" / Bytes(MP_TOKEN_SIZE),
    "token" / Bytes(MP_TOKEN_SIZE),
)
"""MP_RESPONSE (multipath): the challenge's token echoed, and a token of the responder's own
(zeros: none)."""
MpReportBody: Any = Struct(
    "nonce" / Bytes(NONCE_SIZE),
    "path_id" / Int8ub,
    "seq" / Int16ub,
    "hold" / Int8ub,
    "received" / Int32ub,
    "first" / Int32ub,
    "lag" / Int16ub,
    "clock" / Int32ub,
)
"""MP_REPORT (multipath): the master's nonce and one path's receiver report, timed on the reporter's
clock."""
MpAbandonBody: Any = Struct("nonce" / Bytes(NONCE_SIZE), "path_id" / Int8ub, "reason" / Int8ub)

ControlBody: Any = Struct(
    "code" / Int8ub,
    "body"
    / Switch(
        lambda ctx: ctx.code,
        {
            int(ControlCode.OPEN): OpenBody,
            int(ControlCode.OPEN_ACK): OpenAckBody,
            int(ControlCode.COOKIE): CookieBody,
            int(ControlCode.CLOSE): CloseBody,
            int(ControlCode.REJECT): CloseBody,
            int(ControlCode.RESET): ResetBody,
            int(ControlCode.KEEPALIVE): KeepaliveBody,
            int(ControlCode.PATH_CHALLENGE): PathChallengeBody,
            int(ControlCode.PATH_RESPONSE): PathResponseBody,
            int(ControlCode.MESSAGE): MessageBody,
            int(ControlCode.MESSAGE_ACK): MessageAckBody,
            int(ControlCode.TIMESTAMP): TimestampBody,
            int(ControlCode.TIMED_DATA): TimedDataBody,
            int(ControlCode.MP_CHALLENGE): MpChallengeBody,
            int(ControlCode.MP_RESPONSE): MpResponseBody,
            int(ControlCode.MP_REPORT): MpReportBody,
            int(ControlCode.MP_ABANDON): MpAbandonBody,
        },
    ),
)
"""What follows the header in an unkeyed CONTROL packet (and in any OPEN, OPEN_ACK, COOKIE or
REJECT): a code byte, then a body that depends on the code."""


def _remaining(ctx: Any) -> int:
    """Bytes left in the datagram being parsed (when building, the length of the given field)."""
    if ctx._parsing:
        stream = ctx._io
        return int(stream_size(stream) - stream_tell(stream, None))
    return len(ctx.sealed) + TAG_SIZE


ProtectedData: Any = Struct(
    "header" / Header,
    "packet_number" / Int16ub,
    "sealed" / Bytes(lambda ctx: _remaining(ctx) - TAG_SIZE),
    "tag" / Bytes(TAG_SIZE),
)
"""A keyed session's DATA or ACK datagram: header, the low 16 bits of the packet number, the
sealed payload (ciphertext, or plaintext when the session does not encrypt), the tag."""

ProtectedControl: Any = Struct(
    "header" / Header,
    "code" / Int8ub,
    "packet_number" / Int16ub,
    "sealed" / Bytes(lambda ctx: _remaining(ctx) - TAG_SIZE),
    "tag" / Bytes(TAG_SIZE),
)
"""A keyed session's KEEPALIVE, CLOSE, MESSAGE, MESSAGE_ACK, TIMESTAMP, TIMED_DATA, MP_REPORT or
MP_ABANDON: as ProtectedData, with the control code in the clear after the header."""

ProtectedProbe: Any = Struct(
    "header" / Header,
    "code" / Int8ub,
    "nonce" / Bytes(NONCE_SIZE),
    "packet_number" / Int16ub,
    "sealed" / Bytes(lambda ctx: _remaining(ctx) - TAG_SIZE),
    "tag" / Bytes(TAG_SIZE),
)
"""A keyed session's MP_CHALLENGE or MP_RESPONSE: the code and the master's nonce in the clear (a
server finds the session by it), then the packet number, the sealed rest and the tag."""

__all__ = [
    "CloseBody",
    "ControlBody",
    "CookieBody",
    "Header",
    "KeepaliveBody",
    "MessageAckBody",
    "MessageBody",
    "MpAbandonBody",
    "MpChallengeBody",
    "MpReportBody",
    "MpResponseBody",
    "OpenAckBody",
    "OpenBody",
    "PathChallengeBody",
    "PathResponseBody",
    "ProtectedControl",
    "ProtectedData",
    "ProtectedProbe",
    "ResetBody",
    "TimedDataBody",
    "TimestampBody",
]
