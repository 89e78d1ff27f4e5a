"""The TDTP wire format: the 5-byte header, hold-time code, sequence expansion and control bodies."""

from tdtp.wire.control import (
    PROTOCOL_VERSION,
    CloseBody,
    CloseReason,
    ControlCode,
    KeepaliveBody,
    OpenBody,
    OpenFlags,
    decode_control,
    encode_close,
    encode_keepalive,
    encode_open,
)
from tdtp.wire.errors import MalformedPacketError
from tdtp.wire.header import (
    HEADER_SIZE,
    RESERVED_TYPE,
    Header,
    PacketType,
    decode_header,
    encode_header,
)
from tdtp.wire.hold import HOLD_MAX, HOLD_NO_ACK, HOLD_SATURATED, decode_hold, encode_hold
from tdtp.wire.seqnum import SEQ_MODULUS, expand_seq, serial_lt

__all__ = [
    "HEADER_SIZE",
    "HOLD_MAX",
    "HOLD_NO_ACK",
    "HOLD_SATURATED",
    "PROTOCOL_VERSION",
    "RESERVED_TYPE",
    "SEQ_MODULUS",
    "CloseBody",
    "CloseReason",
    "ControlCode",
    "Header",
    "KeepaliveBody",
    "MalformedPacketError",
    "OpenBody",
    "OpenFlags",
    "PacketType",
    "decode_control",
    "decode_header",
    "decode_hold",
    "encode_close",
    "encode_header",
    "encode_hold",
    "encode_keepalive",
    "encode_open",
    "expand_seq",
    "serial_lt",
]
