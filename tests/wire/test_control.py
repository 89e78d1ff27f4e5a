"""CONTROL bodies: pinned codes, golden bytes, round trips and rejection of malformed bodies."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tdtp.wire import (
    HEADER_SIZE,
    PROTOCOL_VERSION,
    TAG_SIZE,
    CipherSuite,
    CloseBody,
    CloseReason,
    ControlCode,
    CookieBody,
    Header,
    KeepaliveBody,
    MalformedPacketError,
    MessageAckBody,
    MessageBody,
    OpenAckBody,
    OpenBody,
    OpenFlags,
    PacketType,
    decode_control,
    decode_header,
    encode_close,
    encode_cookie,
    encode_header,
    encode_hold,
    encode_keepalive,
    encode_message,
    encode_message_ack,
    encode_open,
    encode_open_ack,
)
from tdtp.wire.control import (
    CLOSE_BODY_SIZE,
    COOKIE_BODY_SIZE,
    KEEPALIVE_BODY_SIZE,
    MESSAGE_ACK_BODY_SIZE,
    MESSAGE_PREFIX_SIZE,
    OPEN_ACK_BODY_SIZE,
    OPEN_BODY_SIZE,
    PATH_CHALLENGE_BODY_SIZE,
    PATH_RESPONSE_BODY_SIZE,
    RESET_ECHO_SIZE,
    STAMP_SIZE,
    ControlBody,
    MpAbandonBody,
    MpChallengeBody,
    MpReportBody,
    MpResponseBody,
    PathChallengeBody,
    PathResponseBody,
    ResetBody,
    TimedDataBody,
    TimestampBody,
    encode_mp_abandon,
    encode_mp_challenge,
    encode_mp_report,
    encode_mp_response,
    encode_path_challenge,
    encode_path_response,
    encode_reset,
    encode_timestamp,
    open_version,
)

NONCE = bytes.fromhex("00112233445566778899aabbccddeeff")
SLAVE_NONCE = bytes.fromhex("f0e1d2c3b4a5968778695a4b3c2d1e0f")
COOKIE = bytes.fromhex("0000abcd") + bytes([0x11] * 12)
KEY_ID = bytes.fromhex("0123456789abcdef")
TAG = bytes(range(0xA0, 0xB0))
ZERO8, ZERO16 = bytes(8), bytes(16)

UNKEYED_SIZES = {
    ControlCode.OPEN: OPEN_BODY_SIZE,
    ControlCode.OPEN_ACK: OPEN_ACK_BODY_SIZE,
    ControlCode.COOKIE: COOKIE_BODY_SIZE,
    ControlCode.KEEPALIVE: KEEPALIVE_BODY_SIZE,
    ControlCode.CLOSE: CLOSE_BODY_SIZE,
    ControlCode.REJECT: CLOSE_BODY_SIZE,
    ControlCode.RESET: 1 + RESET_ECHO_SIZE,
    ControlCode.PATH_CHALLENGE: PATH_CHALLENGE_BODY_SIZE,
    ControlCode.PATH_RESPONSE: PATH_RESPONSE_BODY_SIZE,
    ControlCode.MESSAGE: 22,  # the smallest: code, nonce, seq, ack and a one-byte message
    ControlCode.MESSAGE_ACK: 19,
    ControlCode.TIMESTAMP: 5,
    ControlCode.TIMED_DATA: 6,  # the smallest: code, time and a one-byte sample
    ControlCode.MP_CHALLENGE: 26,
    ControlCode.MP_RESPONSE: 34,
    ControlCode.MP_REPORT: 35,
    ControlCode.MP_ABANDON: 19,
}

# Whole CONTROL datagrams, derived by hand field by field (docs/PROTOCOL.md section 7 shows the same).
# Header: TYPE 10 (CONTROL), then SEQ, ACK, SACK, HOLD as in test_header.py; body: big-endian fields
# one after the other, nonces and cookies as raw bytes.
GOLDEN_PACKETS: list[tuple[str, Header, ControlBody, bytes]] = [
    # OPEN, first attempt, no cookie yet: SEQ 0x5A5 (the master's initial data sequence number), no ACK
    # -> 96 94 00 00 ff; code 01, version 04, flags 00, suite 00, max_payload 1200 = 04 b0, attempt
    # 00 00, nonce, key id 0 (unkeyed), cookie 0 (none).
    (
        "96 94 00 00 ff" + "01 04 00 00 04b0 0000" + NONCE.hex() + ZERO8.hex() + ZERO16.hex(),
        Header(PacketType.CONTROL, 0x5A5, 0, 0, 255),
        OpenBody(4, 0, 0, 1200, 0, NONCE, ZERO8, ZERO16),
        b"",
    ),
    # COOKIE: SEQ 0 -> 80 00 00 00 ff; code 06, version 04, the master's nonce, the cookie.
    (
        "80 00 00 00 ff" + "06 04" + NONCE.hex() + COOKIE.hex(),
        Header(PacketType.CONTROL, 0, 0, 0, 255),
        CookieBody(4, NONCE, COOKIE),
        b"",
    ),
    # OPEN, second attempt, echoing the cookie: attempt 00 01.
    (
        "96 94 00 00 ff" + "01 04 00 00 04b0 0001" + NONCE.hex() + ZERO8.hex() + COOKIE.hex(),
        Header(PacketType.CONTROL, 0x5A5, 0, 0, 255),
        OpenBody(4, 0, 0, 1200, 1, NONCE, ZERO8, COOKIE),
        b"",
    ),
    # A keyed OPEN: flags 06 (KEYED | ENCRYPTED), suite 01 (AES-128-GCM), the key id, then the tag.
    (
        "96 94 00 00 ff"
        + "01 04 06 01 04b0 0001"
        + NONCE.hex()
        + KEY_ID.hex()
        + COOKIE.hex()
        + TAG.hex(),
        Header(PacketType.CONTROL, 0x5A5, 0, 0, 255),
        OpenBody(4, 0x06, 1, 1200, 1, NONCE, KEY_ID, COOKIE),
        TAG,
    ),
    # OPEN_ACK: SEQ 0x0C3 -> 83 0c 00 00 ff; code 02, version 04, flags 01 (SEPARATE_ACKS), suite
    # 00, max_payload 100 = 00 64, packet number 00 00, both nonces.
    (
        "83 0c 00 00 ff" + "02 04 01 00 0064 0000" + NONCE.hex() + SLAVE_NONCE.hex(),
        Header(PacketType.CONTROL, 0x0C3, 0, 0, 255),
        OpenAckBody(4, int(OpenFlags.SEPARATE_ACKS), 0, 100, 0, NONCE, SLAVE_NONCE),
        b"",
    ),
    # KEEPALIVE carrying an acknowledgement: SEQ 0xABD, ACK 0x124, SACK 000001, HOLD 0 ->
    # 10 101010111101 000100100100 000001 00000000 = aa f4 49 01 00; code 03, the master's nonce.
    (
        "aa f4 49 01 00 03" + NONCE.hex(),
        Header(PacketType.CONTROL, 0xABD, 0x124, 1, 0),
        KeepaliveBody(ControlCode.KEEPALIVE, NONCE),
        b"",
    ),
    # PATH_CHALLENGE: no sequence, no ACK -> 80 00 00 00 ff; code 08, token (the cookie's format).
    (
        "80 00 00 00 ff 08" + COOKIE.hex(),
        Header(PacketType.CONTROL, 0, 0, 0, 255),
        PathChallengeBody(COOKIE),
        b"",
    ),
    # PATH_RESPONSE: 80 00 00 00 ff; code 09, the token echoed, the master's nonce.
    (
        "80 00 00 00 ff 09" + COOKIE.hex() + NONCE.hex(),
        Header(PacketType.CONTROL, 0, 0, 0, 255),
        PathResponseBody(COOKIE, NONCE),
        b"",
    ),
    # CLOSE: SEQ 0xABD, no ACK -> aa f4 00 00 ff; code 04, nonce, reason 00 (NORMAL).
    (
        "aa f4 00 00 ff 04" + NONCE.hex() + "00",
        Header(PacketType.CONTROL, 0xABD, 0, 0, 255),
        CloseBody(ControlCode.CLOSE, NONCE, CloseReason.NORMAL),
        b"",
    ),
    # RESET (unkeyed): SEQ 0 -> 80 00 00 00 ff; code 07, the first 16 bytes of the DATA packet of
    # PROTOCOL.md 7.1 with an 11-byte payload 00 01 .. 0a.
    (
        "80 00 00 00 ff 07" + "2af048ea1f" + bytes(range(11)).hex(),
        Header(PacketType.CONTROL, 0, 0, 0, 255),
        ResetBody(bytes.fromhex("2af048ea1f") + bytes(range(11)), ()),
        b"",
    ),
    # REJECT: SEQ 0 -> 80 00 00 00 ff; code 05, nonce, reason 05 (BUSY).
    (
        "80 00 00 00 ff 05" + NONCE.hex() + "05",
        Header(PacketType.CONTROL, 0, 0, 0, 255),
        CloseBody(ControlCode.REJECT, NONCE, CloseReason.BUSY),
        b"",
    ),
    # MESSAGE: SEQ 0xABD, no ACK -> aa f4 00 00 ff; code 0a, the master's nonce, message number
    # ff ff, next expected from the peer f0 c4, the message "E-STOP" (PROTOCOL.md 7.7).
    (
        "aa f4 00 00 ff 0a" + NONCE.hex() + "ffff f0c4" + b"E-STOP".hex(),
        Header(PacketType.CONTROL, 0xABD, 0, 0, 255),
        MessageBody(NONCE, 0xFFFF, 0xF0C4, b"E-STOP"),
        b"",
    ),
    # MESSAGE_ACK: code 0b, the master's nonce, next expected 00 00 (0x10000 past the wrap).
    (
        "aa f4 00 00 ff 0b" + NONCE.hex() + "0000",
        Header(PacketType.CONTROL, 0xABD, 0, 0, 255),
        MessageAckBody(NONCE, 0),
        b"",
    ),
    # TIMESTAMP: an ACK's header (SEQ 0xABD, ACK 0x124, SACK 000001, HOLD 0) as TYPE 10 ->
    # aa f4 49 01 00; code 0f, the sender's clock 0x89abcdef microseconds.
    (
        "aa f4 49 01 00 0f 89abcdef",
        Header(PacketType.CONTROL, 0xABD, 0x124, 1, 0),
        TimestampBody(0x89ABCDEF),
        b"",
    ),
    # TIMED_DATA: a DATA header as TYPE 10 -> aa f4 49 01 00; code 10, the clock 00 00 00 01
    # (just past a wrap), the sample 00 01 02.
    (
        "aa f4 49 01 00 10 00000001 000102",
        Header(PacketType.CONTROL, 0xABD, 0x124, 1, 0),
        TimedDataBody(1, bytes(range(3))),
        b"",
    ),
]


def encode_body(body: ControlBody) -> bytes:
    if isinstance(body, OpenBody):
        return encode_open(body)
    if isinstance(body, OpenAckBody):
        return encode_open_ack(body)
    if isinstance(body, CookieBody):
        return encode_cookie(body.nonce, body.cookie)
    if isinstance(body, CloseBody):
        return encode_close(*body)
    if isinstance(body, ResetBody):
        return encode_reset(body.echo, body.tags)
    if isinstance(body, PathChallengeBody):
        return encode_path_challenge(body.token)
    if isinstance(body, PathResponseBody):
        return encode_path_response(body.token, body.nonce)
    if isinstance(body, MessageBody):
        return encode_message(body.nonce, body.seq, body.ack, body.data)
    if isinstance(body, MessageAckBody):
        return encode_message_ack(body.nonce, body.ack)
    if isinstance(body, TimestampBody):
        return encode_timestamp(ControlCode.TIMESTAMP, body.time)
    if isinstance(body, TimedDataBody):
        return encode_timestamp(ControlCode.TIMED_DATA, body.time) + body.payload
    if isinstance(body, MpChallengeBody):
        return encode_mp_challenge(body.nonce, body.path_id, body.token)
    if isinstance(body, MpResponseBody):
        return encode_mp_response(body.nonce, body.path_id, body.echo, body.token)
    if isinstance(body, MpReportBody):
        return encode_mp_report(body)
    if isinstance(body, MpAbandonBody):
        return encode_mp_abandon(body.nonce, body.path_id, body.reason)
    return encode_keepalive(body.nonce)


def test_codes_and_constants_are_pinned() -> None:
    assert PROTOCOL_VERSION == 4
    assert {c.name: int(c) for c in ControlCode} == {
        "OPEN": 1,
        "OPEN_ACK": 2,
        "KEEPALIVE": 3,
        "CLOSE": 4,
        "REJECT": 5,
        "COOKIE": 6,
        "RESET": 7,
        "PATH_CHALLENGE": 8,
        "PATH_RESPONSE": 9,
        "MESSAGE": 10,
        "MESSAGE_ACK": 11,
        "TIMESTAMP": 15,
        "TIMED_DATA": 16,
        "MP_CHALLENGE": 17,
        "MP_RESPONSE": 18,
        "MP_REPORT": 19,
        "MP_ABANDON": 20,
        "REGISTER": 21,
        "REFERRAL": 22,
        "PROBE": 23,
        "PROBE_ACK": 24,
    }
    assert {r.name: int(r) for r in CloseReason} == {
        "NORMAL": 0,
        "IDLE_TIMEOUT": 1,
        "PROTOCOL_ERROR": 2,
        "VERSION_UNSUPPORTED": 3,
        "REFUSED": 4,
        "BUSY": 5,
        "KEY_REQUIRED": 6,
        "KEY_UNKNOWN": 7,
        "PAYLOAD_TOO_SMALL": 8,
        "SUITE_UNSUPPORTED": 9,
        "REPLACED": 10,
        "KEY_EXHAUSTED": 11,
        "IN_USE": 12,
        "TAKEN_OVER": 13,
        "EVICTED": 14,
        "RESTARTING": 15,
        "PATH_CLOSED": 19,
        "PATH_LIMIT": 20,
        "ROLE_CONFLICT": 21,
        "RENDEZVOUS_FULL": 22,
    }
    assert int(OpenFlags.NONE) == 0
    assert {f.name: int(f) for f in OpenFlags if f.name} == {
        "SEPARATE_ACKS": 1,
        "KEYED": 2,
        "ENCRYPTED": 4,
        "TAKEOVER": 8,
        "TIMESTAMPS": 0x20,
        "MULTIPATH": 0x40,
        "SLAVE_DIALS": 128,
    }
    assert {s.name: int(s) for s in CipherSuite} == {
        "NONE": 0,
        "AES_128_GCM": 1,
        "CHACHA20_POLY1305": 2,
    }
    assert (OPEN_BODY_SIZE, OPEN_ACK_BODY_SIZE, COOKIE_BODY_SIZE) == (48, 40, 34)
    assert (CLOSE_BODY_SIZE, KEEPALIVE_BODY_SIZE, TAG_SIZE) == (18, 17, 16)
    assert (PATH_CHALLENGE_BODY_SIZE, PATH_RESPONSE_BODY_SIZE) == (17, 33)
    assert (MESSAGE_PREFIX_SIZE, MESSAGE_ACK_BODY_SIZE) == (21, 19)
    assert STAMP_SIZE == 5


def test_no_answer_to_an_unvalidated_open_is_larger_than_the_open() -> None:
    """Amplification: a COOKIE and a REJECT are smaller than the smallest OPEN."""
    smallest_open = HEADER_SIZE + OPEN_BODY_SIZE
    cookie, reject = HEADER_SIZE + COOKIE_BODY_SIZE, HEADER_SIZE + CLOSE_BODY_SIZE
    assert cookie < smallest_open
    assert reject < smallest_open


@pytest.mark.parametrize(("hexbytes", "header", "body", "tag"), GOLDEN_PACKETS)
def test_golden_control_packets(
    hexbytes: str, header: Header, body: ControlBody, tag: bytes
) -> None:
    raw = bytes.fromhex(hexbytes)
    assert encode_header(*header) + encode_body(body) + tag == raw
    assert decode_header(raw) == header
    assert decode_control(raw[HEADER_SIZE:]) == body
    assert decode_control(memoryview(raw)[HEADER_SIZE:]) == body
    message = len(body.data) - 1 if isinstance(body, MessageBody) else 0  # beyond the smallest
    if isinstance(body, TimedDataBody):
        message = len(body.payload) - 1
    assert len(raw) == HEADER_SIZE + UNKEYED_SIZES[body.code] + message + len(tag)


def test_decoded_code_is_the_enum() -> None:
    body = decode_control(encode_close(ControlCode.REJECT, NONCE, CloseReason.REFUSED))
    assert type(body.code) is ControlCode
    assert body.code is ControlCode.REJECT


u8 = st.integers(0, 0xFF)
u16 = st.integers(0, 0xFFFF)
b8 = st.binary(min_size=8, max_size=8)
b16 = st.binary(min_size=16, max_size=16)
unkeyed_flags = st.integers(0, 0xFF).map(lambda f: f & ~int(OpenFlags.KEYED))


@given(u8, unkeyed_flags, u8, u16, u16, b16, b8, b16)
def test_open_round_trip(
    version: int,
    flags: int,
    suite: int,
    max_payload: int,
    attempt: int,
    nonce: bytes,
    key_id: bytes,
    cookie: bytes,
) -> None:
    body = OpenBody(version, flags, suite, max_payload, attempt, nonce, key_id, cookie)
    raw = encode_open(body)
    assert len(raw) == OPEN_BODY_SIZE
    assert raw[0] == ControlCode.OPEN
    # Version, flags and suite are carried as is; judging them is the admission's job.
    assert decode_control(raw) == body
    assert open_version(raw) == version
    keyed = encode_open(body._replace(flags=flags | OpenFlags.KEYED))
    assert decode_control(keyed + TAG) == body._replace(flags=flags | OpenFlags.KEYED)
    with pytest.raises(MalformedPacketError):  # KEYED promises a tag
        decode_control(keyed)


@given(u8, unkeyed_flags, u8, u16, u16, b16, b16)
def test_open_ack_round_trip(
    version: int, flags: int, suite: int, max_payload: int, pn: int, nonce: bytes, slave: bytes
) -> None:
    body = OpenAckBody(version, flags, suite, max_payload, pn, nonce, slave)
    raw = encode_open_ack(body)
    assert len(raw) == OPEN_ACK_BODY_SIZE
    assert decode_control(raw) == body


@given(b16, b16)
def test_cookie_round_trip(nonce: bytes, cookie: bytes) -> None:
    raw = encode_cookie(nonce, cookie)
    assert len(raw) == COOKIE_BODY_SIZE
    assert decode_control(raw) == CookieBody(PROTOCOL_VERSION, nonce, cookie)


@given(st.sampled_from([ControlCode.CLOSE, ControlCode.REJECT]), b16, u8)
def test_close_round_trip(code: ControlCode, nonce: bytes, reason: int) -> None:
    raw = encode_close(code, nonce, reason)
    assert len(raw) == CLOSE_BODY_SIZE
    assert decode_control(raw) == CloseBody(code, nonce, reason)


def test_keepalive_round_trip() -> None:
    assert encode_keepalive(NONCE) == b"\x03" + NONCE
    assert decode_control(b"\x03" + NONCE) == KeepaliveBody(ControlCode.KEEPALIVE, NONCE)


def test_path_messages_round_trip() -> None:
    assert decode_control(encode_path_challenge(COOKIE)) == PathChallengeBody(COOKIE)
    assert decode_control(encode_path_response(COOKIE, NONCE)) == PathResponseBody(COOKIE, NONCE)
    # A challenge is never larger than the smallest session datagram that can trigger one (an
    # unkeyed KEEPALIVE): it cannot amplify.
    assert PATH_CHALLENGE_BODY_SIZE <= KEEPALIVE_BODY_SIZE


def assert_bad_control(body: bytes) -> None:
    with pytest.raises(MalformedPacketError) as info:
        decode_control(body)
    assert info.value.reason == "bad_control"


def test_empty_body_is_rejected() -> None:
    assert_bad_control(b"")


@pytest.mark.parametrize("code", [0, 12, 13, 14, *range(17, 256)])
def test_unknown_code_is_rejected(code: int) -> None:
    assert_bad_control(bytes([code]))
    assert_bad_control(bytes([code]) + bytes(12))


@pytest.mark.parametrize("code", [c for c in ControlCode if c < ControlCode.REGISTER])
def test_every_wrong_size_is_rejected(code: ControlCode) -> None:
    good = UNKEYED_SIZES[code]
    for size in range(1, 90):
        # Flag byte 0xA9 (where a body has flags): KEYED clear, so no tag is expected.
        body = bytes([code]) + b"\xa9" * (size - 1)
        tags = size - good  # a RESET carries whole 16-byte tags after its echo (keyed)
        # A message, or a timed sample, of any length.
        longer = code in (ControlCode.MESSAGE, ControlCode.TIMED_DATA) and size > good
        if size == good or longer or (code is ControlCode.RESET and tags > 0 and tags % 16 == 0):
            assert decode_control(body).code == code
        else:
            assert_bad_control(body)


@given(st.binary(max_size=80))
def test_arbitrary_bytes_decode_or_raise_bad_control(body: bytes) -> None:
    try:
        decoded = decode_control(body)
    except MalformedPacketError as exc:
        assert exc.reason == "bad_control"
        return
    tag = b""
    if isinstance(decoded, OpenBody | OpenAckBody) and decoded.flags & OpenFlags.KEYED:
        tag = body[-TAG_SIZE:]
    if isinstance(decoded, ResetBody | MessageBody | TimedDataBody):  # of variable length
        assert encode_body(decoded) == body
        return
    assert len(body) == UNKEYED_SIZES[decoded.code] + len(tag)
    assert encode_body(decoded) + tag == body


PROTOCOL_MD = Path(__file__).resolve().parents[2] / "docs" / "PROTOCOL.md"

# The worked examples of docs/PROTOCOL.md section 7, rebuilt here from their field values with the codec.
DOC_EXAMPLES = [
    (
        "2a f0 48 ea 1f",
        encode_header(PacketType.DATA, 0x0ABC, 0x0123, 0b101010, encode_hold(250e-6)),
    ),
    (
        "6a f4 49 3f 6e",
        encode_header(PacketType.ACK, 0x0ABD, 0x0124, 0b111111, encode_hold(1.5e-3)),
    ),
    (
        "aa f4 49 01 00 03" + " 00 11 22 33 44 55 66 77 88 99 aa bb cc dd ee ff",
        encode_header(PacketType.CONTROL, 0x0ABD, 0x0124, 0b000001, encode_hold(0.0))
        + encode_keepalive(NONCE),
    ),
] + [
    (
        " ".join(f"{byte:02x}" for byte in bytes.fromhex(hexbytes)),
        encode_header(*header) + encode_body(body) + tag,
    )
    for hexbytes, header, body, tag in GOLDEN_PACKETS
    if not tag
]


@pytest.mark.parametrize(("hexbytes", "built"), DOC_EXAMPLES)
def test_protocol_md_worked_examples(hexbytes: str, built: bytes) -> None:
    assert built == bytes.fromhex(hexbytes)
    assert f"`{hexbytes}`" in " ".join(PROTOCOL_MD.read_text(encoding="utf-8").split())
