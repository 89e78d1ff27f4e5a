"""The 5-byte base header: fast codec round trips, golden bytes, truncation."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tdtp.wire import (
    HEADER_SIZE,
    RESERVED_TYPE,
    Header,
    MalformedPacketError,
    PacketType,
    decode_header,
    encode_header,
)
from tdtp.wire.header import ACK_BITS, HOLD_BITS, SACK_BITS, SEQ_BITS, TYPE_BITS

ptypes = st.integers(0, 3)
seqs = st.integers(0, 0xFFF)
sacks = st.integers(0, 0x3F)
holds = st.integers(0, 0xFF)
headers = st.builds(Header, ptypes, seqs, seqs, sacks, holds)

# Golden headers. The header is one 40-bit big-endian word
#   TYPE(2) SEQ(12) ACK(12) SACK(6) HOLD(8)
# i.e. bits 39..38, 37..26, 25..14, 13..8, 7..0. Each fixture below was derived by hand: write the
# fields in binary, concatenate them (40 bits), cut into 5 octets. docs/PROTOCOL.md shows the same.
GOLDEN_HEADERS: list[tuple[str, Header]] = [
    # Everything zero: a DATA packet with SEQ 0 acknowledging 0, no SACK bits, held 0 us.
    ("00 00 00 00 00", Header(0, 0, 0, 0, 0)),
    # Everything one: TYPE 3 (reserved), SEQ 0xFFF, ACK 0xFFF, SACK 0x3F, HOLD 255.
    ("ff ff ff ff ff", Header(3, 0xFFF, 0xFFF, 0x3F, 0xFF)),
    # One field at a time set to all ones, the others zero: the five masks must not overlap and must
    # OR to ff ff ff ff ff.
    #   TYPE 11            -> 11000000 00000000 ...                        = c0 00 00 00 00
    ("c0 00 00 00 00", Header(3, 0, 0, 0, 0)),
    #   SEQ 111111111111   -> 00111111 11111100 00000000 ...               = 3f fc 00 00 00
    ("3f fc 00 00 00", Header(0, 0xFFF, 0, 0, 0)),
    #   ACK 111111111111   -> 00000000 00000011 11111111 11000000 00000000 = 00 03 ff c0 00
    ("00 03 ff c0 00", Header(0, 0, 0xFFF, 0, 0)),
    #   SACK 111111        -> 00000000 00000000 00000000 00111111 00000000 = 00 00 00 3f 00
    ("00 00 00 3f 00", Header(0, 0, 0, 0x3F, 0)),
    #   HOLD 11111111      -> ... 11111111                                  = 00 00 00 00 ff
    ("00 00 00 00 ff", Header(0, 0, 0, 0, 0xFF)),
    # The lowest bit of each field: TYPE 1 = bit 38, SEQ 1 = bit 26, ACK 1 = bit 14, SACK 1 = bit 8,
    # HOLD 1 = bit 0.
    ("40 00 00 00 00", Header(1, 0, 0, 0, 0)),
    ("00 04 00 00 00", Header(0, 1, 0, 0, 0)),
    ("00 00 00 40 00", Header(0, 0, 1, 0, 0)),
    ("00 00 00 01 00", Header(0, 0, 0, 1, 0)),
    ("00 00 00 00 01", Header(0, 0, 0, 0, 1)),
    # PROTOCOL.md worked example 1: DATA, SEQ 0x0ABC, ACK 0x0123, SACK 101010,
    # HOLD 250 us -> code 31.
    #   00 | 1010 1011 1100 | 0001 0010 0011 | 101010 | 0001 1111
    #   = 0010 1010 | 1111 0000 | 0100 1000 | 1110 1010 | 0001 1111 = 2a f0 48 ea 1f
    ("2a f0 48 ea 1f", Header(PacketType.DATA, 0x0ABC, 0x0123, 0b101010, 31)),
    # PROTOCOL.md worked example 3: stand-alone ACK, SEQ 0x0ABD, ACK 0x0124, SACK 111111,
    # HOLD 1.5 ms -> code 110 (0x6e).
    #   01 | 1010 1011 1101 | 0001 0010 0100 | 111111 | 0110 1110
    #   = 0110 1010 | 1111 0100 | 0100 1001 | 0011 1111 | 0110 1110 = 6a f4 49 3f 6e
    ("6a f4 49 3f 6e", Header(PacketType.ACK, 0x0ABD, 0x0124, 0b111111, 110)),
    # PROTOCOL.md worked example 2 (header part): CONTROL, SEQ 0x5A5, ACK 0, SACK 0, HOLD 255.
    #   10 | 0101 1010 0101 | 0000 0000 0000 | 000000 | 1111 1111
    #   = 1001 0110 | 1001 0100 | 0000 0000 | 0000 0000 | 1111 1111 = 96 94 00 00 ff
    ("96 94 00 00 ff", Header(PacketType.CONTROL, 0x5A5, 0, 0, 255)),
]


def test_header_size_is_five_bytes() -> None:
    assert HEADER_SIZE == 5
    assert TYPE_BITS + SEQ_BITS + ACK_BITS + SACK_BITS + HOLD_BITS == 8 * HEADER_SIZE
    assert len(encode_header(0, 0, 0, 0, 0)) == HEADER_SIZE


def test_type_values_are_pinned() -> None:
    assert {t.name: int(t) for t in PacketType} == {"DATA": 0, "ACK": 1, "CONTROL": 2}
    assert RESERVED_TYPE == 3
    assert RESERVED_TYPE not in {int(t) for t in PacketType}


@pytest.mark.parametrize(("hexbytes", "header"), GOLDEN_HEADERS)
def test_golden_headers(hexbytes: str, header: Header) -> None:
    raw = bytes.fromhex(hexbytes)
    assert encode_header(*header) == raw
    assert decode_header(raw) == header


def test_field_masks_partition_the_word() -> None:
    masks = [int.from_bytes(bytes.fromhex(h), "big") for h, _ in GOLDEN_HEADERS[2:7]]
    combined = 0
    for mask in masks:
        assert combined & mask == 0
        combined |= mask
    assert combined == (1 << 40) - 1


@given(headers)
def test_round_trip(header: Header) -> None:
    raw = encode_header(*header)
    assert len(raw) == HEADER_SIZE
    assert decode_header(raw) == header


@given(st.binary(min_size=5, max_size=5))
def test_every_five_bytes_decode_and_reencode(raw: bytes) -> None:
    header = decode_header(raw)
    assert 0 <= header.ptype <= 3
    assert 0 <= header.seq <= 0xFFF
    assert 0 <= header.ack <= 0xFFF
    assert 0 <= header.sack <= 0x3F
    assert 0 <= header.hold <= 0xFF
    assert encode_header(*header) == raw


@given(headers, st.binary(max_size=64))
def test_decode_reads_only_the_first_five_bytes(header: Header, payload: bytes) -> None:
    raw = encode_header(*header) + payload
    assert decode_header(raw) == header
    assert decode_header(bytearray(raw)) == header
    assert decode_header(memoryview(raw)) == header


@given(headers, st.integers(-(10**12), 10**12), st.integers(-(10**12), 10**12))
def test_seq_and_ack_are_truncated_to_12_bits(header: Header, full_seq: int, full_ack: int) -> None:
    # Endpoints pass their unbounded sequence numbers; only the low 12 bits go on the wire.
    raw = encode_header(header.ptype, full_seq, full_ack, header.sack, header.hold)
    low_seq, low_ack = full_seq & 0xFFF, full_ack & 0xFFF
    assert raw == encode_header(header.ptype, low_seq, low_ack, header.sack, header.hold)
    decoded = decode_header(raw)
    assert decoded.seq == full_seq % 4096
    assert decoded.ack == full_ack % 4096


@pytest.mark.parametrize("length", range(HEADER_SIZE))
def test_truncated_header_is_rejected(length: int) -> None:
    with pytest.raises(MalformedPacketError) as info:
        decode_header(b"\xff" * length)
    assert info.value.reason == "truncated"
    assert isinstance(info.value, ValueError)


def test_truncated_memoryview_is_rejected() -> None:
    with pytest.raises(MalformedPacketError) as info:
        decode_header(memoryview(b"\x00\x01\x02\x03\x04\x05")[2:])
    assert info.value.reason == "truncated"
