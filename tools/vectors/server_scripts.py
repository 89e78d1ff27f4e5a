"""The inputs of tdtp-v4-server.json: a slave serving several masters on one address (PROTOCOL.md
5.1, "A server with several masters"), fed datagrams from named addresses. generate.py records what
tdtp does with each (tests/vectors/tdtp_adapter.py, ServerRunner): the RESET rule of section 5.7,
path migration and the challenge budget of 5.8, the slot policy and eviction notices of 5.1 rule
2.7, exclusive control and takeover of 5.9, a restarted master's new session (5.1 rule 5)."""

from __future__ import annotations

from typing import Any

from endpoint_scripts import (
    MASTER_ISN,
    MASTER_NONCE,
    OTHER_NONCE,
    PSK,
    SLAVE_ISN,
    SLAVE_NONCE,
)

from tdtp.protection.derivation import derive_session_secrets
from tdtp.protection.packet_protection import PacketSealer
from tdtp.wire import (
    CipherSuite,
    encode_header,
    encode_keepalive,
    encode_path_response,
)

SECOND_NONCE = bytes(range(0x20, 0x30))
"""The slave nonce of the server's second session."""
SECOND_ISN = 0x777
MASTER2_NONCE = bytes(range(0x40, 0x50))
MASTER2_ISN = 0x123


def _step(at: float, source: str, datagram: bytes | str, **extra: Any) -> dict[str, Any]:
    text = datagram if isinstance(datagram, str) else datagram.hex()
    return {"at": at, "from": source, "datagram": text, **extra}


def _open(
    at: float,
    source: str,
    *,
    nonce: bytes = MASTER_NONCE,
    seq: int = MASTER_ISN,
    cookie: bool = False,
    attempt: int = 0,
    psk: bytes | None = None,
    flags: int | None = None,
    **extra: Any,
) -> dict[str, Any]:
    """An OPEN the runner builds: it alone knows the server's cookie, which a keyed tag covers."""
    fields: dict[str, Any] = {
        "nonce": nonce.hex(),
        "seq": seq,
        "attempt": attempt,
        "cookie": cookie,
    }
    if psk is not None:
        fields["psk"] = psk.hex()
    if flags is not None:
        fields["flags"] = flags
    return {"at": at, "from": source, "open": fields, **extra}


def _advance(at: float, **extra: Any) -> dict[str, Any]:
    return {"at": at, "action": "advance", **extra}


def _keepalive(nonce: bytes = MASTER_NONCE, seq: int = MASTER_ISN) -> bytes:
    return encode_header(2, seq, 0, 0, 255) + encode_keepalive(nonce)


def _data(seq: int, payload: bytes) -> bytes:
    return encode_header(0, seq, 0, 0, 255) + payload


def _opening(
    start: float = 0.0,
    source: str = "master",
    nonce: bytes = MASTER_NONCE,
    seq: int = MASTER_ISN,
) -> list[dict[str, Any]]:
    """An unkeyed master's opening: OPEN, OPEN with the cookie, its first packet (a KEEPALIVE)."""
    return [
        _open(start, source, nonce=nonce, seq=seq),
        _open(start + 0.001, source, nonce=nonce, seq=seq, cookie=True, attempt=1),
        _step(start + 0.002, source, _keepalive(nonce, seq)),
    ]


def _sessions(*pairs: tuple[bytes, int]) -> dict[str, Any]:
    return {"sessions": [{"nonce": nonce.hex(), "initial_seq": isn} for nonce, isn in pairs]}


FIRST = (SLAVE_NONCE, SLAVE_ISN)
SECOND = (SECOND_NONCE, SECOND_ISN)


def server_resets() -> dict[str, Any]:
    """Section 5.7: a RESET only for a datagram no session can claim; section 5.8's challenge
    budget once an unkeyed session is quiet."""
    stray = _data(0x100, bytes(range(35)))  # 40 bytes
    steps = [
        _step(
            0.0,
            "stranger",
            stray,
            exact=True,
            note="no session at all: nobody can claim it, a RESET echoing its first 16 bytes",
        ),
        _step(0.0005, "stranger", _data(0x100, b"x"), note="6 bytes: too small for a RESET"),
        *_opening(0.001),
        _step(
            0.004,
            "stranger",
            stray,
            note="an established session whose master was heard 1 ms ago: the datagram may be "
            "that master's after a NAT rebinding, so no RESET",
        ),
        _step(
            0.3,
            "stranger",
            _keepalive(OTHER_NONCE),
            note="the unkeyed session has been quiet longer than a live master is (keep-alive "
            "interval + 2 srtt = 0.233 s): a PATH_CHALLENGE, never a RESET",
        ),
        _step(0.301, "stranger", _keepalive(OTHER_NONCE), note="the second of the burst of 3"),
        _step(0.302, "stranger", _keepalive(OTHER_NONCE), note="the third"),
        _step(0.303, "stranger", _keepalive(OTHER_NONCE), note="over the session's budget"),
        _step(
            0.404,
            "stranger",
            _keepalive(OTHER_NONCE),
            note="10 a second refill: one token after 0.1 s",
        ),
        _step(0.405, "stranger", _data(0x100, b"tiny"), note="under 22 bytes: no challenge"),
    ]
    return {
        "name": "server: RESET only for a datagram no session can claim; the challenge budget",
        "config": {},
        "random": _sessions(FIRST),
        "steps": steps,
    }


def server_path_validation() -> dict[str, Any]:
    """Section 5.8, unkeyed: a PATH_CHALLENGE, a PATH_RESPONSE that moves the session, the 3x
    limit, a move back when the old address speaks, and validation once it stays silent."""
    response = encode_header(2, 0, 0, 0, 255) + encode_path_response(bytes(16), MASTER_NONCE)
    token_response = response.hex()[:12] + "{token}" + MASTER_NONCE.hex()
    other_response = response.hex()[:12] + "{token}" + OTHER_NONCE.hex()
    steps = [
        *_opening(),
        _step(
            0.3,
            "master_moved",
            _keepalive(),
            note="the master after a NAT rebinding: its session is quiet, so a PATH_CHALLENGE",
        ),
        _step(0.31, "master_moved", response, note="a token the server never minted: bad_token"),
        _step(0.32, "master_moved", other_response, note="the token, another nonce: no_session"),
        _step(
            0.33,
            "master_moved",
            token_response,
            note="the token and the session's nonce: the session moves, under the 3x limit "
            "(nothing may leave until it has received enough)",
        ),
        _step(
            0.34,
            "master_moved",
            _keepalive(),
            note="66 bytes of allowance: less than one flush may need, so still nothing leaves "
            "(delayed, not dropped)",
        ),
        _step(
            0.35,
            "master",
            _data(MASTER_ISN, b"old path"),
            note="the old address speaks before the move is proven: the session goes back there "
            "(validated before) and takes the datagram in",
        ),
        _step(0.6, "master_moved", _keepalive(), note="quiet again: a challenge"),
        _step(0.61, "master_moved", token_response, note="moved again"),
        _advance(
            0.711,
            note="the old address silent for silence_timeout after the move: validated, and what "
            "was held leaves",
        ),
    ]
    return {
        "name": "server: unkeyed path validation, the 3x limit, a move back",
        "config": {},
        "random": _sessions(FIRST),
        "steps": steps,
    }


def server_keyed_roaming() -> dict[str, Any]:
    """Section 5.8, keyed: a copy of an accepted datagram from another address is `replayed` (no
    RESET, it moves nothing); a datagram no session authenticates gets a RESET once every session
    is keyed and quiet; one above every accepted number moves the session."""
    suite = CipherSuite.AES_128_GCM
    session = derive_session_secrets(PSK, MASTER_NONCE, SLAVE_NONCE, suite)
    sealer = PacketSealer(suite, session.master_to_slave, encrypt=True)

    def sealed(number: int, prefix: bytes, body: bytes) -> bytes:
        sealer.next_number = number
        return sealer.seal(prefix, body)

    keepalive = sealed(0, encode_header(2, MASTER_ISN, 0, 0, 255) + b"\x03", MASTER_NONCE)
    data1 = sealed(1, encode_header(0, MASTER_ISN, 0, 0, 255), b"one")
    data2 = sealed(2, encode_header(0, MASTER_ISN + 1, 0, 0, 255), b"two")
    data3 = sealed(3, encode_header(0, MASTER_ISN + 2, 0, 0, 255), b"three")
    data4 = sealed(4, encode_header(0, MASTER_ISN + 3, 0, 0, 255), b"four")
    forged = data1[:-1] + bytes([data1[-1] ^ 1]) + bytes(13)  # 40 bytes, authenticates nowhere
    steps = [
        _open(0.0, "master", psk=PSK),
        _open(0.001, "master", psk=PSK, cookie=True, attempt=1),
        _step(0.002, "master", keepalive, note="authenticates: established"),
        _step(0.003, "master", data1),
        _step(
            0.004,
            "stranger",
            data1,
            note="a copy of an accepted datagram while its master was heard 1 ms ago: no session "
            "is quiet, nothing is tried, no RESET",
        ),
        _step(
            0.02,
            "stranger",
            data1,
            note="the session is quiet (migration_quiet 5 ms): the copy authenticates at a number "
            "it accepted already: replayed, it moves nothing and no RESET is signed for it",
        ),
        _step(
            0.021,
            "stranger",
            forged,
            exact=True,
            note="authenticates under no session, and every session is keyed and quiet: a RESET "
            "with one tag (40 bytes leave room for one)",
        ),
        _step(
            0.022,
            "master_moved",
            data2,
            note="above every number accepted: the session moves (roaming) and takes it in",
        ),
        _step(
            0.023,
            "master",
            data3,
            note="the old address, 1 ms after the move: the session is not quiet, no trial",
        ),
        _step(
            0.04,
            "master",
            data4,
            note="quiet at its new address now: the real master's next datagram (a newer number) "
            "takes the session back",
        ),
    ]
    return {
        "name": "server with a key: roaming, replayed copies, RESET",
        "config": {"psks": [PSK.hex()]},
        "random": _sessions(FIRST),
        "steps": steps,
    }


def server_slots() -> dict[str, Any]:
    """Section 5.1, rule 2.7: a full server gives a slot only from a master that is gone, tells it
    with CLOSE EVICTED, and repeats that CLOSE to its later datagrams (never a RESET)."""
    evicted_data = _data(MASTER_ISN + 1, bytes(range(25)))  # 30 bytes: room for the 23-byte CLOSE
    steps = [
        *_opening(),
        _open(0.5, "master2", nonce=MASTER2_NONCE, seq=MASTER2_ISN),
        _open(
            0.501,
            "master2",
            nonce=MASTER2_NONCE,
            seq=MASTER2_ISN,
            cookie=True,
            attempt=1,
            note="the only slot is held by a master heard 0.498 s ago: REJECT BUSY",
        ),
        _open(
            1.1,
            "master2",
            nonce=MASTER2_NONCE,
            seq=MASTER2_ISN,
            cookie=True,
            attempt=2,
            note="the first master has been silent for 1.1 s, over reclaim_after (1 s): gone. "
            "Its session ends EVICTED and the second master takes the slot",
        ),
        _step(
            1.15,
            "master",
            _keepalive(),
            note="the evicted master is back: a KEEPALIVE (22 bytes) is smaller than the CLOSE, so "
            "nothing (and never a RESET)",
        ),
        _step(1.16, "master", evicted_data, note="within silence_timeout of the CLOSE: nothing"),
        _step(1.21, "master", evicted_data, exact=True, note="the CLOSE EVICTED again"),
        _step(1.22, "master", evicted_data, note="within silence_timeout of the repeat: nothing"),
    ]
    return {
        "name": "server: a slot reclaimed from a master that is gone, and its eviction notice",
        "config": {"max_peers": 1, "reclaim_after": 1.0},
        "random": _sessions(FIRST, SECOND),
        "steps": steps,
    }


def server_exclusive() -> dict[str, Any]:
    """Section 5.9, unkeyed: another master is refused IN_USE while the one in control is heard,
    and takes over once it has been silent for takeover_after watchdog periods; the displaced
    master's later datagrams get its CLOSE TAKEN_OVER again."""
    late = _data(MASTER_ISN + 1, bytes(range(25)))
    steps = [
        *_opening(),
        _open(0.1, "master2", nonce=MASTER2_NONCE, seq=MASTER2_ISN),
        _open(
            0.101,
            "master2",
            nonce=MASTER2_NONCE,
            seq=MASTER2_ISN,
            cookie=True,
            attempt=1,
            note="the master in control was heard 0.098 s ago: REJECT IN_USE",
        ),
        _open(
            0.35,
            "master2",
            nonce=MASTER2_NONCE,
            seq=MASTER2_ISN,
            cookie=True,
            attempt=2,
            note="silent for 0.348 s, over takeover_after (3) x silence_timeout: taken over",
        ),
        _step(0.36, "master", late, note="within silence_timeout of the CLOSE: nothing"),
        _step(0.46, "master", late, note="the CLOSE TAKEN_OVER again, never a RESET"),
    ]
    return {
        "name": "server, exclusive: IN_USE, then a takeover after the silence",
        "config": {"exclusive": True},
        "random": _sessions(FIRST, SECOND),
        "steps": steps,
    }


def server_exclusive_takeover_flag() -> dict[str, Any]:
    """Section 5.9, keyed: TAKEOVER ends the controlling session at once; the OPEN_ACK echoes the
    OPEN's bits 0..2 only (section 4.3)."""
    suite = CipherSuite.AES_128_GCM
    session = derive_session_secrets(PSK, MASTER_NONCE, SLAVE_NONCE, suite)
    sealer = PacketSealer(suite, session.master_to_slave, encrypt=True)
    keepalive = sealer.seal(encode_header(2, MASTER_ISN, 0, 0, 255) + b"\x03", MASTER_NONCE)
    steps = [
        _open(0.0, "master", psk=PSK),
        _open(0.001, "master", psk=PSK, cookie=True, attempt=1),
        _step(0.002, "master", keepalive),
        _open(0.01, "master2", nonce=MASTER2_NONCE, seq=MASTER2_ISN, psk=PSK),
        _open(
            0.011,
            "master2",
            nonce=MASTER2_NONCE,
            seq=MASTER2_ISN,
            psk=PSK,
            cookie=True,
            attempt=1,
            note="keyed, without TAKEOVER, while the master in control is heard: IN_USE",
        ),
        _open(
            0.012,
            "master2",
            nonce=MASTER2_NONCE,
            seq=MASTER2_ISN,
            psk=PSK,
            cookie=True,
            attempt=2,
            flags=0x0E,
            exact=True,
            note="with TAKEOVER (flags 0x0E): the controlling session ends at once; the OPEN_ACK "
            "says flags 0x06",
        ),
    ]
    return {
        "name": "server with a key, exclusive: TAKEOVER",
        "config": {"exclusive": True, "psks": [PSK.hex()]},
        "random": _sessions(FIRST, SECOND),
        "steps": steps,
    }


def server_restarted_master() -> dict[str, Any]:
    """Section 5.1, rule 5: an OPEN with another nonce from a session's address replaces the
    session only once it has been silent longer than a live master is, and then opens at once."""
    steps = [
        *_opening(),
        _open(0.1, "master", nonce=OTHER_NONCE),
        _open(
            0.101,
            "master",
            nonce=OTHER_NONCE,
            cookie=True,
            attempt=1,
            note="another nonce, the session heard 0.098 s ago (a live master is silent at most "
            "0.233 s): a replay, dropped",
        ),
        _open(
            0.3,
            "master",
            nonce=OTHER_NONCE,
            cookie=True,
            attempt=2,
            note="silent for 0.298 s: the master restarted. The old session ends (replaced, no "
            "CLOSE) and the OPEN opens the new one at once",
        ),
    ]
    return {
        "name": "server: a restarted master replaces its silent session",
        "config": {},
        "random": _sessions(FIRST, SECOND),
        "steps": steps,
    }


def all_server_scripts() -> list[dict[str, Any]]:
    return [
        server_resets(),
        server_path_validation(),
        server_keyed_roaming(),
        server_slots(),
        server_exclusive(),
        server_exclusive_takeover_flag(),
        server_restarted_master(),
    ]
