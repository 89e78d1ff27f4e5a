"""The sender's packet log: ACK expansion, SACK marking, loss by threshold and by timeout."""

from __future__ import annotations

import pytest

from tdtp.session.sent_log import LostPacket, SentPacketLog


def _log(first: int = 4000, count: int = 0, gap: float = 0.001) -> SentPacketLog:
    log = SentPacketLog(first, reorder_threshold=3, max_tracked=300_000)
    lost: list[LostPacket] = []
    for i in range(count):
        log.on_sent(i * gap, 105, lost)
    assert not lost
    return log


def test_ack_expands_across_the_wrap_and_rejects_packets_never_sent() -> None:
    log = _log(4000, 200)  # sequence numbers 4000..4199
    assert log.expand_ack(4150 & 0xFFF, 0.0, 0.3, 0.1) == 4150
    assert log.expand_ack(4199 & 0xFFF, 0.0, 0.3, 0.1) == 4199
    assert log.expand_ack(4200 & 0xFFF, 0.0, 0.3, 0.1) is None  # not sent yet: optimistic
    assert log.expand_ack(3999 & 0xFFF, 0.0, 0.3, 0.1) is None  # before the first packet
    assert (
        SentPacketLog(7, reorder_threshold=3, max_tracked=64).expand_ack(7, 0.0, 0.0, 0.1) is None
    )


def test_ack_and_sack_mark_packets_and_give_one_rtt_sample() -> None:
    log = _log(0, 20)
    outcome = log.on_ack(10, 0b000101, 0.002, 0.040)  # 10, 9 and 7 received
    assert outcome.newly_acked == 3
    assert outcome.rtt_sample == pytest.approx(0.040 - 0.010 - 0.002)
    assert log.largest_acked == 10
    again = log.on_ack(10, 0b000101, 0.003, 0.041)
    assert again.newly_acked == 0 and again.rtt_sample is None  # no sample from a repeat
    lost: list[LostPacket] = []
    log.detect_losses(0.041, 1.0, lost)
    # The ACK covered 4..10: 4, 5, 6 and 8 reported absent. 4..6 are 3+ below 10: lost. 8 is only
    # 2 below: open until its time threshold. 0..3 were never covered by any ACK and no future one
    # can reach them: their fate is unknown, which is no evidence of loss.
    assert [p.seq for p in lost] == [4, 5, 6]
    assert log.unknown == 4
    assert log.loss_deadline(1.0) == pytest.approx(1.008)


def test_silence_declares_nothing_and_a_reported_gap_times_out() -> None:
    log = _log(0, 5)
    lost: list[LostPacket] = []
    assert log.loss_deadline(0.1) is None  # no ACK at all: a blackout, not evidence of loss
    log.detect_losses(10.0, 0.1, lost)
    assert lost == []
    # ACK 4 with SACK 3 and 1: 2 and 0 reported absent.
    log.on_ack(4, 0b0101, 0.0, 0.05)
    log.detect_losses(0.05, 0.1, lost)
    assert [p.seq for p in lost] == [0]  # 0 is 4 below the ACK; 2 only 2 below
    assert log.loss_deadline(0.1) == pytest.approx(0.102)
    log.detect_losses(0.1025, 0.1, lost)
    assert [p.seq for p in lost] == [0, 2]  # the time threshold caught up with 2


def test_late_report_of_a_declared_loss_is_spurious() -> None:
    log = _log(0, 10)
    log.on_ack(9, 0, 0.0, 0.05)
    lost: list[LostPacket] = []
    log.detect_losses(0.05, 1.0, lost)
    # ACK 9 covered 3..9 (3..8 absent); 0..2 were never covered: unknown, not lost.
    assert [p.seq for p in lost] == [3, 4, 5, 6]
    assert log.unknown == 3
    assert log.on_ack(9, 0b100000, 0.0, 0.06).spurious == 1  # 3 (9 - 6) arrived after all


def test_table_bound_retires_the_oldest() -> None:
    log = SentPacketLog(0, reorder_threshold=3, max_tracked=64)
    lost: list[LostPacket] = []
    for i in range(70):
        log.on_sent(i * 0.001, 10, lost)
    assert lost == [] and log.unknown == 6  # never reported: unknown
    log.on_ack(69, 0, 0.0, 0.07)  # reports 63..68 absent
    for i in range(70, 76):
        log.on_sent(i * 0.001, 10, lost)
    assert [p.seq for p in lost] == []  # evicting 6..11: still never reported
    assert log.unknown == 12


def test_many_candidates_in_flight_are_told_apart_by_rtt() -> None:
    """100 kHz with a 2 s RTT: 200,000 packets in flight, so a 12-bit ACK fits ~49 of them."""
    rate, rtt = 100_000, 2.0
    log = _log(0, 210_000, gap=1 / rate)
    now = 2.09  # the packet sent at now - rtt (= 0.09 s) is seq 9000
    assert log.expand_ack(9000 & 0xFFF, 0.0, now, rtt) == 9000
    log.on_ack(9000, 0, 0.0, now)
    # Later ACKs are matched the same way, against the send time the RTT points at.
    assert log.expand_ack(9100 & 0xFFF, 0.0, now + 0.001, rtt) == 9100


def test_3_or_more_later_means_the_largest_ack_field() -> None:
    """PROTOCOL.md 5.4: a packet reported absent is lost once LA (the largest ACK *field*) is 3 or
    more above it. SACK bits lie below their ACK field, so they never move LA."""
    log = _log(0, 12)
    lost: list[LostPacket] = []
    log.on_ack(5, 0b111110, 0.0, 0.02)  # 4 absent; 3..0 present
    log.detect_losses(0.02, 1.0, lost)
    assert lost == [] and log.largest_acked == 5  # 4 is 1 below LA: not yet
    log.on_ack(6, 0b111101, 0.0, 0.02)  # still absent, LA 6: 2 below
    log.detect_losses(0.02, 1.0, lost)
    assert lost == []
    log.on_ack(7, 0b111011, 0.0, 0.02)  # LA 7 = 4 + 3
    log.detect_losses(0.02, 1.0, lost)
    assert [p.seq for p in lost] == [4]


def test_the_time_threshold_runs_from_the_send_time() -> None:
    """PROTOCOL.md 5.4: lost when P < LA and now >= send_time(P) + loss_delay; the clock starts at
    the send time, not at the report. A packet first reported absent after loss_delay is lost at
    once; one reported earlier waits until send_time + loss_delay exactly."""
    log = _log(0, 3, gap=0.001)  # sent at 0, 1 and 2 ms
    lost: list[LostPacket] = []
    log.on_ack(1, 0b000000, 0.0, 0.5)  # 0 absent, reported at 0.5 s, 1 below LA
    log.detect_losses(0.5, 0.3, lost)  # 0.3 s after its send time already: lost now
    assert [p.seq for p in lost] == [0]
    log = _log(0, 3, gap=0.001)
    lost = []
    log.on_ack(1, 0b000000, 0.0, 0.1)  # reported at 0.1 s
    assert log.loss_deadline(0.3) == pytest.approx(0.3)  # send time 0 + 0.3, not 0.1 + 0.3
    log.detect_losses(0.2999, 0.3, lost)
    assert lost == []
    log.detect_losses(0.3, 0.3, lost)
    assert [p.seq for p in lost] == [0]
