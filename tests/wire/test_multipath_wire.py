"""The multipath CONTROL bodies (PROTOCOL.md 4.3, 5.11): golden bytes, round trips, the schema of
record agreeing with the struct codecs, and malformed bodies refused."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tdtp.wire import (
    HEADER_SIZE,
    ControlCode,
    Header,
    MalformedPacketError,
    MpAbandonBody,
    MpChallengeBody,
    MpReportBody,
    MpResponseBody,
    OpenBody,
    OpenFlags,
    PacketType,
    decode_control,
    decode_header,
    encode_header,
    encode_mp_abandon,
    encode_mp_challenge,
    encode_mp_report,
    encode_mp_response,
    encode_open,
    schema,
)
from tdtp.wire.control import (
    MP_ABANDON_BODY_SIZE,
    MP_CHALLENGE_BODY_SIZE,
    MP_PROBE_PREFIX_SIZE,
    MP_REPORT_BODY_SIZE,
    MP_RESPONSE_BODY_SIZE,
    MULTIPATH_CODES,
    PROBE_CODES,
)

NONCE = bytes.fromhex("00112233445566778899aabbccddeeff")
TOKEN = bytes.fromhex("0102030405060708")
ECHO = bytes.fromhex("a1a2a3a4a5a6a7a8")
NO_TOKEN = bytes(8)

u8 = st.integers(0, 0xFF)
u12 = st.integers(0, 0xFFF)
u16 = st.integers(0, 0xFFFF)
u32 = st.integers(0, 0xFFFFFFFF)
b8 = st.binary(min_size=8, max_size=8)
b16 = st.binary(min_size=16, max_size=16)


def test_sizes_are_pinned() -> None:
    assert (MP_CHALLENGE_BODY_SIZE, MP_RESPONSE_BODY_SIZE) == (26, 34)
    assert (MP_REPORT_BODY_SIZE, MP_ABANDON_BODY_SIZE) == (35, 19)
    assert MP_PROBE_PREFIX_SIZE == 17
    assert {17, 18, 19, 20} == MULTIPATH_CODES
    assert {17, 18} == PROBE_CODES


def test_a_response_never_amplifies_the_challenge_beyond_three_times() -> None:
    """A listener answers a new path's first challenge with one response before it validated the
    address: 39 bytes for 31 unkeyed (57 for 49 keyed), inside the 3x budget."""
    assert HEADER_SIZE + MP_RESPONSE_BODY_SIZE <= 3 * (HEADER_SIZE + MP_CHALLENGE_BODY_SIZE)
    assert HEADER_SIZE + MP_ABANDON_BODY_SIZE <= HEADER_SIZE + MP_CHALLENGE_BODY_SIZE


GOLDEN = [
    # MP_CHALLENGE on path 1: 80 00 00 00 ff; code 11 (17), nonce, path 01, token.
    (
        "80 00 00 00 ff 11" + NONCE.hex() + "01" + TOKEN.hex(),
        MpChallengeBody(NONCE, 1, TOKEN),
    ),
    # MP_RESPONSE on path 1: code 12 (18), nonce, path 01, the echo, a token of the responder's.
    (
        "80 00 00 00 ff 12" + NONCE.hex() + "01" + ECHO.hex() + TOKEN.hex(),
        MpResponseBody(NONCE, 1, ECHO, TOKEN),
    ),
    # MP_REPORT for path 2: code 13 (19), nonce, path 02, seq 0abc, hold 0x40 (512 us), received
    # 1000, first 600, lag 150 (15 ms), clock 0x89ABCDEF.
    (
        "80 00 00 00 ff 13" + NONCE.hex() + "02 0abc 40 000003e8 00000258 0096 89abcdef",
        MpReportBody(NONCE, 2, 0xABC, 0x40, 1000, 600, 150, 0x89ABCDEF),
    ),
    # MP_ABANDON of path 1: code 14 (20), nonce, path 01, reason 13 (19, PATH_CLOSED).
    (
        "80 00 00 00 ff 14" + NONCE.hex() + "01 13",
        MpAbandonBody(NONCE, 1, 19),
    ),
]


def _encode(body: object) -> bytes:
    if isinstance(body, MpChallengeBody):
        return encode_mp_challenge(body.nonce, body.path_id, body.token)
    if isinstance(body, MpResponseBody):
        return encode_mp_response(body.nonce, body.path_id, body.echo, body.token)
    if isinstance(body, MpReportBody):
        return encode_mp_report(body)
    assert isinstance(body, MpAbandonBody)
    return encode_mp_abandon(body.nonce, body.path_id, body.reason)


@pytest.mark.parametrize(("hexbytes", "body"), GOLDEN)
def test_golden_multipath_packets(hexbytes: str, body: object) -> None:
    raw = bytes.fromhex(hexbytes)
    assert encode_header(PacketType.CONTROL, 0, 0, 0, 255) + _encode(body) == raw
    assert decode_header(raw) == Header(PacketType.CONTROL, 0, 0, 0, 255)
    assert decode_control(raw[HEADER_SIZE:]) == body
    parsed = schema.ControlBody.parse(raw[HEADER_SIZE:])
    assert parsed.code == raw[HEADER_SIZE]
    assert tuple(parsed.body[name] for name in body._fields) == tuple(body)  # type: ignore[attr-defined]


def test_an_open_with_the_multipath_flag() -> None:
    body = OpenBody(4, int(OpenFlags.MULTIPATH), 0, 1200, 0, NONCE, bytes(8), bytes(16))
    raw = encode_open(body)
    assert raw[:3] == bytes.fromhex("01 04 40")
    assert decode_control(raw) == body


@given(b16, u8, b8)
def test_challenge_round_trip_and_schema(nonce: bytes, path_id: int, token: bytes) -> None:
    fast = encode_mp_challenge(nonce, path_id, token)
    built = schema.ControlBody.build(
        {"code": 17, "body": {"nonce": nonce, "path_id": path_id, "token": token}}
    )
    assert built == fast
    assert decode_control(fast) == MpChallengeBody(nonce, path_id, token)


@given(b16, u8, b8, b8)
def test_response_round_trip_and_schema(
    nonce: bytes, path_id: int, echo: bytes, token: bytes
) -> None:
    fast = encode_mp_response(nonce, path_id, echo, token)
    fields = {"nonce": nonce, "path_id": path_id, "echo": echo, "token": token}
    assert schema.ControlBody.build({"code": 18, "body": fields}) == fast
    assert decode_control(fast) == MpResponseBody(nonce, path_id, echo, token)


@given(st.binary(min_size=16, max_size=16), u8, u12, u8, u32, u32, u16, u32)
def test_report_round_trip_and_schema(
    nonce: bytes,
    path_id: int,
    seq: int,
    hold: int,
    received: int,
    first: int,
    lag: int,
    clock: int,
) -> None:
    body = MpReportBody(nonce, path_id, seq, hold, received, first, lag, clock)
    fast = encode_mp_report(body)
    assert schema.ControlBody.build({"code": 19, "body": body._asdict()}) == fast
    assert decode_control(fast) == body


def test_report_counters_and_clock_wrap_and_the_lag_saturates() -> None:
    body = MpReportBody(NONCE, 1, 0x1ABC, 0, (1 << 32) + 5, (1 << 33) + 7, 1 << 20, (1 << 32) + 9)
    expected = MpReportBody(NONCE, 1, 0xABC, 0, 5, 7, 0xFFFF, 9)
    assert decode_control(encode_mp_report(body)) == expected


@given(b16, u8, u8)
def test_abandon_round_trip_and_schema(nonce: bytes, path_id: int, reason: int) -> None:
    fast = encode_mp_abandon(nonce, path_id, reason)
    fields = {"nonce": nonce, "path_id": path_id, "reason": reason}
    assert schema.ControlBody.build({"code": 20, "body": fields}) == fast
    assert decode_control(fast) == MpAbandonBody(nonce, path_id, reason)


@pytest.mark.parametrize(
    ("code", "size"),
    [
        (ControlCode.MP_CHALLENGE, MP_CHALLENGE_BODY_SIZE),
        (ControlCode.MP_RESPONSE, MP_RESPONSE_BODY_SIZE),
        (ControlCode.MP_REPORT, MP_REPORT_BODY_SIZE),
        (ControlCode.MP_ABANDON, MP_ABANDON_BODY_SIZE),
    ],
)
@pytest.mark.parametrize("delta", [-1, 1])
def test_a_body_of_the_wrong_length_is_bad_control(
    code: ControlCode, size: int, delta: int
) -> None:
    raw = bytes([code]) + bytes(size - 1 + delta)
    with pytest.raises(MalformedPacketError) as info:
        decode_control(raw)
    assert info.value.reason == "bad_control"


def test_a_reports_top_four_sequence_bits_are_ignored() -> None:
    raw = bytearray(encode_mp_report(MpReportBody(NONCE, 1, 0x123, 0, 0, 0, 0, 0)))
    assert raw[18:20] == bytes.fromhex("0123")
    raw[18] |= 0xF0
    assert decode_control(bytes(raw)) == MpReportBody(NONCE, 1, 0x123, 0, 0, 0, 0, 0)


@pytest.mark.parametrize("code", [12, 13, 14, 21, 255])
def test_codes_outside_the_allotment_stay_unknown(code: int) -> None:
    with pytest.raises(MalformedPacketError):
        decode_control(bytes([code]) + bytes(20))


@given(u16, st.binary(min_size=1, max_size=40), b16)
def test_protected_probe_layout_agrees(number: int, sealed: bytes, tag: bytes) -> None:
    """A keyed MP_CHALLENGE: code and nonce in the clear, then PN, sealed rest, tag."""
    header = encode_header(PacketType.CONTROL, 0x123, 0, 0, 255)
    fast = header + bytes([ControlCode.MP_CHALLENGE]) + NONCE + number.to_bytes(2, "big")
    fast += sealed + tag
    parsed = schema.ProtectedProbe.parse(fast)
    assert (parsed.code, parsed.nonce, parsed.packet_number, parsed.sealed, parsed.tag) == (
        ControlCode.MP_CHALLENGE,
        NONCE,
        number,
        sealed,
        tag,
    )
    assert schema.ProtectedProbe.build(parsed) == fast


PROTOCOL_MD = Path(__file__).resolve().parents[2] / "docs" / "PROTOCOL.md"


def test_the_worked_examples_of_protocol_md_7_8() -> None:
    header = encode_header(PacketType.CONTROL, 0xABD, 0, 0, 255)
    built = [
        header + encode_mp_challenge(NONCE, 1, TOKEN),
        header + encode_mp_response(NONCE, 1, TOKEN, ECHO),
        header + encode_mp_report(MpReportBody(NONCE, 1, 0x123, 0x40, 1000, 600, 150, 0x89ABCDEF)),
        header + encode_mp_abandon(NONCE, 1, 19),
    ]
    text = " ".join(PROTOCOL_MD.read_text(encoding="utf-8").split())
    for datagram in built:
        assert "`" + " ".join(f"{byte:02x}" for byte in datagram) + "`" in text
