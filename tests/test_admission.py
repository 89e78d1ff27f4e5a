"""The slave's front door in fake time: cookies, rate limits, keys, amplification, restarts."""

from __future__ import annotations

import random

import pytest

from tdtp import (
    AdmissionConfig,
    CloseCause,
    Connection,
    ConnectionClosed,
    ConnectionConfig,
    Role,
    State,
)
from tdtp.admission.admission import Admission, AdmittedOpen, Reply
from tdtp.admission.cookie import CookieJar
from tdtp.admission.rate_limit import SourceRateLimiter
from tdtp.protection import KeyRing, PresharedKey
from tdtp.session.stats import DropReason
from tdtp.wire import (
    HEADER_SIZE,
    CloseReason,
    ControlCode,
    OpenBody,
    OpenFlags,
    encode_header,
    encode_open,
)
from tdtp.wire.control import PROTOCOL_VERSION

from pair import MASTER_ADDR, SLAVE_ADDR, Endpoint, Pair

NONCE = bytes(range(16))
KEY = PresharedKey(bytes(range(32)), "station-1")


def _open(
    nonce: bytes = NONCE, cookie: bytes = bytes(16), max_payload: int = 1200, flags: int = 0
) -> bytes:
    return encode_header(2, 0x123, 0, 0, 255) + encode_open(
        OpenBody(PROTOCOL_VERSION, flags, 0, max_payload, 0, nonce, bytes(8), cookie)
    )


def _forged_keyed_open(rng: random.Random) -> bytes:
    """A well-formed keyed OPEN naming the slave's key, with a tag nobody computed."""
    body = OpenBody(
        2,
        OpenFlags.KEYED | OpenFlags.ENCRYPTED,
        1,
        1200,
        0,
        rng.randbytes(16),
        KEY.key_id,
        bytes(16),
    )
    return encode_header(2, 0x123, 0, 0, 255) + encode_open(body) + rng.randbytes(16)


def _cookie_for(admission: Admission, addr: tuple[str, int], nonce: bytes, now: float) -> bytes:
    reply = admission.admit(_open(nonce), addr, now)
    assert isinstance(reply, Reply) and reply.reason is DropReason.UNVALIDATED
    return reply.datagram[-16:]


# ---------------------------------------------------------------------------- cookies


def test_a_cookie_is_bound_to_address_port_and_nonce_and_expires() -> None:
    jar = CookieJar(bytes(32), lifetime=5.0)
    cookie = jar.mint(MASTER_ADDR, NONCE, now=100.0)
    assert jar.check(cookie, MASTER_ADDR, NONCE, now=100.0)
    assert jar.check(cookie, MASTER_ADDR, NONCE, now=104.9)
    assert not jar.check(cookie, MASTER_ADDR, NONCE, now=105.2)  # expired
    assert not jar.check(cookie, (MASTER_ADDR[0], MASTER_ADDR[1] + 1), NONCE, now=100.0)
    assert not jar.check(cookie, ("192.0.2.99", MASTER_ADDR[1]), NONCE, now=100.0)
    assert not jar.check(cookie, MASTER_ADDR, bytes(16), now=100.0)
    assert not jar.check(cookie[:-1] + bytes([cookie[-1] ^ 1]), MASTER_ADDR, NONCE, now=100.0)
    other = CookieJar(bytes([1]) * 32, lifetime=5.0)  # another slave's secret
    assert not other.check(cookie, MASTER_ADDR, NONCE, now=100.0)


def test_an_open_without_a_cookie_gets_a_smaller_cookie_and_leaves_no_state() -> None:
    slave = Connection(role=Role.SLAVE, rng=random.Random(1))
    datagram = _open()
    slave.receive_datagram(datagram, MASTER_ADDR, now=0.0)
    ((reply, addr),) = slave.datagrams_to_send(now=0.0)
    assert addr == MASTER_ADDR and reply[HEADER_SIZE] == ControlCode.COOKIE
    assert len(reply) == 39 < len(datagram) == 53
    assert slave.state is State.LISTENING and slave.peer is None
    assert slave.stats.drops == {"unvalidated": 1}


def test_the_echoed_cookie_opens_the_session() -> None:
    slave = Connection(role=Role.SLAVE, rng=random.Random(1))
    admission = slave.admission
    assert admission is not None
    cookie = _cookie_for(admission, MASTER_ADDR, NONCE, 0.0)
    slave.receive_datagram(_open(cookie=cookie), MASTER_ADDR, now=0.01)
    assert slave.state is State.OPENING and slave.peer == MASTER_ADDR  # until the master confirms
    ((reply, _),) = slave.datagrams_to_send(now=0.01)
    assert reply[HEADER_SIZE] == ControlCode.OPEN_ACK


def test_opens_per_source_are_rate_limited() -> None:
    admission = Admission(ConnectionConfig(admission=AdmissionConfig(open_burst=5)))
    verdicts = [admission.admit(_open(), MASTER_ADDR, 0.0) for _ in range(10)]
    assert sum(isinstance(v, Reply) for v in verdicts) == 5
    assert verdicts[5:] == [DropReason.RATE_LIMITED] * 5
    # Every source address has its own bucket: another port of the same host, another host.
    assert isinstance(admission.admit(_open(), (MASTER_ADDR[0], 1), 0.0), Reply)
    assert isinstance(admission.admit(_open(), ("192.0.2.77", 1), 0.0), Reply)
    # The bucket refills at opens_per_source (20/s).
    assert isinstance(admission.admit(_open(), MASTER_ADDR, 0.1), Reply)


def test_the_rate_table_is_bounded() -> None:
    limiter = SourceRateLimiter(rate=1.0, burst=1.0, max_sources=100)
    for host in range(10_000):
        limiter.allow(f"10.0.{host // 256}.{host % 256}", 0.0)
    assert len(limiter) == 100


def test_replies_to_unvalidated_sources_have_a_global_budget() -> None:
    config = ConnectionConfig(admission=AdmissionConfig(replies_per_second=100.0))
    admission = Admission(config)
    verdicts = [
        admission.admit(_open(), (f"10.1.{i // 256}.{i % 256}", 9), 0.0) for i in range(500)
    ]
    assert sum(isinstance(v, Reply) for v in verdicts) == 100
    assert admission.stats.drops == {"rate_limited": 400}


def test_amplification_towards_forged_sources_is_at_most_one() -> None:
    """10,000 OPENs from forged sources (random addresses, some repeated, some keyed, some with
    garbage cookies): every byte the slave sends goes back to a source, and never more bytes than
    that source sent. No state is kept."""
    rng = random.Random(3)
    for keys in (None, KeyRing([KEY])):
        slave = Connection(role=Role.SLAVE, rng=random.Random(1), keys=keys)
        sent: dict[tuple[str, int], int] = {}
        answered: dict[tuple[str, int], int] = {}
        for index in range(10_000):
            source = (f"203.0.{rng.randrange(64)}.{rng.randrange(256)}", rng.randrange(1, 65536))
            flags = int(OpenFlags.KEYED | OpenFlags.ENCRYPTED) if index % 3 == 0 else 0
            datagram = _open(rng.randbytes(16), rng.randbytes(16) if index % 2 else bytes(16))
            if flags:
                datagram = datagram[:7] + bytes([flags, 1]) + datagram[9:] + rng.randbytes(16)
            sent[source] = sent.get(source, 0) + len(datagram)
            slave.receive_datagram(datagram, source, now=index * 0.001)
            for reply, addr in slave.datagrams_to_send(now=index * 0.001):
                answered[addr] = answered.get(addr, 0) + len(reply)
        assert slave.state is State.LISTENING and slave.peer is None
        assert all(answered[addr] <= sent[addr] for addr in answered)
        admission = slave.admission
        assert admission is not None
        assert admission.stats.bytes_out <= admission.stats.bytes_in
        assert admission.stats.admitted == 0


# ---------------------------------------------------------------------------- keys and payloads


def test_a_keyed_slave_checks_the_key_only_after_the_cookie() -> None:
    admission = Admission(keys=KeyRing([KEY]))
    # Unkeyed OPEN, no cookie: COOKIE first (a REJECT to a forged source would reflect).
    first = admission.admit(_open(), MASTER_ADDR, 0.0)
    assert isinstance(first, Reply) and first.reason is DropReason.UNVALIDATED
    cookie = first.datagram[-16:]
    second = admission.admit(_open(cookie=cookie), MASTER_ADDR, 0.0)
    assert isinstance(second, Reply) and second.reason is DropReason.REFUSED
    assert second.datagram[-1] == CloseReason.KEY_REQUIRED


def test_a_master_whose_max_payload_is_too_small_for_the_slave_is_refused() -> None:
    """The OPEN with max_payload 1 that made the CLI slave raise PayloadTooLargeError later."""
    admission = Admission(ConnectionConfig(min_peer_payload=100))
    cookie = _cookie_for(admission, MASTER_ADDR, NONCE, 0.0)
    verdict = admission.admit(_open(cookie=cookie, max_payload=1), MASTER_ADDR, 0.0)
    assert isinstance(verdict, Reply) and verdict.datagram[-1] == CloseReason.PAYLOAD_TOO_SMALL
    ok = admission.admit(_open(cookie=cookie, max_payload=100), MASTER_ADDR, 0.0)
    assert isinstance(ok, AdmittedOpen)


def test_the_master_hears_why_its_payload_is_too_small() -> None:
    pair = Pair(ConnectionConfig(max_payload=50), ConnectionConfig(min_peer_payload=100))
    pair.master.conn.connect(SLAVE_ADDR, now=0.0)
    pair._flush(pair.master)
    pair.run_for(0.1)
    closed = [e for e in pair.master.events if isinstance(e, ConnectionClosed)]
    assert [c.cause for c in closed] == [CloseCause.REJECTED]
    assert "max_payload (50)" in closed[0].detail


def test_min_peer_payload_is_validated() -> None:
    with pytest.raises(ValueError, match="min_peer_payload"):
        ConnectionConfig(max_payload=100, min_peer_payload=101)
    with pytest.raises(ValueError, match="cookie_lifetime"):
        AdmissionConfig(cookie_lifetime=0.0)


# ---------------------------------------------------------------------------- restarts and replays


def test_a_restarted_master_replaces_its_quiet_session_at_once() -> None:
    """The master process restarts (same address, new nonce, no CLOSE): the slave's old session
    ends at the first OPEN that finds it silent for longer than a live master ever is (a keep-alive
    interval plus two RTTs), instead of after the idle timeout."""
    pair = Pair()
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(0.5)
    old_slave = pair.slave.conn
    pair.master = Endpoint(Connection(role=Role.MASTER, rng=random.Random(77)), MASTER_ADDR)
    pair.master.rate = 1000  # the new process starts sampling at once
    restart = pair.now
    pair.master.conn.connect(SLAVE_ADDR, now=pair.now)
    pair._flush(pair.master)
    pair.run_until(restart + 1.0, stop=lambda: old_slave.state is State.CLOSED)
    closed = [e for e in pair.slave.events if isinstance(e, ConnectionClosed)]
    assert [c.cause for c in closed] == [CloseCause.REPLACED]
    # The OPEN with the cookie (sent at 0.02 s) finds the session heard 0.02 s before (the limit:
    # a keep-alive interval, 33 ms, plus two RTTs, 40 ms); its retry at 0.27 s takes over.
    assert pair.now - restart == pytest.approx(0.27 + 0.010)


def test_a_replayed_open_for_a_dead_session_gets_one_open_ack_and_nothing_more() -> None:
    """An on-path attacker replays a master's OPEN (cookie still valid) after that master left:
    the slave answers one OPEN_ACK to the master's address, sends no data, and gives up."""
    admission = Admission()
    cookie = _cookie_for(admission, MASTER_ADDR, NONCE, 0.0)
    slave = Connection(role=Role.SLAVE, admission=admission, rng=random.Random(2))
    slave.receive_datagram(_open(cookie=cookie), MASTER_ADDR, now=0.5)

    out = slave.datagrams_to_send(now=0.5)
    assert [d[HEADER_SIZE] for d, _ in out] == [ControlCode.OPEN_ACK]
    timer = slave.get_timer()
    assert timer == pytest.approx(0.5 + 5.0)
    slave.handle_timer(now=timer)
    assert slave.state is State.CLOSED
    events = []
    while (event := slave.next_event()) is not None:
        events.append(event)
    assert [type(e) for e in events] == [ConnectionClosed]
    assert slave.datagrams_to_send(now=timer) == []


def test_a_master_opens_in_one_cookie_round_trip_while_forged_opens_flood_the_slave() -> None:
    """1,000 forged OPENs per second from random sources, interleaved with a real handshake: the
    master is established after exactly OPEN, COOKIE, OPEN, OPEN_ACK (2 round trips of 20 ms)."""
    pair = Pair()
    rng = random.Random(11)
    flood_until = 1.0

    def flood() -> None:
        while pair.now < flood_until and rng.random() < 0.5:
            source = (f"198.18.{rng.randrange(256)}.{rng.randrange(256)}", rng.randrange(1, 65536))
            pair.slave.conn.receive_datagram(_open(rng.randbytes(16)), source, now=pair.now)
            pair.slave.conn.datagrams_to_send(now=pair.now)  # COOKIEs to the forged sources

    for step in range(500):  # the flood starts half a second before the master
        pair.now = step * 0.001
        flood()
    start = pair.now
    pair.master.conn.connect(SLAVE_ADDR, now=start)
    pair._flush(pair.master)
    while pair.master.conn.state is not State.ESTABLISHED and pair.now < start + 1.0:
        pair.run_for(0.001)
        flood()
    assert pair.master.conn.state is State.ESTABLISHED
    assert pair.now - start == pytest.approx(0.040, abs=0.0011)
    assert pair.master.conn._handshake.open_attempt == 2
    admission = pair.slave.conn.admission
    assert admission is not None and admission.stats.cookies_sent > 400


def test_a_valid_cookie_is_never_held_back_by_the_rate_limit() -> None:
    """An OPEN that proves its address skips the per-source limit that OPENs proving nothing use up."""
    admission = Admission(ConnectionConfig(admission=AdmissionConfig(open_burst=2)))
    cookie = _cookie_for(admission, MASTER_ADDR, NONCE, 0.0)
    for _ in range(50):  # the source's bucket is empty now
        admission.admit(_open(), MASTER_ADDR, 0.0)
    assert admission.admit(_open(), MASTER_ADDR, 0.0) is DropReason.RATE_LIMITED
    assert isinstance(admission.admit(_open(cookie=cookie), MASTER_ADDR, 0.0), AdmittedOpen)


@pytest.mark.parametrize("keyed", [False, True], ids=["unkeyed", "keyed"])
def test_forged_opens_from_the_masters_host_do_not_lock_it_out(keyed: bool) -> None:
    """Issue 20, item 1: forged OPENs at 1,000/s from the master's own IP with random ports (an
    off-path attacker knows the host, not the port) used up the host's OPEN budget, and 0 of 8 real
    connects succeeded. Now the master opens in its usual two round trips, in every try."""
    key = KEY if keyed else None
    for attempt in range(8):
        pair = Pair(master_key=key, slave_keys=key) if keyed else Pair()
        rng = random.Random(attempt)

        def flood(pair: Pair = pair, rng: random.Random = rng) -> None:
            source = (MASTER_ADDR[0], rng.randrange(1024, 65536))
            if source[1] == MASTER_ADDR[1]:
                return
            forged = _forged_keyed_open(rng) if keyed else _open(rng.randbytes(16))
            pair.slave.conn.receive_datagram(forged, source, now=pair.now)
            pair.slave.conn.datagrams_to_send(now=pair.now)

        for step in range(500):  # half a second of flood before the master starts
            pair.now = step * 0.001
            flood()
        start = pair.now
        pair.master.conn.connect(SLAVE_ADDR, now=start)
        pair._flush(pair.master)
        while pair.master.conn.state is not State.ESTABLISHED and pair.now < start + 2.0:
            pair.run_for(0.001)
            flood()
        assert pair.master.conn.state is State.ESTABLISHED, f"try {attempt}"
        assert pair.now - start == pytest.approx(0.040, abs=0.0011)
