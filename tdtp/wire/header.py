"""The 5-byte TDTP base header: layout constants and the fast ``struct`` codec used on the hot path.

Every TDTP datagram starts with one 40-bit big-endian word::

    bit 39..38  TYPE  (2)   DATA, ACK, CONTROL, 3 reserved
    bit 37..26  SEQ   (12)  this endpoint's data sequence number, truncated
    bit 25..14  ACK   (12)  highest peer data sequence number received, truncated
    bit 13..8   SACK  (6)   bit i-1 set: peer packet ACK-i was received too (i = 1..6)
    bit  7..0   HOLD  (8)   how long ACK was held before this packet left (see ``hold.py``);
                            255 = this packet carries no acknowledgement

``docs/PROTOCOL.md`` explains each width. ``schema.py`` declares the same layout with construct; the
test suite proves the two agree byte for byte.
"""

from __future__ import annotations

import enum
import struct
from typing import Final, NamedTuple

from tdtp.wire.errors import MalformedPacketError

HEADER_SIZE: Final = 5
"""Bytes of the TDTP base header on every datagram."""

TYPE_BITS: Final = 2
SEQ_BITS: Final = 12
ACK_BITS: Final = 12
SACK_BITS: Final = 6
HOLD_BITS: Final = 8

SEQ_MASK: Final = (1 << SEQ_BITS) - 1
SACK_MASK: Final = (1 << SACK_BITS) - 1
HOLD_MASK: Final = (1 << HOLD_BITS) - 1


class PacketType(enum.IntEnum):
    """The 2-bit TYPE field."""

    DATA = 0
    """Supermedia payload; in bidirectional mode it also acknowledges the peer's newest data."""
    ACK = 1
    """Stand-alone acknowledgement: reverse flow idle, or separate-ACK (Trinomial) mode."""
    CONTROL = 2
    """Connection management; the first payload byte is a :class:`~tdtp.wire.control.ControlCode`."""


RESERVED_TYPE: Final = 3
"""TYPE value kept for a future revision; receivers drop it as an unknown type."""


class Header(NamedTuple):
    """A decoded base header (truncated 12-bit sequence numbers, raw SACK bits and HOLD code)."""

    ptype: int
    seq: int
    ack: int
    sack: int
    hold: int


_WORD: Final = struct.Struct(">BI")
_pack = _WORD.pack
_unpack_from = _WORD.unpack_from
pack_header_words: Final = _pack
"""The header from its two words, ``(ptype << 6 | seq >> 6, (seq & 0x3F) << 26 | ack << 14 | sack <<
8 | hold)`` with ``seq`` and ``ack`` already 12 bits: :func:`encode_header` for a per-packet path that
builds the words in place (one Python call less per datagram)."""


def encode_header(ptype: int, seq: int, ack: int, sack: int, hold: int) -> bytes:
    """Encode one header. ``seq`` and ``ack`` are truncated to 12 bits here; other fields must fit."""
    seq &= SEQ_MASK
    return _pack(
        (ptype << 6) | (seq >> 6),
        ((seq & 0x3F) << 26) | ((ack & SEQ_MASK) << 14) | (sack << 8) | hold,
    )


def decode_header(data: bytes | bytearray | memoryview) -> Header:
    """Decode the first five bytes of ``data``.

    Raises :class:`MalformedPacketError` (reason ``"truncated"``) when fewer than five bytes are given. The
    TYPE value is returned as is; deciding what to do with the reserved value is the caller's job.
    """
    if len(data) < HEADER_SIZE:
        raise MalformedPacketError(
            "truncated", f"{len(data)} bytes, the header alone needs {HEADER_SIZE}"
        )
    hi, lo = _unpack_from(data)
    return Header(
        hi >> 6,
        ((hi & 0x3F) << 6) | (lo >> 26),
        (lo >> 14) & SEQ_MASK,
        (lo >> 8) & SACK_MASK,
        lo & HOLD_MASK,
    )
