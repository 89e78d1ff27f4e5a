"""Answer first: the acknowledgement a data packet carries is taken at once (validated, its round
trip timed) and finished later, after whatever the application sends in answer has left. What must
hold: the answer leaves before that bookkeeping, yet nothing anyone can read, and nothing on the
wire, comes out different from finishing it at once."""

from __future__ import annotations

import math

from tdtp import Connection, ConnectionConfig, DataReceived
from tdtp.control.fixed import FixedConfig
from tdtp.session.stats import DropReason

from pair import MASTER_ADDR as MASTER
from pair import SLAVE_ADDR as SLAVE
from pair import Pair

CONFIG = ConnectionConfig(controller="fixed", controller_config=FixedConfig(rate=math.inf))


def _established() -> tuple[Connection, Connection, float]:
    pair = Pair(CONFIG, CONFIG)
    pair.open()
    master, slave = pair.master.conn, pair.slave.conn
    while master.next_event() is not None or slave.next_event() is not None:
        pass
    return master, slave, pair.now + 0.001


def _data(conn: Connection, now: float) -> bytes:
    """One sample from ``conn``, as it leaves."""
    sent: list[bytes] = []
    assert conn.send_direct(bytes(100), lambda d, a: sent.append(d), connected=True, now=now)
    return sent[0]


def test_the_answer_leaves_before_the_acknowledgement_is_finished() -> None:
    master, slave, now = _established()
    slave.receive_datagram(_data(master, now), MASTER, now=now)
    now += 0.0005
    answer = _data(slave, now)  # carries the master's sample's ACK
    acked_before = master.stats.packets_acked
    now += 0.0005
    master.receive_datagram(answer, SLAVE, now=now)
    event = master.next_event()
    assert isinstance(event, DataReceived)
    assert event.sent_at is not None  # the round trip was timed at once, from the echo
    # Nothing of the acknowledgement beyond that has run yet: the master answers first ...
    assert master._recovery.pending
    transmitted: list[bytes] = []

    def transmit(datagram: bytes, addr: object) -> None:
        assert master._recovery.pending  # ... and the bookkeeping comes after the send
        transmitted.append(datagram)

    assert master.send_direct(bytes(100), transmit, connected=True, now=now)
    assert len(transmitted) == 1
    assert not master._recovery.pending  # the send's own bookkeeping settled it
    stats = master.stats
    assert stats.packets_acked == acked_before + 1
    assert stats.rtt_samples >= 1


def test_anything_read_after_an_input_sees_the_acknowledgement() -> None:
    """stats, get_timer, handle_timer and datagrams_to_send each settle it first."""
    for read in ("stats", "get_timer", "handle_timer", "datagrams_to_send"):
        master, slave, now = _established()
        slave.receive_datagram(_data(master, now), MASTER, now=now)
        answer = _data(slave, now + 0.001)
        master.receive_datagram(answer, SLAVE, now=now + 0.002)
        assert master._recovery.pending
        acked = master._stats.packets_acked
        if read == "stats":
            assert master.stats.packets_acked == acked + 1
        elif read == "get_timer":
            master.get_timer()
        elif read == "handle_timer":
            master.handle_timer(now=now + 0.002)
        else:
            master.datagrams_to_send(now=now + 0.002)
        assert not master._recovery.pending, read
        assert master._stats.packets_acked == acked + 1, read


def test_an_optimistic_ack_is_still_ignored_at_once() -> None:
    """The acknowledgement names a packet never sent: nothing of it is used, nor left pending; the
    sample it carries is delivered (PROTOCOL.md 3.1: one forged field costs only itself)."""
    master, slave, now = _established()
    slave.receive_datagram(_data(master, now), MASTER, now=now)
    answer = bytearray(_data(slave, now))  # it carries an ACK (not HOLD_NO_ACK)
    # ACK a sequence number the master never sent (far above its next one).
    seq_next = master._recovery.sent.next_seq
    forged_ack = (seq_next + 2000) & 0xFFF
    answer[1] = (answer[1] & 0xFC) | (forged_ack >> 10)
    answer[2] = (forged_ack >> 2) & 0xFF
    answer[3] = ((forged_ack & 0x03) << 6) | (answer[3] & 0x3F)
    dropped = master.stats.drops.get(DropReason.OPTIMISTIC_ACK.value, 0)
    acked = master._stats.packets_acked
    master.receive_datagram(bytes(answer), SLAVE, now=now + 0.001)
    assert master.next_event() is not None  # the sample is delivered
    assert not master._recovery.pending
    assert master.stats.drops.get(DropReason.OPTIMISTIC_ACK.value, 0) == dropped
    assert master.stats.optimistic_acks == 1 and master._stats.packets_acked == acked


def test_consecutive_datagrams_are_acknowledged_as_if_each_finished_at_once() -> None:
    """The same exchange, with and without reads between the inputs that settle each one: the
    same counters, RTT and wire bytes."""

    def run(settle_each: bool) -> tuple[object, ...]:
        master, slave, now = _established()
        wire: list[bytes] = []
        for _ in range(50):
            for _k in range(3):
                slave.receive_datagram(_data(master, now), MASTER, now=now)
                now += 0.0002
            answers = [_data(slave, now), _data(slave, now + 0.0001)]
            now += 0.001
            for answer in answers:
                master.receive_datagram(answer, SLAVE, now=now)
                if settle_each:
                    master._recovery.settle()
            wire += [d for d, _ in master.datagrams_to_send(now=now)]
            wire += [d for d, _ in slave.datagrams_to_send(now=now)]
            while master.next_event() is not None or slave.next_event() is not None:
                pass
            now += 0.001
        stats = master.stats
        return (
            stats.packets_acked,
            stats.rtt_samples,
            stats.srtt,
            stats.packets_lost,
            stats.spurious_losses,
            tuple(wire),
        )

    assert run(settle_each=False) == run(settle_each=True)
