"""NetemLink's deterministic behaviour: timing, ordering, the queue limit, reordering, duplication,
corruption, accounting and reproducibility. Statistical properties are in test_netem_statistics.py."""

from __future__ import annotations

import itertools
import math
import random

import pytest

from tdtp.netem import (
    DelaySpec,
    NetemLink,
    NetemSpec,
    RateSpec,
    ReorderSpec,
    parse_netem,
)

Delivery = tuple[float, bytes, object]


def drain(link: NetemLink, now: float, until: float = math.inf) -> list[Delivery]:
    """Collect deliveries one due time after another, from ``now`` up to ``until``: (time, data, tag)."""
    out: list[Delivery] = []
    while (due := link.next_delivery()) is not None and due <= until:
        now = max(now, due)
        out += [(now, data, tag) for data, tag in link.deliver(now)]
    return out


def packets(n: int) -> list[bytes]:
    return [i.to_bytes(4, "big") for i in range(n)]


def accounted(link: NetemLink) -> bool:
    s = link.stats
    return s.sent + s.duplicated == s.delivered + s.lost + s.queue_dropped + link.pending


# -- timing and order ---------------------------------------------------------------------------------


def test_no_impairment_delivers_at_once_in_order() -> None:
    link = NetemLink(NetemSpec(), seed=1)
    for i, data in enumerate(packets(5)):
        link.send(data, 1.0, tag=i)
    assert link.next_delivery() == 1.0
    assert link.deliver(1.0) == [(data, i) for i, data in enumerate(packets(5))]
    assert link.next_delivery() is None
    assert link.pending == 0
    assert link.stats.delivered == link.stats.sent == 5
    assert link.stats.bytes_in == link.stats.bytes_out == 20


def test_fixed_delay_holds_each_packet_exactly_that_long() -> None:
    link = NetemLink(parse_netem("delay 20ms"), seed=1)
    link.send(b"a", 10.0, "A")
    link.send(b"b", 10.005, "B")
    assert link.next_delivery() == pytest.approx(10.02)
    assert link.deliver(10.0199) == []
    assert link.deliver(10.02) == [(b"a", "A")]
    assert link.next_delivery() == pytest.approx(10.025)
    assert link.deliver(11.0) == [(b"b", "B")]
    assert link.next_delivery() is None


def test_tag_travels_with_the_datagram_and_its_copies() -> None:
    link = NetemLink(parse_netem("duplicate 100%"), seed=1)
    address = ("127.0.0.1", 9000)
    link.send(b"x", 0.0, address)
    assert link.deliver(0.0) == [(b"x", address), (b"x", address)]


def test_bytes_like_datagrams_are_stored_as_bytes() -> None:
    link = NetemLink(NetemSpec(), seed=1)
    link.send(bytearray(b"abc"), 0.0)
    link.send(memoryview(b"def"), 0.0)
    delivered = link.deliver(0.0)
    assert [data for data, _ in delivered] == [b"abc", b"def"]
    assert all(type(data) is bytes for data, _ in delivered)


def test_equal_send_times_keep_arrival_order() -> None:
    link = NetemLink(parse_netem("delay 10ms"), seed=1)
    for data in packets(50):
        link.send(data, 0.0)
    assert [data for _, data, _ in drain(link, 0.0)] == packets(50)


def test_large_jitter_reorders_without_rate_but_not_with_rate() -> None:
    # Packets 1 ms apart with a +/-10 ms uniform jitter overtake each other, because netem's queue is
    # ordered by send time; a rate makes send times increase, so the order holds.
    for text, reorders in (("delay 50ms 10ms", True), ("delay 50ms 10ms rate 100mbit", False)):
        link = NetemLink(parse_netem(text), seed=3)
        for i, data in enumerate(packets(200)):
            link.send(data, i * 0.001)
        order = [data for _, data, _ in drain(link, 0.2)]
        assert sorted(order) == packets(200)
        assert (order != packets(200)) is reorders, text
        assert link.stats.reordered == 0  # jitter reordering is not the reorder option


def test_a_negative_delay_means_at_once() -> None:
    # delay 0 with a jitter: about half the draws are negative; those packets leave at once.
    link = NetemLink(parse_netem("delay 0 5ms"), seed=2)
    immediate = 0
    for i in range(200):
        link.send(b"x", float(i))
        due = link.next_delivery()
        assert due is not None
        assert due <= i + 0.005
        immediate += link.in_flight == 0
        assert len(link.deliver(float(i) + 0.005)) == 1
    assert 50 < immediate < 150


def test_next_delivery_may_be_past_when_not_collected() -> None:
    link = NetemLink(parse_netem("delay 10ms"), seed=1)
    link.send(b"a", 0.0)
    link.send(b"b", 1.0)  # a is due since 0.01 but not collected
    assert link.next_delivery() == pytest.approx(0.01)
    assert link.pending == 2
    assert link.in_flight == 1
    assert link.deliver(1.0) == [(b"a", None)]


def test_time_must_not_go_backwards() -> None:
    link = NetemLink(NetemSpec(), seed=1)
    link.send(b"a", 5.0)
    with pytest.raises(ValueError, match="went backwards"):
        link.send(b"b", 4.0)
    with pytest.raises(ValueError, match="went backwards"):
        link.deliver(4.999)
    with pytest.raises(ValueError, match="finite"):
        link.deliver(math.nan)


# -- rate ---------------------------------------------------------------------------------------------


def test_rate_serialises_packets_back_to_back() -> None:
    # 1250 bytes at 1 Mbit/s take 10 ms; with a 10 ms delay, three packets sent together arrive at
    # 20, 30 and 40 ms: send_time = max(now + delay, last send time) + transmit time.
    link = NetemLink(parse_netem("delay 10ms rate 1mbit"), seed=1)
    for data in (b"a", b"b", b"c"):
        link.send(data * 1250, 0.0)
    times = [t for t, _, _ in drain(link, 0.0)]
    assert times == pytest.approx([0.02, 0.03, 0.04])
    # Once the queue is empty again, only the delay and the packet's own transmit time count.
    link.send(b"d" * 1250, 0.5)
    assert link.next_delivery() == pytest.approx(0.52)


def test_rate_queues_behind_the_last_packet_still_held() -> None:
    # 125 bytes at 1 Mbit/s: 1 ms. The second packet's now + delay (10.5 ms) is before the first's
    # send time (11 ms), so it waits for it: 11 + 1 = 12 ms.
    link = NetemLink(parse_netem("delay 10ms rate 1mbit"), seed=1)
    link.send(b"a" * 125, 0.0)
    link.send(b"b" * 125, 0.0005)
    times = [t for t, _, _ in drain(link, 0.0005)]
    assert times == pytest.approx([0.011, 0.012])


def test_rate_with_jitter_follows_the_kernel_and_does_not_accumulate_jitter() -> None:
    """With a rate, the kernel (netem_enqueue) takes the tail packet still queued as its reference:
    ``delay -= T_tail - now`` (the time bonus), clamped at 0, then ``time_to_send = T_tail + delay +
    transmit time``, i.e. ``max(now + delay, T_tail) + transmit``. So a packet waits behind a
    longer-delayed one (head-of-line), but the wait is bounded by the jitter's range: jitter does not
    pile up while the rate has room. Here the same arithmetic, step by step, against the link."""
    spec = parse_netem("delay 40ms 10ms rate 2mbit limit 100")
    assert spec.rate is not None
    transmit = spec.rate.transmit_time(105)
    link = NetemLink(spec, seed=4)
    draws = NetemLink(parse_netem("delay 40ms 10ms"), seed=4)  # the same delay draws, no rate
    sent = [i * 0.001 for i in range(5000)]  # 1000 packets/s of 105 bytes (0.42 ms at 2 Mbit/s)
    due: dict[object, float] = {}  # by the packet's send time, when it left the link
    delay: dict[object, float] = {}
    for i, now in enumerate(sent):
        link.send(bytes(105), now, now)
        draws.send(b"", now, now)
        until = sent[i + 1] if i + 1 < len(sent) else math.inf
        due.update((tag, t) for t, _, tag in drain(link, now, until))
        for t, _, tag in drain(draws, now, until):
            assert isinstance(tag, float)
            delay[tag] = t - tag
    tail = -math.inf
    for now in sent:
        wait = delay[now]
        if tail > now:  # a packet is still queued: the kernel's time bonus
            wait = max(wait - (tail - now), 0.0)
            start = tail
        else:
            start = now
        tail = start + wait + transmit
        assert due[now] == pytest.approx(tail, abs=1e-9)
        assert (
            due[now] - now <= 0.050 + transmit + 1e-9
        )  # never more than delay + jitter + 1 packet
    assert max(due[now] - now for now in sent) > 0.049  # the head-of-line wait is real


def test_rate_overheads_and_cells() -> None:
    # tc-netem(8): a 50-byte packet on ATM (48-byte cells with 5 bytes of header) takes 2 cells,
    # 106 bytes on the wire.
    atm = RateSpec(1e6, packet_overhead=0, cell_size=48, cell_overhead=5)
    assert atm.wire_bytes(50) == 106
    assert atm.wire_bytes(48) == 53
    assert atm.transmit_time(50) == pytest.approx(106 * 8 / 1e6)
    assert RateSpec(1e6, packet_overhead=28).wire_bytes(100) == 128
    assert RateSpec(1e6, packet_overhead=-14).wire_bytes(10) == 0  # never negative
    link = NetemLink(NetemSpec(rate=atm), seed=1)
    link.send(b"x" * 50, 0.0)
    assert link.next_delivery() == pytest.approx(106 * 8 / 1e6)


# -- the queue limit (DropTail) ---------------------------------------------------------------------


def test_droptail_drops_exactly_when_limit_packets_are_held() -> None:
    # 1000 bytes at 8 kbit/s: 1 s each, so everything sent at t = 0 queues.
    link = NetemLink(parse_netem("rate 8kbit limit 5"), seed=1)
    for data in packets(8):
        link.send(data * 250, 0.0)
    assert link.in_flight == 5
    assert link.stats.queue_dropped == 3
    # By t = 2 s the first two have left (at 1 s and 2 s): two places free, the third arrival is dropped.
    for data in packets(3):
        link.send(data * 250, 2.0)
    assert link.in_flight == 5
    assert link.stats.queue_dropped == 4
    delivered = [data[:4] for _, data, _ in drain(link, 2.0)]
    assert delivered == [*packets(5), *packets(2)]
    assert accounted(link)


def test_limit_zero_drops_everything_and_limit_one_holds_one() -> None:
    link = NetemLink(parse_netem("delay 1s limit 0"), seed=1)
    link.send(b"x", 0.0)
    assert link.stats.queue_dropped == 1
    assert link.pending == 0
    link = NetemLink(parse_netem("delay 1s limit 1"), seed=1)
    link.send(b"x", 0.0)
    link.send(b"y", 0.5)
    link.send(b"z", 1.0)  # x left at 1.0: room again
    assert link.stats.queue_dropped == 1
    assert [data for _, data, _ in drain(link, 1.0)] == [b"x", b"z"]


def test_the_limit_does_not_depend_on_how_often_the_caller_collects() -> None:
    # Due datagrams leave the queue at their time whether or not deliver() has collected them, so a
    # caller polling late sees the same decisions as one polling on time.
    spec = parse_netem("delay 30ms 20ms rate 2mbit limit 8 loss 5% duplicate 5%")
    eager, lazy = NetemLink(spec, seed=9), NetemLink(spec, seed=9)
    rng = random.Random(4)
    now = 0.0
    eager_out: list[bytes] = []
    for i in range(3000):
        now += rng.expovariate(1500.0)
        data = i.to_bytes(4, "big") * rng.randint(10, 300)
        eager.send(data, now)
        lazy.send(data, now)
        eager_out += [d for d, _ in eager.deliver(now)]
        assert eager.in_flight <= 8 + 1  # + 1: a duplicate's original, see the test below
    lazy_out = [d for d, _ in lazy.deliver(now + 10.0)]
    eager_out += [d for d, _ in eager.deliver(now + 10.0)]
    assert eager.stats == lazy.stats
    assert eager_out == lazy_out
    assert eager.stats.queue_dropped > 0


def test_lost_packets_take_no_place_in_the_queue() -> None:
    link = NetemLink(parse_netem("delay 1s loss 100% limit 1"), seed=1)
    for data in packets(10):
        link.send(data, 0.0)
    assert link.stats.lost == 10
    assert link.stats.queue_dropped == 0


# -- reorder --------------------------------------------------------------------------------------------


def test_reorder_needs_a_delay() -> None:
    with pytest.raises(ValueError, match="reordering needs a delay"):
        NetemSpec(reorder=ReorderSpec(0.5))
    with pytest.raises(ValueError, match="reordering needs a delay"):
        NetemSpec(delay=DelaySpec(0.0, 0.01), reorder=ReorderSpec(0.5))
    with pytest.raises(ValueError, match="reordering needs a delay"):
        parse_netem("rate 1mbit reorder 50%")


def test_reorder_100_percent_gap_5_sends_every_5th_packet_at_once() -> None:
    # tc-netem(8): "reorder 100% gap 5" -> the first 4 packets are delayed, the 5th is sent at once,
    # and the count restarts.
    link = NetemLink(parse_netem("delay 10ms reorder 100% gap 5"), seed=1)
    immediate = []
    for i, data in enumerate(packets(20)):  # all within 2 ms: no delayed packet is due yet
        link.send(data, i * 0.0001)
        immediate += [int.from_bytes(d, "big") for d, _ in link.deliver(i * 0.0001)]
    assert immediate == [4, 9, 14, 19]
    assert link.stats.reordered == 4
    rest = [int.from_bytes(d, "big") for _, d, _ in drain(link, 0.0019)]
    assert rest == [i for i in range(20) if i % 5 != 4]


def test_reordered_packets_overtake_delayed_ones() -> None:
    link = NetemLink(parse_netem("delay 10ms reorder 50%"), seed=5)
    for i, data in enumerate(packets(100)):
        link.send(data, i * 0.001)
    order = [int.from_bytes(d, "big") for _, d, _ in drain(link, 0.099)]
    assert sorted(order) == list(range(100))
    assert order != list(range(100))
    overtakes = sum(1 for a, b in itertools.pairwise(order) if a > b)
    assert overtakes > 0
    assert 20 < link.stats.reordered < 80


def test_reorder_zero_percent_reorders_nothing() -> None:
    link = NetemLink(parse_netem("delay 10ms reorder 0%"), seed=1)
    for i, data in enumerate(packets(50)):
        link.send(data, i * 0.001)
    assert [d for _, d, _ in drain(link, 0.05)] == packets(50)
    assert link.stats.reordered == 0


# -- duplicate, corrupt, loss interplay ------------------------------------------------------------------


def test_duplicate_creates_a_copy_that_is_not_duplicated_again() -> None:
    link = NetemLink(parse_netem("duplicate 100%"), seed=1)
    for data in packets(10):
        link.send(data, 0.0)
    delivered = [d for d, _ in link.deliver(0.0)]
    assert delivered == [d for data in packets(10) for d in (data, data)]
    assert link.stats.duplicated == 10
    assert link.stats.delivered == 20
    assert accounted(link)


def test_duplicated_and_lost_goes_on_once_as_in_netem() -> None:
    # In netem_enqueue a loss removes one of the copies: duplicate 100% plus loss 100% delivers each
    # packet exactly once (the copy is never made).
    link = NetemLink(parse_netem("duplicate 100% loss 100%"), seed=1)
    for data in packets(10):
        link.send(data, 0.0)
    assert [d for d, _ in link.deliver(0.0)] == packets(10)
    assert link.stats.lost == link.stats.duplicated == 10
    assert accounted(link)


def test_the_copy_faces_loss_on_its_own() -> None:
    link = NetemLink(parse_netem("duplicate 100% loss 50%"), seed=3)
    for data in packets(1000):
        link.send(data, 0.0)
    link.deliver(0.0)
    s = link.stats
    assert s.duplicated == 1000
    # The original's loss decision removes the copy-to-be (1 delivered); otherwise the copy faces its
    # own loss decision (2 or 1 delivered): 1 w.p. 3/4, 2 w.p. 1/4, mean 1.25, variance 3/16 each.
    assert abs(s.delivered - 1250) < 5 * math.sqrt(1000 * 3 / 16)
    assert accounted(link)


def test_a_duplicate_can_take_the_queue_one_past_its_limit_as_in_netem() -> None:
    # netem checks the limit for the original, enqueues the copy (checked against the limit on its
    # own), then queues the original without a second check: limit + 1 packets can be held.
    link = NetemLink(parse_netem("delay 1s duplicate 100% limit 3"), seed=1)
    link.send(b"a", 0.0)  # a and its copy: 2 held
    link.send(b"b", 0.0)  # 2 < 3: the copy takes the third place, b itself the fourth
    assert link.in_flight == 4
    link.send(b"c", 0.0)  # 4 >= 3: dropped with its copy
    assert link.stats.queue_dropped == 2
    link = NetemLink(parse_netem("delay 1s limit 3"), seed=1)
    for data in packets(10):
        link.send(data, 0.0)
    assert link.in_flight == 3  # without duplication the limit is exact


def test_corrupt_flips_exactly_one_bit() -> None:
    link = NetemLink(parse_netem("corrupt 100%"), seed=1)
    rng = random.Random(2)
    originals = [rng.randbytes(rng.randint(1, 200)) for _ in range(500)]
    for data in originals:
        link.send(data, 0.0)
    delivered = [d for d, _ in link.deliver(0.0)]
    assert len(delivered) == 500
    for before, after in zip(originals, delivered, strict=True):
        assert len(before) == len(after)
        flipped = int.from_bytes(before, "big") ^ int.from_bytes(after, "big")
        assert flipped.bit_count() == 1
    assert link.stats.corrupted == 500


def test_corrupt_leaves_empty_datagrams_alone() -> None:
    link = NetemLink(parse_netem("corrupt 100%"), seed=1)
    link.send(b"", 0.0)
    assert link.deliver(0.0) == [(b"", None)]
    assert link.stats.corrupted == 0


def test_the_copy_is_taken_before_corruption() -> None:
    # Both copies get their own corrupt decision: with corrupt 100% each differs from the original in
    # exactly one bit, never two (the copy is not a copy of the corrupted original).
    link = NetemLink(parse_netem("duplicate 100% corrupt 100%"), seed=4)
    original = bytes(64)
    for _ in range(200):
        link.send(original, 0.0)
    for data, _ in link.deliver(0.0):
        assert int.from_bytes(data, "big").bit_count() == 1
    assert link.stats.corrupted == 400


def test_everything_is_accounted_for_under_mixed_impairment() -> None:
    spec = parse_netem(
        "delay 20ms 15ms 20% distribution paretonormal loss gemodel 5% 30% 60% 1% "
        "duplicate 10% corrupt 5% reorder 10% 20% gap 3 rate 5mbit 28 limit 20"
    )
    link = NetemLink(spec, seed=11)
    rng = random.Random(1)
    now = 0.0
    for i in range(5000):
        now += rng.expovariate(2000.0)
        link.send(i.to_bytes(4, "big") * rng.randint(1, 100), now)
        assert link.in_flight <= 20 + 1  # + 1: duplication, as in netem
        if i % 7 == 0:
            link.deliver(now)
        assert accounted(link)
    link.deliver(now + 10.0)
    assert link.pending == 0
    assert accounted(link)
    s = link.stats
    assert min(s.lost, s.queue_dropped, s.duplicated, s.corrupted, s.reordered) > 0


# -- reproducibility ----------------------------------------------------------------------------------


def run_trace(link: NetemLink, n: int = 2000) -> list[Delivery]:
    rng = random.Random(0)
    out: list[Delivery] = []
    now = 0.0
    for i in range(n):
        now += rng.expovariate(1000.0)
        link.send(i.to_bytes(4, "big") * 8, now, i)
        out += [(now, d, t) for d, t in link.deliver(now)]
    return out + drain(link, now)


SPEC = parse_netem(
    "delay 20ms 5ms 25% distribution normal loss 2% duplicate 2% corrupt 2% reorder 5% rate 10mbit"
)


def test_same_seed_same_decisions() -> None:
    first, second = NetemLink(SPEC, seed=123), NetemLink(SPEC, seed=123)
    assert run_trace(first) == run_trace(second)
    assert first.stats == second.stats


def test_different_seed_different_decisions() -> None:
    first, second = NetemLink(SPEC, seed=123), NetemLink(SPEC, seed=124)
    assert run_trace(first) != run_trace(second)


def test_seed_comes_from_the_argument_then_the_spec_then_the_os() -> None:
    seeded = parse_netem(str(SPEC) + " seed 77")
    assert NetemLink(seeded).seed == 77
    assert NetemLink(seeded, seed=5).seed == 5
    assert run_trace(NetemLink(seeded)) == run_trace(NetemLink(SPEC, seed=77))
    drawn = NetemLink(SPEC)
    assert 0 <= drawn.seed < 2**64
    assert run_trace(drawn) == run_trace(NetemLink(SPEC, seed=drawn.seed))  # replayable


def test_link_rejects_bad_arguments() -> None:
    with pytest.raises(TypeError, match="needs a NetemSpec"):
        NetemLink("delay 20ms")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="seed"):
        NetemLink(NetemSpec(), seed=-1)


def test_repr_and_stats_dict() -> None:
    link = NetemLink(parse_netem("delay 20ms"), seed=3)
    link.send(b"x", 0.0)
    assert repr(link) == "NetemLink('delay 20ms', seed=3, pending=1)"
    assert link.stats.as_dict()["sent"] == 1


def test_change_takes_the_link_down_and_back_like_tc_qdisc_change() -> None:
    link = NetemLink(parse_netem("delay 10ms"), seed=1)
    link.send(b"before", 0.0)
    link.change(parse_netem("loss 100%"))
    link.send(b"during", 0.001)  # lost
    assert str(link.spec) == "loss 100%"
    link.change(parse_netem("delay 1ms"))
    link.send(b"after", 0.002)
    # The packet already on the link keeps its 10 ms; the new delay applies to new packets only.
    assert link.deliver(0.0031) == [(b"after", None)]
    assert link.deliver(0.010) == [(b"before", None)]
    assert (link.stats.sent, link.stats.lost, link.stats.delivered) == (3, 1, 2)
    with pytest.raises(TypeError):
        link.change("loss 1%")  # type: ignore[arg-type]
