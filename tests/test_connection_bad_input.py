"""Hostile and broken datagrams: dropped, counted by reason, never raised."""

from __future__ import annotations

import random

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tdtp import Connection, ConnectionConfig, EmptyPayloadError, Role, State
from tdtp.wire import (
    PROTOCOL_VERSION,
    CloseReason,
    ControlCode,
    OpenAckBody,
    OpenBody,
    PacketType,
    encode_close,
    encode_header,
    encode_keepalive,
    encode_open,
    encode_open_ack,
    encode_path_challenge,
    encode_path_response,
)

from pair import MASTER_ADDR, SLAVE_ADDR, Pair

STRANGER = ("198.51.100.7", 666)
OTHER_NONCE = bytes(range(16))
CONTROL_HEADER = encode_header(2, 0, 0, 0, 255)


def _open(
    nonce: bytes = OTHER_NONCE, cookie: bytes = bytes(16), version: int = PROTOCOL_VERSION
) -> bytes:
    body = OpenBody(version, 0, 0, 1200, 0, nonce, bytes(8), cookie)
    return CONTROL_HEADER + encode_open(body)


def _established() -> Pair:
    pair = Pair()
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(0.2)
    return pair


def _drops(pair: Pair) -> dict[str, int]:
    return dict(pair.slave.conn.stats.drops)


@pytest.mark.parametrize(
    ("datagram", "source", "reason"),
    [
        (b"", MASTER_ADDR, "truncated"),
        (b"\x00\x01\x02\x03", MASTER_ADDR, "truncated"),
        (encode_header(3, 0, 0, 0, 255) + b"x", MASTER_ADDR, "unknown_type"),
        (encode_header(0, 0, 0, 0, 255) + bytes(1201), MASTER_ADDR, "oversized"),
        (encode_header(0, 0, 0, 0, 255), MASTER_ADDR, "empty_data"),
        (encode_header(0, 0, 0, 0, 255) + b"x", STRANGER, "wrong_address"),
        (encode_header(2, 0, 0, 0, 255), MASTER_ADDR, "bad_control"),
        (encode_header(2, 0, 0, 0, 255) + b"\x09", MASTER_ADDR, "bad_control"),
        (encode_header(2, 0, 0, 0, 255) + b"\x04" + bytes(3), MASTER_ADDR, "bad_control"),
        (
            CONTROL_HEADER + encode_close(ControlCode.CLOSE, OTHER_NONCE, 0),
            MASTER_ADDR,
            "nonce_mismatch",
        ),
        # A KEEPALIVE with another nonce (a blind forgery): no sign of life, counted.
        (CONTROL_HEADER + encode_keepalive(OTHER_NONCE), MASTER_ADDR, "nonce_mismatch"),
        # Path validation is the master's to answer and the server's to check, not a slave session's.
        (CONTROL_HEADER + encode_path_challenge(OTHER_NONCE), MASTER_ADDR, "unexpected_control"),
        (
            CONTROL_HEADER + encode_path_response(OTHER_NONCE, OTHER_NONCE),
            MASTER_ADDR,
            "unexpected_control",
        ),
        # An OPEN without a cookie: answered with a COOKIE, nothing kept.
        (_open(), MASTER_ADDR, "unvalidated"),
        (_open(), STRANGER, "wrong_address"),
        (
            CONTROL_HEADER
            + encode_open_ack(
                OpenAckBody(PROTOCOL_VERSION, 0, 0, 1200, 0, OTHER_NONCE, OTHER_NONCE)
            ),
            MASTER_ADDR,
            "unexpected_control",
        ),
    ],
)
def test_bad_datagrams_are_dropped_by_reason(
    datagram: bytes, source: tuple[str, int], reason: str
) -> None:
    pair = _established()
    before = _drops(pair).get(reason, 0)
    delivered = len(pair.slave.received)
    pair.inject(datagram, to_slave=True, source=source)
    assert _drops(pair).get(reason, 0) == before + 1
    pair.run_for(0.2)
    assert pair.established
    assert len(pair.slave.received) > delivered + 150  # the session carries on undisturbed


def test_an_optimistic_ack_is_ignored_and_a_standalone_one_dropped() -> None:
    """An acknowledgement of a packet never sent is never used. In a DATA packet only the
    acknowledgement is ignored (PROTOCOL.md 3.1: the sample is not lost with it); a stand-alone
    ACK carries nothing else and is dropped."""
    pair = _established()
    master = pair.master.conn
    ahead = master._recovery.sent.next_seq + 100  # a packet the master has not sent yet
    seq = pair.slave.conn._recovery.sent.next_seq  # the slave's next sample: new, in order
    forged = encode_header(PacketType.DATA, seq, ahead, 0, 0) + b"x"
    pair.inject(forged, to_slave=False, source=SLAVE_ADDR)
    assert master.stats.drops == {} and master.stats.optimistic_acks == 1
    assert pair.master.received[-1].payload == b"x"
    pair.inject(encode_header(PacketType.ACK, 0, ahead, 0, 0), to_slave=False, source=SLAVE_ADDR)
    assert master.stats.drops == {"optimistic_ack": 1}
    pair.run_for(0.2)
    assert master.stats.packets_lost == 0  # the forged ACKs changed nothing


def test_replayed_data_is_a_duplicate() -> None:
    pair = Pair(ConnectionConfig(timestamp_interval=0.0))  # every sample a DATA: the index counts
    pair.ms.keep_wire = True
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(0.1)
    data = [d for d in pair.ms.wire if d[0] >> 6 == PacketType.DATA]
    pair.inject(data[-20], to_slave=True, source=MASTER_ADDR)  # arrived ~10 ms ago
    assert _drops(pair).get("duplicate") == 1
    pair.inject(data[-90], to_slave=True, source=MASTER_ADDR)  # older than the 64-packet window
    assert _drops(pair).get("stale") == 1


def test_open_from_the_masters_address_with_a_valid_cookie_cannot_end_a_live_session() -> None:
    """A replayed or forged OPEN (another nonce, even with a valid cookie) while the master is
    talking: dropped. Only a session that has gone quiet is replaced (test_restart_*)."""
    pair = _established()
    admission = pair.slave.conn.admission
    assert admission is not None
    cookie = admission._cookies.mint(MASTER_ADDR, OTHER_NONCE, pair.now)
    pair.inject(_open(cookie=cookie), to_slave=True, source=MASTER_ADDR)
    assert _drops(pair).get("nonce_mismatch") == 1
    pair.run_for(0.2)
    assert pair.established


def test_unknown_version_open_is_rejected_and_the_master_told() -> None:
    slave = Connection(role=Role.SLAVE, rng=random.Random(1))
    slave.receive_datagram(_open(version=99), MASTER_ADDR, now=0.0)
    assert slave.stats.drops == {"unknown_version": 1}
    assert slave.state is State.LISTENING
    ((reply, addr),) = slave.datagrams_to_send(now=0.0)
    assert addr == MASTER_ADDR
    assert reply[5] == ControlCode.REJECT and reply[-1] == CloseReason.VERSION_UNSUPPORTED
    assert reply[6:22] == OTHER_NONCE


def test_a_version_1_open_gets_nothing_larger_than_itself() -> None:
    """Version 1's OPEN was 18 bytes; a REJECT is 23: no answer at all (no amplification)."""
    slave = Connection(role=Role.SLAVE, rng=random.Random(1))
    slave.receive_datagram(CONTROL_HEADER + bytes([1, 1, 0]) + bytes(10), MASTER_ADDR, now=0.0)
    assert slave.stats.drops == {"unknown_version": 1}
    assert slave.datagrams_to_send(now=0.0) == []


def test_data_before_the_open_and_after_the_close_is_dropped() -> None:
    slave = Connection(role=Role.SLAVE, rng=random.Random(1))
    slave.receive_datagram(encode_header(0, 1, 0, 0, 255) + b"x", MASTER_ADDR, now=0.0)
    assert slave.stats.drops == {"not_established": 1}
    slave.close(now=0.0)
    slave.receive_datagram(encode_header(0, 1, 0, 0, 255) + b"x", MASTER_ADDR, now=0.0)
    assert slave.stats.drops == {"not_established": 1, "closed": 1}


# ---------------------------------------------------------------------------- fuzzing


def _connections_in_every_state() -> list[Connection]:
    idle = Connection(role=Role.MASTER, rng=random.Random(1))
    opening = Connection(role=Role.MASTER, rng=random.Random(2))
    opening.connect(SLAVE_ADDR, now=0.0)
    listening = Connection(role=Role.SLAVE, rng=random.Random(3))
    pair = _established()
    closed = Connection(role=Role.MASTER, rng=random.Random(4))
    closed.connect(SLAVE_ADDR, now=0.0)
    closed.close(now=0.0)
    return [idle, opening, listening, pair.master.conn, pair.slave.conn, closed]


def _valid_packets() -> list[bytes]:
    pair = Pair()
    pair.ms.keep_wire = pair.sm.keep_wire = True
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(0.05)
    pair.master.conn.close(now=pair.now)
    pair._flush(pair.master)
    return pair.ms.wire + pair.sm.wire


VALID = _valid_packets()


def _mutated(data: st.DataObject) -> bytes:
    packet = bytearray(data.draw(st.sampled_from(VALID)))
    for _ in range(data.draw(st.integers(0, 4))):
        if packet:
            index = data.draw(st.integers(0, len(packet) - 1))
            packet[index] = data.draw(st.integers(0, 255))
    cut = data.draw(st.integers(0, len(packet)))
    return bytes(packet[:cut]) if data.draw(st.booleans()) else bytes(packet)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_any_bytes_never_raise_and_every_datagram_is_accounted(data: st.DataObject) -> None:
    connections = _connections_in_every_state()
    now = 0.3
    for _ in range(data.draw(st.integers(1, 25))):
        datagram = data.draw(st.binary(max_size=80)) if data.draw(st.booleans()) else _mutated(data)
        source = data.draw(st.sampled_from([MASTER_ADDR, SLAVE_ADDR, STRANGER]))
        now += data.draw(st.floats(0, 0.05))
        for conn in connections:
            conn.receive_datagram(datagram, source, now=now)
            conn.datagrams_to_send(now=now)
            timer = conn.get_timer()
            if timer is not None and timer <= now:
                conn.handle_timer(now=now)
            while conn.next_event() is not None:
                pass
    for conn in connections:
        stats = conn.stats
        assert stats.datagrams_in == stats.received.datagrams + stats.dropped


def test_config_is_validated_with_messages() -> None:
    with pytest.raises(ValueError, match="max_payload"):
        ConnectionConfig(max_payload=0)
    with pytest.raises(ValueError, match="ack_size"):
        ConnectionConfig(ack_size=4)
    with pytest.raises(ValueError, match="ack_delay must be at most"):
        ConnectionConfig(ack_delay=0.5)
    with pytest.raises(ValueError, match="keepalive_interval"):
        ConnectionConfig(keepalive_interval=3.0, idle_timeout=2.0)
    with pytest.raises(ValueError, match="idle_timeout"):
        ConnectionConfig(idle_timeout=float("nan"))
    with pytest.raises(ValueError, match="reorder_threshold"):
        ConnectionConfig(reorder_threshold=7)
    with pytest.raises(ValueError, match="unknown controller"):
        Connection(ConnectionConfig(controller="bbr"), role=Role.MASTER)


def test_an_empty_data_packet_is_never_sent_and_dropped_on_arrival() -> None:
    """PROTOCOL.md 4.1: a DATA payload is 1..max_payload bytes. A sender MUST NOT send an empty
    one (send() refuses it); a receiver drops one as empty_data, delivers nothing, and takes
    nothing from the acknowledgement it carries."""
    pair = _established()
    slave = pair.slave.conn
    with pytest.raises(EmptyPayloadError, match="at least one byte"):
        pair.master.conn.send(b"", now=pair.now)
    delivered = slave.stats.samples_delivered
    highest = slave._acks.window.highest if slave._acks.window is not None else None
    # The next sequence number, acknowledging something the slave really sent: looks legitimate.
    master = pair.master.conn
    datagram = encode_header(PacketType.DATA, master._recovery.sent.next_seq, 0, 0, 255)
    pair.inject(datagram, to_slave=True, source=MASTER_ADDR)
    assert _drops(pair).get("empty_data") == 1
    assert slave.stats.samples_delivered == delivered
    window = slave._acks.window
    assert window is not None and window.highest == highest  # no sequence consumed
