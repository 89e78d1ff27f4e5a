"""The receiver's window: expansion, late/duplicate/stale, SACK bits, coverage, resync."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from tdtp.session.receive_window import RESYNC_RUN, Arrival, HeldAck, ReceiveWindow


def test_in_order_gap_late_duplicate_and_stale() -> None:
    window = ReceiveWindow(4090)
    assert window.on_data(4090, 0.0) == (Arrival.NEW, 4090, 0)
    assert window.on_data(4093, 0.1) == (Arrival.NEW, 4093, 2)  # 4091 and 4092 missing
    assert window.on_data(4091, 0.2) == (Arrival.LATE, 4091, 0)
    assert window.on_data(4091, 0.3) == (Arrival.DUPLICATE, 4091, 0)
    assert window.on_data(2, 0.4) == (Arrival.NEW, 4098, 4)  # across the 12-bit wrap
    assert window.highest == 4098 and window.highest_arrival == 0.4
    for seq in range(4099, 4099 + 64):
        window.on_data(seq & 0xFFF, 1.0)
    assert window.on_data(4098 & 0xFFF, 1.0)[0] is Arrival.STALE


def test_sack_bits_describe_the_six_below() -> None:
    window = ReceiveWindow(100)
    for seq in (100, 101, 103, 105, 106):
        window.on_data(seq, 0.0)
    # Below 106: 105 yes, 104 no, 103 yes, 102 no, 101 yes, 100 yes -> bits 1..6 = 1,0,1,0,1,1
    assert window.sack_below(106) == 0b110101
    assert window.sack_below(103) == 0b000110  # 102 no, 101 yes, 100 yes, older unknown


def test_coverage_rule_fires_on_the_seventh_unreported_packet() -> None:
    window = ReceiveWindow(0)
    for seq in range(6):
        window.on_data(seq, 0.0)
    window.mark_reported()
    for seq in range(6, 12):
        window.on_data(seq, 0.0)
        assert not window.coverage_exhausted()
    window.on_data(12, 0.0)
    assert window.coverage_exhausted()
    assert window.unreported_since == 0.0
    window.mark_reported()
    assert window.unreported_since is None and window.last_reported == 12


def test_a_burst_longer_than_half_the_space_resyncs_instead_of_starving() -> None:
    window = ReceiveWindow(0)
    window.on_data(0, 0.0)
    # 3000 consecutive packets lost: the next ones look 1096 *behind* (older than the window).
    kinds = [window.on_data((3001 + i) & 0xFFF, 1.0)[0] for i in range(10)]
    assert kinds[: RESYNC_RUN - 1] == [Arrival.STALE] * (RESYNC_RUN - 1)
    assert kinds[RESYNC_RUN - 1 :] == [Arrival.NEW] * (10 - RESYNC_RUN + 1)
    assert window.highest & 0xFFF == 3010 & 0xFFF


def test_scattered_replays_of_old_packets_do_not_resync() -> None:
    window = ReceiveWindow(0)
    for seq in range(500):
        window.on_data(seq, 0.0)
    for old in (10, 50, 90, 130, 170):
        assert window.on_data(old, 1.0)[0] is Arrival.STALE
    assert window.highest == 499


def test_consecutive_stale_numbers_spread_between_live_packets_do_not_resync() -> None:
    """Only a run of consecutive *arrivals* re-anchors the window: three consecutive old numbers
    replayed one at a time between live packets are each stale (they once moved the window 4096
    ahead, found by the ring's property test below)."""
    window = ReceiveWindow(0)
    for seq in range(100):
        window.on_data(seq, seq * 0.001)
    live = 100
    for old in (10, 11, 12, 13):
        assert window.on_data(old, live * 0.001)[0] is Arrival.STALE
        assert window.on_data(live, live * 0.001)[0] is Arrival.NEW
        live += 1
    assert window.highest == live - 1


def test_jump_rule_reports_the_packets_a_lost_seventh_would_orphan() -> None:
    """PROTOCOL.md 3.2: after a report at L, L+1..L+6 arrive, L+7 is lost, L+8 arrives. An ACK of
    L+8 reaches down to L+2 only, so the ACK of L+6 must go out first (L = -1 here)."""
    window = ReceiveWindow(0)
    for seq in range(6):
        window.on_data(seq, 0.001 * seq)
        assert not window.coverage_exhausted() and not window.held
    window.on_data(7, 0.007)
    # 5 with 4..0 received below it (bit 6, for -1, was never sent)
    assert window.take_held() == [HeldAck(5, 0b011111, 0.005)]
    assert window.last_reported == 5 and window.pending_low == 6
    assert window.unreported_since == 0.007
    assert window.take_held() == []


def test_a_late_packet_within_reach_is_reported_again() -> None:
    window = ReceiveWindow(0)
    for seq in (0, 1, 3, 4):
        window.on_data(seq, 0.0)
    window.mark_reported()  # ACK 4 said: 2 absent
    assert window.pending_low is None
    assert window.on_data(2, 0.1)[0] is Arrival.LATE
    assert window.pending_low == 2  # the next ACK must tell the sender it arrived after all
    window.on_data(9, 0.2)  # an ACK of 9 would reach 3 only: hold the ACK of 4 first
    assert window.take_held() == [HeldAck(4, 0b001111, 0.0)]


def test_without_coverage_rules_nothing_is_held() -> None:
    window = ReceiveWindow(0, coverage=False)  # separate-ACK mode: every packet is ACKed anyway
    for seq in (0, 1, 2, 3, 4, 5, 20):
        window.on_data(seq, 0.0)
    assert not window.held and not window.coverage_exhausted()


def _reports(arrivals: list[int]) -> list[tuple[int, int]]:
    """Run a receiver that flushes after every arrival, as the connection does with no reverse
    data: the ACKs (value, SACK) it sends, the last one when ack_delay runs out."""
    window = ReceiveWindow(arrivals[0])
    sent: list[tuple[int, int]] = []
    for seq in arrivals:
        window.on_data(seq & 0xFFF, 0.0)
        sent += [(held.ack, held.sack) for held in window.take_held()]
        if window.coverage_exhausted():
            sent.append((window.highest, window.sack_below(window.highest)))
            window.mark_reported()
    if window.pending_low is not None:
        sent.append((window.highest, window.sack_below(window.highest)))
    return sent


@settings(max_examples=100, deadline=None)
@given(st.lists(st.booleans(), min_size=1, max_size=300), st.integers(0, 4095))
def test_every_received_packet_is_acknowledged_and_every_short_gap_reported(
    lost: list[bool], first: int
) -> None:
    """The section 3.2 promise for an in-order flow with any loss pattern: every packet that
    arrived is named by some ACK (value or SACK bit), and every lost packet with an arrival at
    most 6 above it is described as absent by some ACK."""
    received = [first + i for i, gone in enumerate(lost) if not gone]
    if not received:
        return
    described: dict[int, bool] = {}
    for ack, sack in _reports(received):
        described[ack] = True
        for i in range(1, 7):
            described.setdefault(ack - i, bool(sack >> (i - 1) & 1))
            if sack >> (i - 1) & 1:
                described[ack - i] = True
    arrived = set(received)
    for seq in arrived:
        assert described.get(seq) is True, seq
    for seq in range(received[0], received[-1]):
        if seq not in arrived and any(seq < r <= seq + 6 for r in arrived):
            assert described.get(seq) is False, seq


def _window_at(highest: int, now: float) -> ReceiveWindow:
    window = ReceiveWindow(highest - 99)
    for seq in range(highest - 99, highest + 1):
        assert window.on_data(seq & 0xFFF, now)[0] is Arrival.NEW
    return window


def test_after_a_silence_a_wrap_that_lands_inside_the_window_resyncs() -> None:
    """An outage of 4096 - 6 packets: the live flow decodes 6 below the newest, as duplicates."""
    window = _window_at(5000, now=1.0)
    live = 5000 + 4096 - 6
    kinds = [window.on_data(seq & 0xFFF, 5.0)[0] for seq in range(live, live + RESYNC_RUN + 2)]
    assert kinds == [Arrival.DUPLICATE, Arrival.DUPLICATE, Arrival.NEW, Arrival.NEW, Arrival.NEW]
    assert window.highest & 0xFFF == (live + RESYNC_RUN + 1) & 0xFFF


def test_late_packets_right_after_new_ones_are_still_late() -> None:
    """Legitimate reordering (a burst overtaken by newer packets) happens within milliseconds."""
    window = ReceiveWindow(0)
    for seq in (0, 1, 2, 10):
        window.on_data(seq, 0.0)
    kinds = [window.on_data(seq, 0.002)[0] for seq in range(3, 10)]
    assert kinds == [Arrival.LATE] * 7
    assert window.highest == 10
    # The same after a silence (silence_guard), but replayed as duplicates of a scattered few, does
    # not resync either: only a consecutive run does.
    kinds = [window.on_data(seq, 1.0)[0] for seq in (4, 8, 6)]
    assert kinds == [Arrival.DUPLICATE] * 3
    assert window.highest == 10


class _MaskModel:
    """The window as docs/PROTOCOL.md states it: a 64-bit mask of the last 64 sequence numbers (bit 0
    the highest), full numbers given directly. The reference the ring of slots must agree with."""

    def __init__(self, highest: int) -> None:
        self.highest = highest
        self.mask = 0

    def receive(self, seq: int) -> str:
        distance = seq - self.highest
        if distance > 0:
            self.mask = ((self.mask << distance) | 1) & ((1 << 64) - 1) if distance < 64 else 1
            self.highest = seq
            return "new"
        if distance <= -64:
            return "stale"
        if self.mask >> -distance & 1:
            return "duplicate"
        self.mask |= 1 << -distance
        return "late"

    def sack_below(self, seq: int) -> int:
        return (self.mask >> (self.highest - seq + 1)) & 0x3F


@settings(max_examples=300, deadline=None)
@given(
    start=st.integers(0, 4095),
    steps=st.lists(st.integers(-80, 80), min_size=1, max_size=300),
)
def test_the_ring_of_slots_agrees_with_a_64_bit_mask(start: int, steps: list[int]) -> None:
    """Arrival kinds and SACK bits (of the highest and of every number in the window) are those of
    the 64-bit mask, over random walks with gaps, reordering, duplicates and stale copies. Times
    stay within the silence guard and stale numbers never run, so no resync re-anchors the window
    here (resyncs have tests of their own above)."""
    window = ReceiveWindow(start)
    model = _MaskModel(start - 1)
    seq = start
    for index, step in enumerate(steps):
        seq = seq + step if index else start
        if seq - model.highest > 2000:
            seq = model.highest + 2000
        if seq - model.highest <= -64:
            # Stale, never two in a row one apart (a run of consecutive stale numbers resyncs).
            seq = model.highest - 64 - 3 * (index % 3)
        kind, full, _gap = window.on_data(seq & 0xFFF, index * 0.001)
        assert full == seq
        assert kind.value == model.receive(seq)
        assert window.report(index * 0.001)[:2] == (model.highest, model.sack_below(model.highest))
        for below in range(model.highest - 63, model.highest + 1):
            assert window.sack_below(below) == model.sack_below(below), below
