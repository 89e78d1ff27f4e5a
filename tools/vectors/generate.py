"""Generate the TDTP version 4 conformance vectors in tests/vectors/ (see tests/vectors/README.md).

    python tools/vectors/generate.py            # rewrite tests/vectors/tdtp-v4-*.json
    python tools/vectors/generate.py --check    # exit 1 if the committed files differ

The expected values come from tdtp, the reference implementation, except where the specification
gives plain arithmetic (header bit layout, HOLD codes, 12-bit expansion): those are computed here with
integers, independently, and the script stops if tdtp disagrees. Every input is fixed, so the output
is the same on every run. The test suite never runs this script: it checks the committed files.
"""

from __future__ import annotations

import argparse
import hmac
import json
import random
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from tdtp.protection.derivation import (  # noqa: E402  # noqa: E402
    derive_key_id,
    derive_open_secret,
    derive_reset_key,
    derive_session_secrets,
    reset_tag,
)
from tdtp.protection.keys import PresharedKey  # noqa: E402
from tdtp.protection.packet_protection import Direction, PacketOpener, PacketSealer  # noqa: E402
from tdtp.rendezvous.relay import RelayCore  # noqa: E402
from tdtp.rendezvous.settings import meeting  # noqa: E402
from tdtp.session.receive_window import ReceiveWindow  # noqa: E402
from tdtp.session.recovery import loss_delay_of  # noqa: E402
from tdtp.session.rtt import RttEstimator  # noqa: E402
from tdtp.session.sent_log import LostPacket, SentPacketLog  # noqa: E402
from tdtp.session.stats import DropReason  # noqa: E402
from tdtp.wire import PROTOCOL_VERSION as WIRE_VERSION  # noqa: E402
from tdtp.wire import (  # noqa: E402
    CipherSuite,
    CloseReason,
    ControlCode,
    MpReportBody,
    OpenAckBody,
    OpenBody,
    decode_control,
    decode_header,
    decode_hold,
    encode_close,
    encode_cookie,
    encode_header,
    encode_hold,
    encode_keepalive,
    encode_message,
    encode_message_ack,
    encode_mp_abandon,
    encode_mp_challenge,
    encode_mp_report,
    encode_mp_response,
    encode_open,
    encode_open_ack,
    encode_path_challenge,
    encode_path_response,
    encode_reset,
    encode_timestamp,
    expand_seq,
)
from tdtp.wire.errors import MalformedPacketError  # noqa: E402
from tdtp.wire.header import HEADER_SIZE  # noqa: E402
from tdtp.wire.rendezvous import (  # noqa: E402
    PROBE,
    PROBE_ACK,
    ReferralBody,
    ReferralKind,
    RegisterBody,
    decode_referral,
    decode_register,
    encode_probe,
    encode_referral,
    encode_register,
)

sys.path.insert(0, str(ROOT / "tests" / "vectors"))
from endpoint_scripts import (  # noqa: E402  (beside this file)
    COOKIE_BYTES,
    MASTER_ISN,
    MASTER_NONCE,
    PSK,
    SLAVE_ISN,
    SLAVE_NONCE,
    all_scripts,
)
from server_scripts import all_server_scripts  # noqa: E402  (beside this file)

from tdtp_adapter import ADDRESSES, ScriptRunner, ServerRunner  # noqa: E402  (tests/vectors/)

MP_TOKEN = bytes.fromhex("0102030405060708")
FORMAT = "tdtp-conformance-vectors"
FORMAT_VERSION = 1
PROTOCOL_VERSION = WIRE_VERSION
OUT = ROOT / "tests" / "vectors"


def _file(suite: str, description: str, vectors: dict[str, Any]) -> dict[str, Any]:
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "protocol_version": PROTOCOL_VERSION,
        "suite": suite,
        "description": description,
        **vectors,
    }


def _check(condition: bool, what: str) -> None:
    if not condition:
        raise SystemExit(f"generate.py: tdtp disagrees with the specification: {what}")


# ---------------------------------------------------------------------------- header


def _header_word(ptype: int, seq: int, ack: int, sack: int, hold: int) -> bytes:
    """Section 2, by hand: W = TYPE << 38 | SEQ << 26 | ACK << 14 | SACK << 8 | HOLD."""
    word = ptype << 38 | (seq & 0xFFF) << 26 | (ack & 0xFFF) << 14 | sack << 8 | hold
    return word.to_bytes(5, "big")


def header_vectors() -> dict[str, Any]:
    rng = random.Random(2)
    cases: list[tuple[str, tuple[int, int, int, int, int]]] = [
        ("worked example 7.1: DATA with a piggybacked ACK", (0, 0x0ABC, 0x0123, 0b101010, 31)),
        ("worked example 7.3: stand-alone ACK", (1, 0x0ABD, 0x0124, 0b111111, 110)),
        ("worked example 7.2: OPEN header", (2, MASTER_ISN, 0, 0, 255)),
        ("all zero", (0, 0, 0, 0, 0)),
        ("all ones: TYPE 3 (reserved) is still a valid header to decode", (3, 4095, 4095, 63, 255)),
        ("SEQ only", (0, 4095, 0, 0, 0)),
        ("ACK only", (0, 0, 4095, 0, 0)),
        ("SACK only", (0, 0, 0, 63, 0)),
        ("HOLD saturated", (1, 1, 2, 3, 254)),
        ("single bits of SEQ and ACK", (2, 0x801, 0x001, 0b000001, 1)),
    ]
    cases += [
        (
            f"random {i}",
            (
                rng.randrange(4),
                rng.randrange(4096),
                rng.randrange(4096),
                rng.randrange(64),
                rng.randrange(256),
            ),
        )
        for i in range(12)
    ]
    valid = []
    for name, (ptype, seq, ack, sack, hold) in cases:
        raw = _header_word(ptype, seq, ack, sack, hold)
        _check(encode_header(ptype, seq, ack, sack, hold) == raw, f"header {name}")
        _check(tuple(decode_header(raw)) == (ptype, seq, ack, sack, hold), f"decode {name}")
        valid.append(
            {
                "name": name,
                "hex": raw.hex(),
                "type": ptype,
                "seq": seq,
                "ack": ack,
                "sack": sack,
                "hold": hold,
            }
        )
    truncated = [
        {"name": f"{n} bytes", "hex": bytes(range(n)).hex(), "error": "truncated"} for n in range(5)
    ]
    return _file(
        "header",
        "The 5-byte base header (section 2): each datagram's first five bytes and the fields they "
        "hold. Decoding ignores anything after byte 5; fewer than 5 bytes is 'truncated'.",
        {"valid": valid, "invalid": truncated},
    )


# ---------------------------------------------------------------------------- hold


def _hold_units(code: int) -> int:
    exponent, mantissa = code >> 5, code & 31
    return mantissa if exponent == 0 else (32 + mantissa) << (exponent - 1)


def _encode_hold_ns(ns: int) -> int:
    """Section 3.4 with integers: the largest code 0..253 not above the hold; 254 from 31.744 ms."""
    if ns <= 0:
        return 0
    if ns >= _hold_units(254) * 8000:
        return 254
    return max(code for code in range(254) if _hold_units(code) * 8000 <= ns)


def hold_vectors() -> dict[str, Any]:
    decode = []
    for code in range(256):
        if code == 254:
            decode.append({"code": code, "hold_ns": None, "meaning": "saturated"})
        elif code == 255:
            decode.append({"code": code, "hold_ns": None, "meaning": "no_ack"})
        else:
            ns = _hold_units(code) * 8000
            decoded = decode_hold(code)
            _check(decoded is not None and round(decoded * 1e9) == ns, f"decode hold {code}")
            decode.append({"code": code, "hold_ns": ns})
    points = [
        -1_000_000,
        0,
        1,
        7_999,
        8_000,
        248_000,
        250_000,
        255_999,
        256_000,
        504_000,
        511_999,
        512_000,
        1_000_000,
        1_500_000,
        2_047_999,
        2_048_000,
        20_000_000,
        31_231_999,
        31_232_000,
        31_500_000,
        31_743_999,
        31_744_000,
        31_744_001,
        100_000_000,
        1_000_000_000,
    ]
    rng = random.Random(3)
    points += sorted(rng.randrange(0, 32_000_000) for _ in range(40))
    encode = []
    for ns in points:
        code = _encode_hold_ns(ns)
        _check(encode_hold(ns / 1e9) == code, f"encode hold {ns} ns")
        encode.append({"hold_ns": ns, "code": code})
    return _file(
        "hold",
        "HOLD, the 8-bit mini-float of section 3.4, in integer nanoseconds: every code's value "
        "(254 saturated and 255 no acknowledgement carry none), and holds with the code a sender "
        "must encode (round down; 254 from 31.744 ms; zero or negative is 0).",
        {"decode": decode, "encode": encode},
    )


# ---------------------------------------------------------------------------- sequence numbers


def _expand_by_hand(truncated: int, expected: int) -> int:
    """Section 3.1: the candidate nearest to ``expected``; the window is [expected - 2048,
    expected + 2047]."""
    low = expected - 2048
    return low + ((truncated - low) % 4096)


def seqnum_vectors() -> dict[str, Any]:
    cases = [
        (0, 0),
        (1, 0),
        (4095, 0),
        (0, 4095),
        (0, 4096),
        (2047, 0),
        (2048, 0),
        (2049, 0),
        (100, 5000),
        (4000, 8200),
        (5, 8190),
        (0xABC, 0x10ABB),
    ]
    rng = random.Random(4)
    cases += [(rng.randrange(4096), rng.randrange(100_000)) for _ in range(20)]
    expand = []
    for truncated, expected in cases:
        full = _expand_by_hand(truncated, expected)
        _check(expand_seq(truncated, expected) == full, f"expand {truncated} near {expected}")
        expand.append({"truncated": truncated, "expected": expected, "full": full})
    # The sender's ACK expansion: first_seq, packets sent, largest acknowledged, 12-bit ACK.
    ack_cases = [
        ("repeat of the largest acknowledged", 100, 50, 120, 120 & 0xFFF),
        ("newly acknowledged, ahead", 100, 50, 120, 140),
        ("the newest packet sent", 100, 50, 120, 149),
        ("never sent: optimistic", 100, 50, 120, 150),
        ("before the first packet: optimistic", 100, 50, None, 99),
        ("across the 12-bit wrap", 4090, 20, 4095, (4100) & 0xFFF),
        ("reordered feedback, below the largest", 4000, 600, 4500, 4450 & 0xFFF),
        ("a jump of 3000 (reverse path lost many ACKs)", 0, 4000, 500, 3500),
    ]
    ack_expand = []
    for name, first, count, largest, ack in ack_cases:
        log = SentPacketLog(first, reorder_threshold=3, max_tracked=100_000)
        lost: list[LostPacket] = []
        for i in range(count):
            log.on_sent(i * 0.001, 10, lost)
        if largest is not None:
            log.on_ack(largest, 0, None, 1.0)
        full = log.expand_ack(ack, None, 1.0, 0.1)
        ack_expand.append(
            {
                "name": name,
                "first_seq": first,
                "packets_sent": count,
                "largest_acked": largest,
                "ack": ack,
                "full": full,
                "optimistic": full is None,
            }
        )
    return _file(
        "seqnum",
        "12-bit sequence numbers (section 3.1). 'expand': the full number nearest to 'expected' "
        "with these 12 bits (the receiver expands SEQ against highest received + 1). "
        "'ack_expand': how a sender that sent packets first_seq .. first_seq + packets_sent - 1 "
        "and has 'largest_acked' (null: nothing acknowledged yet) reads a 12-bit ACK, or that it is "
        "optimistic (names a packet never sent: the datagram is dropped).",
        {"expand": expand, "ack_expand": ack_expand},
    )


# ---------------------------------------------------------------------------- control bodies


def _control_fields(body: object) -> dict[str, Any]:
    fields: dict[str, Any] = {}
    for name, value in body._asdict().items():  # type: ignore[attr-defined]
        if isinstance(value, tuple):  # a RESET's tags
            fields[name] = [tag.hex() for tag in value]
        else:
            fields[name] = value.hex() if isinstance(value, bytes) else int(value)
    return fields


def control_vectors() -> dict[str, Any]:
    header = encode_header(2, MASTER_ISN, 0, 0, 255).hex()
    bodies: list[tuple[str, bytes]] = [
        (
            "OPEN, first attempt (7.2)",
            encode_open(OpenBody(WIRE_VERSION, 0, 0, 1200, 0, MASTER_NONCE, bytes(8), bytes(16))),
        ),
        (
            "OPEN with the cookie, separate ACKs",
            encode_open(OpenBody(WIRE_VERSION, 1, 0, 100, 1, MASTER_NONCE, bytes(8), COOKIE_BYTES)),
        ),
        (
            "keyed OPEN (flags KEYED | ENCRYPTED, suite 1): the tag is 16 more bytes",
            encode_open(
                OpenBody(
                    WIRE_VERSION,
                    6,
                    1,
                    1200,
                    1,
                    MASTER_NONCE,
                    bytes.fromhex("eb494c5fa44b9c55"),
                    bytes(16),
                )
            )
            + bytes(range(16)),
        ),
        (
            "OPEN_ACK (7.2)",
            encode_open_ack(OpenAckBody(WIRE_VERSION, 1, 0, 100, 0, MASTER_NONCE, SLAVE_NONCE)),
        ),
        (
            "keyed OPEN_ACK, packet number 0",
            encode_open_ack(OpenAckBody(WIRE_VERSION, 2, 2, 1200, 0, MASTER_NONCE, SLAVE_NONCE))
            + bytes(16),
        ),
        ("COOKIE (7.2)", encode_cookie(MASTER_NONCE, COOKIE_BYTES)),
        ("KEEPALIVE (the master's nonce)", encode_keepalive(MASTER_NONCE)),
        ("PATH_CHALLENGE (the cookie's format)", encode_path_challenge(COOKIE_BYTES)),
        ("PATH_RESPONSE", encode_path_response(COOKIE_BYTES, MASTER_NONCE)),
        ("CLOSE NORMAL", encode_close(ControlCode.CLOSE, MASTER_NONCE, CloseReason.NORMAL)),
        (
            "MESSAGE E-STOP, number 0xFFFF, next expected 0xF0C4 (7.7)",
            encode_message(MASTER_NONCE, 0xFFFF, 0xF0C4, b"E-STOP"),
        ),
        (
            "MESSAGE_ACK, next expected 0x0000 (past the wrap)",
            encode_message_ack(MASTER_NONCE, 0),
        ),
        ("CLOSE with an unknown reason 200", encode_close(ControlCode.CLOSE, MASTER_NONCE, 200)),
        (
            "CLOSE RESTARTING (5.2: the sender will be back soon)",
            encode_close(ControlCode.CLOSE, MASTER_NONCE, CloseReason.RESTARTING),
        ),
        (
            "CLOSE EVICTED (5.1 rule 2.7: the slot went to another master)",
            encode_close(ControlCode.CLOSE, MASTER_NONCE, CloseReason.EVICTED),
        ),
        ("REJECT BUSY", encode_close(ControlCode.REJECT, MASTER_NONCE, CloseReason.BUSY)),
        (
            "RESET, unkeyed: the first 16 bytes of the DATA it answers (7.6)",
            encode_reset(bytes.fromhex("2af048ea1f") + bytes(range(11))),
        ),
        (
            "RESET, keyed: the echo and two tags (a slave holding two keys)",
            encode_reset(bytes(range(16)), (bytes(range(16, 32)), bytes(range(32, 48)))),
        ),
        (
            "OPEN asking for a multipath session (flag MULTIPATH, 0x40)",
            encode_open(
                OpenBody(WIRE_VERSION, 0x40, 0, 1200, 0, MASTER_NONCE, bytes(8), bytes(16))
            ),
        ),
        ("MP_CHALLENGE on path 1", encode_mp_challenge(MASTER_NONCE, 1, MP_TOKEN)),
        (
            "MP_RESPONSE on path 1: the echo and a token of the responder's",
            encode_mp_response(MASTER_NONCE, 1, MP_TOKEN, MP_TOKEN[::-1]),
        ),
        (
            "MP_RESPONSE with no token of its own (zeros)",
            encode_mp_response(MASTER_NONCE, 1, MP_TOKEN, bytes(8)),
        ),
        (
            "MP_REPORT for path 2: the nonce, newest 0xabc held 512 us, 1000 received, 600 first, lag 15 ms",
            encode_mp_report(
                MpReportBody(MASTER_NONCE, 2, 0xABC, 0x40, 1000, 600, 150, 0x89ABCDEF)
            ),
        ),
        (
            "MP_ABANDON of path 1, PATH_CLOSED",
            encode_mp_abandon(MASTER_NONCE, 1, CloseReason.PATH_CLOSED),
        ),
        (
            "OPEN asking for send timestamps (flag TIMESTAMPS, 0x20)",
            encode_open(
                OpenBody(WIRE_VERSION, 0x20, 0, 1200, 0, MASTER_NONCE, bytes(8), bytes(16))
            ),
        ),
        (
            "TIMESTAMP: the sender's clock 0x89abcdef us (its header carries an ACK's fields)",
            encode_timestamp(ControlCode.TIMESTAMP, 0x89ABCDEF),
        ),
        (
            "TIMED_DATA: the clock 1 us past a wrap, then a 3-byte sample",
            encode_timestamp(ControlCode.TIMED_DATA, 1) + bytes(range(3)),
        ),
    ]
    valid = []
    for name, body in bodies:
        decoded = decode_control(body)
        valid.append(
            {
                "name": name,
                "body_hex": body.hex(),
                "datagram_hex": header + body.hex(),
                "code": ControlCode(body[0]).name,
                "fields": {k: v for k, v in _control_fields(decoded).items() if k != "code"},
            }
        )
    open_body = encode_open(
        OpenBody(WIRE_VERSION, 0, 0, 1200, 0, MASTER_NONCE, bytes(8), bytes(16))
    )
    broken: list[tuple[str, bytes]] = [
        ("no code byte", b""),
        ("code 0", b"\x00"),
        ("code 12", b"\x0c" + bytes(17)),
        ("MESSAGE without a message", encode_message(MASTER_NONCE, 1, 2, b"")),
        ("MESSAGE without its nonce (version 3's layout)", b"\x0a\x00\x01\x00\x02E-STOP"[:21]),
        ("MESSAGE_ACK one byte long", encode_message_ack(MASTER_NONCE, 1) + b"\x00"),
        ("MESSAGE_ACK one byte short", encode_message_ack(MASTER_NONCE, 1)[:-1]),
        ("MESSAGE_ACK without its nonce (version 3's layout)", b"\x0b\x00\x01"),
        ("RESET one byte short of its echo", b"\x07" + bytes(15)),
        ("RESET with a partial tag", b"\x07" + bytes(16 + 15)),
        ("code 255", b"\xff"),
        ("OPEN one byte short", open_body[:-1]),
        ("OPEN one byte long", open_body + b"\x00"),
        ("OPEN with KEYED but no tag", open_body[:2] + b"\x02" + open_body[3:]),
        ("OPEN too short to hold its flags", b"\x01\x02"),
        (
            "OPEN_ACK without its last byte",
            encode_open_ack(OpenAckBody(WIRE_VERSION, 0, 0, 100, 0, MASTER_NONCE, SLAVE_NONCE))[
                :-1
            ],
        ),
        ("COOKIE one byte long", encode_cookie(MASTER_NONCE, bytes(16)) + b"\x00"),
        ("KEEPALIVE without its nonce", b"\x03"),
        ("KEEPALIVE one byte long", encode_keepalive(MASTER_NONCE) + b"\x00"),
        ("PATH_CHALLENGE one byte short", encode_path_challenge(COOKIE_BYTES)[:-1]),
        (
            "PATH_RESPONSE without the nonce",
            encode_path_challenge(COOKIE_BYTES)[:1].replace(b"\x08", b"\x09") + COOKIE_BYTES,
        ),
        ("CLOSE without its reason", encode_close(ControlCode.CLOSE, MASTER_NONCE, 0)[:-1]),
        ("code 14 (unassigned)", b"\x0e" + bytes(20)),
        ("TIMESTAMP one byte short", encode_timestamp(ControlCode.TIMESTAMP, 7)[:-1]),
        ("TIMESTAMP one byte long", encode_timestamp(ControlCode.TIMESTAMP, 7) + b"\x00"),
        ("TIMED_DATA without a sample", encode_timestamp(ControlCode.TIMED_DATA, 7)),
        ("code 21 (REGISTER: never a session's, and too short)", b"\x15" + bytes(20)),
        ("code 25 (unassigned)", b"\x19" + bytes(20)),
        ("MP_CHALLENGE one byte short", encode_mp_challenge(MASTER_NONCE, 1, MP_TOKEN)[:-1]),
        (
            "MP_RESPONSE without its own token",
            encode_mp_response(MASTER_NONCE, 1, MP_TOKEN, MP_TOKEN)[:-8],
        ),
        (
            "MP_REPORT one byte long",
            encode_mp_report(MpReportBody(MASTER_NONCE, 1, 0, 0, 0, 0, 0, 0)) + b"\x00",
        ),
        ("MP_ABANDON without its reason", encode_mp_abandon(MASTER_NONCE, 1, 19)[:-1]),
        ("REJECT one byte long", encode_close(ControlCode.REJECT, MASTER_NONCE, 0) + b"\x00"),
    ]
    invalid = []
    for name, body in broken:
        try:
            decode_control(body)
        except MalformedPacketError as exc:
            _check(exc.reason == "bad_control", f"control {name}")
        else:
            _check(False, f"control {name} decoded")
        invalid.append({"name": name, "body_hex": body.hex(), "error": "bad_control"})
    return _file(
        "control",
        "CONTROL bodies (section 4.3): the bytes after the 5-byte header and the fields they "
        "hold (byte strings in hex). Handshake bodies are checked in full; a keyed OPEN or "
        "OPEN_ACK carries a 16-byte tag (not verified here). 'invalid' bodies are 'bad_control'.",
        {"valid": valid, "invalid": invalid},
    )


# ---------------------------------------------------------------------------- receiver


def _receiver_case(name: str, initial: int, events: list[Any]) -> dict[str, Any]:
    """Run a receive window as the connection does in bidirectional mode with its reverse flow
    idle: after every arrival, the ACKs the jump rule and the full rule owe."""
    window = ReceiveWindow(initial)
    out = []
    for event in events:
        if event == "piggyback":
            owed = []
            if window.has_data:
                owed = [[window.highest, window.sack_below(window.highest)]]
                window.mark_reported()
            out.append({"event": "piggyback", "acks": owed})
            continue
        if event == "ack_delay":
            owed = []
            if window.unreported_since is not None:
                owed = [[window.highest, window.sack_below(window.highest)]]
                window.mark_reported()
            out.append({"event": "ack_delay", "acks": owed})
            continue
        seq, at = event if isinstance(event, tuple) else (event, None)
        kind, full, gap = window.on_data(seq & 0xFFF, 0.0 if at is None else at)
        acks = [[held.ack, held.sack] for held in window.take_held()]
        if window.coverage_exhausted():
            acks.append([window.highest, window.sack_below(window.highest)])
            window.mark_reported()
        arrival: dict[str, Any] = {"seq": seq & 0xFFF}
        if at is not None:
            arrival["at"] = at
        out.append({**arrival, "kind": kind.value, "full": full, "gap": gap, "acks": acks})
    return {"name": name, "initial_seq": initial, "events": out}


def receiver_vectors() -> dict[str, Any]:
    rng = random.Random(5)
    random_loss = [s for s in range(300, 500) if rng.random() > 0.1]
    cases = [
        _receiver_case("in order, reverse flow idle", 100, [*range(100, 121), "ack_delay"]),
        _receiver_case(
            "L+7 lost: the jump rule reports L+1..L+6 first", 0, [*range(0, 6), *range(7, 20)]
        ),
        _receiver_case("first packets lost", 50, [*range(60, 70), "ack_delay"]),
        _receiver_case(
            "a burst of 10 lost: the 4 oldest cannot be described",
            0,
            [0, 1, 2, 13, 14, 15, "ack_delay"],
        ),
        _receiver_case(
            "a late packet within 6 of the highest is reported by the next ACK of the highest",
            0,
            [
                0,
                1,
                3,
                4,
                "piggyback",
                2,
                5,
                6,
                7,
                8,
                9,
                10,
                11,
                12,
                13,
                14,
                15,
                16,
                17,
                "ack_delay",
            ],
        ),
        _receiver_case("duplicate", 7, [7, 8, 8, 9, "ack_delay"]),
        _receiver_case(
            "stale: 64 or more below the highest", 0, [*range(0, 70), 6, 5, 69, "ack_delay"]
        ),
        _receiver_case(
            "across the 12-bit wrap", 4090, [4090, 4091, 4093, 4095, 4096, 4100, "ack_delay"]
        ),
        _receiver_case(
            "piggybacked reports clear the pending range",
            0,
            [0, 1, "piggyback", 2, 3, 4, "piggyback", 5, 12, "piggyback", 30, "ack_delay"],
        ),
        _receiver_case(
            "a 3000-packet burst: three stale, then re-anchored one wrap ahead",
            0,
            [0, 1, 2, *range(3003, 3010), "ack_delay"],
        ),
        _receiver_case(
            "late rule: a late packet more than 6 below the highest gets a stand-alone ACK naming "
            "it (3.2)",
            0,
            [0, 1, *range(3, 13), 2, "ack_delay"],
        ),
        _receiver_case(
            "three consecutive stale numbers arriving between live packets: no re-anchoring (3.1)",
            0,
            [*range(0, 10), 3000, 10, 3001, 11, 3002, 12, "ack_delay"],
        ),
        _receiver_case(
            "a stale run broken by another stale number starts again at 1 (3.1)",
            0,
            [*range(0, 10), 3000, 3001, 3005, 3006, 3007, 3008, "ack_delay"],
        ),
        _receiver_case(
            "after a silence of 0.1 s (the silence_timeout) three consecutive numbers inside the "
            "window below the newest re-anchor it one wrap ahead; without the silence they are "
            "duplicates (3.1)",
            0,
            [
                *[(n, round(0.001 * n, 6)) for n in range(0, 20)],
                (5, 0.02),
                (6, 0.021),
                (7, 0.022),
                (8, 0.2),
                (9, 0.201),
                (10, 0.202),
                (11, 0.203),
                "ack_delay",
            ],
        ),
        _receiver_case("10 % random loss", 300, [*random_loss, "ack_delay"]),
    ]
    return _file(
        "receiver",
        "The receiver (sections 3.1, 3.2, 5.3, 5.5) of a keyed session (no far-ahead check) in "
        "bidirectional mode with its reverse flow idle and a silence_timeout of 0.1 s. Events in "
        "order: an arriving DATA packet's 12-bit 'seq', arriving 'at' seconds (0 when absent; "
        "only the re-anchoring after a silence looks at it), with its arrival kind new, late, "
        "duplicate or stale, its full number, the gap it left, and the stand-alone ACKs owed "
        "right after it, [ack, sack] with ack as a full number, a jump-rule or late-rule ACK "
        "first, then a full-rule ACK; 'piggyback' (an acknowledgement of the highest leaves in a "
        "DATA or KEEPALIVE: the [ack, sack] it carries) or 'ack_delay' (ack_delay passed: the ACK "
        "owed, if any). The first packet's full number is initial_seq.",
        {"cases": cases},
    )


# ---------------------------------------------------------------------------- sender


def _sender_case(
    name: str,
    first: int,
    sends: list[float],
    acks: list[tuple[float, int, int, int] | tuple[float, str]],
    *,
    ack_delay: float = 0.020,
    initial_rtt: float = 0.1,
) -> dict[str, Any]:
    log = SentPacketLog(first, reorder_threshold=3, max_tracked=16384)
    rtt = RttEstimator(initial_rtt)
    sent_out = []
    lost: list[LostPacket] = []
    for at in sends:
        sent_out.append({"at": at, "seq": log.on_sent(at, 100, lost)})

    def spec_loss_delay() -> float:
        """Section 5.4 by hand: srtt + max(reorder window, 4 rttvar, 1 ms) + ack_delay, the reorder
        window min(k min_rtt / 4, srtt) only once there is an RTT sample."""
        margin = max(4.0 * rtt.rttvar, 0.001)
        if rtt.has_sample:
            margin = max(margin, min(log.reorder_window_scale * rtt.min_rtt / 4.0, rtt.srtt))
        delay = rtt.srtt + margin + ack_delay
        tdtp_delay = loss_delay_of(rtt, log.reorder_window_scale, ack_delay)
        _check(abs(delay - tdtp_delay) <= 1e-12, f"loss delay in {name!r}")
        return tdtp_delay

    # Computed at the start and after each RTT sample only (section 5.4).
    delay = spec_loss_delay()
    events = []
    for item in acks:
        if item[1] == "timer":
            at = item[0]
            lost = []
            log.detect_losses(at, delay, lost)
            events.append(
                {
                    "at": at,
                    "event": "timer",
                    "expect": {
                        "lost": [p.seq for p in lost],
                        "unknown_total": log.unknown,
                        "loss_delay": delay,
                        "loss_timer": log.loss_deadline(delay),
                    },
                }
            )
            continue
        at, ack, sack, hold_code = item  # type: ignore[misc]
        hold = decode_hold(hold_code)
        full = log.expand_ack(ack, hold, at, rtt.srtt)
        if full is None:
            events.append(
                {
                    "at": at,
                    "ack": ack,
                    "sack": sack,
                    "hold": hold_code,
                    "expect": {"optimistic": True},
                }
            )
            continue
        outcome = log.on_ack(full, sack, hold, at)
        if outcome.rtt_sample is not None:
            rtt.on_sample(outcome.rtt_sample)
            delay = spec_loss_delay()
        lost = []
        log.detect_losses(at, delay, lost)
        events.append(
            {
                "at": at,
                "ack": ack,
                "sack": sack,
                "hold": hold_code,
                "expect": {
                    "optimistic": False,
                    "ack_full": full,
                    "newly_acked": outcome.newly_acked,
                    "rtt_sample": outcome.rtt_sample,
                    "srtt": rtt.srtt,
                    "rttvar": rtt.rttvar,
                    "largest_acked": log.largest_acked,
                    "lost": [p.seq for p in lost],
                    "unknown_total": log.unknown,
                    "spurious": outcome.spurious,
                    "loss_delay": delay,
                    "loss_timer": log.loss_deadline(delay),
                },
            }
        )
    return {
        "name": name,
        "first_seq": first,
        "reorder_threshold": 3,
        "ack_delay": ack_delay,
        "initial_rtt": initial_rtt,
        "sent": sent_out,
        "events": events,
    }


def _ms(n: int, start: float = 0.0) -> list[float]:
    return [round(start + i * 0.001, 6) for i in range(n)]


def sender_vectors() -> dict[str, Any]:
    h1ms = encode_hold(0.001)
    cases = [
        _sender_case(
            "every packet acknowledged in order, one RTT sample per ACK",
            100,
            _ms(10),
            [(0.040 + i * 0.001, 100 + i, 0b111111, 0) for i in range(10)],
        ),
        _sender_case(
            "a packet reported absent is lost when LA is 3 above it",
            0,
            _ms(12),
            [(0.05, 5, 0b111110, 0), (0.051, 6, 0b111101, 0), (0.052, 7, 0b111011, 0)],
        ),
        _sender_case(
            "the time threshold runs from the send time",
            0,
            _ms(3),
            [(0.05, 1, 0b000000, 0), (0.1665, "timer"), (0.1675, "timer")],
        ),
        _sender_case(
            "reported absent after loss_delay has passed since it was sent: lost at once",
            0,
            _ms(3),
            [(0.5, 1, 0b000000, 254)],
        ),
        _sender_case(
            "never covered: unknown, not lost",
            0,
            _ms(20),
            [(0.05, 19, 0b111111, h1ms)],
        ),
        _sender_case(
            "a loss reported received after all: spurious",
            0,
            _ms(10),
            [(0.05, 9, 0b000000, 0), (0.06, 9, 0b100000, 0)],
        ),
        _sender_case(
            "optimistic ACK names a packet never sent",
            4090,
            _ms(5),
            [(0.05, (4094 + 1) & 0xFFF, 0, 0), (0.051, 4094 & 0xFFF, 0b001111, 0)],
        ),
        _sender_case(
            "HOLD 254 and 255: no RTT sample, the ACK still counts",
            0,
            _ms(6),
            [(0.05, 2, 0b000011, 254), (0.051, 3, 0b000111, 254), (0.09, 5, 0b001111, h1ms)],
        ),
        _sender_case(
            "reordered feedback and a repeat",
            0,
            _ms(12),
            [(0.05, 8, 0b111111, 0), (0.051, 6, 0b111111, 0), (0.052, 8, 0b111111, 0)],
        ),
        _sender_case(
            "the reorder window: k grows with a spurious loss, and the loss delay follows at the "
            "next RTT sample",
            0,
            _ms(24),
            [
                *[(0.040 + i * 0.001, i, 0b111111, 0) for i in range(15)],
                (0.056, 16, 0b111110, 0),
                (0.057, 17, 0b111101, 0),
                (0.058, 18, 0b111011, 0),
                (0.0585, 18, 0b111111, 254),
                (0.060, 20, 0b111111, 0),
            ],
        ),
        _sender_case(
            "the RTT sample subtracts the hold",
            0,
            _ms(3),
            [
                (0.1, 0, 0, encode_hold(0.0305)),
                (0.101, 1, 1, encode_hold(0.031)),
                (0.102, 2, 3, encode_hold(0.0316)),
            ],
        ),
    ]
    return _file(
        "sender",
        "The sender's verdicts (section 5.4). 'sent': each DATA packet's send time and full "
        "sequence number. Events in order: an accepted acknowledgement (12-bit 'ack', 'sack', HOLD "
        "code 'hold', arriving 'at') or a 'timer' expiry at 'at', with what must follow: the ACK's "
        "full value or that it is optimistic, packets newly acknowledged, the RTT sample, srtt and "
        "rttvar after it, the largest acknowledged, packets declared lost by this event in order, "
        "the running count of unknown packets, spurious losses, the loss delay in force (computed "
        "at the start and after each RTT sample only), and when the loss timer is due (null: "
        "none). Times in seconds.",
        {"cases": cases},
    )


# ---------------------------------------------------------------------------- keyed


def _reset_tags() -> list[dict[str, Any]]:
    """Keyed RESET tags (section 5.7): HMAC-SHA256(reset_key, echo)[:16]."""
    cases = []
    for psk in (PSK, bytes(range(100, 116))):
        echo = bytes.fromhex("2af048ea1f0001") + bytes(range(9))
        tag = reset_tag(derive_reset_key(psk), echo)
        datagram = encode_header(2, 0, 0, 0, 255) + encode_reset(echo, (tag,))
        cases.append(
            {"psk": psk.hex(), "echo": echo.hex(), "tag": tag.hex(), "datagram": datagram.hex()}
        )
    return cases


def keyed_vectors() -> dict[str, Any]:
    derivations = []
    for suite in (CipherSuite.AES_128_GCM, CipherSuite.CHACHA20_POLY1305):
        for psk in (PSK, bytes(range(100, 116))):
            open_secret = derive_open_secret(psk, MASTER_NONCE, suite)
            session = derive_session_secrets(psk, MASTER_NONCE, SLAVE_NONCE, suite)
            derivations.append(
                {
                    "psk": psk.hex(),
                    "suite": int(suite),
                    "master_nonce": MASTER_NONCE.hex(),
                    "slave_nonce": SLAVE_NONCE.hex(),
                    "key_id": derive_key_id(psk).hex(),
                    "open_key": open_secret.key.hex(),
                    "open_iv": open_secret.iv.hex(),
                    "m2s_key": session.master_to_slave.key.hex(),
                    "m2s_iv": session.master_to_slave.iv.hex(),
                    "s2m_key": session.slave_to_master.key.hex(),
                    "s2m_iv": session.slave_to_master.iv.hex(),
                    "reset_key": derive_reset_key(psk).hex(),
                }
            )
    # The keyed OPEN and OPEN_ACK tags.
    handshake = []
    for suite in (CipherSuite.AES_128_GCM, CipherSuite.CHACHA20_POLY1305):
        key = PresharedKey(PSK)
        for attempt in (0, 1, 65535):
            datagram = encode_header(2, MASTER_ISN, 0, 0, 255) + encode_open(
                OpenBody(
                    WIRE_VERSION,
                    6,
                    int(suite),
                    1200,
                    attempt,
                    MASTER_NONCE,
                    key.key_id,
                    COOKIE_BYTES,
                )
            )
            tagger = Direction(suite, derive_open_secret(PSK, MASTER_NONCE, suite))
            handshake.append(
                {
                    "message": "OPEN",
                    "psk": PSK.hex(),
                    "suite": int(suite),
                    "nonce_counter": attempt,
                    "datagram_without_tag": datagram.hex(),
                    "tag": tagger.tag(attempt, datagram).hex(),
                }
            )
        session = derive_session_secrets(PSK, MASTER_NONCE, SLAVE_NONCE, suite)
        datagram = encode_header(2, SLAVE_ISN, 0, 0, 255) + encode_open_ack(
            OpenAckBody(WIRE_VERSION, 6, int(suite), 1200, 0, MASTER_NONCE, SLAVE_NONCE)
        )
        handshake.append(
            {
                "message": "OPEN_ACK",
                "psk": PSK.hex(),
                "suite": int(suite),
                "nonce_counter": 0,
                "datagram_without_tag": datagram.hex(),
                "tag": Direction(suite, session.slave_to_master).tag(0, datagram).hex(),
            }
        )
    seal = []
    prefixes = [
        ("DATA", encode_header(0, 0x0ABC, 0x0123, 0x2A, 31), b"hello"),
        ("ACK", encode_header(1, 0x0ABD, 0x0124, 0x3F, 110), b""),
        ("KEEPALIVE", encode_header(2, 0x0ABD, 0x0124, 0x01, 0) + b"\x03", MASTER_NONCE),
        (
            "CLOSE",
            encode_header(2, 0x0ABD, 0, 0, 255) + b"\x04",
            encode_close(ControlCode.CLOSE, MASTER_NONCE, CloseReason.NORMAL)[1:],
        ),
        (
            "MP_CHALLENGE: the code and the master's nonce are the 22-byte prefix",
            encode_header(2, 0x0ABD, 0, 0, 255)
            + encode_mp_challenge(MASTER_NONCE, 1, MP_TOKEN)[:17],
            encode_mp_challenge(MASTER_NONCE, 1, MP_TOKEN)[17:],
        ),
        (
            "MP_REPORT",
            encode_header(2, 0x0ABD, 0, 0, 255) + b"\x13",
            encode_mp_report(MpReportBody(MASTER_NONCE, 1, 0x123, 0x40, 7, 5, 3, 0x01020304))[1:],
        ),
    ]
    for suite in (CipherSuite.AES_128_GCM, CipherSuite.CHACHA20_POLY1305):
        session = derive_session_secrets(PSK, MASTER_NONCE, SLAVE_NONCE, suite)
        for encrypt in (True, False):
            for kind, prefix, body in prefixes:
                for number in (1, 70000):
                    sealer = PacketSealer(suite, session.master_to_slave, encrypt=encrypt)
                    sealer.next_number = number
                    seal.append(
                        {
                            "packet": kind,
                            "suite": int(suite),
                            "key": session.master_to_slave.key.hex(),
                            "iv": session.master_to_slave.iv.hex(),
                            "encrypt": encrypt,
                            "packet_number": number,
                            "prefix": prefix.hex(),
                            "body": body.hex(),
                            "datagram": sealer.seal(prefix, body).hex(),
                        }
                    )
    # A receiver's replay window and tag checks over a sequence of datagrams.
    suite = CipherSuite.AES_128_GCM
    session = derive_session_secrets(PSK, MASTER_NONCE, SLAVE_NONCE, suite)
    sealer = PacketSealer(suite, session.master_to_slave, encrypt=True)
    opener = PacketOpener(suite, session.master_to_slave, encrypt=True)
    prefix = encode_header(0, 1, 0, 0, 255)

    def sealed(number: int, body: bytes) -> bytes:
        sealer.next_number = number
        return sealer.seal(prefix, body)

    def forged(datagram: bytes) -> bytes:
        return datagram[:-1] + bytes([datagram[-1] ^ 1])

    script: list[tuple[str, bytes]] = [
        ("first", sealed(0, b"a")),
        ("next", sealed(1, b"b")),
        ("replay of 1", sealed(1, b"b")),
        ("ahead by 99", sealed(100, b"c")),
        ("37 below the highest: inside the window", sealed(63, b"d")),
        ("a forged tag", forged(sealed(64, b"e"))),
        ("the same number, authentic: the forgery did not spend it", sealed(64, b"e")),
        ("63 below the highest: the window's edge", sealed(37, b"f")),
        ("64 below the highest: outside the window", sealed(36, b"g")),
        ("replay of 63", sealed(63, b"d")),
        ("ciphertext altered", sealed(101, b"h")[:7] + b"\x00" + sealed(101, b"h")[8:]),
        ("101 for real", sealed(101, b"h")),
        (
            "65436 ahead, across the 16-bit wrap: 65537 arrives as 0x0001 and is found by the "
            "resynchronisation search (section 5.6)",
            sealed(65537, b"i"),
        ),
        ("the old 1 now reads as 65537: a replay", sealed(1, b"b")),
    ]
    steps = []
    for name, datagram in script:
        body = opener.open(datagram, 5)
        step: dict[str, Any] = {"name": name, "datagram": datagram.hex()}
        if body is None:
            step["verdict"] = opener.failure
        else:
            step["verdict"] = "accepted"
            step["body"] = body.hex()
        step["highest"] = opener.window.highest
        steps.append(step)
    opening = {
        "suite": int(suite),
        "key": session.master_to_slave.key.hex(),
        "iv": session.master_to_slave.iv.hex(),
        "encrypt": True,
        "prefix_size": 5,
        "steps": steps,
    }
    return _file(
        "keyed",
        "Keyed sessions (sections 4.4, 5.6). 'derivations': HKDF-SHA256 outputs for a PSK, suite "
        "and both nonces. 'handshake_tags': the tag of a keyed OPEN (OPEN key, nonce counter = "
        "attempt) and OPEN_ACK (slave-to-master key, nonce counter = its packet number) over the "
        "whole datagram before the tag. 'seal': protected datagrams (prefix, PN, sealed body, "
        "tag). 'opening': a receiver's verdicts over a sequence of datagrams (accepted with the "
        "opened body, replayed, or unauthenticated) and the highest packet number accepted after "
        "each.",
        {
            "derivations": derivations,
            "handshake_tags": handshake,
            "seal": seal,
            "opening": opening,
            "reset_tags": _reset_tags(),
        },
    )


# ---------------------------------------------------------------------------- endpoint scripts


def drop_vectors() -> dict[str, Any]:
    scripts = []
    for script in all_scripts():
        scripts.append(ScriptRunner(script).record())
    covered = {step["expect"]["drop"] for s in scripts for step in s["steps"]} - {None}
    missing = {reason.value for reason in DropReason} - covered
    _check(not missing, f"drop reasons without a vector: {sorted(missing)}")
    return _file(
        "endpoint",
        "Endpoint scripts (sections 5.1, 5.2, 5.5, 5.7, 5.8, 5.10): a fresh endpoint with the "
        "given role, "
        "configuration and random values is fed datagrams (hex, '{cookie}' replaced by the 16 "
        "cookie bytes of the last COOKIE it sent) from named addresses at given times, or told "
        "to connect or close. After each step: the one drop reason it counted (null: taken in), "
        "its state, the samples it delivered, and the control packets it sent, in order. Every "
        "drop reason of section 5.5 appears at least once. Addresses: "
        + ", ".join(f"{name} {host}:{port}" for name, (host, port) in ADDRESSES.items())
        + ".",
        {"scripts": scripts},
    )


def server_vectors() -> dict[str, Any]:
    scripts = [ServerRunner(script).record() for script in all_server_scripts()]
    return _file(
        "server",
        "Server scripts (sections 5.1, 5.7, 5.8, 5.9): one slave serving several masters on one "
        "address, fed datagrams from named addresses at given times. After each step: the drop "
        "reasons counted (by a session, admission or path migration), the sessions by master "
        "address and their states, every datagram sent and to whom, and what the sessions' "
        "applications got. Addresses: "
        + ", ".join(f"{name} {host}:{port}" for name, (host, port) in ADDRESSES.items())
        + ".",
        {"scripts": scripts},
    )


# ---------------------------------------------------------------------------- rendezvous (5.12)


def rendezvous_vectors() -> dict[str, Any]:
    """REGISTER, REFERRAL, PROBE and PROBE_ACK datagrams, the names a pair meets under, probe MACs,
    and what a relay answers (section 5.12)."""
    psk = bytes(range(32))
    names = []
    for label, key, name in (
        ("keyed (the PSK of 7.5), no name", PresharedKey(psk), None),
        ("unkeyed, name 'robot-7'", None, "robot-7"),
        ("keyed (the PSK of 7.5) and name 'robot-7'", PresharedKey(psk), "robot-7"),
    ):
        met = meeting(key, name)
        names.append(
            {
                "name": label,
                "psk_hex": None if key is None else psk.hex(),
                "rendezvous_name": name,
                "rendezvous_id_hex": met.rendezvous_id.hex(),
                "probe_key_hex": met.probe_key.hex(),
            }
        )
    probe_key = meeting(None, "robot-7").probe_key
    token = bytes(range(0x20, 0x30))
    probes = []
    for kind, code, tag in (("PROBE", PROBE, b"P"), ("PROBE_ACK", PROBE_ACK, b"A")):
        for side in (0, 1):
            mac = hmac.digest(probe_key, tag + bytes([side]) + token, "sha256")[:16]
            probes.append(
                {
                    "name": f"{kind} from the {'listener' if side else 'dialer'}",
                    "side": side,
                    "token_hex": token.hex(),
                    "datagram_hex": encode_probe(code, token, mac).hex(),
                }
            )
    rid = meeting(None, "robot-7").rendezvous_id
    nonce = bytes(range(0x40, 0x50))
    registers = [
        (
            "REGISTER, dialer, no cookie yet, no local address",
            RegisterBody(0, nonce, rid, bytes(16), ()),
        ),
        (
            "REGISTER, listener, a cookie, one IPv4 and one IPv6 local address",
            RegisterBody(1, nonce, rid, COOKIE_BYTES, (("192.168.1.2", 7000), ("fe80::1", 7000))),
        ),
        ("REGISTER LEAVE, dialer", RegisterBody(2, nonce, rid, COOKIE_BYTES, ())),
    ]
    referrals = [
        ("COOKIE", ReferralBody(0, 0, nonce, COOKIE_BYTES, 0, None, None, False, ())),
        (
            "WAITING",
            ReferralBody(1, 0, nonce, bytes(16), 30, ("203.0.113.1", 40000), None, False, ()),
        ),
        (
            "PEER: the listener's addresses, told to the dialer",
            ReferralBody(
                2,
                0,
                nonce,
                bytes(16),
                30,
                ("203.0.113.2", 50000),
                ("203.0.113.1", 40000),
                True,
                (("192.168.1.2", 40000),),
            ),
        ),
        (
            "REFUSED RENDEZVOUS_FULL",
            ReferralBody(3, 22, nonce, bytes(16), 0, None, None, False, ()),
        ),
        ("UNKNOWN", ReferralBody(4, 0, bytes(16), bytes(16), 0, None, None, False, ())),
    ]

    def fields(body: Any) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for key, value in body._asdict().items():
            if isinstance(value, bytes):
                out[key] = value.hex()
            elif isinstance(value, tuple) and value and isinstance(value[0], tuple):
                out[key] = [[host, port] for host, port in value]
            elif isinstance(value, tuple):
                out[key] = list(value)
            else:
                out[key] = value
        return out

    valid = []
    for name, body in registers:
        datagram = encode_register(body)
        _check(decode_register(datagram) == body, name)
        valid.append({"name": name, "datagram_hex": datagram.hex(), "fields": fields(body)})
    for name, referral in referrals:
        datagram = encode_referral(referral)
        _check(decode_referral(datagram).kind == referral.kind, name)
        valid.append(
            {"name": f"REFERRAL {name}", "datagram_hex": datagram.hex(), "fields": fields(referral)}
        )
    relay = RelayCore(rng=random.Random(7))
    first = encode_register(RegisterBody(0, nonce, rid, bytes(16), ()))
    replies = relay.receive(first, ("203.0.113.1", 40000), 0.0)
    _check(len(replies) == 1 and len(replies[0][0]) < len(first), "cookie reply")
    relay_answers = [
        {
            "name": "a REGISTER without a cookie: a COOKIE referral, smaller, to its source",
            "datagram_hex": first.hex(),
            "answer_kind": "COOKIE",
            "answer_size": len(replies[0][0]),
        },
        {
            "name": "25 bytes of anything from an address without a registration: UNKNOWN",
            "datagram_hex": bytes(25).hex(),
            "answer_kind": "UNKNOWN",
            "answer_size": len(relay.receive(bytes(25), ("198.51.100.1", 1), 0.0)[0][0]),
        },
        {
            "name": "24 bytes from an address without a registration: nothing",
            "datagram_hex": bytes(24).hex(),
            "answer_kind": None,
            "answer_size": 0,
        },
    ]
    _check(relay.receive(bytes(24), ("198.51.100.1", 2), 0.0) == [], "no answer to 24 bytes")
    odd = bytearray(first)
    odd[HEADER_SIZE + 2] |= 0x80  # a flag bit no version-4 relay knows
    odd[HEADER_SIZE + 3] = 1  # the reserved byte
    other_version = bytearray(first)
    other_version[HEADER_SIZE + 1] = 3
    for index, (name, datagram) in enumerate(
        [
            (
                "a REGISTER with an unknown flag bit and a non-zero reserved byte: both ignored, "
                "a COOKIE referral",
                bytes(odd),
            ),
            ("a REGISTER of version 3: dropped, nothing", bytes(other_version)),
            ("a REGISTER one byte long: malformed, nothing", first + b"\x00"),
            (
                "a REGISTER naming 5 local addresses: malformed, nothing",
                encode_register(RegisterBody(0, nonce, rid, bytes(16), ()))[:-1]
                + b"\x05"
                + bytes((4, 0, 1, 10, 0, 0, 1)) * 5,
            ),
        ]
    ):
        answers = relay.receive(datagram, ("198.51.100.2", 3000 + index), 0.0)
        relay_answers.append(
            {
                "name": name,
                "datagram_hex": datagram.hex(),
                "answer_kind": (
                    ReferralKind(decode_referral(answers[0][0]).kind).name if answers else None
                ),
                "answer_size": len(answers[0][0]) if answers else 0,
            }
        )
    return _file(
        "rendezvous",
        "Rendezvous (section 5.12): the ids and probe keys a pair meets under (HKDF-SHA256), "
        "REGISTER and REFERRAL datagrams with their fields (addresses as [host, port]), PROBE "
        "and PROBE_ACK datagrams with their MACs (under the probe key of the name 'robot-7'), and "
        "what a relay answers to datagrams from addresses it has not validated.",
        {"names": names, "probes": probes, "valid": valid, "relay_answers": relay_answers},
    )


SUITES: dict[str, Callable[[], dict[str, Any]]] = {
    "header": header_vectors,
    "hold": hold_vectors,
    "seqnum": seqnum_vectors,
    "control": control_vectors,
    "receiver": receiver_vectors,
    "sender": sender_vectors,
    "keyed": keyed_vectors,
    "endpoint": drop_vectors,
    "server": server_vectors,
    "rendezvous": rendezvous_vectors,
}


def render(data: dict[str, Any]) -> str:
    return json.dumps(data, indent=1, sort_keys=False) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="compare, do not write")
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args(argv)
    stale = []
    for suite, build in SUITES.items():
        path = args.out / f"tdtp-v{PROTOCOL_VERSION}-{suite}.json"
        text = render(build())
        if args.check:
            if not path.exists() or path.read_text(encoding="utf-8") != text:
                stale.append(path.name)
        else:
            path.write_text(text, encoding="utf-8")
            print(f"wrote {path.relative_to(ROOT)}")
    if stale:
        print("out of date: " + ", ".join(stale), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
