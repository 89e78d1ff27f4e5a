"""The inputs of tdtp-v4-endpoint.json: what each script feeds an endpoint (generate.py records the
expected outcomes by running tdtp). Every drop reason of PROTOCOL.md section 5.5 appears."""

from __future__ import annotations

from typing import Any

from tdtp.protection.derivation import derive_reset_key, derive_session_secrets, reset_tag
from tdtp.protection.keys import PresharedKey
from tdtp.protection.packet_protection import Direction, PacketSealer
from tdtp.wire import (
    PROTOCOL_VERSION,
    CipherSuite,
    CloseReason,
    ControlCode,
    MpReportBody,
    OpenAckBody,
    OpenBody,
    encode_close,
    encode_cookie,
    encode_header,
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
)

from tdtp_adapter import (  # tests/vectors: generate.py puts it on the path
    COOKIE_PLACEHOLDER,
    TOKEN_PLACEHOLDER,
)

MASTER_NONCE = bytes.fromhex("00112233445566778899aabbccddeeff")
SLAVE_NONCE = bytes.fromhex("f0e1d2c3b4a5968778695a4b3c2d1e0f")
OTHER_NONCE = bytes(range(16))
MASTER_ISN = 0x5A5
SLAVE_ISN = 0x0C3
PSK = bytes(range(32))
COOKIE_BYTES = b"\x00\x00\xab\xcd" + b"\x11" * 12


def _hex(data: bytes) -> str:
    return data.hex()


def _open(
    nonce: bytes = MASTER_NONCE,
    *,
    cookie: bool = False,
    max_payload: int = 1200,
    version: int = PROTOCOL_VERSION,
    flags: int = 0,
    suite: int = 0,
    key_id: bytes = bytes(8),
    attempt: int = 0,
    tag: bytes = b"",
) -> str:
    """An OPEN from the master (hex); ``cookie`` puts the placeholder where the cookie goes."""
    body = encode_open(
        OpenBody(version, flags, suite, max_payload, attempt, nonce, key_id, bytes(16))
    )
    text = _hex(encode_header(2, MASTER_ISN, 0, 0, 255) + body[:-16])
    return text + (COOKIE_PLACEHOLDER if cookie else bytes(16).hex()) + tag.hex()


def _open_ack(max_payload: int = 1200, *, seq: int = SLAVE_ISN) -> str:
    """An unkeyed OPEN_ACK from the slave (hex) answering the master's OPEN."""
    body = OpenAckBody(PROTOCOL_VERSION, 0, 0, max_payload, 0, MASTER_NONCE, SLAVE_NONCE)
    return _hex(encode_header(2, seq, 0, 0, 255) + encode_open_ack(body))


def _cookie(nonce: bytes = MASTER_NONCE) -> str:
    """A COOKIE from the slave (hex) answering the OPEN that carried ``nonce``."""
    return _hex(encode_header(2, 0, 0, 0, 255) + encode_cookie(nonce, COOKIE_BYTES))


def _data(seq: int, payload: bytes, ack: tuple[int, int, int] = (0, 0, 255)) -> str:
    return _hex(encode_header(0, seq, *ack) + payload)


def _step(at: float, source: str, datagram: str, **extra: Any) -> dict[str, Any]:
    return {"at": at, "from": source, "datagram": datagram, **extra}


def _action(at: float, action: str, **extra: Any) -> dict[str, Any]:
    return {"at": at, "action": action, **extra}


def _slave_random() -> dict[str, Any]:
    return {"nonce": SLAVE_NONCE.hex(), "initial_seq": SLAVE_ISN}


def _master_random() -> dict[str, Any]:
    return {"nonce": MASTER_NONCE.hex(), "initial_seq": MASTER_ISN}


def _opening(start: float = 0.0) -> list[dict[str, Any]]:
    """The master's side of an unkeyed opening, fed to a slave: OPEN, OPEN with the cookie, and the
    first packet of the session (a KEEPALIVE)."""
    return [
        _step(start, "master", _open()),
        _step(start + 0.010, "master", _open(cookie=True, attempt=1), exact=True),
        _step(
            start + 0.020,
            "master",
            _hex(encode_header(2, MASTER_ISN, 0, 0, 255) + encode_keepalive(MASTER_NONCE)),
            note="the master's first packet of the session",
        ),
    ]


def slave_session() -> dict[str, Any]:
    s = MASTER_ISN
    header_close = encode_header(2, s, 0, 0, 255)
    steps = [
        *_opening(),
        _step(0.021, "master", _data(s, b"s1")),
        _step(0.022, "master", _data(s, b"s1"), note="the same packet again"),
        _step(0.023, "master", _data(s + 2, b"s3"), note="s + 1 is missing"),
        _step(0.024, "master", _data(s + 1, b"s2"), note="arrives after s + 2"),
        _step(0.025, "stranger", _data(s + 3, b"s4")),
        _step(0.026, "master", "00010203"),
        _step(0.027, "master", _hex(encode_header(3, s, 0, 0, 255) + b"x")),
        _step(0.028, "master", _data(s + 3, bytes(1201)), note="payload over max_payload"),
        _step(0.029, "master", _data(s + 3, bytes(1300)), note="datagram over 5 + 1200 + 18"),
        _step(0.030, "master", _data(s + 3, b""), note="no payload"),
        _step(
            0.031,
            "master",
            _data(s + 3, b"s4", ack=(SLAVE_ISN + 5, 0, 0)),
            note="acknowledges a packet the slave never sent: the acknowledgement is ignored, the "
            "sample delivered",
        ),
        _step(0.032, "master", _hex(encode_header(2, s, 0, 0, 255) + b"\x09")),
        _step(
            0.033,
            "master",
            _hex(encode_header(2, s, 0, 0, 255) + encode_keepalive(MASTER_NONCE) + b"\x00"),
        ),
        _step(
            0.0335,
            "master",
            _hex(encode_header(2, s, 0, 0, 255) + encode_keepalive(OTHER_NONCE)),
            note="a KEEPALIVE with another nonce: a blind forgery, no sign of life",
        ),
        _step(
            0.034,
            "master",
            _hex(header_close + encode_close(ControlCode.CLOSE, OTHER_NONCE, CloseReason.NORMAL)),
        ),
        _step(
            0.035,
            "master",
            _open_ack(seq=s),
            note="an OPEN_ACK sent to a slave",
        ),
        _step(0.036, "master", _open(version=99), note="answered REJECT VERSION_UNSUPPORTED"),
        _step(0.037, "master", _open(cookie=True, max_payload=0, attempt=2)),
        _step(
            0.038,
            "master",
            _open(cookie=True, attempt=3),
            note="a late retransmission: answered, but no sign of life",
        ),
        _step(0.039, "master", _open(OTHER_NONCE), note="another nonce: a COOKIE for it"),
        _step(
            0.040,
            "master",
            _open(OTHER_NONCE, cookie=True, attempt=1),
            note="another nonce, valid cookie, session alive: a replay",
        ),
        _step(
            0.041,
            "master",
            _data(s + 80, b"77 ahead"),
            note="77 above the highest, 10 ms after it arrived: more than 32 + 10 ms at 1000/s, "
            "the least rate assumed (a blind forgery): far_ahead",
        ),
        _step(
            0.100,
            "master",
            _data(s + 100, b"97 ahead"),
            note="97 above the highest, 69 ms after it: 32 + 69 at 1000/s, a loss burst: taken",
        ),
        _step(0.101, "master", _data(s + 36, b"64 below the highest")),
        _step(0.102, "master", _data(s + 37, b"63 below: late")),
        _step(
            0.110,
            "master",
            _hex(header_close + encode_close(ControlCode.CLOSE, MASTER_NONCE, CloseReason.NORMAL)),
        ),
        _step(0.111, "master", _data(s + 101, b"after the close")),
    ]
    return {
        "name": "slave: opening, a session's bad input, closing",
        "role": "slave",
        "config": {"max_payload": 1200},
        "random": _slave_random(),
        "steps": steps,
    }


def slave_before_the_open() -> dict[str, Any]:
    s = MASTER_ISN
    steps = [
        _step(
            0.0,
            "master",
            _data(s, b"too early"),
            note="14 bytes: smaller than a RESET (22), so no answer",
        ),
        _step(
            0.0005,
            "master",
            _data(s, bytes(range(40))),
            note="a session datagram with no session: answered with a RESET echoing its first 16 "
            "bytes (section 5.7)",
            exact=True,
        ),
        _step(0.001, "master", _hex(encode_header(1, s, 0, 0, 255))),
        _step(
            0.002,
            "master",
            _hex(encode_header(2, s, 0, 0, 255) + encode_keepalive(MASTER_NONCE)),
            note="a KEEPALIVE is 22 bytes since version 3: with no session, answered with a RESET",
        ),
        _step(
            0.003,
            "master",
            _hex(encode_header(2, 0, 0, 0, 255) + b"\x01\x01\x00") + "00" * 10,
            note="a version 1 OPEN (18 bytes): smaller than a REJECT, so no answer",
        ),
        *[
            _step(0.010, "master", _open(), note=f"OPEN {i + 1} within one instant")
            for i in range(41)
        ],
        _step(
            0.010,
            "master",
            _hex(encode_header(2, 0, 0, 0, 255) + b"\x01\x01\x00") + "00" * 10,
            note="a version 1 OPEN over the rate: an OPEN of another version takes a token of its "
            "source's rate whatever its size (5.1 rule 2.1), so rate_limited, not unknown_version",
        ),
        _step(0.011, "stranger", _open(OTHER_NONCE), note="another host has its own budget"),
        _step(
            0.012,
            "master",
            _hex(encode_header(2, s, 0, 0, 255) + encode_message(MASTER_NONCE, 1, 2, b"hello")),
            note="a MESSAGE (43 bytes) with no session: not a datagram a RESET answers (5.7)",
        ),
    ]
    return {
        "name": "slave: before any session, and the per-source OPEN rate",
        "role": "slave",
        "config": {},
        "random": _slave_random(),
        "steps": steps,
    }


def slave_refusals() -> dict[str, Any]:
    key_id = PresharedKey(PSK).key_id
    keyed = {"flags": 6, "suite": 1, "key_id": key_id, "tag": bytes(16)}
    steps = [
        _step(0.0, "master", _open(**keyed)),  # type: ignore[arg-type]
        _step(
            0.001, "master", _open(cookie=True, attempt=1, **keyed), note="this slave has no keys"
        ),  # type: ignore[arg-type]
        _step(0.002, "master", _open(flags=4), note="ENCRYPTED without KEYED"),
        _step(0.003, "master", _open(suite=1), note="a suite without KEYED"),
        _step(0.004, "master", _open(key_id=key_id), note="a key id without KEYED"),
        _step(0.005, "master", _open(max_payload=100)),
        _step(
            0.006,
            "master",
            _open(cookie=True, max_payload=100, attempt=1),
            note="below this slave's min_peer_payload (200)",
        ),
    ]
    return {
        "name": "slave: refused OPENs",
        "role": "slave",
        "config": {"min_peer_payload": 200},
        "random": _slave_random(),
        "steps": steps,
    }


def keyed_slave_refusals() -> dict[str, Any]:
    key_id = PresharedKey(PSK).key_id
    steps = [
        _step(0.0, "master", _open(flags=6, suite=1, key_id=key_id, tag=bytes(16))),
        _step(
            0.001,
            "master",
            _open(cookie=True, flags=6, suite=1, key_id=key_id, attempt=1, tag=bytes(16)),
            note="the right key id, a tag that does not verify: no answer",
        ),
        _step(0.002, "master", _open(OTHER_NONCE)),
        _step(
            0.003,
            "master",
            _open(OTHER_NONCE, cookie=True, attempt=1),
            note="unkeyed OPEN to a keyed slave",
        ),
        _step(
            0.004,
            "master",
            _open(OTHER_NONCE, flags=6, suite=1, key_id=bytes(range(8)), tag=bytes(16)),
        ),
        _step(
            0.005,
            "master",
            _open(
                OTHER_NONCE,
                cookie=True,
                flags=6,
                suite=1,
                key_id=bytes(range(8)),
                attempt=1,
                tag=bytes(16),
            ),
            note="a key id this slave does not hold",
        ),
        _step(
            0.006,
            "master",
            _data(MASTER_ISN, bytes(range(35))),
            exact=True,
            note="a 40-byte DATA with no session: a RESET with one tag of the ring's key (room "
            "for floor((40 - 22) / 16) = 1)",
        ),
        _step(
            0.007,
            "master",
            _hex(encode_header(1, MASTER_ISN, 0, 0, 255) + bytes(18)),
            note="a keyed ACK (23 bytes) has no room for a tag: no RESET",
        ),
    ]
    return {
        "name": "slave with a key: refused and unauthenticated OPENs, a RESET with a tag",
        "role": "slave",
        "config": {"psk": PSK.hex()},
        "random": _slave_random(),
        "steps": steps,
    }


def keyed_master_session() -> dict[str, Any]:
    suite = CipherSuite.AES_128_GCM
    session = derive_session_secrets(PSK, MASTER_NONCE, SLAVE_NONCE, suite)
    to_master = Direction(suite, session.slave_to_master)
    sealer = PacketSealer(suite, session.slave_to_master, encrypt=True)

    def open_ack(number: int, flags: int = 6, forge: bool = False) -> str:
        datagram = encode_header(2, SLAVE_ISN, 0, 0, 255) + encode_open_ack(
            OpenAckBody(
                PROTOCOL_VERSION, flags, int(suite), 1200, number, MASTER_NONCE, SLAVE_NONCE
            )
        )
        if flags & 2:
            tag = to_master.tag(number, datagram)
            if forge:
                tag = bytes([tag[0] ^ 0x80]) + tag[1:]
            datagram += tag
        return _hex(datagram)

    def sealed(number: int, prefix: bytes, body: bytes) -> bytes:
        sealer.next_number = number
        return sealer.seal(prefix, body)

    data1 = sealed(1, encode_header(0, SLAVE_ISN, 0, 0, 255), b"hi")
    data2 = sealed(2, encode_header(0, SLAVE_ISN + 1, 0, 0, 255), b"there")
    tampered = data2[:-3] + bytes([data2[-3] ^ 1]) + data2[-2:]
    data3 = sealed(3, encode_header(0, SLAVE_ISN + 1, 0, 0, 255), b"there")
    close = sealed(
        4,
        encode_header(2, SLAVE_ISN + 2, 0, 0, 255) + bytes((ControlCode.CLOSE,)),
        encode_close(ControlCode.CLOSE, MASTER_NONCE, CloseReason.NORMAL)[1:],
    )
    steps = [
        _action(0.0, "connect", exact=True),
        _step(0.001, "slave", _data(SLAVE_ISN, b"too early"), note="no session keys yet"),
        _step(
            0.002,
            "slave",
            _cookie(),
            exact=True,
            note="the OPEN that answers a COOKIE carries it, attempt 1, a fresh tag",
        ),
        _step(
            0.003,
            "slave",
            _cookie(OTHER_NONCE),
        ),
        _step(0.004, "slave", open_ack(0, flags=0), note="flags differ from the OPEN's"),
        _step(
            0.005,
            "slave",
            _hex(
                encode_header(2, SLAVE_ISN, 0, 0, 255)
                + encode_open_ack(
                    OpenAckBody(PROTOCOL_VERSION + 1, 6, 1, 1200, 0, MASTER_NONCE, SLAVE_NONCE)
                )
                + bytes(16)
            ),
            note="a later version",
        ),
        _step(0.006, "slave", open_ack(0, forge=True)),
        _step(0.007, "slave", open_ack(0), exact=True),
        _step(0.008, "slave", open_ack(0), note="the same OPEN_ACK again: its PN is spent"),
        _step(0.009, "slave", _open(), note="an OPEN sent to a master"),
        _step(0.010, "slave", _hex(data1)),
        _step(0.011, "slave", _hex(data1)),
        _step(0.012, "slave", _hex(tampered)),
        _step(0.013, "slave", _hex(data3)),
        _step(0.014, "slave", _hex(data2[:10])),
        _step(0.015, "slave", _hex(close)),
        _step(0.016, "slave", _hex(data3)),
    ]
    return {
        "name": "master with a key: opening, then protected packets",
        "role": "master",
        "config": {"psk": PSK.hex(), "suite": int(suite), "encrypt": True},
        "random": _master_random(),
        "steps": steps,
    }


def master_rejected() -> dict[str, Any]:
    steps = [
        _action(0.0, "connect", exact=True),
        _step(
            0.001,
            "slave",
            _hex(encode_header(2, 0, 0, 0, 255) + encode_close(ControlCode.REJECT, OTHER_NONCE, 5)),
        ),
        _step(
            0.002,
            "slave",
            _hex(
                encode_header(2, 0, 0, 0, 255) + encode_close(ControlCode.REJECT, MASTER_NONCE, 5)
            ),
        ),
        _step(
            0.003,
            "slave",
            _open_ack(),
        ),
    ]
    return {
        "name": "master: refused with REJECT BUSY",
        "role": "master",
        "config": {},
        "random": _master_random(),
        "steps": steps,
    }


def master_payload_too_small() -> dict[str, Any]:
    steps = [
        _action(0.0, "connect"),
        _step(
            0.001,
            "slave",
            _open_ack(0),
            note="max_payload 0",
        ),
        _step(
            0.002,
            "slave",
            _open_ack(50),
            note="below this master's min_peer_payload (100)",
        ),
    ]
    return {
        "name": "master: an OPEN_ACK whose max_payload is too small",
        "role": "master",
        "config": {"min_peer_payload": 100},
        "random": _master_random(),
        "steps": steps,
    }


def master_session() -> dict[str, Any]:
    open_ack = _open_ack()
    steps = [
        _action(0.0, "connect"),
        _step(0.001, "slave", open_ack, exact=True),
        _step(0.002, "slave", open_ack, note="a duplicate: absorbed"),
        _step(
            0.003,
            "slave",
            _cookie(),
            note="a COOKIE once established",
        ),
        _step(
            0.004,
            "slave",
            _data(SLAVE_ISN, b"one", ack=(MASTER_ISN, 0, 0)),
            note="acknowledges the master's first DATA, which it never sent: the acknowledgement "
            "is ignored, the sample delivered",
        ),
        _step(0.005, "slave", _data(SLAVE_ISN, b"one"), note="the same again: a duplicate"),
        _step(
            0.006,
            "slave",
            _hex(encode_header(1, SLAVE_ISN + 1, MASTER_ISN - 1, 0, 0)),
            note="a stand-alone ACK of a packet before the first: optimistic",
        ),
        _step(0.007, "slave", _hex(encode_header(1, SLAVE_ISN + 1, 0, 0, 255))),
        _step(
            0.0075,
            "slave",
            _hex(encode_header(2, 0, 0, 0, 255) + encode_reset(bytes(range(16)))),
            note="a RESET that echoes nothing the master sent: unmatched_reset, the session goes on",
        ),
        _step(
            0.0076,
            "slave",
            _reset_of_first_keepalive(),
            note="a RESET echoing the master's KEEPALIVE, 2.6 ms after the slave was last heard: "
            "a slave that holds the session is talking (a copy of the KEEPALIVE drew it "
            "elsewhere): peer_alive, the session goes on",
        ),
        _action(0.008, "close", exact=True),
        _step(0.009, "slave", _data(SLAVE_ISN + 1, b"two")),
    ]
    return {
        "name": "master: an unkeyed session and its close",
        "role": "master",
        "config": {},
        "random": _master_random(),
        "steps": steps,
    }


def _reset_of_first_keepalive() -> str:
    """An unkeyed RESET echoing the master's KEEPALIVE sent on its OPEN_ACK (no data yet: HOLD 255)."""
    keepalive = encode_header(2, MASTER_ISN, 0, 0, 255) + encode_keepalive(MASTER_NONCE)
    return _hex(encode_header(2, 0, 0, 0, 255) + encode_reset(keepalive[:16]))


def master_slave_restarted() -> dict[str, Any]:
    """A RESET is believed only from a slave the master has not heard for its silence_timeout
    (section 5.7): one that holds the session is talking."""
    steps = [
        _action(0.0, "connect"),
        _step(0.001, "slave", _open_ack(), note="established: the master sends a KEEPALIVE"),
        _step(
            0.050,
            "slave",
            _reset_of_first_keepalive(),
            note="the slave was heard 49 ms ago: peer_alive",
        ),
        _step(
            0.102,
            "slave",
            _reset_of_first_keepalive(),
            note="nothing from the slave for 101 ms (every KEEPALIVE since had the same first "
            "bytes): it lost the session, PEER_RESTARTED",
        ),
    ]
    return {
        "name": "master: a RESET from a slave that talks, then from one that lost the session",
        "role": "master",
        "config": {},
        "random": _master_random(),
        "steps": steps,
    }


def master_closed_by(reason: CloseReason) -> dict[str, Any]:
    """Section 5.2, "What a CLOSE says": a slave's CLOSE RESTARTING ends the master's session as
    peer_restarting (a reconnecting master reopens at once), a CLOSE EVICTED (section 5.1, rule
    2.7) as evicted (it backs off first); a CLOSE after the end is dropped."""
    header = encode_header(2, SLAVE_ISN, 0, 0, 255)
    what = {
        CloseReason.RESTARTING: "the slave stops and will be back soon",
        CloseReason.EVICTED: "a full slave gave this session's slot to another master",
        CloseReason.TAKEN_OVER: "an exclusive slave handed control to another master (a "
        "peer_close whose reason says why)",
    }[reason]
    steps = [
        _action(0.0, "connect"),
        _step(0.001, "slave", _open_ack()),
        _step(0.002, "slave", _data(SLAVE_ISN, b"one")),
        _step(
            0.003,
            "slave",
            _hex(header + encode_close(ControlCode.CLOSE, MASTER_NONCE, reason)),
            note=f"CLOSE {reason.name}: {what}",
        ),
        _step(
            0.004,
            "slave",
            _hex(header + encode_close(ControlCode.CLOSE, MASTER_NONCE, CloseReason.NORMAL)),
            note="after the close: dropped",
        ),
    ]
    return {
        "name": f"master: the slave closes with {reason.name}",
        "role": "master",
        "config": {},
        "random": _master_random(),
        "steps": steps,
    }


def slave_restarting() -> dict[str, Any]:
    """The slave's application stops with restarting=True (Ctrl-C of `tdtp slave`): its CLOSE
    carries reason 15, byte for byte."""
    steps = [
        *_opening(),
        _step(0.021, "master", _data(MASTER_ISN, b"s1")),
        _action(0.022, "close", restarting=True, exact=True),
    ]
    return {
        "name": "slave: a restarting slave's CLOSE",
        "role": "slave",
        "config": {"max_payload": 1200},
        "random": _slave_random(),
        "steps": steps,
    }


def slave_control_channel() -> dict[str, Any]:
    """The reliable control channel (section 5.10) at a slave whose control_window is 4: a lost
    MESSAGE, the next one held, the retransmission delivering both in order, a duplicate, the slave's
    own message retransmitted after its loss delay, and every way a MESSAGE can be dropped."""
    m = 0xF000 | MASTER_ISN  # the master's first message number
    s = 0xF000 | SLAVE_ISN  # the slave's
    header = encode_header(2, MASTER_ISN, 0, 0, 255)

    def message(seq: int, ack: int, data: bytes, nonce: bytes = MASTER_NONCE) -> str:
        return _hex(header + encode_message(nonce, seq, ack, data))

    def message_ack(ack: int, nonce: bytes = MASTER_NONCE) -> str:
        return _hex(header + encode_message_ack(nonce, ack))

    steps = [
        *_opening(),
        _step(
            0.021,
            "master",
            message(m + 1, s, b"c1"),
            exact=True,
            note="the master's message 1; message 0 was lost on its way: held, not delivered, and "
            "acknowledged as 'next expected: message 0'",
        ),
        _step(
            0.022,
            "master",
            message(m, s, b"c0"),
            exact=True,
            note="message 0 retransmitted: 0 and 1 delivered in order",
        ),
        _step(
            0.023, "master", message(m + 1, s, b"c1"), note="message 1 again: acknowledged again"
        ),
        _action(0.024, "send_control", message="6f6b", exact=True, note="the slave sends 'ok'"),
        _action(
            0.35,
            "advance",
            exact=True,
            note="no acknowledgement within the loss delay (0.32 s: no RTT sample yet): sent again",
        ),
        _step(0.36, "master", message_ack(s + 1), note="the master acknowledges it"),
        _step(0.37, "master", message_ack(s + 5), note="acknowledges messages never sent"),
        _step(0.38, "master", message(m + 6, s + 1, b"c6"), note="4 past the next expected"),
        _step(
            0.39,
            "master",
            _hex(header + encode_message(MASTER_NONCE, m + 2, s + 1, b"")),
            note="no message",
        ),
        _step(
            0.395,
            "master",
            message(m + 2, s + 1, b"c2", nonce=bytes(16)),
            note="another nonce (an off-path forgery: right numbers, wrong nonce): nothing in it "
            "is read, no sign of life",
        ),
        _step(
            0.396,
            "master",
            message_ack(s + 1, nonce=bytes(16)),
            note="a MESSAGE_ACK with another nonce: dropped the same way",
        ),
        _step(0.40, "master", message(m + 2, s + 1, bytes(257)), note="over control_max_message"),
        _action(0.41, "hold_control", count=4, note="the application holds 4 unread messages"),
        _step(0.411, "master", message(m + 2, s + 1, b"c2"), note="the receive bound is full"),
        _action(0.42, "hold_control", count=0, note="the application read them"),
        _step(0.421, "master", message(m + 2, s + 1, b"c2"), note="retransmitted: delivered"),
    ]
    return {
        "name": "slave: the reliable control channel",
        "role": "slave",
        "config": {"max_payload": 1200, "control_window": 4},
        "random": _slave_random(),
        "steps": steps,
    }


def _mp(body: bytes) -> str:
    """A multipath control datagram (unkeyed) from the master (hex): header, then ``body``."""
    return _hex(encode_header(2, MASTER_ISN + 2, 0, 0, 255) + body)


def slave_multipath() -> dict[str, Any]:
    """A multipath slave (PROTOCOL.md 5.11): the master opens path 1 from its second socket, the
    slave validates it; copies, forged and refused multipath packets."""
    s = MASTER_ISN
    token = bytes.fromhex("0102030405060708")
    steps = [
        *_mp_opening(),
        _step(0.021, "master", _data(s, b"s1")),
        _step(
            0.022,
            "master_socket2",
            _mp(encode_mp_challenge(MASTER_NONCE, 1, token)),
            note="a new path from the master's second socket: answered on it with the echo and a "
            "token of the slave's own (within three times the challenge's bytes)",
        ),
        _step(0.023, "master_socket2", _data(s + 1, b"s2"), note="data on the new path: taken in"),
        _step(0.024, "master", _data(s + 1, b"s2"), note="its copy on path 0: a duplicate"),
        _step(
            0.025,
            "master_socket2",
            _mp(encode_mp_response(MASTER_NONCE, 1, bytes.fromhex("ffeeddccbbaa9988"), bytes(8))),
            note="an echo of a token the slave never sent",
        ),
        _step(
            0.026,
            "master_socket2",
            _mp(encode_mp_response(MASTER_NONCE, 1, bytes(8), bytes(8))).replace(
                "00" * 8 + "00" * 8, TOKEN_PLACEHOLDER + "00" * 8
            ),
            note="the master echoes the slave's token: path 1 is validated at the slave",
        ),
        _step(
            0.027,
            "master",
            _mp(encode_mp_report(MpReportBody(MASTER_NONCE, 1, SLAVE_ISN, 255, 0, 0, 0, 0))),
            note="a report naming path 1 that came on path 0",
        ),
        _step(
            0.028,
            "stranger",
            _mp(encode_mp_challenge(MASTER_NONCE, 2, token)),
            note="a third path: over this slave's max_paths (2), refused with MP_ABANDON "
            "PATH_LIMIT",
        ),
        _step(
            0.029,
            "stranger",
            _mp(encode_mp_challenge(OTHER_NONCE, 3, token)),
            note="another session's nonce from an address no path has",
        ),
        _step(
            0.030,
            "master_socket2",
            _mp(encode_mp_challenge(MASTER_NONCE, 1, token)[:-1]),
            note="a challenge one byte short",
        ),
        _step(
            0.031,
            "master",
            _mp(encode_mp_abandon(OTHER_NONCE, 1, 19)),
            note="an abandon with another nonce",
        ),
        _step(
            0.032,
            "master",
            _mp(encode_mp_abandon(MASTER_NONCE, 1, 19)),
            note="the master abandons path 1 (on path 0)",
        ),
        _step(0.033, "master_socket2", _data(s + 2, b"s3"), note="from path 1's address, gone now"),
        _step(0.034, "master", _data(s + 2, b"s3")),
    ]
    return {
        "name": "slave: a multipath session's second path, copies and forgeries",
        "role": "slave",
        "config": {"max_payload": 1200, "multipath": {"max_paths": 2}},
        "random": _slave_random(),
        "steps": steps,
    }


def _mp_opening(flags: int = 0x40) -> list[dict[str, Any]]:
    """An unkeyed opening fed to a slave, the OPENs carrying ``flags`` (MULTIPATH unless given)."""
    keepalive = _hex(encode_header(2, MASTER_ISN, 0, 0, 255) + encode_keepalive(MASTER_NONCE))
    return [
        _step(0.0, "master", _open(flags=flags)),
        _step(0.010, "master", _open(cookie=True, attempt=1, flags=flags)),
        _step(0.020, "master", keepalive, note="the master's first packet of the session"),
    ]


def _mp_slave(name: str, steps: list[dict[str, Any]], **multipath: Any) -> dict[str, Any]:
    config: dict[str, Any] = {"max_payload": 1200}
    if multipath:
        config["multipath"] = multipath
    return {
        "name": name,
        "role": "slave",
        "config": config,
        "random": _slave_random(),
        "steps": steps,
    }


def slave_multipath_limits() -> dict[str, Any]:
    """Section 5.11, learning a path: the rate is checked before the table, and a refused challenge
    spends a token too; an MP_ABANDON naming no path of the table is ``unknown_path``."""
    token = bytes.fromhex("0102030405060708")
    steps = [
        *_mp_opening(),
        _step(
            0.021,
            "master_socket2",
            _mp(encode_mp_challenge(MASTER_NONCE, 1, token)),
            note="path 1: the table's second path, one of the rate's two tokens",
        ),
        _step(
            0.022,
            "stranger",
            _mp(encode_mp_challenge(MASTER_NONCE, 2, token)),
            note="the table is full: refused with MP_ABANDON PATH_LIMIT, the second token spent",
        ),
        _step(
            0.023,
            "stranger",
            _mp(encode_mp_challenge(MASTER_NONCE, 2, token)),
            note="again: over the rate, checked first: refused without an answer",
        ),
        _step(
            0.024,
            "master",
            _mp(encode_mp_abandon(MASTER_NONCE, 1, 19)),
            note="the master abandons path 1 (on path 0)",
        ),
        _step(
            0.025,
            "master",
            _mp(encode_mp_abandon(MASTER_NONCE, 1, 19)),
            note="its copy: path 1 is no longer in the table",
        ),
    ]
    return _mp_slave(
        "slave: multipath limits, the rate before the table",
        steps,
        max_paths=2,
        new_paths_per_second=1.0,
    )


def slave_multipath_probes() -> dict[str, Any]:
    """Sections 5.2 and 5.11: an idle multipath slave probes path 0 every ``probe_interval`` from
    the instant it is established; a probe is session traffic, so while the probe interval is
    shorter than the keep-alive interval no KEEPALIVE leaves."""
    advance = [_action(round(0.02 + 0.01 * i, 3), "advance") for i in range(1, 9)]
    return _mp_slave(
        "slave: an idle multipath session probes instead of keeping alive",
        [*_mp_opening(), *advance],
    )


def slave_multipath_slow_probes() -> dict[str, Any]:
    """As above with a probe interval longer than the keep-alive interval: the probe leaves first
    and the KEEPALIVE check of the same instant does not count it."""
    advance = [_action(round(0.02 + 0.01 * i, 3), "advance") for i in range(1, 9)]
    return _mp_slave(
        "slave: a multipath probe and a KEEPALIVE leave together, the probe first",
        [*_mp_opening(), *advance],
        probe_interval=0.04,
    )


def slave_multipath_codes_elsewhere() -> dict[str, Any]:
    """Sections 5.5 (row 13) and 5.11: the multipath codes outside an established multipath
    session, and a multipath packet as the master's first packet of the session."""
    token = bytes.fromhex("0102030405060708")
    report = encode_mp_report(MpReportBody(MASTER_NONCE, 0, SLAVE_ISN, 255, 0, 0, 0, 0))
    steps = [
        *_mp_opening(flags=0),
        _step(
            0.021,
            "master",
            _mp(encode_mp_challenge(MASTER_NONCE, 1, token)),
            note="a session opened without MULTIPATH: well formed, unexpected_control",
        ),
        _step(0.022, "master", _mp(encode_mp_response(MASTER_NONCE, 0, token, bytes(8)))),
        _step(0.023, "master", _mp(report)),
        _step(0.024, "master", _mp(encode_mp_abandon(MASTER_NONCE, 0, 19))),
        _step(
            0.025,
            "master",
            _mp(encode_mp_abandon(MASTER_NONCE, 0, 19) + b"\x00"),
            note="one byte long: bad_control",
        ),
    ]
    return _mp_slave("slave: multipath codes in a session without MULTIPATH", steps)


def slave_multipath_first_packet() -> dict[str, Any]:
    """Section 5.11: before the session is established an MP code is a session CONTROL; at a slave
    in OPENING, from the master's address, it is the master's first packet (section 5.1 rule 3)."""
    report = encode_mp_report(MpReportBody(MASTER_NONCE, 0, SLAVE_ISN, 255, 0, 0, 0, 0))
    token = bytes.fromhex("0102030405060708")
    steps = [
        _step(0.0, "master", _mp(report), note="a LISTENING slave: not_established"),
        *_mp_opening()[:2],
        _step(
            0.015,
            "master_socket2",
            _mp(encode_mp_challenge(MASTER_NONCE, 1, token)),
            note="a new path before the session is established: wrong_address",
        ),
        _step(
            0.020,
            "master",
            _mp(report),
            note="the master's first packet: the session is established, the report dropped",
        ),
    ]
    return _mp_slave(
        "slave: a multipath packet before the session is established", steps, max_paths=2
    )


def master_multipath_flag() -> dict[str, Any]:
    """Section 5.11: a master given multipath parameters sets MULTIPATH (bit 6) in its OPENs."""
    return {
        "name": "master: multipath parameters set the MULTIPATH flag",
        "role": "master",
        "config": {"max_payload": 1200, "multipath": {"max_paths": 3}},
        "random": _master_random(),
        "steps": [_action(0.0, "connect", exact=True)],
    }


def master_path_challenge() -> dict[str, Any]:
    """Section 5.8: an established unkeyed master answers its slave's PATH_CHALLENGE with a
    PATH_RESPONSE (the token and its nonce), at most one per 5 ms; neither is a sign of life nor
    session traffic (5.2), so the KEEPALIVE stays on its schedule."""
    challenge = _hex(encode_header(2, 0, 0, 0, 255) + encode_path_challenge(COOKIE_BYTES))
    steps = [
        _action(0.0, "connect"),
        _step(0.001, "slave", _open_ack(), note="established: a KEEPALIVE at once"),
        _step(0.030, "slave", challenge, exact=True, note="answered with a PATH_RESPONSE"),
        _step(0.032, "slave", challenge, note="2 ms after the last answer: rate_limited"),
        _step(0.034, "stranger", challenge, note="not from the slave's address"),
        _action(
            0.0345,
            "advance",
            note="a keep-alive interval (33.3 ms) after the last session traffic (the KEEPALIVE "
            "at 0.001; the PATH_RESPONSE does not count): a KEEPALIVE",
        ),
        _step(0.036, "slave", challenge, note="6 ms after the last answer: answered"),
        _step(
            0.037,
            "slave",
            _hex(encode_header(2, 0, 0, 0, 255) + encode_path_response(COOKIE_BYTES, MASTER_NONCE)),
            note="a PATH_RESPONSE sent to a master",
        ),
    ]
    return {
        "name": "master: PATH_CHALLENGE and PATH_RESPONSE",
        "role": "master",
        "config": {},
        "random": _master_random(),
        "steps": steps,
    }


def keyed_master_reset() -> dict[str, Any]:
    """Section 5.7 keyed: a RESET must carry a tag made with the reset key of the master's PSK,
    and is believed only from a slave silent for the master's silence_timeout."""
    suite = CipherSuite.AES_128_GCM
    session = derive_session_secrets(PSK, MASTER_NONCE, SLAVE_NONCE, suite)
    master_sealer = PacketSealer(suite, session.master_to_slave, encrypt=True)
    # The master's first protected datagram: its KEEPALIVE right after the OPEN_ACK (PN 0).
    keepalive = master_sealer.seal(
        encode_header(2, MASTER_ISN, 0, 0, 255) + bytes((ControlCode.KEEPALIVE,)), MASTER_NONCE
    )
    echo = keepalive[:16]
    tag = reset_tag(derive_reset_key(PSK), echo)
    header = encode_header(2, 0, 0, 0, 255)
    to_master = Direction(suite, session.slave_to_master)
    open_ack = encode_header(2, SLAVE_ISN, 0, 0, 255) + encode_open_ack(
        OpenAckBody(PROTOCOL_VERSION, 6, int(suite), 1200, 0, MASTER_NONCE, SLAVE_NONCE)
    )
    open_ack += to_master.tag(0, open_ack)
    steps = [
        _action(0.0, "connect"),
        _step(0.001, "slave", _cookie()),
        _step(0.002, "slave", _hex(open_ack), exact=True, note="established: a KEEPALIVE, PN 0"),
        _step(
            0.003,
            "slave",
            _hex(header + encode_reset(echo, (bytes(16),))),
            note="it echoes the KEEPALIVE, but its tag is not the reset key's: unmatched_reset",
        ),
        _step(
            0.004,
            "slave",
            _hex(header + encode_reset(echo, (bytes(16), tag))),
            note="one of its tags verifies, but the slave was heard 2 ms ago: peer_alive",
        ),
        _step(
            0.103,
            "slave",
            _hex(header + encode_reset(echo, (tag,))),
            note="nothing from the slave for 101 ms: it lost the session, PEER_RESTARTED",
        ),
    ]
    return {
        "name": "master with a key: RESET tags and the slave's silence",
        "role": "master",
        "config": {"psk": PSK.hex(), "suite": int(suite), "encrypt": True},
        "random": _master_random(),
        "steps": steps,
    }


def keyed_master_takeover_flags() -> dict[str, Any]:
    """Section 4.3: a keyed master that asks for control (TAKEOVER, flags 0x0E) expects an OPEN_ACK
    whose flags are its OPEN's bits 0..2 only (0x06); one that echoes TAKEOVER is bad_control."""
    suite = CipherSuite.AES_128_GCM
    session = derive_session_secrets(PSK, MASTER_NONCE, SLAVE_NONCE, suite)
    to_master = Direction(suite, session.slave_to_master)

    def open_ack(number: int, flags: int) -> str:
        datagram = encode_header(2, SLAVE_ISN, 0, 0, 255) + encode_open_ack(
            OpenAckBody(
                PROTOCOL_VERSION, flags, int(suite), 1200, number, MASTER_NONCE, SLAVE_NONCE
            )
        )
        return _hex(datagram + to_master.tag(number, datagram))

    steps = [
        _action(0.0, "connect", exact=True, note="the OPEN's flags: 0x0E (TAKEOVER | keyed)"),
        _step(0.001, "slave", open_ack(0, 0x0E), note="TAKEOVER echoed: bad_control"),
        _step(0.002, "slave", open_ack(1, 0x06), note="the OPEN's bits 0..2: established"),
    ]
    return {
        "name": "master with a key asking for control: the OPEN_ACK's flags",
        "role": "master",
        "config": {"psk": PSK.hex(), "suite": int(suite), "encrypt": True, "takeover": True},
        "random": _master_random(),
        "steps": steps,
    }


def slave_keepalive_and_idle() -> dict[str, Any]:
    """Section 5.2: the KEEPALIVE check comes last at an instant, so a MESSAGE leaving then counts
    as session traffic; after idle_timeout without a sign of life, CLOSE IDLE_TIMEOUT. Timers run
    only at the steps' instants."""
    steps = [
        *_opening(),
        _action(
            0.06,
            "send_control",
            message="676f",
            note="a KEEPALIVE was due (0.02 + 33.3 ms), but the MESSAGE leaving at the same "
            "instant is session traffic: no KEEPALIVE",
        ),
        _action(0.09, "advance", note="less than a keep-alive interval after the MESSAGE"),
        _action(0.094, "advance", note="a keep-alive interval after the MESSAGE: a KEEPALIVE"),
        _action(
            30.03,
            "advance",
            note="nothing from the master since its first packet at 0.02: idle_timeout",
        ),
    ]
    return {
        "name": "slave: the KEEPALIVE check comes last; the idle timeout",
        "role": "slave",
        "config": {"max_payload": 1200},
        "random": _slave_random(),
        "steps": steps,
    }


def slave_opened_by_a_message() -> dict[str, Any]:
    """Section 5.1, rule 3: the master's first packet of the session is any datagram that gets as
    far as the checks by type, here a MESSAGE."""
    m = 0xF000 | MASTER_ISN
    s = 0xF000 | SLAVE_ISN
    header = encode_header(2, MASTER_ISN, 0, 0, 255)
    steps = [
        *_opening()[:2],
        _step(
            0.02,
            "master",
            _hex(header + encode_message(MASTER_NONCE, m, s, b"go")),
            note="the master's first packet of the session is a MESSAGE: established, delivered",
        ),
    ]
    return {
        "name": "slave: established by a MESSAGE",
        "role": "slave",
        "config": {"max_payload": 1200},
        "random": _slave_random(),
        "steps": steps,
    }


def all_scripts() -> list[dict[str, Any]]:
    return [
        slave_session(),
        slave_before_the_open(),
        slave_refusals(),
        keyed_slave_refusals(),
        master_session(),
        master_slave_restarted(),
        master_rejected(),
        master_payload_too_small(),
        keyed_master_session(),
        slave_control_channel(),
        master_closed_by(CloseReason.RESTARTING),
        master_closed_by(CloseReason.EVICTED),
        master_closed_by(CloseReason.TAKEN_OVER),
        slave_restarting(),
        master_path_challenge(),
        keyed_master_reset(),
        keyed_master_takeover_flags(),
        slave_keepalive_and_idle(),
        slave_opened_by_a_message(),
        slave_multipath(),
        slave_multipath_limits(),
        slave_multipath_probes(),
        slave_multipath_slow_probes(),
        slave_multipath_codes_elsewhere(),
        slave_multipath_first_packet(),
        master_multipath_flag(),
    ]
