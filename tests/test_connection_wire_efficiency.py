"""Bidirectionality on the wire: the paper's central claim, checked packet by packet."""

from __future__ import annotations

import pytest

from tdtp import AckMode, ConnectionConfig
from tdtp.control.fixed import FixedConfig
from tdtp.wire import HEADER_SIZE, STAMP_SIZE, ControlCode, PacketType, decode_header

from pair import Direction, Pair

UNLIMITED = ConnectionConfig(controller="fixed", controller_config=FixedConfig(rate=float("inf")))


def _run(config: ConnectionConfig, seconds: float) -> Pair:
    pair = Pair(config, config, ms=Direction(keep_wire=True), sm=Direction(keep_wire=True))
    pair.open()
    pair.start_samples(1000, 1000, size=100)
    pair.run_for(seconds)
    return pair


def _carries_a_sample(datagram: bytes) -> bool:
    """DATA, or TIMED_DATA (a DATA with its sender's clock: PROTOCOL.md 5.13)."""
    ptype = decode_header(datagram).ptype
    return ptype == PacketType.DATA or (
        ptype == PacketType.CONTROL and datagram[HEADER_SIZE] == ControlCode.TIMED_DATA
    )


@pytest.mark.parametrize("stamps", [False, True])
def test_tdtp_mode_sends_no_standalone_acks_and_five_byte_headers(stamps: bool) -> None:
    """The paper's framing (without send timestamps), and with them: 5 more bytes on one sample
    every 4 ms, nothing else."""
    pair = _run(ConnectionConfig(timestamp_interval=0.004 if stamps else 0.0), 10.0)
    for direction, endpoint in ((pair.ms, pair.master), (pair.sm, pair.slave)):
        kinds = [decode_header(d).ptype for d in direction.wire]
        data = [d for d in direction.wire if _carries_a_sample(d)]
        timed = [d for d in data if decode_header(d).ptype == PacketType.CONTROL]
        assert kinds.count(PacketType.ACK) == 0
        assert len(data) >= 9990  # 1000 samples/s for 10 s, less the open's few milliseconds
        assert all(len(d) == 100 + HEADER_SIZE for d in data if d not in timed)
        assert all(len(d) == 100 + HEADER_SIZE + STAMP_SIZE for d in timed)
        assert (1990 <= len(timed) <= 2510) if stamps else not timed, len(timed)
        # Every data packet after the first reverse one carries a real acknowledgement.
        assert sum(decode_header(d).hold != 255 for d in data) >= len(data) - 15
        stats = endpoint.conn.stats
        assert stats.sent.ack_packets == 0
        assert stats.packets_lost == 0
        assert 0.0199 < stats.srtt < 0.0201  # 10 ms each way; the hold time is subtracted


def test_separate_ack_mode_sends_one_ack_per_received_data_packet() -> None:
    pair = _run(ConnectionConfig(ack_mode=AckMode.SEPARATE, ack_size=20), 2.0)
    for endpoint, direction in ((pair.master, pair.ms), (pair.slave, pair.sm)):
        stats = endpoint.conn.stats
        assert stats.sent.ack_packets == stats.received.data_packets > 1900
        acks = [d for d in direction.wire if decode_header(d).ptype == PacketType.ACK]
        assert all(len(a) == 20 for a in acks)
        data = [d for d in direction.wire if decode_header(d).ptype == PacketType.DATA]
        assert all(decode_header(d).hold == 255 for d in data)  # data carries no ACK


@pytest.mark.parametrize("plain", [False, True])
def test_plain_acks_report_their_own_packet_only(plain: bool) -> None:
    # Master to slave at 1000/s; every 50th ACK the slave sends back is lost.
    config = ConnectionConfig(
        ack_mode=AckMode.SEPARATE,
        plain_acks=plain,
        controller="fixed",
        controller_config=FixedConfig(rate=float("inf")),
    )
    pair = Pair(
        config,
        config,
        sm=Direction(keep_wire=True, drop=lambda i: i > 10 and i % 50 == 0),
    )
    pair.open()
    pair.start_samples(1000, 0)
    pair.run_for(2.0)
    pair.drain()
    acks = [decode_header(d) for d in pair.sm.wire if decode_header(d).ptype == PacketType.ACK]
    assert len(acks) > 1900 and pair.sm.dropped >= 38
    master = pair.master.conn.stats
    if plain:
        # Each ACK names its packet and nothing else (SACK zero): a lost ACK reads as a lost
        # packet, as with the paper's one-ACK-per-packet Trinomial.
        assert all(a.sack == 0 for a in acks)
        assert master.packets_lost == pair.sm.dropped
    else:
        # Each ACK repeats the 6 packets below it: a lost ACK costs nothing.
        assert sum(a.sack == 0b111111 for a in acks) > 0.99 * len(acks)
        assert master.packets_lost == 0
    assert pair.slave.conn.stats.received.data_packets == master.sent.data_packets  # none lost


def test_plain_acks_is_validated_and_ignored_with_piggybacked_acks() -> None:
    with pytest.raises(ValueError, match="plain_acks"):
        ConnectionConfig(plain_acks=1)  # type: ignore[arg-type]
    pair = _run(ConnectionConfig(plain_acks=True), 1.0)  # bidirectional: SACK as always
    data = [decode_header(d) for d in pair.ms.wire if _carries_a_sample(d)]
    reports = [d for d in data if d.hold != 255]  # all but the few before the reverse flow began
    assert len(reports) > 950
    assert sum(d.sack == 0b111111 for d in reports) > 0.99 * len(reports)


def test_slave_adopts_the_masters_ack_mode() -> None:
    pair = Pair(ConnectionConfig(ack_mode=AckMode.SEPARATE), ConnectionConfig())
    pair.open()
    assert pair.slave.conn.ack_mode is AckMode.SEPARATE
    pair.start_samples(1000, 1000)
    pair.run_for(0.5)
    assert pair.slave.conn.stats.sent.ack_packets > 400


def test_asymmetric_rates_stay_accurate_with_coverage_acks() -> None:
    """Forward 1000/s, reverse 50/s: stand-alone ACKs keep every packet reported, no false loss."""
    pair = Pair(UNLIMITED, UNLIMITED)
    pair.open()
    pair.start_samples(1000, 50)
    pair.run_for(5.0)
    pair.drain()
    master, slave = pair.master.conn.stats, pair.slave.conn.stats
    assert master.packets_lost == 0
    assert master.packets_acked == master.sent.data_packets
    # Something reports the forward flow at least every 7 packets, and no more often than needed:
    # the slave's own 50 data packets/s carry some reports, stand-alone ACKs the rest.
    reports = slave.sent.ack_packets + slave.sent.data_packets
    assert master.sent.data_packets / 7 <= reports <= master.sent.data_packets / 6
    assert 0.0195 < master.srtt < 0.0205


def test_reverse_silence_is_acknowledged_by_standalone_acks() -> None:
    pair = Pair(UNLIMITED, UNLIMITED)
    pair.open()
    pair.start_samples(100, 0)
    pair.run_for(3.0)
    master, slave = pair.master.conn.stats, pair.slave.conn.stats
    assert master.packets_lost == 0
    # 100 packets/s, nothing flowing back: one ACK per ack_delay (20 ms) window at most.
    assert 100 <= slave.sent.ack_packets <= 160
    assert 0.0199 < master.srtt < 0.0221  # the hold (up to 20 ms) is removed from the sample


def test_a_1khz_application_does_not_inflate_its_allowance() -> None:
    """The connection tells the controller which packets the pacer held back; a 1 kHz loop that
    never waits keeps the trinomial allowance within 2x its own rate (docs/CONTROL.md 3.4)."""
    pair = Pair(ms=Direction(delay=0.0001), sm=Direction(delay=0.0001))  # a LAN: srtt 0.2 ms
    pair.open()
    # Every 7th tick runs 0.7 ms late, so it and the next one leave 0.3 ms apart, as on a real loop.
    pair.start_samples(1000, 1000, jitter=lambda k: 0.0007 if k % 7 == 3 else 0.0)
    highest = 0.0
    for _ in range(50):
        pair.run_for(0.1)
        highest = max(highest, pair.master.conn.stats.rate, pair.slave.conn.stats.rate)
    # 2x the measured rate; the moving average of gaps reads up to ~10 % high just after a short gap.
    # (Measuring each interval's spacing alone let this loop inflate the allowance to 6667/s.)
    assert 1000.0 < highest <= 2200.0
    assert pair.master.conn.stats.samples_superseded == 0
