"""Bodies of CONTROL packets: open, accept, keep-alive, close and reject.

A CONTROL datagram is the 5-byte base header (TYPE = CONTROL) followed by a one-byte code and a
code-specific fixed-size body. Control packets are rare (a handful per connection plus one keep-alive per
idle interval), so they carry what the data path leaves out: the protocol version and a 64-bit
connection nonce that ties every control packet to one connection and makes replays from an earlier
connection on the same addresses detectable.
"""

from __future__ import annotations

import enum
import struct
from typing import NamedTuple

from tdtp.wire.errors import MalformedPacketError

PROTOCOL_VERSION = 1
"""The only version this implementation speaks."""


class ControlCode(enum.IntEnum):
    OPEN = 1
    """master -> slave: version, flags, nonce, maximum payload the master accepts."""
    OPEN_ACK = 2
    """slave -> master: the same fields; the nonce echoes the master's."""
    KEEPALIVE = 3
    """either way, only after ``keepalive_interval`` with nothing else sent."""
    CLOSE = 4
    """either way: nonce and a reason code; the connection is over."""
    REJECT = 5
    """slave -> master: nonce and a reason code; the OPEN was refused."""


class OpenFlags(enum.IntFlag):
    NONE = 0
    SEPARATE_ACKS = 0x01
    """The connection runs in separate-ACK (Trinomial) mode instead of bidirectional (TDTP) mode."""


KNOWN_FLAGS = int(OpenFlags.SEPARATE_ACKS)


class CloseReason(enum.IntEnum):
    NORMAL = 0
    IDLE_TIMEOUT = 1
    PROTOCOL_ERROR = 2
    VERSION_UNSUPPORTED = 3
    REFUSED = 4


class OpenBody(NamedTuple):
    code: ControlCode
    version: int
    flags: int
    nonce: int
    max_payload: int


class CloseBody(NamedTuple):
    code: ControlCode
    nonce: int
    reason: int


class KeepaliveBody(NamedTuple):
    code: ControlCode


ControlBody = OpenBody | CloseBody | KeepaliveBody

_OPEN = struct.Struct(">BBBQH")  # code, version, flags, nonce, max_payload
_CLOSE = struct.Struct(">BQB")  # code, nonce, reason
OPEN_BODY_SIZE = _OPEN.size
CLOSE_BODY_SIZE = _CLOSE.size
KEEPALIVE_BODY_SIZE = 1


def encode_open(code: ControlCode, version: int, flags: int, nonce: int, max_payload: int) -> bytes:
    return _OPEN.pack(code, version, flags, nonce, max_payload)


def encode_close(code: ControlCode, nonce: int, reason: int) -> bytes:
    return _CLOSE.pack(code, nonce, reason)


def encode_keepalive() -> bytes:
    return bytes((ControlCode.KEEPALIVE,))


def decode_control(body: bytes | memoryview) -> ControlBody:
    """Decode the body after the base header; raises :class:`MalformedPacketError` on anything else."""
    if not body:
        raise MalformedPacketError("bad_control", "control packet without a control code")
    raw = body[0]
    try:
        code = ControlCode(raw)
    except ValueError:
        raise MalformedPacketError("bad_control", f"unknown control code {raw}") from None
    if code in (ControlCode.OPEN, ControlCode.OPEN_ACK):
        if len(body) != OPEN_BODY_SIZE:
            raise MalformedPacketError(
                "bad_control", f"{code.name} body is {len(body)} bytes, not 13"
            )
        _, version, flags, nonce, max_payload = _OPEN.unpack(body)
        return OpenBody(code, version, flags, nonce, max_payload)
    if code in (ControlCode.CLOSE, ControlCode.REJECT):
        if len(body) != CLOSE_BODY_SIZE:
            raise MalformedPacketError(
                "bad_control", f"{code.name} body is {len(body)} bytes, not 10"
            )
        _, nonce, reason = _CLOSE.unpack(body)
        return CloseBody(code, nonce, reason)
    if len(body) != KEEPALIVE_BODY_SIZE:
        raise MalformedPacketError("bad_control", f"KEEPALIVE body is {len(body)} bytes, not 1")
    return KeepaliveBody(code)
