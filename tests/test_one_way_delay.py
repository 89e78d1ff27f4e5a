"""Send timestamps (PROTOCOL.md 5.13): who stamps, what each end reads into each direction's queue,
the sample age on an asymmetric path, what a forged stamp can do, and a direction whose way back
fails (CONTROL.md 9.8). Fake time: tests/pair.py."""

from __future__ import annotations

import random

from tdtp import AckMode, Connection, ConnectionConfig, Role
from tdtp.config import MultipathConfig
from tdtp.wire import HEADER_SIZE, ControlCode, OpenFlags, PacketType, encode_header
from tdtp.wire.control import encode_timestamp
from tdtp.wire.hold import HOLD_NO_ACK

from pair import MASTER_ADDR, SLAVE_ADDR, Direction, Pair


def _open_flags(config: ConnectionConfig) -> int:
    master = Connection(config, role=Role.MASTER, rng=random.Random(1))
    master.connect(SLAVE_ADDR, now=0.0)
    ((datagram, _),) = master.datagrams_to_send(now=0.0)
    assert datagram[HEADER_SIZE] == ControlCode.OPEN
    return datagram[HEADER_SIZE + 2]


def test_a_teleop_master_asks_for_stamps_unless_told_not_to_or_multipath() -> None:
    assert _open_flags(ConnectionConfig()) & OpenFlags.TIMESTAMPS
    assert _open_flags(ConnectionConfig(ack_mode=AckMode.SEPARATE)) & OpenFlags.TIMESTAMPS
    assert not _open_flags(ConnectionConfig(timestamp_interval=0.0)) & OpenFlags.TIMESTAMPS
    assert not _open_flags(ConnectionConfig(controller="trinomial")) & OpenFlags.TIMESTAMPS
    multipath = ConnectionConfig(multipath=MultipathConfig())
    assert not _open_flags(multipath) & OpenFlags.TIMESTAMPS


def _stamped(datagram: bytes) -> bool:
    return datagram[0] >> 6 == PacketType.CONTROL and datagram[HEADER_SIZE] in (15, 16)


def test_both_ends_stamp_about_once_per_interval_and_the_slave_follows_its_master() -> None:
    ms, sm = Direction(keep_wire=True), Direction(keep_wire=True)
    # The slave's own setting is 0: it stamps anyway, at the default pace, not on every packet.
    pair = Pair(ConnectionConfig(), ConnectionConfig(timestamp_interval=0.0), ms=ms, sm=sm)
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(2.0)
    for direction, conn in ((ms, pair.master.conn), (sm, pair.slave.conn)):
        stamps = sum(_stamped(d) for d in direction.wire)
        assert 400 <= stamps <= 520, stamps  # every 4 ms for 2 s
        assert conn.stats.timestamps
        assert conn.stats.stamps_rejected == 0
        assert set(conn.stats.drops) <= {"unvalidated"}  # (the first OPEN, without a cookie)
    # The samples all arrive, stamped or not.
    assert len(pair.slave.received) >= 1990
    assert len(pair.master.received) >= 1990


def test_separate_acks_stamp_only_acks_and_keep_1_khz_on_a_clean_path() -> None:
    # A separate-ACK session's DATA acknowledges nothing: a stamp on one would time none of the
    # peer's packets. Stamped DATA left the peer's window accounting without news for tens of ms
    # whenever its own DATA, not its ACK, was first out after each interval (a matter of phase), so
    # it read a full window and fell to its probes: 20 samples/s here.
    ticks = random.Random(5)
    late = [ticks.uniform(0.0, 0.0005) for _ in range(4000)]
    ms, sm = Direction(delay=0.002, keep_wire=True), Direction(delay=0.002, keep_wire=True)
    config = ConnectionConfig(ack_mode=AckMode.SEPARATE)
    pair = Pair(config, ConnectionConfig(), ms=ms, sm=sm)
    pair.open()
    pair.start_samples(1000, 1000, jitter=lambda k: late[k % len(late)])
    limits: set[str] = set()
    for _ in range(20):
        pair.run_for(0.1)
        limits |= {pair.master.conn.stats.rate_limit, pair.slave.conn.stats.rate_limit}
    assert "window full" not in limits
    for direction, conn, peer in (
        (ms, pair.master.conn, pair.slave.conn),
        (sm, pair.slave.conn, pair.master.conn),
    ):
        assert conn.stats.timestamps and conn.stats.stamps_rejected == 0
        codes = [d[HEADER_SIZE] for d in direction.wire if _stamped(d)]
        assert 400 <= len(codes) <= 520, len(codes)  # every 4 ms for 2 s...
        assert set(codes) == {ControlCode.TIMESTAMP}  # ...on ACKs only
        assert conn.stats.samples_superseded <= 10
        assert peer.stats.received.data_packets >= 1990


def test_stamps_off_nothing_stamped_and_a_stamp_is_dropped() -> None:
    ms = Direction(keep_wire=True)
    config = ConnectionConfig(timestamp_interval=0.0)
    pair = Pair(config, config, ms=ms)
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(0.5)
    assert not any(_stamped(d) for d in ms.wire)
    stamp = encode_timestamp(ControlCode.TIMESTAMP, 123)
    pair.inject(
        encode_header(PacketType.CONTROL, 1, 0, 0, HOLD_NO_ACK) + stamp,
        to_slave=True,
        source=MASTER_ADDR,
    )
    assert pair.slave.conn.stats.drops.get("unexpected_control") == 1


def _queue_on_the_way_back(pair: Pair, start: float, queue: float) -> None:
    """From ``start`` on, the slave's packets wait ``queue`` more on their way to the master."""
    sm = pair.sm
    index_at_start: list[int] = []

    def extra(index: int) -> float:
        if pair.now < start:
            return 0.0
        if not index_at_start:
            index_at_start.append(index)
        return queue

    sm.extra_delay = extra


def test_each_end_reads_each_directions_queue_and_the_clear_direction_keeps_its_rate() -> None:
    pair = Pair()
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(3.0)  # both bases learnt: 10 ms each way
    _queue_on_the_way_back(pair, pair.now, 0.030)
    sent_before = pair.master.conn.stats.sent.data_packets
    received_before = len(pair.master.received)
    pair.run_for(3.0)
    master, slave = pair.master.conn.stats, pair.slave.conn.stats
    # The master's packets queue nowhere; the slave's wait 30 ms more: both ends see which.
    assert master.queue_delay_out < 0.002
    assert 0.025 < master.queue_delay_in < 0.035
    assert 0.025 < slave.queue_delay_out < 0.035
    assert slave.queue_delay_in < 0.002
    # The master's commands keep their rate: the queue is not theirs.
    assert master.sent.data_packets - sent_before >= 2950
    assert master.rate_limit in ("application", "")
    # Sample ages follow each direction: 40 ms at the master, 10 ms at the slave.
    late = pair.master.received[received_before + 500 :]
    master_ages = sorted(e.age for e in late if e.age is not None)
    slave_ages = sorted(e.age for e in pair.slave.received[-2000:] if e.age is not None)
    assert abs(master_ages[len(master_ages) // 2] - 0.040) < 0.003
    assert abs(slave_ages[len(slave_ages) // 2] - 0.010) < 0.003
    assert received_before < len(pair.master.received)


def test_forged_stamps_are_not_used_and_move_no_base() -> None:
    pair = Pair()
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(2.0)
    before = pair.slave.conn.stats.queue_delay_in
    for k in range(100):  # a clock far ahead, and far behind: no real stamp says either
        time_us = (int(pair.now * 1e6) + (5_000_000 if k % 2 else -5_000_000)) & 0xFFFFFFFF
        stamp = encode_timestamp(ControlCode.TIMESTAMP, time_us)
        pair.inject(
            encode_header(PacketType.CONTROL, 1, 0, 0, HOLD_NO_ACK) + stamp,
            to_slave=True,
            source=MASTER_ADDR,
        )
        pair.run_for(0.001)
    stats = pair.slave.conn.stats
    assert stats.stamps_rejected >= 50  # (the rest: overtaken by the master's own)
    pair.run_for(0.5)
    assert abs(pair.slave.conn.stats.queue_delay_in - before) < 0.002
    assert pair.slave.conn.stats.queue_delay_out < 0.002
    ages = sorted(e.age for e in pair.slave.received[-300:] if e.age is not None)
    assert abs(ages[len(ages) // 2] - 0.010) < 0.003


def test_commands_keep_a_safe_rate_when_only_the_way_back_fails() -> None:
    """The robot's uplink fails (its data and the acknowledgements of the master's commands with
    it); the commands keep going at half what the link delivered (CONTROL.md 9.8)."""
    pair = Pair()
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(3.0)
    pair.sm.drop = lambda _: True
    start = len(pair.slave.received)
    pair.run_for(1.5)
    delivered = len(pair.slave.received) - start
    assert delivered >= 600, delivered  # >= 400/s; it was 16/s before (issue 32)
    assert pair.master.conn.stats.rate_limit.startswith("no feedback")
    # Once the way back returns, the rate recovers within about a second.
    pair.sm.drop = lambda _: False
    pair.run_for(1.0)
    start = len(pair.slave.received)
    pair.run_for(1.0)
    assert len(pair.slave.received) - start >= 900
