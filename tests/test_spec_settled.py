"""The points docs/PROTOCOL.md used to leave open (issue 20, item 8), pinned in fake time where the
library had to change: (b) a receiver enforces its own max_payload, whatever the peer announced;
(d) a master sends at most open_timeout / open_retry_interval OPENs, COOKIEs or not."""

from __future__ import annotations

import random

from tdtp import Connection, ConnectionConfig, Role, State
from tdtp.wire import (
    HEADER_SIZE,
    OpenBody,
    PacketType,
    decode_control,
    encode_cookie,
    encode_header,
)

from pair import MASTER_ADDR, SLAVE_ADDR, Pair

_REPLY_HEADER = encode_header(int(PacketType.CONTROL), 0, 0, 0, 255)


def test_cookies_never_make_a_master_send_more_opens_than_the_retry_schedule() -> None:
    """Every OPEN answered by a COOKIE (a slave whose cookies never check out, or an attacker
    answering them) used to restart the retry timer: 40 OPENs in 5 s. Now 20 at most."""
    config = ConnectionConfig()
    master = Connection(config, role=Role.MASTER, rng=random.Random(1))
    now = 0.0
    master.connect(SLAVE_ADDR, now=now)
    opens = 0
    cookies_due: list[float] = []
    while master.state is State.OPENING:
        for datagram, _ in master.datagrams_to_send(now=now):
            body = decode_control(datagram[HEADER_SIZE:])
            assert isinstance(body, OpenBody)
            opens += 1
            cookies_due.append(now + 0.01)
            nonce = body.nonce
        timer = master.get_timer()
        assert timer is not None
        upcoming = min([timer, *cookies_due])
        now = upcoming
        if cookies_due and cookies_due[0] <= now:
            cookies_due.pop(0)
            cookie = _REPLY_HEADER + encode_cookie(nonce, random.Random(now).randbytes(16))
            master.receive_datagram(cookie, SLAVE_ADDR, now=now)
        master.handle_timer(now=now)
    assert opens <= config.open_timeout / config.open_retry_interval
    assert opens >= 19  # and the COOKIEs did pull OPENs forward rather than hold them back


def test_a_receiver_enforces_its_own_max_payload_not_the_peers() -> None:
    """The master announces max_payload 100 (what it accepts); the slave, whose own limit is 1200,
    delivers a 500-byte sample from it (the master broke no rule of the slave's), and the master
    drops a 500-byte sample from a slave as oversized, whatever the slave announced."""
    pair = Pair(ConnectionConfig(max_payload=100), ConnectionConfig(max_payload=1200))
    pair.open()
    master, slave = pair.master.conn, pair.slave.conn
    assert master.max_send_payload == 100 and slave.max_send_payload == 100
    # A sample the sender's own rule forbids (larger than the peer announced), crafted on the wire.
    big = encode_header(int(PacketType.DATA), 0, 0, 0, 255) + bytes(500)
    pair.inject(big, to_slave=False, source=SLAVE_ADDR)
    assert master.stats.drops.get("oversized") == 1
    assert master.stats.samples_delivered == 0
    seq = slave.stats.received.data_packets  # nothing yet: the master's first DATA has this SEQ
    first = encode_header(int(PacketType.DATA), pair.master.conn._recovery.sent.next_seq, 0, 0, 255)
    pair.inject(first + bytes(500), to_slave=True, source=MASTER_ADDR)
    assert seq == 0 and "oversized" not in slave.stats.drops
    assert slave.stats.samples_delivered == 1
    assert slave.stats.received.data_packets == 1
