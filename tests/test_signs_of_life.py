"""What keeps a session alive, and OPENs in every state (PROTOCOL.md 5.1, 5.2; issue 14, points 5
and 6): only the peer's session traffic refreshes the idle timer, and what a slave answers to an
OPEN (COOKIE, REJECT) does not stand in for its own KEEPALIVEs."""

from __future__ import annotations

import random

import pytest

from tdtp import CloseCause, Connection, ConnectionClosed, ConnectionConfig, Role, State
from tdtp.wire import ControlCode, OpenBody, PacketType, encode_header, encode_open
from tdtp.wire.control import PROTOCOL_VERSION

from pair import MASTER_ADDR, SLAVE_ADDR, Direction, Pair

OTHER_NONCE = bytes(range(16))


def _open(nonce: bytes, cookie: bytes = bytes(16), max_payload: int = 1200) -> bytes:
    return encode_header(PacketType.CONTROL, 0x123, 0, 0, 255) + encode_open(
        OpenBody(PROTOCOL_VERSION, 0, 0, max_payload, 1, nonce, bytes(8), cookie)
    )


def _closed(events: list[object]) -> list[ConnectionClosed]:
    return [event for event in events if isinstance(event, ConnectionClosed)]


class Partition:
    """A drop rule that can be switched on: the path fails at some instant."""

    def __init__(self) -> None:
        self.down = False

    def __call__(self, _: int) -> bool:
        return self.down


def _partitioned_pair() -> tuple[Pair, Partition]:
    cut = Partition()
    # A short outage limit, so that "the session still ends" shows within the test's 4 s.
    config = ConnectionConfig(idle_timeout=2.0)
    pair = Pair(config, config, ms=Direction(drop=cut, keep_wire=True), sm=Direction(drop=cut))
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(0.3)
    return pair, cut


def test_a_replayed_open_with_the_sessions_nonce_does_not_keep_a_dead_session_alive() -> None:
    """The master is gone; an attacker near the slave replays the master's last OPEN (nonce and
    cookie both still valid) every 100 ms. The slave answers it, but must still time out
    idle_timeout after the master's last real packet."""
    pair, cut = _partitioned_pair()
    opens = [
        d for d in pair.ms.wire if d[0] >> 6 == PacketType.CONTROL and d[5] == ControlCode.OPEN
    ]
    replayed = opens[-1]  # the OPEN that carried the cookie
    cut.down = True
    pair.master.rate = pair.slave.rate = 0.0
    silent_since = pair.now
    slave = pair.slave.conn
    answered = slave.stats.received.control_packets
    while slave.state is State.ESTABLISHED and pair.now < silent_since + 4.0:
        pair.inject(replayed, to_slave=True, source=MASTER_ADDR)
        pair.run_for(0.1)
    assert slave.stats.received.control_packets > answered  # the replays were taken (answered)
    (closed,) = _closed(pair.slave.events)
    assert closed.cause is CloseCause.IDLE_TIMEOUT
    idle = slave.config.idle_timeout
    assert silent_since + idle <= pair.now <= silent_since + idle + 0.15


def test_opens_with_another_nonce_do_not_keep_a_dead_session_alive() -> None:
    pair, cut = _partitioned_pair()
    cut.down = True
    pair.master.rate = pair.slave.rate = 0.0
    silent_since = pair.now
    slave = pair.slave.conn
    while slave.state is State.ESTABLISHED and pair.now < silent_since + 4.0:
        pair.inject(_open(OTHER_NONCE), to_slave=True, source=MASTER_ADDR)  # answered: COOKIE
        pair.run_for(0.1)
    assert slave.stats.drops.get("unvalidated", 0) >= 15
    (closed,) = _closed(pair.slave.events)
    assert closed.cause is CloseCause.IDLE_TIMEOUT
    assert pair.now <= silent_since + slave.config.idle_timeout + 0.15


def test_cookies_answering_forged_opens_do_not_silence_the_slaves_keepalives() -> None:
    """Both sides idle, so only KEEPALIVEs prove life. Forged OPENs from the master's address make
    the slave send COOKIEs there, which the master drops (another nonce). Counting those as the
    slave's traffic held its KEEPALIVEs back and the master timed out: a blind, off-path kill."""
    pair = Pair()
    pair.open()
    assert pair.established
    start = pair.now
    while pair.now < start + 5.0:
        pair.inject(_open(OTHER_NONCE), to_slave=True, source=MASTER_ADDR)
        pair.run_for(0.2)
    assert pair.established
    assert pair.master.conn.stats.drops.get("nonce_mismatch", 0) >= 20  # the COOKIEs
    assert pair.slave.conn.stats.drops.get("unvalidated", 0) >= 20
    assert _closed(pair.master.events) == [] and _closed(pair.slave.events) == []


# ---------------------------------------------------------------------------- max_payload 0


def _slave_listening() -> tuple[Connection, bytes]:
    return Connection(role=Role.SLAVE, rng=random.Random(3)), OTHER_NONCE


def _slave_opening() -> tuple[Connection, bytes]:
    slave = Connection(role=Role.SLAVE, rng=random.Random(3))
    admission = slave.admission
    assert admission is not None
    cookie = admission._cookies.mint(MASTER_ADDR, OTHER_NONCE, 0.0)
    slave.receive_datagram(_open(OTHER_NONCE, cookie), MASTER_ADDR, now=0.0)
    assert slave.state is State.OPENING
    return slave, OTHER_NONCE


def _slave_established() -> tuple[Connection, bytes]:
    pair = Pair()
    pair.open()
    slave = pair.slave.conn
    assert slave.state is State.ESTABLISHED
    return slave, slave._handshake.master_nonce


def _slave_closed() -> tuple[Connection, bytes]:
    slave, nonce = _slave_established()
    slave.close(now=1.0)
    return slave, nonce


@pytest.mark.parametrize(
    ("make", "reason"),
    [
        (_slave_listening, "bad_control"),
        (_slave_opening, "bad_control"),
        (_slave_established, "bad_control"),
        (_slave_closed, "closed"),
    ],
    ids=["listening", "opening", "established", "closed"],
)
def test_an_open_with_max_payload_0_is_dropped_in_every_state(make: object, reason: str) -> None:
    """Every OPEN passes admission first, whatever the state: max_payload 0 is bad_control (after
    the close: closed), with the session's own nonce and a valid cookie, and nothing answers it."""
    slave, nonce = make()  # type: ignore[operator]
    now = 1.0
    slave.datagrams_to_send(now=now)  # whatever was queued before
    admission = slave.admission
    assert admission is not None
    cookie = admission._cookies.mint(MASTER_ADDR, nonce, now)
    before = dict(slave.stats.drops)
    state = slave.state
    slave.receive_datagram(_open(nonce, cookie, max_payload=0), MASTER_ADDR, now=now)
    assert slave.stats.drops.get(reason, 0) == before.get(reason, 0) + 1
    assert slave.state is state
    replies = [d for d, _ in slave.datagrams_to_send(now=now) if d[0] >> 6 == PacketType.CONTROL]
    assert not any(d[5] in (ControlCode.OPEN_ACK, ControlCode.COOKIE) for d in replies)
    assert slave.stats.datagrams_in == slave.stats.received.datagrams + slave.stats.dropped


def test_the_master_counts_any_open_as_unexpected() -> None:
    pair = Pair()
    pair.open()
    master = pair.master.conn
    pair.inject(
        _open(master._handshake.master_nonce, max_payload=0), to_slave=False, source=SLAVE_ADDR
    )
    assert master.stats.drops == {"unexpected_control": 1}
