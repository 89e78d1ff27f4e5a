"""The receiver's window: expansion, late/duplicate/stale, SACK bits, coverage, resync."""

from __future__ import annotations

from tdtp.receive_window import RESYNC_RUN, Arrival, ReceiveWindow


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
