"""CONTROL bodies: pinned codes, golden bytes, round trips and rejection of malformed bodies."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tdtp.wire import (
    HEADER_SIZE,
    PROTOCOL_VERSION,
    CloseBody,
    CloseReason,
    ControlCode,
    Header,
    KeepaliveBody,
    MalformedPacketError,
    OpenBody,
    OpenFlags,
    PacketType,
    decode_control,
    decode_header,
    encode_close,
    encode_header,
    encode_hold,
    encode_keepalive,
    encode_open,
)
from tdtp.wire.control import CLOSE_BODY_SIZE, KEEPALIVE_BODY_SIZE, OPEN_BODY_SIZE

NONCE = 0x0123456789ABCDEF
BODY_SIZES = {
    ControlCode.OPEN: OPEN_BODY_SIZE,
    ControlCode.OPEN_ACK: OPEN_BODY_SIZE,
    ControlCode.KEEPALIVE: KEEPALIVE_BODY_SIZE,
    ControlCode.CLOSE: CLOSE_BODY_SIZE,
    ControlCode.REJECT: CLOSE_BODY_SIZE,
}

# Whole CONTROL datagrams from docs/PROTOCOL.md, derived by hand. Header: TYPE 10 (CONTROL), then
# SEQ, ACK, SACK, HOLD as in test_header.py; body: big-endian fields one after the other.
GOLDEN_PACKETS: list[tuple[str, Header, OpenBody | CloseBody | KeepaliveBody]] = [
    # OPEN: header TYPE 2, SEQ 0x5A5 (the master's initial data sequence number), ACK 0, SACK 0,
    # HOLD 255 (no ACK) -> 10 010110100101 000000000000 000000 11111111 = 96 94 00 00 ff;
    # body code 01, version 01, flags 00, nonce 01 23 45 67 89 ab cd ef, max_payload 1200 = 04 b0.
    (
        "96 94 00 00 ff 01 01 00 0123456789abcdef 04b0",
        Header(PacketType.CONTROL, 0x5A5, 0, 0, 255),
        OpenBody(ControlCode.OPEN, 1, 0, NONCE, 1200),
    ),
    # OPEN_ACK: SEQ 0x0C3 -> 10 000011000011 0... 11111111 = 83 0c 00 00 ff; the body echoes the
    # nonce; flags 01 = SEPARATE_ACKS; max_payload 100 = 00 64.
    (
        "83 0c 00 00 ff 02 01 01 0123456789abcdef 0064",
        Header(PacketType.CONTROL, 0x0C3, 0, 0, 255),
        OpenBody(ControlCode.OPEN_ACK, 1, int(OpenFlags.SEPARATE_ACKS), NONCE, 100),
    ),
    # KEEPALIVE carrying an acknowledgement: SEQ 0xABD, ACK 0x124, SACK 000001, HOLD 0 ->
    # 10 101010111101 000100100100 000001 00000000 = aa f4 49 01 00; body is the code alone: 03.
    (
        "aa f4 49 01 00 03",
        Header(PacketType.CONTROL, 0xABD, 0x124, 1, 0),
        KeepaliveBody(ControlCode.KEEPALIVE),
    ),
    # CLOSE: SEQ 0xABD, no ACK -> aa f4 00 00 ff; code 04, nonce, reason 00 (NORMAL).
    (
        "aa f4 00 00 ff 04 0123456789abcdef 00",
        Header(PacketType.CONTROL, 0xABD, 0, 0, 255),
        CloseBody(ControlCode.CLOSE, NONCE, CloseReason.NORMAL),
    ),
    # REJECT: SEQ 0 -> 80 00 00 00 ff; code 05, nonce, reason 03 (VERSION_UNSUPPORTED).
    (
        "80 00 00 00 ff 05 0123456789abcdef 03",
        Header(PacketType.CONTROL, 0, 0, 0, 255),
        CloseBody(ControlCode.REJECT, NONCE, CloseReason.VERSION_UNSUPPORTED),
    ),
]


def encode_body(body: OpenBody | CloseBody | KeepaliveBody) -> bytes:
    if isinstance(body, OpenBody):
        return encode_open(*body)
    if isinstance(body, CloseBody):
        return encode_close(*body)
    return encode_keepalive()


def test_codes_and_constants_are_pinned() -> None:
    assert PROTOCOL_VERSION == 1
    assert {c.name: int(c) for c in ControlCode} == {
        "OPEN": 1,
        "OPEN_ACK": 2,
        "KEEPALIVE": 3,
        "CLOSE": 4,
        "REJECT": 5,
    }
    assert {r.name: int(r) for r in CloseReason} == {
        "NORMAL": 0,
        "IDLE_TIMEOUT": 1,
        "PROTOCOL_ERROR": 2,
        "VERSION_UNSUPPORTED": 3,
        "REFUSED": 4,
    }
    assert int(OpenFlags.SEPARATE_ACKS) == 0x01
    assert (OPEN_BODY_SIZE, CLOSE_BODY_SIZE, KEEPALIVE_BODY_SIZE) == (13, 10, 1)


@pytest.mark.parametrize(("hexbytes", "header", "body"), GOLDEN_PACKETS)
def test_golden_control_packets(
    hexbytes: str, header: Header, body: OpenBody | CloseBody | KeepaliveBody
) -> None:
    raw = bytes.fromhex(hexbytes)
    assert encode_header(*header) + encode_body(body) == raw
    assert decode_header(raw) == header
    assert decode_control(raw[HEADER_SIZE:]) == body
    assert decode_control(memoryview(raw)[HEADER_SIZE:]) == body
    assert len(raw) == HEADER_SIZE + BODY_SIZES[body.code]


def test_decoded_code_is_the_enum() -> None:
    body = decode_control(encode_close(ControlCode.REJECT, 7, CloseReason.REFUSED))
    assert type(body.code) is ControlCode
    assert body.code is ControlCode.REJECT


@given(
    st.sampled_from([ControlCode.OPEN, ControlCode.OPEN_ACK]),
    st.integers(0, 0xFF),
    st.integers(0, 0xFF),
    st.integers(0, 2**64 - 1),
    st.integers(0, 0xFFFF),
)
def test_open_round_trip(
    code: ControlCode, version: int, flags: int, nonce: int, max_payload: int
) -> None:
    raw = encode_open(code, version, flags, nonce, max_payload)
    assert len(raw) == OPEN_BODY_SIZE
    assert raw[0] == code
    # Version and flags are carried as is; judging them is the connection's job.
    assert decode_control(raw) == OpenBody(code, version, flags, nonce, max_payload)


@given(
    st.sampled_from([ControlCode.CLOSE, ControlCode.REJECT]),
    st.integers(0, 2**64 - 1),
    st.integers(0, 0xFF),
)
def test_close_round_trip(code: ControlCode, nonce: int, reason: int) -> None:
    raw = encode_close(code, nonce, reason)
    assert len(raw) == CLOSE_BODY_SIZE
    assert decode_control(raw) == CloseBody(code, nonce, reason)


def test_keepalive_round_trip() -> None:
    assert encode_keepalive() == b"\x03"
    assert decode_control(b"\x03") == KeepaliveBody(ControlCode.KEEPALIVE)


def assert_bad_control(body: bytes) -> None:
    with pytest.raises(MalformedPacketError) as info:
        decode_control(body)
    assert info.value.reason == "bad_control"


def test_empty_body_is_rejected() -> None:
    assert_bad_control(b"")


@pytest.mark.parametrize("code", [0, *range(6, 256)])
def test_unknown_code_is_rejected(code: int) -> None:
    assert_bad_control(bytes([code]))
    assert_bad_control(bytes([code]) + bytes(12))


@pytest.mark.parametrize("code", list(ControlCode))
def test_every_wrong_size_is_rejected(code: ControlCode) -> None:
    good = BODY_SIZES[code]
    for size in range(1, 40):
        body = bytes([code]) + b"\xaa" * (size - 1)
        if size == good:
            assert decode_control(body).code == code
        else:
            assert_bad_control(body)


@given(st.binary(max_size=32))
def test_arbitrary_bytes_decode_or_raise_bad_control(body: bytes) -> None:
    try:
        decoded = decode_control(body)
    except MalformedPacketError as exc:
        assert exc.reason == "bad_control"
        return
    assert len(body) == BODY_SIZES[decoded.code]
    assert encode_body(decoded) == body


PROTOCOL_MD = Path(__file__).resolve().parents[2] / "docs" / "PROTOCOL.md"

# The worked examples of docs/PROTOCOL.md section 7, rebuilt here from their field values with the codec.
DOC_EXAMPLES = [
    (
        "2a f0 48 ea 1f",
        encode_header(PacketType.DATA, 0x0ABC, 0x0123, 0b101010, encode_hold(250e-6)),
    ),
    (
        "96 94 00 00 ff 01 01 00 01 23 45 67 89 ab cd ef 04 b0",
        encode_header(PacketType.CONTROL, 0x5A5, 0, 0, 255)
        + encode_open(ControlCode.OPEN, 1, 0, NONCE, 1200),
    ),
    (
        "83 0c 00 00 ff 02 01 00 01 23 45 67 89 ab cd ef 04 b0",
        encode_header(PacketType.CONTROL, 0x0C3, 0, 0, 255)
        + encode_open(ControlCode.OPEN_ACK, 1, 0, NONCE, 1200),
    ),
    (
        "6a f4 49 3f 6e",
        encode_header(PacketType.ACK, 0x0ABD, 0x0124, 0b111111, encode_hold(1.5e-3)),
    ),
    (
        "aa f4 49 01 00 03",
        encode_header(PacketType.CONTROL, 0x0ABD, 0x0124, 0b000001, encode_hold(0.0))
        + encode_keepalive(),
    ),
    (
        "aa f4 00 00 ff 04 01 23 45 67 89 ab cd ef 00",
        encode_header(PacketType.CONTROL, 0x0ABD, 0, 0, 255)
        + encode_close(ControlCode.CLOSE, NONCE, CloseReason.NORMAL),
    ),
    (
        "80 00 00 00 ff 05 01 23 45 67 89 ab cd ef 03",
        encode_header(PacketType.CONTROL, 0, 0, 0, 255)
        + encode_close(ControlCode.REJECT, NONCE, CloseReason.VERSION_UNSUPPORTED),
    ),
]


@pytest.mark.parametrize(("hexbytes", "built"), DOC_EXAMPLES)
def test_protocol_md_worked_examples(hexbytes: str, built: bytes) -> None:
    assert built == bytes.fromhex(hexbytes)
    assert f"`{hexbytes}`" in PROTOCOL_MD.read_text(encoding="utf-8")
