"""The construct declaration (schema of record) and the fast struct codecs agree byte for byte."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tdtp.wire import (
    CloseBody,
    ControlCode,
    Header,
    KeepaliveBody,
    OpenBody,
    decode_control,
    decode_header,
    encode_close,
    encode_header,
    encode_keepalive,
    encode_open,
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
u8 = st.integers(0, 0xFF)
u16 = st.integers(0, 0xFFFF)
u64 = st.integers(0, 2**64 - 1)
open_codes = st.sampled_from([ControlCode.OPEN, ControlCode.OPEN_ACK])
close_codes = st.sampled_from([ControlCode.CLOSE, ControlCode.REJECT])


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


@given(open_codes, u8, u8, u64, u16)
def test_open_body_agreement(
    code: ControlCode, version: int, flags: int, nonce: int, max_payload: int
) -> None:
    fields = {"version": version, "flags": flags, "nonce": nonce, "max_payload": max_payload}
    fast = encode_open(code, version, flags, nonce, max_payload)
    assert len(fast) == OPEN_BODY_SIZE == 13
    assert schema_control_bytes(code, fields) == fast
    parsed = schema.ControlBody.parse(fast)
    assert parsed.code == code
    assert {name: parsed.body[name] for name in fields} == fields
    assert decode_control(fast) == OpenBody(code, version, flags, nonce, max_payload)


@given(close_codes, u64, u8)
def test_close_body_agreement(code: ControlCode, nonce: int, reason: int) -> None:
    fields = {"nonce": nonce, "reason": reason}
    fast = encode_close(code, nonce, reason)
    assert len(fast) == CLOSE_BODY_SIZE == 10
    assert schema_control_bytes(code, fields) == fast
    parsed = schema.ControlBody.parse(fast)
    assert parsed.code == code
    assert {name: parsed.body[name] for name in fields} == fields
    assert decode_control(fast) == CloseBody(code, nonce, reason)


def test_keepalive_body_agreement() -> None:
    fast = encode_keepalive()
    assert len(fast) == KEEPALIVE_BODY_SIZE == 1
    assert schema_control_bytes(ControlCode.KEEPALIVE, None) == fast
    assert schema.ControlBody.parse(fast).code == ControlCode.KEEPALIVE
    assert decode_control(fast) == KeepaliveBody(ControlCode.KEEPALIVE)


@given(open_codes, st.binary(min_size=12, max_size=12))
def test_arbitrary_open_bodies_parse_identically(code: ControlCode, rest: bytes) -> None:
    raw = bytes([code]) + rest
    fast = decode_control(raw)
    assert isinstance(fast, OpenBody)
    parsed = schema.ControlBody.parse(raw)
    assert (parsed.code, parsed.body.version, parsed.body.flags) == (code, fast.version, fast.flags)
    assert (parsed.body.nonce, parsed.body.max_payload) == (fast.nonce, fast.max_payload)
    assert encode_open(*fast) == raw


@given(close_codes, st.binary(min_size=9, max_size=9))
def test_arbitrary_close_bodies_parse_identically(code: ControlCode, rest: bytes) -> None:
    raw = bytes([code]) + rest
    fast = decode_control(raw)
    assert isinstance(fast, CloseBody)
    parsed = schema.ControlBody.parse(raw)
    assert (parsed.code, parsed.body.nonce, parsed.body.reason) == (code, fast.nonce, fast.reason)
    assert encode_close(*fast) == raw
