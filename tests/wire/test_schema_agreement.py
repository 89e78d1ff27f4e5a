"""The construct declaration (schema of record) and the fast struct codecs agree byte for byte."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tdtp.wire import (
    HEADER_SIZE,
    PN_SIZE,
    PROTECTION_OVERHEAD,
    PROTOCOL_VERSION,
    TAG_SIZE,
    CloseBody,
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
    PathChallengeBody,
    PathResponseBody,
    ResetBody,
    decode_control,
    decode_header,
    encode_close,
    encode_cookie,
    encode_header,
    encode_keepalive,
    encode_message,
    encode_message_ack,
    encode_open,
    encode_open_ack,
    encode_path_challenge,
    encode_path_response,
    encode_reset,
    schema,
)
from tdtp.wire.control import CLOSE_BODY_SIZE, KEEPALIVE_BODY_SIZE, OPEN_BODY_SIZE

HEADER_FIELDS = ("ptype", "seq", "ack", "sack", "hold")
FIELD_RANGES = {"ptype": 4, "seq": 4096, "ack": 4096, "sack": 64, "hold": 256}

headers = st.builds(
    Header,
    st.integers(0, 3),
    st.integers(0, 0xFFF),
    st.integers(0, 0xFFF),
    st.integers(0, 0x3F),
    st.integers(0, 0xFF),
)


def schema_header_fields(raw: bytes) -> Header:
    parsed = schema.Header.parse(raw)
    return Header(*(parsed[name] for name in HEADER_FIELDS))


def schema_header_bytes(header: Header) -> bytes:
    built: bytes = schema.Header.build(header._asdict())
    return built


def check_header_agreement(header: Header) -> None:
    fast = encode_header(*header)
    assert schema_header_bytes(header) == fast
    assert decode_header(fast) == header
    assert schema_header_fields(fast) == header


def test_schema_header_is_five_bytes() -> None:
    assert schema.Header.sizeof() == 5


@pytest.mark.parametrize("field", HEADER_FIELDS)
def test_every_value_of_every_field_agrees(field: str) -> None:
    # Exhaustive per field (4 + 4096 + 4096 + 64 + 256 values), the other fields held at a value
    # with mixed bits so that a shifted or overlapping field would show.
    base = Header(2, 0xA5C, 0x3B6, 0b100101, 0x5A)
    for value in range(FIELD_RANGES[field]):
        check_header_agreement(base._replace(**{field: value}))


@given(headers)
def test_header_agreement_on_random_headers(header: Header) -> None:
    check_header_agreement(header)


@given(st.binary(min_size=5, max_size=5))
def test_every_five_byte_string_parses_identically(raw: bytes) -> None:
    fast = decode_header(raw)
    assert schema_header_fields(raw) == fast
    assert schema_header_bytes(fast) == raw


# Control bodies -----------------------------------------------------------------------------------


def schema_control_bytes(code: int, body: dict[str, Any] | None) -> bytes:
    built: bytes = schema.ControlBody.build({"code": int(code), "body": body})
    return built


u8 = st.integers(0, 0xFF)
u16 = st.integers(0, 0xFFFF)
b8 = st.binary(min_size=8, max_size=8)
b16 = st.binary(min_size=16, max_size=16)
close_codes = st.sampled_from([ControlCode.CLOSE, ControlCode.REJECT])


@given(u8, u8, u8, u16, u16, b16, b8, b16, b16)
def test_open_body_agreement(
    version: int,
    flags: int,
    suite: int,
    max_payload: int,
    attempt: int,
    nonce: bytes,
    key_id: bytes,
    cookie: bytes,
    tag: bytes,
) -> None:
    body = OpenBody(version, flags, suite, max_payload, attempt, nonce, key_id, cookie)
    keyed = bool(flags & OpenFlags.KEYED)
    fast = encode_open(body) + (tag if keyed else b"")
    assert len(fast) == OPEN_BODY_SIZE + (TAG_SIZE if keyed else 0)
    fields = body._asdict() | {"tag": tag if keyed else None}
    assert schema_control_bytes(ControlCode.OPEN, fields) == fast
    parsed = schema.ControlBody.parse(fast)
    assert parsed.code == ControlCode.OPEN
    assert {name: parsed.body[name] for name in fields} == fields
    assert decode_control(fast) == body


@given(u8, u8, u8, u16, u16, b16, b16, b16)
def test_open_ack_body_agreement(
    version: int,
    flags: int,
    suite: int,
    max_payload: int,
    number: int,
    nonce: bytes,
    slave_nonce: bytes,
    tag: bytes,
) -> None:
    body = OpenAckBody(version, flags, suite, max_payload, number, nonce, slave_nonce)
    keyed = bool(flags & OpenFlags.KEYED)
    fast = encode_open_ack(body) + (tag if keyed else b"")
    fields = body._asdict() | {"tag": tag if keyed else None}
    assert schema_control_bytes(ControlCode.OPEN_ACK, fields) == fast
    parsed = schema.ControlBody.parse(fast)
    assert {name: parsed.body[name] for name in fields} == fields
    assert decode_control(fast) == body


@given(b16, b16)
def test_cookie_body_agreement(nonce: bytes, cookie: bytes) -> None:
    fast = encode_cookie(nonce, cookie)
    fields = {"version": PROTOCOL_VERSION, "nonce": nonce, "cookie": cookie}
    assert schema_control_bytes(ControlCode.COOKIE, fields) == fast
    assert decode_control(fast) == CookieBody(PROTOCOL_VERSION, nonce, cookie)


@given(close_codes, b16, u8)
def test_close_body_agreement(code: ControlCode, nonce: bytes, reason: int) -> None:
    fields = {"nonce": nonce, "reason": reason}
    fast = encode_close(code, nonce, reason)
    assert len(fast) == CLOSE_BODY_SIZE == 18
    assert schema_control_bytes(code, fields) == fast
    parsed = schema.ControlBody.parse(fast)
    assert parsed.code == code
    assert {name: parsed.body[name] for name in fields} == fields
    assert decode_control(fast) == CloseBody(code, nonce, reason)


@given(b16, st.lists(b16, max_size=4))
def test_reset_body_agreement(echo: bytes, tags: list[bytes]) -> None:
    fast = encode_reset(echo, tuple(tags))
    assert len(fast) == 17 + 16 * len(tags)
    assert schema_control_bytes(ControlCode.RESET, {"echo": echo, "tags": tags}) == fast
    parsed = schema.ControlBody.parse(fast)
    assert parsed.body.echo == echo and list(parsed.body.tags) == tags
    assert decode_control(fast) == ResetBody(echo, tuple(tags))


@given(b16)
def test_keepalive_body_agreement(nonce: bytes) -> None:
    fast = encode_keepalive(nonce)
    assert len(fast) == KEEPALIVE_BODY_SIZE == 17
    assert schema_control_bytes(ControlCode.KEEPALIVE, {"nonce": nonce}) == fast
    parsed = schema.ControlBody.parse(fast)
    assert parsed.code == ControlCode.KEEPALIVE
    assert parsed.body.nonce == nonce
    assert decode_control(fast) == KeepaliveBody(ControlCode.KEEPALIVE, nonce)


@given(b16, b16)
def test_path_bodies_agreement(token: bytes, nonce: bytes) -> None:
    challenge = encode_path_challenge(token)
    assert schema_control_bytes(ControlCode.PATH_CHALLENGE, {"token": token}) == challenge
    assert decode_control(challenge) == PathChallengeBody(token)
    response = encode_path_response(token, nonce)
    fields = {"token": token, "nonce": nonce}
    assert schema_control_bytes(ControlCode.PATH_RESPONSE, fields) == response
    parsed = schema.ControlBody.parse(response)
    assert (parsed.body.token, parsed.body.nonce) == (token, nonce)
    assert decode_control(response) == PathResponseBody(token, nonce)


@given(b16, u16, u16, st.binary(min_size=1, max_size=300))
def test_message_body_agreement(nonce: bytes, seq: int, ack: int, data: bytes) -> None:
    fast = encode_message(nonce, seq, ack, data)
    assert len(fast) == 21 + len(data)
    fields = {"nonce": nonce, "seq": seq, "ack": ack, "data": data}
    assert schema_control_bytes(ControlCode.MESSAGE, fields) == fast
    parsed = schema.ControlBody.parse(fast)
    body = parsed.body
    assert (parsed.code, body.nonce, body.seq, body.ack, body.data) == (
        ControlCode.MESSAGE,
        nonce,
        seq,
        ack,
        data,
    )
    assert decode_control(fast) == MessageBody(nonce, seq, ack, data)


@given(b16, u16)
def test_message_ack_body_agreement(nonce: bytes, ack: int) -> None:
    fast = encode_message_ack(nonce, ack)
    assert len(fast) == 19
    assert schema_control_bytes(ControlCode.MESSAGE_ACK, {"nonce": nonce, "ack": ack}) == fast
    parsed = schema.ControlBody.parse(fast)
    assert (parsed.body.nonce, parsed.body.ack) == (nonce, ack)
    assert decode_control(fast) == MessageAckBody(nonce, ack)


@given(st.binary(max_size=24))
def test_short_or_long_message_bodies_are_malformed(rest: bytes) -> None:
    """A MESSAGE without a message byte, or a MESSAGE_ACK of any other length, is bad_control."""
    if len(rest) <= 20:
        with pytest.raises(MalformedPacketError):
            decode_control(bytes([ControlCode.MESSAGE]) + rest)
    if len(rest) != 18:
        with pytest.raises(MalformedPacketError):
            decode_control(bytes([ControlCode.MESSAGE_ACK]) + rest)


@given(headers.map(lambda h: h._replace(ptype=2)), u16, st.binary(min_size=5, max_size=40), b16)
def test_protected_message_layout_agrees(
    header: Header, number: int, sealed: bytes, tag: bytes
) -> None:
    """A keyed MESSAGE: the code in the clear after the header, then PN, sealed body, tag."""
    fast = encode_header(*header) + bytes([ControlCode.MESSAGE]) + number.to_bytes(2, "big")
    fast += sealed + tag
    parsed = schema.ProtectedControl.parse(fast)
    assert (parsed.code, parsed.packet_number, parsed.sealed) == (
        ControlCode.MESSAGE,
        number,
        sealed,
    )
    assert schema.ProtectedControl.build(parsed) == fast


@given(st.binary(min_size=OPEN_BODY_SIZE - 1, max_size=OPEN_BODY_SIZE - 1), st.binary(max_size=16))
def test_arbitrary_open_bodies_parse_identically(rest: bytes, tail: bytes) -> None:
    raw = bytes([ControlCode.OPEN]) + rest + tail
    try:
        fast = decode_control(raw)
    except MalformedPacketError:
        keyed = bool(rest[1] & OpenFlags.KEYED)
        assert len(tail) != (TAG_SIZE if keyed else 0)
        return
    assert isinstance(fast, OpenBody)
    parsed = schema.ControlBody.parse(raw)
    assert tuple(parsed.body[name] for name in OpenBody._fields) == tuple(fast)
    assert encode_open(fast) + tail == raw


@given(close_codes, st.binary(min_size=17, max_size=17))
def test_arbitrary_close_bodies_parse_identically(code: ControlCode, rest: bytes) -> None:
    raw = bytes([code]) + rest
    fast = decode_control(raw)
    assert isinstance(fast, CloseBody)
    parsed = schema.ControlBody.parse(raw)
    assert (parsed.code, parsed.body.nonce, parsed.body.reason) == (code, fast.nonce, fast.reason)
    assert encode_close(*fast) == raw


# The keyed layout ----------------------------------------------------------------------------------


@given(headers.map(lambda h: h._replace(ptype=0)), u16, st.binary(max_size=64), b16)
def test_protected_data_layout_agrees(
    header: Header, number: int, sealed: bytes, tag: bytes
) -> None:
    fast = encode_header(*header) + number.to_bytes(PN_SIZE, "big") + sealed + tag
    assert len(fast) == HEADER_SIZE + PROTECTION_OVERHEAD + len(sealed)
    parsed = schema.ProtectedData.parse(fast)
    assert decode_header(fast) == Header(*(parsed.header[name] for name in HEADER_FIELDS))
    assert (parsed.packet_number, parsed.sealed, parsed.tag) == (number, sealed, tag)
    assert schema.ProtectedData.build(parsed) == fast


@given(headers.map(lambda h: h._replace(ptype=2)), u16, st.binary(max_size=17), b16)
def test_protected_control_layout_agrees(
    header: Header, number: int, sealed: bytes, tag: bytes
) -> None:
    fast = encode_header(*header) + bytes([ControlCode.CLOSE]) + number.to_bytes(2, "big")
    fast += sealed + tag
    parsed = schema.ProtectedControl.parse(fast)
    assert (parsed.code, parsed.packet_number, parsed.sealed) == (ControlCode.CLOSE, number, sealed)
    assert schema.ProtectedControl.build(parsed) == fast
