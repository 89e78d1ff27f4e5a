"""The receiver's reorder wait: in-order delivery on reordering paths, no delay on the others, bounded."""

from __future__ import annotations

import math
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tdtp import ConnectionConfig
from tdtp.control.fixed import FixedConfig
from tdtp.session.reorder_buffer import SPAN, ReorderBuffer

from pair import Direction, Pair

UNLIMITED = ConnectionConfig(controller="fixed", controller_config=FixedConfig(rate=float("inf")))


def _learn(buffer: ReorderBuffer, displacement: float, now: float) -> float:
    """Show ``buffer`` (no reordering seen yet) one sample reordered by ``displacement``: it is
    late (its gap was given up at once), but measured. Returns the time after it."""
    seq = buffer.next_seq
    assert buffer.accept(seq, b"a", now)  # in order
    buffer.on_gap(seq + 1, seq + 2, now)  # seq + 2 arrives, skipping seq + 1
    assert buffer.accept(seq + 2, b"c", now)
    now += displacement
    buffer.on_late(seq + 1, now)
    assert not buffer.accept(seq + 1, b"b", now)
    return now


def test_in_order_samples_are_delivered_at_once_and_gaps_are_losses_until_reordering_is_seen() -> (
    None
):
    buffer = ReorderBuffer(100, max_wait=0.02)
    assert buffer.accept(100, b"x", 0.0) and buffer.accept(101, b"x", 0.001)
    buffer.on_gap(102, 105, 0.002)
    assert buffer.accept(105, b"x", 0.002)  # no reordering measured: the gap is given up at once
    assert buffer.given_up == 3 and buffer.next_seq == 106 and buffer.wait == 0.0
    assert not buffer.accept(103, b"x", 0.003)  # its gap is gone: the caller drops it as late
    assert buffer.deadline() is None


def test_a_measured_displacement_sets_the_wait_and_a_filled_gap_releases_in_order() -> None:
    buffer = ReorderBuffer(0, max_wait=0.02)
    now = _learn(buffer, 0.004, 1.0)
    assert buffer.wait == pytest.approx(0.005)  # 1.25 x 4 ms
    assert buffer.given_up == 1  # the one it learnt from
    # 3 and 4 are missing; 5 and 6 arrive and wait for them.
    buffer.on_gap(3, 5, now)
    assert not buffer.accept(5, b"5", now)
    assert not buffer.accept(6, b"6", now + 0.001)
    assert buffer.deadline() == pytest.approx(now + 0.005)
    assert buffer.release(now + 0.002) == []
    buffer.on_late(3, now + 0.003)
    assert buffer.accept(3, b"3", now + 0.003)
    assert buffer.release(now + 0.003) == []  # 4 still open
    buffer.on_late(4, now + 0.004)
    assert buffer.accept(4, b"4", now + 0.004)
    released = buffer.release(now + 0.004)
    assert [seq for seq, *_ in released] == [5, 6]
    assert [arrival for _, _, arrival, _ in released] == [now, now + 0.001]
    assert buffer.given_up == 1 and not buffer.held


def test_a_gap_is_given_up_when_its_wait_runs_out_and_its_sample_is_then_late() -> None:
    buffer = ReorderBuffer(0, max_wait=0.02)
    now = _learn(buffer, 0.004, 1.0)
    buffer.on_gap(3, 4, now)
    assert not buffer.accept(4, b"4", now)
    deadline = buffer.deadline()
    assert deadline is not None
    assert buffer.release(deadline - 1e-6) == []
    assert buffer.release(deadline) == [(4, b"4", now, None)]
    assert buffer.given_up == 2
    assert not buffer.accept(3, b"3", deadline + 0.001) and buffer.next_seq > 3


def test_the_wait_is_capped_and_decays_once_reordering_stops() -> None:
    buffer = ReorderBuffer(0, max_wait=0.01)
    now = _learn(buffer, 0.5, 1.0)
    assert buffer.wait == 0.01
    # Two seconds of in-order samples: both buckets age out, the wait returns to zero.
    seq = buffer.next_seq
    for step in range(2500):
        now += 0.001
        assert buffer.accept(seq + step, b"x", now)
    buffer.on_gap(seq + 2500, seq + 2501, now)
    assert buffer.accept(seq + 2501, b"x", now)  # a loss, given up at once
    assert buffer.wait == 0.0


def test_a_sample_far_ahead_gives_up_the_oldest_gaps_so_the_buffer_stays_bounded() -> None:
    buffer = ReorderBuffer(0, max_wait=0.02)
    now = _learn(buffer, 0.004, 1.0)
    buffer.on_gap(3, 4, now)
    assert not buffer.accept(4, b"4", now)
    far = 4 + 10 * SPAN
    buffer.on_gap(5, far, now)
    assert not buffer.accept(far, b"far", now)
    released = buffer.release(now)  # well before any deadline
    assert [seq for seq, *_ in released] == [4]
    # Only the gaps the span still reaches are awaited.
    assert len(buffer.held) == 1 and buffer.next_seq == far - SPAN + 1


@settings(max_examples=150, deadline=None)
@given(
    st.lists(st.tuples(st.floats(0.0, 0.012), st.booleans()), min_size=1, max_size=300),
    st.floats(0.0, 0.03),
)
def test_any_arrival_order_delivers_each_sample_at_most_once_in_order(
    path: list[tuple[float, bool]], max_wait: float
) -> None:
    """Sample k leaves at k ms and arrives ``delay`` later unless lost: whatever the network does,
    the application sees increasing sequence numbers, nothing twice, nothing lost that arrived in
    time, and never more than SPAN held."""
    arrivals = sorted((k * 0.001 + delay, k) for k, (delay, lost) in enumerate(path) if not lost)
    buffer = ReorderBuffer(0, max_wait=max_wait)
    highest = -1
    delivered: list[int] = []
    late = 0
    for now, seq in arrivals:
        deadline = buffer.deadline()
        if deadline is not None and deadline <= now:
            delivered.extend(s for s, *_ in buffer.release(deadline))
        if seq > highest:
            buffer.on_gap(highest + 1, seq, now)
            highest = seq
        else:
            buffer.on_late(seq, now)
        if buffer.accept(seq, b"", now):
            delivered.append(seq)
        elif seq < buffer.next_seq:
            late += 1
        delivered.extend(s for s, *_ in buffer.release(now))
        assert len(buffer.held) <= SPAN
        assert 0.0 <= buffer.wait <= max_wait
    delivered.extend(s for s, *_ in buffer.release(math.inf))
    assert delivered == sorted(set(delivered))
    assert len(delivered) + late == len(arrivals)


def _jitter(seed: int, spread: float) -> Direction:
    rng = random.Random(seed)
    return Direction(delay=0.015, extra_delay=lambda _: rng.uniform(0.0, spread))


def test_netem_style_jitter_delivers_nearly_every_sample_in_order_within_the_wait() -> None:
    # 20 +- 5 ms at 1 kHz: most samples arrive behind a newer one.
    pair = Pair(UNLIMITED, UNLIMITED, ms=_jitter(3, 0.010))
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(5.0)
    pair.drain()
    slave = pair.slave.conn.stats
    sent = pair.master.conn.stats.sent.data_packets
    assert slave.reordered > sent * 0.4
    seqs = [event.seq for event in pair.slave.received]
    assert seqs == sorted(set(seqs))
    # Only samples that came before the wait had learnt the path's reordering are lost.
    assert slave.samples_delivered >= sent * 0.99
    assert slave.samples_delivered + slave.drops.get("late", 0) == sent
    assert 0.008 < slave.reorder_wait <= 0.02


def test_a_lossy_path_that_does_not_reorder_adds_no_wait() -> None:
    lossy = Direction(drop=lambda i: i % 17 == 3)
    pair = Pair(UNLIMITED, UNLIMITED, ms=lossy)
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(3.0)
    slave = pair.slave.conn.stats
    assert slave.peer_gaps > 150
    assert slave.reorder_held == 0 and slave.reorder_wait == 0.0
    assert pair.slave.conn.get_timer() is not None
    seqs = [event.seq for event in pair.slave.received]
    assert seqs == sorted(set(seqs))


def test_a_held_sample_reports_the_time_it_was_delivered_and_its_wait_in_its_age() -> None:
    # Every 25th packet is 3 ms late (its gap opens when the next one arrives 1 ms after it was
    # due: a 2 ms displacement), every 50th is lost outright: the samples behind a loss wait the
    # whole reorder wait, those behind a reordering only until it arrives.
    path = Direction(
        drop=lambda i: i % 50 == 30, extra_delay=lambda i: 0.003 if i % 25 == 10 else 0.0
    )
    pair = Pair(UNLIMITED, UNLIMITED, ms=path)
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(3.0)
    slave = pair.slave.conn.stats
    wait = slave.reorder_wait
    assert wait == pytest.approx(0.0025, abs=0.0002)
    ages = [event.estimated_age for event in pair.slave.received[500:]]
    base = min(age for age in ages if age is not None)
    assert base == pytest.approx(0.010, abs=0.001)  # half the RTT on a 10 ms each way path
    longest = max(age for age in ages if age is not None)
    assert wait - 0.0015 <= longest - base <= wait + 0.0005


@pytest.mark.parametrize("value", [-0.001, 1.5, math.nan, math.inf, "0.02", None])
def test_max_reorder_wait_is_validated(value: object) -> None:
    with pytest.raises(ValueError, match="max_reorder_wait"):
        ConnectionConfig(max_reorder_wait=value)  # type: ignore[arg-type]


@pytest.mark.parametrize("deliver_duplicates", [False, True])
def test_a_duplicate_goes_up_as_it_came_only_when_asked_for(deliver_duplicates: bool) -> None:
    from pair import MASTER_ADDR

    path = Direction(keep_wire=True)
    config = ConnectionConfig(deliver_duplicates=deliver_duplicates)
    pair = Pair(UNLIMITED, config, ms=path)
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(0.5)
    stats = pair.slave.conn.stats
    before = stats.samples_delivered
    data = [d for d in path.wire if d[0] >> 6 == 0]  # DATA; the one 50 ms back has arrived
    pair.inject(data[-50], to_slave=True, source=MASTER_ADDR)
    if deliver_duplicates:
        assert stats.samples_delivered == before + 1
        assert pair.slave.received[-1].payload == data[-50][5:]
    else:
        assert stats.samples_delivered == before and stats.drops["duplicate"] == 1


def test_the_newest_held_sample_is_offered_to_latest_value_readers_until_delivered() -> None:
    # Every 25th packet is 3 ms late: the ones behind it wait, and meanwhile the connection offers
    # the newest of them to a latest-value reader; once delivered in order it is no longer offered.
    path = Direction(extra_delay=lambda i: 0.003 if i % 25 == 10 else 0.0)
    pair = Pair(UNLIMITED, UNLIMITED, ms=path)
    pair.open()
    pair.start_samples(1000, 1000)
    conn = pair.slave.conn
    seen = 0
    end = pair.now + 2.0
    while pair.now < end:
        pair.run_for(0.0005)
        held = conn.newest_held
        if held is not None:
            seen += 1
            delivered = [event.seq for event in pair.slave.received]
            assert not delivered or held.seq > max(delivered)  # newer than anything delivered
            assert held.seq in conn._delivery.reorder.held  # type: ignore[union-attr]
    assert seen > 20
    pair.drain()
    assert conn.newest_held is None
    seqs = [event.seq for event in pair.slave.received]
    assert seqs == sorted(set(seqs))
