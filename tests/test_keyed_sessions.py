"""Keyed sessions in fake time: what they carry, and every attack of issue 11 failing against them."""

from __future__ import annotations

import random

import pytest

from tdtp import (
    CloseCause,
    Connection,
    ConnectionClosed,
    ConnectionConfig,
    InvalidKeyError,
    Role,
    State,
)
from tdtp.control.fixed import FixedConfig
from tdtp.protection import KeyRing, PresharedKey
from tdtp.protection.packet_protection import PACKET_LIMIT
from tdtp.wire import (
    HEADER_SIZE,
    PROTECTION_OVERHEAD,
    CipherSuite,
    CloseReason,
    ControlCode,
    PacketType,
    encode_close,
    encode_header,
)

from pair import MASTER_ADDR, SLAVE_ADDR, Direction, Pair

KEY = PresharedKey(bytes(range(32)), "station-1")
OTHER_KEY = PresharedKey(bytes(range(1, 33)), "station-2")
ATTACKER = ("198.51.100.66", 4000)


def _keyed(
    config: ConnectionConfig | None = None, *, seed: int = 1, keep_wire: bool = True
) -> Pair:
    pair = Pair(config, config, master_key=KEY, slave_keys=[KEY], seed=seed)
    pair.ms.keep_wire = pair.sm.keep_wire = keep_wire
    pair.open()
    assert pair.established
    pair.start_samples(1000, 1000)
    pair.run_for(0.3)
    return pair


def _drops(conn: Connection) -> dict[str, int]:
    return dict(conn.stats.drops)


def _refused(conn: Connection) -> int:
    """Protected datagrams refused: a tag that did not verify, or a packet number already used
    (checked first, as SRTP does, so a forgery reusing one counts as replayed)."""
    drops = conn.stats.drops
    return drops.get("unauthenticated", 0) + drops.get("replayed", 0)


def _open_until_settled(pair: Pair) -> None:
    """Open, and stop as soon as the master is established or closed."""
    pair.master.conn.connect(SLAVE_ADDR, now=pair.now)
    pair._flush(pair.master)
    pair.run_until(1.0, stop=lambda: pair.master.conn.state in (State.ESTABLISHED, State.CLOSED))


def _closed(events: list[object]) -> list[ConnectionClosed]:
    return [e for e in events if isinstance(e, ConnectionClosed)]


def _data(wire: list[bytes]) -> list[bytes]:
    return [d for d in wire if d[0] >> 6 == PacketType.DATA]


# ---------------------------------------------------------------------------- what a session carries


def test_a_keyed_session_carries_samples_with_18_bytes_of_protection() -> None:
    pair = _keyed()
    pair.drain()
    for endpoint in (pair.master, pair.slave):
        conn = endpoint.conn
        assert conn.keyed and conn.encrypted and conn.key == KEY
        stats = conn.stats
        assert stats.packets_lost == 0 and stats.dropped <= 1  # the first OPEN: a COOKIE
        assert stats.sent.data_packets >= 290
        # Every datagram after the handshake carries 18 bytes; the master's two OPENs and the
        # slave's OPEN_ACK a 16-byte tag; the slave's COOKIE nothing.
        handshake = 2 * 16 if endpoint is pair.master else 16
        assert stats.sent.protection_bytes == (
            PROTECTION_OVERHEAD * (stats.sent.datagrams - 2) + handshake
        )
    data = _data(pair.ms.wire)
    assert {len(d) for d in data} == {HEADER_SIZE + 100 + PROTECTION_OVERHEAD}
    # Encrypted: the 4-byte sample counter the pair writes first never shows on the wire.
    received = pair.slave.received
    assert [int.from_bytes(r.payload[:4], "big") for r in received[:3]] == [1, 2, 3]
    assert not any(d[7:11] == (1).to_bytes(4, "big") for d in data)


def test_encryption_off_leaves_payloads_readable_but_authenticated() -> None:
    # Every sample a DATA (no send timestamps), so the first one is sample 1.
    pair = _keyed(ConnectionConfig(encrypt=False, timestamp_interval=0.0))
    assert pair.slave.conn.keyed and not pair.slave.conn.encrypted  # the slave adopted it
    data = _data(pair.ms.wire)
    first = data[0]
    assert first[7:11] == (1).to_bytes(4, "big")  # the payload in the clear after header + PN
    tampered = bytearray(data[-1])
    tampered[10] ^= 0x01
    pair.inject(bytes(tampered), to_slave=True, source=MASTER_ADDR)
    assert _drops(pair.slave.conn).get("unauthenticated") == 1


@pytest.mark.parametrize("suite", [CipherSuite.AES_128_GCM, CipherSuite.CHACHA20_POLY1305])
def test_both_cipher_suites(suite: CipherSuite) -> None:
    pair = _keyed(ConnectionConfig(cipher_suite=suite))
    pair.drain()
    assert pair.slave.conn.stats.samples_delivered >= 290
    assert pair.slave.conn._handshake.suite is suite


def test_a_slave_serves_each_master_with_its_own_key_and_says_which() -> None:
    ring = KeyRing([KEY, OTHER_KEY])
    for key in (KEY, OTHER_KEY):
        pair = Pair(master_key=key, slave_keys=ring)
        pair.open()
        assert pair.established
        assert pair.slave.conn.key is not None and pair.slave.conn.key.name == key.name


# ---------------------------------------------------------------------------- refusals


def test_a_master_with_an_unknown_key_is_refused_at_once_and_told_why() -> None:
    pair = Pair(master_key=OTHER_KEY, slave_keys=[KEY])
    _open_until_settled(pair)
    (closed,) = _closed(pair.master.events)
    assert closed.cause is CloseCause.REJECTED
    assert OTHER_KEY.key_id.hex() in closed.detail and "does not hold this key" in closed.detail
    assert pair.now == pytest.approx(0.040)  # a cookie round trip and the REJECT, no open_timeout
    assert pair.slave.conn.state is State.LISTENING  # nothing kept


def test_an_unkeyed_master_is_refused_by_a_keyed_slave() -> None:
    pair = Pair(slave_keys=[KEY])
    _open_until_settled(pair)
    (closed,) = _closed(pair.master.events)
    assert closed.cause is CloseCause.REJECTED and "keyed sessions only" in closed.detail


def test_a_keyed_master_is_refused_by_an_unkeyed_slave() -> None:
    pair = Pair(master_key=KEY)
    _open_until_settled(pair)
    (closed,) = _closed(pair.master.events)
    assert closed.cause is CloseCause.REJECTED and "unkeyed sessions only" in closed.detail


def test_key_arguments_are_checked() -> None:
    with pytest.raises(InvalidKeyError, match=r"16\.\.64 random bytes"):
        PresharedKey(b"short")
    with pytest.raises(InvalidKeyError, match="keys="):
        Connection(role=Role.SLAVE, key=KEY)
    with pytest.raises(InvalidKeyError, match="key="):
        Connection(role=Role.MASTER, keys=[KEY])
    with pytest.raises(InvalidKeyError, match="same secret twice"):
        KeyRing([KEY, PresharedKey(KEY.secret, "again")])
    assert "secret" not in repr(KEY) and KEY.secret.hex() not in repr(KEY)


# ---------------------------------------------------------------------------- attacks


def test_blind_injection_from_the_masters_address_is_dropped() -> None:
    """Forging the master's address with random sequence numbers (half got in on unkeyed code)."""
    pair = _keyed()
    rng = random.Random(7)
    delivered = len(pair.slave.received)
    for _ in range(2000):
        seq, pn = rng.randrange(4096), rng.randrange(65536)
        forged = encode_header(PacketType.DATA, seq, 0, 0, 255) + pn.to_bytes(2, "big")
        forged += rng.randbytes(100 + 16)
        pair.inject(forged, to_slave=True, source=MASTER_ADDR)
    assert _refused(pair.slave.conn) == 2000
    assert len(pair.slave.received) == delivered  # not one forged command delivered
    pair.run_for(0.2)
    assert pair.established and len(pair.slave.received) >= delivered + 150


def test_on_path_replay_and_modification_are_dropped() -> None:
    pair = _keyed()
    pair.drain(0.05)  # everything in flight has arrived: what the attacker replays is old
    data = _data(pair.ms.wire)
    delivered = len(pair.slave.received)
    for datagram in data[-50:]:  # an on-path attacker replays what it saw
        pair.inject(datagram, to_slave=True, source=MASTER_ADDR)
    assert _drops(pair.slave.conn).get("replayed") == 50
    # One bit flipped in the header, the packet number, the payload, the tag: each is covered.
    for index in (1, 3, 5, 6, 50, len(data[-1]) - 1):
        tampered = bytearray(data[-1])
        tampered[index] ^= 0x80
        pair.inject(bytes(tampered), to_slave=True, source=MASTER_ADDR)
    assert _refused(pair.slave.conn) == 56
    dropped = pair.slave.conn.stats.dropped
    tampered = bytearray(data[-1])
    tampered[0] ^= 0x80  # TYPE becomes CONTROL: read as something else, and dropped all the same
    pair.inject(bytes(tampered), to_slave=True, source=MASTER_ADDR)
    assert pair.slave.conn.stats.dropped == dropped + 1
    assert len(pair.slave.received) == delivered


def test_a_forged_close_with_the_sniffed_nonce_does_not_end_the_session() -> None:
    pair = _keyed()
    nonce = pair.master.conn._handshake.master_nonce  # an attacker sniffed it from the OPEN
    forged = encode_header(PacketType.CONTROL, 0, 0, 0, 255) + encode_close(
        ControlCode.CLOSE, nonce, CloseReason.NORMAL
    )
    pair.inject(forged, to_slave=True, source=MASTER_ADDR)
    pair.inject(forged, to_slave=False, source=SLAVE_ADDR)
    assert _drops(pair.slave.conn).get("truncated") == 1  # too short to be a protected CLOSE
    padded = forged + bytes(PROTECTION_OVERHEAD)
    pair.inject(padded, to_slave=True, source=MASTER_ADDR)
    pair.inject(padded, to_slave=False, source=SLAVE_ADDR)
    assert _drops(pair.slave.conn).get("unauthenticated") == 1
    assert _drops(pair.master.conn).get("unauthenticated") == 1
    pair.run_for(0.2)
    assert pair.established


def test_a_captured_session_cannot_be_replayed_into_a_new_one() -> None:
    """Same key, new nonces: yesterday's packets do not authenticate today."""
    old = _keyed(seed=1)
    new = _keyed(seed=5)
    delivered = len(new.slave.received)
    for datagram in _data(old.ms.wire)[-100:]:
        new.inject(datagram, to_slave=True, source=MASTER_ADDR)
    assert _refused(new.slave.conn) == 100
    assert len(new.slave.received) == delivered


def test_a_masters_packets_reflected_back_to_it_do_not_authenticate() -> None:
    pair = _keyed()
    for datagram in _data(pair.ms.wire)[-20:]:
        pair.inject(datagram, to_slave=False, source=SLAVE_ADDR)
    assert _refused(pair.master.conn) == 20


def test_a_replayed_open_ack_is_dropped() -> None:
    pair = _keyed()
    open_ack = next(d for d in pair.sm.wire if d[0] >> 6 == 2 and d[5] == ControlCode.OPEN_ACK)
    pair.inject(open_ack, to_slave=False, source=SLAVE_ADDR)
    assert _drops(pair.master.conn).get("replayed") == 1


def test_a_sniffed_open_replayed_from_elsewhere_creates_nothing() -> None:
    """The attacker copies the master's OPEN (nonce, key id, tag) from its own address: it gets a
    cookie for its address, but cannot re-tag the OPEN around it."""
    pair = _keyed()
    slave = Connection(role=Role.SLAVE, keys=[KEY], rng=random.Random(9))
    sniffed = next(d for d in pair.ms.wire if d[5] == ControlCode.OPEN)
    slave.receive_datagram(sniffed, ATTACKER, now=1.0)
    ((cookie_reply, _),) = slave.datagrams_to_send(now=1.0)
    cookie = cookie_reply[-16:]
    replay = bytearray(sniffed)
    replay[HEADER_SIZE + 32 : HEADER_SIZE + 48] = cookie  # the cookie field of the OPEN
    slave.receive_datagram(bytes(replay), ATTACKER, now=1.0)
    assert slave.stats.drops == {"unvalidated": 1, "unauthenticated": 1}
    assert slave.state is State.LISTENING and slave.datagrams_to_send(now=1.0) == []


def test_a_ten_second_outage_at_1khz_recovers() -> None:
    """10,000 lost datagrams each way (2.4 wraps of the 12-bit sequence): the 16-bit packet
    number still decodes, and the session carries on."""
    config = ConnectionConfig(
        controller="fixed", controller_config=FixedConfig(rate=1000.0), idle_timeout=20.0
    )
    pair = _keyed(config, keep_wire=False)
    start = pair.now
    pair.ms.drop = pair.sm.drop = lambda i: start + 0.0 <= pair.now < start + 10.0
    pair.run_for(10.0)
    before = len(pair.slave.received), len(pair.master.received)
    pair.ms.drop = pair.sm.drop = lambda i: False
    pair.run_for(1.0)
    assert pair.established
    assert len(pair.slave.received) - before[0] > 900
    assert len(pair.master.received) - before[1] > 900
    assert "unauthenticated" not in _drops(pair.slave.conn)


@pytest.mark.parametrize("seconds", [20.0, 40.0])
def test_a_blackout_longer_than_the_packet_number_window_recovers(seconds: float) -> None:
    """Issue 20, item 2: at 2 kHz a 40-second blackout loses 80,000 datagrams each way, more than the
    16-bit packet number decodes by itself (32,767); every later datagram used to be refused as a
    replay until the idle timeout closed the session (this test fails without the resynchronisation).
    The first one after the blackout now resynchronises. (20 s, 40,000 lost, early in a session is
    saved by the expansion's wrap below zero; a test in test_protection.py covers the general case.)"""
    config = ConnectionConfig(
        controller="fixed", controller_config=FixedConfig(rate=2000.0), idle_timeout=60.0
    )
    pair = _keyed(config, keep_wire=False)
    pair.start_samples(2000.0, 2000.0)
    pair.run_for(1.0)
    start = pair.now
    pair.ms.drop = pair.sm.drop = lambda i: start <= pair.now < start + seconds
    pair.run_for(seconds)
    before = len(pair.slave.received), len(pair.master.received)
    pair.ms.drop = pair.sm.drop = lambda i: False
    pair.run_for(1.0)
    assert pair.established
    assert len(pair.slave.received) - before[0] > 1800
    assert len(pair.master.received) - before[1] > 1800
    assert "replayed" not in _drops(pair.slave.conn) and "replayed" not in _drops(pair.master.conn)


def test_the_key_is_retired_before_its_packet_limit() -> None:
    pair = _keyed()
    sealer = pair.master.conn._outbox.sealer
    assert sealer is not None
    sealer.next_number = PACKET_LIMIT - 1
    pair.run_for(0.01)
    (closed,) = _closed(pair.master.events)
    assert closed.cause is CloseCause.KEY_EXHAUSTED


def test_a_tampered_open_ack_is_dropped_and_the_master_keeps_trying() -> None:
    def tamper(index: int, datagram: bytes) -> bytes:
        if index == 1:  # the first OPEN_ACK (0 is the COOKIE): one bit of its tag flipped
            return datagram[:-1] + bytes([datagram[-1] ^ 1])
        return datagram

    pair = Pair(master_key=KEY, slave_keys=[KEY], sm=Direction(rewrite=tamper))
    pair.open()
    assert pair.established  # the retransmitted OPEN got a fresh OPEN_ACK
    assert _drops(pair.master.conn) == {"unauthenticated": 1}
    assert pair.now == pytest.approx(0.25 + 0.05)


@pytest.mark.parametrize("keyed", [False, True])
@pytest.mark.parametrize("mode", ["bidirectional", "separate"])
def test_what_one_side_sends_the_other_counts_received_byte_for_byte(
    keyed: bool, mode: str
) -> None:
    """On a lossless path every datagram, byte and protection byte one side sent is counted by
    the other, except the master's first OPEN (answered with a COOKIE, counted as a drop)."""
    from tdtp import AckMode

    config = ConnectionConfig(
        ack_mode=AckMode.SEPARATE if mode == "separate" else AckMode.BIDIRECTIONAL, ack_size=12
    )
    pair = Pair(
        config, config, master_key=KEY if keyed else None, slave_keys=[KEY] if keyed else None
    )
    pair.ms.keep_wire = True
    pair.open()
    pair.start_samples(1000, 300)
    pair.run_for(0.5)
    pair.drain(0.06)
    while pair._in_flight:  # keep-alives go every 33 ms: stop between two of them
        pair.run_for(0.001)
    master, slave = pair.master.conn.stats, pair.slave.conn.stats
    first_open = len(pair.ms.wire[0])
    assert slave.drops == {"unvalidated": 1} and master.dropped == 0
    assert master.sent.datagrams - 1 == slave.received.datagrams
    assert master.sent.bytes - first_open == slave.received.bytes
    assert slave.sent.datagrams == master.received.datagrams
    assert slave.sent.bytes == master.received.bytes
    for field in ("data_packets", "ack_packets", "payload_bytes", "header_bytes"):
        assert getattr(slave.sent, field) == getattr(master.received, field), field
    tag = 16 if keyed else 0
    assert master.sent.protection_bytes - tag == slave.received.protection_bytes
    assert slave.sent.protection_bytes == master.received.protection_bytes


def test_an_empty_sealed_data_packet_is_dropped_after_it_authenticates() -> None:
    """A keyed peer that seals an empty DATA (a sender MUST NOT) gets it dropped as empty_data:
    the check is on the opened body, after the tag."""
    pair = _keyed()
    sealer = pair.master.conn._outbox.sealer
    assert sealer is not None
    datagram = sealer.seal(
        encode_header(PacketType.DATA, pair.master.conn._recovery.sent.next_seq, 0, 0, 255), b""
    )
    assert len(datagram) == HEADER_SIZE + PROTECTION_OVERHEAD
    pair.inject(datagram, to_slave=True, source=MASTER_ADDR)
    assert _drops(pair.slave.conn).get("empty_data") == 1
    assert _refused(pair.slave.conn) == 0


def test_a_sample_of_max_payload_bytes_arrives_in_a_keyed_session() -> None:
    """The size check allows the 18 bytes of protection on top of max_payload (PROTOCOL.md 5.5);
    it once refused every keyed sample longer than max_payload - 18 as oversized."""
    config = ConnectionConfig(max_payload=300)
    pair = Pair(config, config, master_key=KEY, slave_keys=[KEY])
    pair.open()
    pair.start_samples(100, 100, size=300)
    pair.run_for(0.5)
    assert "oversized" not in _drops(pair.slave.conn)
    assert len(pair.slave.received) >= 45 and len(pair.master.received) >= 45
    assert {len(event.payload) for event in pair.slave.received} == {300}
    # One byte more than max_payload is still refused (by the datagram size, before the tag).
    sealer = pair.master.conn._outbox.sealer
    assert sealer is not None
    header = encode_header(PacketType.DATA, pair.master.conn._recovery.sent.next_seq, 0, 0, 255)
    pair.inject(sealer.seal(header, bytes(301)), to_slave=True, source=MASTER_ADDR)
    assert _drops(pair.slave.conn).get("oversized") == 1
