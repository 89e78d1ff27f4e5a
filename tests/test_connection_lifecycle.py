"""Opening, keep-alive, idle timeout, closing and caller misuse."""

from __future__ import annotations

import itertools
import random

import pytest

from tdtp import (
    CloseCause,
    Connection,
    ConnectionClosed,
    ConnectionClosedError,
    ConnectionConfig,
    ConnectionEstablished,
    ConnectionStateError,
    PayloadTooLargeError,
    Role,
    State,
)
from tdtp.wire import ControlCode, PacketType

from pair import MASTER_ADDR, SLAVE_ADDR, Direction, Pair


def _closed(events: list[object]) -> list[ConnectionClosed]:
    return [e for e in events if isinstance(e, ConnectionClosed)]


def test_open_validates_the_address_then_establishes_both_sides() -> None:
    """OPEN, COOKIE, OPEN with the cookie, OPEN_ACK: the master is established after two round
    trips (40 ms); the slave half a round trip later, when the master's first packet of the session
    confirms it got the OPEN_ACK."""
    pair = Pair()
    pair.ms.keep_wire = pair.sm.keep_wire = True
    pair.open()
    assert pair.established
    assert pair.now == pytest.approx(0.050)
    codes = [d[5] for d in pair.ms.wire] + [d[5] for d in pair.sm.wire]
    assert codes == [1, 1, 3, 6, 2]  # OPEN, OPEN+cookie, KEEPALIVE; COOKIE, OPEN_ACK
    assert pair.master.events == [ConnectionEstablished(SLAVE_ADDR)]
    assert pair.slave.events == [ConnectionEstablished(MASTER_ADDR)]
    assert pair.slave.conn.peer == MASTER_ADDR


def test_lost_open_is_retransmitted() -> None:
    pair = Pair(ms=Direction(drop=lambda i: i < 3))
    pair.open()
    assert pair.established
    assert pair.now == pytest.approx(3 * 0.25 + 0.050)


def test_lost_open_ack_is_answered_again() -> None:
    pair = Pair(sm=Direction(drop=lambda i: i == 1))  # 0 is the COOKIE, 1 the OPEN_ACK
    pair.open()
    assert pair.established
    # The OPEN with the cookie, its retransmission, and the master's confirming KEEPALIVE.
    assert pair.slave.conn.stats.received.control_packets == 3


def test_unanswered_open_times_out() -> None:
    pair = Pair(ms=Direction(drop=lambda i: True))
    pair.open(timeout=10.0)
    pair.run_for(6.0)
    assert pair.master.conn.state is State.CLOSED
    (closed,) = _closed(pair.master.events)
    assert closed.cause is CloseCause.OPEN_TIMEOUT
    assert pair.ms.datagrams == 20  # one OPEN every 0.25 s for 5 s


def test_keepalives_hold_a_silent_connection_open() -> None:
    pair = Pair()
    pair.open()
    pair.run_for(10.0)
    assert pair.established
    for endpoint in (pair.master, pair.slave):
        # One keep-alive per third of silence_timeout (33 ms): a quiet peer never looks silent.
        assert 290 <= endpoint.conn.stats.sent.control_packets <= 313  # + the handshake
        assert endpoint.conn.stats.peer_silences == 0
        assert not endpoint.conn.peer_silent


def test_peer_that_disappears_is_reported_within_the_idle_timeout() -> None:
    pair = Pair()
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(1.0)
    pair.sm.drop = lambda i: True  # the slave drops off the network
    pair.run_for(29.9)
    assert pair.master.conn.state is State.ESTABLISHED  # an outage of 29.9 s is survived
    heard = pair.master.conn.silent_since
    assert heard is not None
    pair.run_until(heard + 30.0 + 0.001)
    (closed,) = _closed(pair.master.events)
    assert closed.cause is CloseCause.IDLE_TIMEOUT
    assert "30 s" in closed.detail
    assert pair.master.conn.state is State.CLOSED


def test_close_reaches_the_peer() -> None:
    pair = Pair()
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(0.5)
    pair.master.conn.close(now=pair.now)
    pair._flush(pair.master)
    pair.run_for(0.1)
    assert [c.cause for c in _closed(pair.master.events)] == [CloseCause.LOCAL_CLOSE]
    assert [c.cause for c in _closed(pair.slave.events)] == [CloseCause.PEER_CLOSE]
    assert pair.slave.conn.state is State.CLOSED


def test_misuse_raises_specific_errors_that_say_what_to_do() -> None:
    master = Connection(role=Role.MASTER, rng=random.Random(3))
    with pytest.raises(ConnectionStateError, match="wait for the ConnectionEstablished"):
        master.send(b"x", now=0.0)
    slave = Connection(role=Role.SLAVE)
    with pytest.raises(ConnectionStateError, match="for the side that dials"):
        slave.connect(MASTER_ADDR, now=0.0)
    master.connect(SLAVE_ADDR, now=0.0)
    with pytest.raises(ConnectionStateError, match="already called"):
        master.connect(SLAVE_ADDR, now=0.0)
    master.close(now=0.0)
    with pytest.raises(ConnectionClosedError, match="open a new one"):
        master.send(b"x", now=0.0)
    with pytest.raises(TypeError):
        Connection(role="master")  # type: ignore[arg-type]


def test_payload_limit_is_the_smaller_of_both_ends() -> None:
    pair = Pair(ConnectionConfig(max_payload=1000), ConnectionConfig(max_payload=200))
    pair.open()
    assert pair.master.conn.max_send_payload == 200
    assert pair.slave.conn.max_send_payload == 200
    pair.master.conn.send(bytes(200), now=pair.now)
    with pytest.raises(PayloadTooLargeError, match="exceeds the connection's maximum of 200"):
        pair.master.conn.send(bytes(201), now=pair.now)


def test_faster_samples_than_allowed_keep_only_the_freshest() -> None:
    from tdtp.control.fixed import FixedConfig

    limited = ConnectionConfig(controller="fixed", controller_config=FixedConfig(rate=100.0))
    pair = Pair(limited, limited)
    pair.open()
    pair.start_samples(1000, 0)
    pair.run_for(2.0)
    stats = pair.master.conn.stats
    assert 195 <= stats.sent.data_packets <= 202  # the pacer allows 100 packets/s
    assert stats.samples_superseded == stats.samples_offered - stats.sent.data_packets - (
        1 if pair.master.conn._sender.pending is not None else 0
    )
    # Each delivered sample was the newest one offered when it left: stamps advance ~10 at a time.
    stamps = [int.from_bytes(e.payload[:4], "big") for e in pair.slave.received]
    gaps = [b - a for a, b in itertools.pairwise(stamps)]
    assert min(gaps[2:]) >= 9 and max(gaps) <= 11


def test_pacer_deadline_shows_in_get_timer() -> None:
    from tdtp.control.fixed import FixedConfig

    limited = ConnectionConfig(controller="fixed", controller_config=FixedConfig(rate=100.0))
    pair = Pair(limited, limited)
    pair.open()
    conn = pair.master.conn
    now = pair.now
    # The schedule lets one catch-up packet follow the first at once, then paces at 100/s.
    for sample in (b"a", b"b"):
        conn.send(sample, now=now)
        assert len(conn.datagrams_to_send(now=now)) == 1
    conn.send(b"c", now=now)
    assert conn.datagrams_to_send(now=now) == []
    assert conn.get_timer() == pytest.approx(now + 0.010)
    assert len(conn.datagrams_to_send(now=now + 0.010)) == 1


def test_unread_events_are_bounded() -> None:
    pair = Pair(ConnectionConfig(), ConnectionConfig(max_pending_events=50))
    pair.open()
    pair._drain = lambda endpoint: None  # type: ignore[method-assign]  # the app stops reading
    pair.start_samples(1000, 0)
    pair.run_for(1.0)
    stats = pair.slave.conn.stats
    assert stats.events_discarded >= stats.samples_delivered - 50 > 900
    events = []
    while (event := pair.slave.conn.next_event()) is not None:
        events.append(event)
    assert len(events) == 50


@pytest.mark.parametrize("now", [0.001, 0.003, 0.1, 1234.567])
def test_the_master_confirms_in_the_same_instant_as_the_open_ack(now: float) -> None:
    """PROTOCOL.md 5.1, rule 6: the master sends its first packet at once. (The deadline used to be
    now - 0.25 + 0.25, which rounds above now for some values, e.g. 0.001.)"""
    pair = Pair()
    master = pair.master.conn
    master.connect(SLAVE_ADDR, now=now)
    opens = [d for d, _ in master.datagrams_to_send(now=now)]
    slave = pair.slave.conn
    slave.receive_datagram(opens[0], MASTER_ADDR, now=now)
    ((cookie, _),) = slave.datagrams_to_send(now=now)
    master.receive_datagram(cookie, SLAVE_ADDR, now=now)
    ((second, _),) = master.datagrams_to_send(now=now)
    slave.receive_datagram(second, MASTER_ADDR, now=now)
    ((open_ack, _),) = slave.datagrams_to_send(now=now)
    master.receive_datagram(open_ack, SLAVE_ADDR, now=now)
    assert master.state is State.ESTABLISHED
    ((confirm, _),) = master.datagrams_to_send(now=now)
    assert confirm[0] >> 6 == PacketType.CONTROL and confirm[5] == ControlCode.KEEPALIVE
