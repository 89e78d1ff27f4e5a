"""How a session ends, in fake time (PROTOCOL.md 5.2 "Closing", 5.10 sender rule 6): a CLOSE says
whether its sender is restarting or evicting, each reason a cause of its own; control messages the
peer never acknowledged are reported, never dropped unsaid; a closed connection reads as closed."""

from __future__ import annotations

import math

import pytest

from tdtp import (
    CloseCause,
    ConnectionClosed,
    ConnectionClosedError,
    ControlChannelFailedError,
    ControlExpired,
    PresharedKey,
    State,
)
from tdtp.wire.control import CloseReason, ControlCode, encode_close
from tdtp.wire.header import encode_header

from pair import MASTER_ADDR, SLAVE_ADDR, Pair

KEY = PresharedKey(bytes(range(32)))


def _closed(events: list[object]) -> ConnectionClosed:
    (event,) = [e for e in events if isinstance(e, ConnectionClosed)]
    return event


@pytest.mark.parametrize("keyed", [False, True], ids=["unkeyed", "keyed"])
def test_a_restarting_slave_says_so_and_the_master_ends_peer_restarting(keyed: bool) -> None:
    pair = Pair(master_key=KEY if keyed else None, slave_keys=KEY if keyed else None)
    pair.open()
    pair.slave.conn.close(now=pair.now, restarting=True)
    pair.run_for(0.1)
    master, slave = _closed(pair.master.events), _closed(pair.slave.events)
    assert master.cause is CloseCause.PEER_RESTARTING and master.reason == CloseReason.RESTARTING
    assert "restarting" in master.detail and "reconnect=" in master.detail
    assert slave.cause is CloseCause.LOCAL_CLOSE and slave.reason == CloseReason.RESTARTING
    assert pair.master.conn.state is State.CLOSED


def test_a_normal_close_and_an_unknown_reason_end_peer_close() -> None:
    pair = Pair()
    pair.open()
    pair.slave.conn.close(now=pair.now)
    pair.run_for(0.1)
    event = _closed(pair.master.events)
    assert event.cause is CloseCause.PEER_CLOSE and event.reason == CloseReason.NORMAL
    pair = Pair()
    pair.open()
    nonce = pair.master.conn.master_nonce
    close = encode_header(2, 0, 0, 0, 255) + encode_close(ControlCode.CLOSE, nonce, 200)
    pair.inject(close, to_slave=False, source=SLAVE_ADDR)
    event = _closed(pair.master.events)
    assert event.cause is CloseCause.PEER_CLOSE and event.detail == "reason code 200"
    assert event.reason == 200


@pytest.mark.parametrize("keyed", [False, True], ids=["unkeyed", "keyed"])
def test_an_evicted_master_is_told_why(keyed: bool) -> None:
    pair = Pair(master_key=KEY if keyed else None, slave_keys=KEY if keyed else None)
    pair.open()
    close = pair.slave.conn.evict("given to another master", now=pair.now)
    assert close is not None
    pair.run_for(0.1)
    slave, master = _closed(pair.slave.events), _closed(pair.master.events)
    assert slave.cause is CloseCause.EVICTED and slave.detail == "given to another master"
    assert master.cause is CloseCause.EVICTED and master.reason == CloseReason.EVICTED
    assert "reopen later" in master.detail
    assert pair.slave.conn.evict("again", now=pair.now) is None  # closed already: nothing


def test_unacknowledged_control_messages_are_reported_when_the_session_ends() -> None:
    """An emergency stop sent into an outage is never dropped unsaid: the session's end reports
    it (ControlExpired with the payloads, before the ConnectionClosed)."""
    pair = Pair()
    pair.open()
    pair.master.conn.send_control(b"delivered", now=pair.now)
    pair.run_for(0.1)
    pair.ms.drop = lambda _: True  # the path to the slave goes down
    pair.master.conn.send_control(b"E-STOP", now=pair.now)
    pair.master.conn.send_control(b"mode 2", now=pair.now)
    pair.run_for(0.5)
    pair.master.conn.close(now=pair.now)
    pair._drain(pair.master)
    kinds = [type(e) for e in pair.master.events]
    assert kinds.index(ControlExpired) == kinds.index(ConnectionClosed) - 1
    (expired,) = [e for e in pair.master.events if isinstance(e, ControlExpired)]
    assert expired.payloads == (b"E-STOP", b"mode 2") and expired.first_index == 1
    assert "not resent" in expired.detail and "local_close" in expired.detail
    assert pair.master.conn.stats.control_given_up == 2
    with pytest.raises(ConnectionClosedError):
        pair.master.conn.send_control(b"late", now=pair.now)
    # Every message acknowledged: nothing to report.
    quiet = Pair()
    quiet.open()
    quiet.master.conn.send_control(b"ok", now=quiet.now)
    quiet.run_for(0.2)
    quiet.master.conn.close(now=quiet.now)
    quiet._drain(quiet.master)
    assert not [e for e in quiet.master.events if isinstance(e, ControlExpired)]
    assert ControlChannelFailedError  # the error a failed channel raises (kept importable)


def test_a_closed_connection_reads_as_closed() -> None:
    pair = Pair()
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(0.5)
    live = pair.master.conn.stats
    assert not pair.master.conn.peer_silent and live.srtt > 0 and not live.closed
    pair.slave.conn.close(now=pair.now)
    pair.run_for(0.05)
    for conn in (pair.master.conn, pair.slave.conn):
        stats = conn.stats
        assert conn.peer_silent and stats.closed
        assert math.isnan(stats.srtt) and math.isnan(stats.rttvar)
        assert stats.rate == 0.0 and stats.rate_limit == "closed"
        assert stats.min_rtt > 0 and stats.sent.data_packets > 400  # the history stays
        data = stats.as_dict()
        assert data["srtt"] is None and data["rate"] == 0.0 and data["closed"] is True


def test_a_reject_carries_its_reason() -> None:
    """The REJECT's reason code travels with the master's ConnectionClosed (reconnect= retries a
    BUSY, not a KEY_UNKNOWN)."""
    pair = Pair()
    pair.master.conn.connect(SLAVE_ADDR, now=pair.now)
    for data, _ in pair.master.conn.datagrams_to_send(now=pair.now):
        del data
    nonce = pair.master.conn.master_nonce
    reject = encode_header(2, 0, 0, 0, 255) + encode_close(ControlCode.REJECT, nonce, 5)
    pair.inject(reject, to_slave=False, source=SLAVE_ADDR)
    event = _closed(pair.master.events)
    assert event.cause is CloseCause.REJECTED and event.reason == CloseReason.BUSY
    assert MASTER_ADDR  # the pair's master address (unused here)
