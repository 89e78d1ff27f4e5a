"""Recorded traces in the emulator: ``trace FILE [offset T] [overhead N]`` and ``limit-bytes N``.

Every trace here is synthetic, written to a temporary file (the recorded ones are GPL and stay out of
the repository). What is checked is Mahimahi's link semantics (src/frontend/link_queue.cc and its
droptail queue): opportunities of 1500 bytes counted in bytes, unused bytes lost, a FIFO queue whose
size counts only the datagrams not yet being served, looping at the last timestamp; then how the
trace combines with netem's other options, the parser, and the simulator's link doing the same.
"""

from __future__ import annotations

import math
import random
from collections.abc import Iterable
from pathlib import Path

import pytest

from tdtp.netem import (
    NetemLink,
    NetemSpec,
    NetemSyntaxError,
    TraceFileError,
    TraceQueue,
    TraceSpec,
    load_trace,
    parse_netem,
)
from tdtp.sim.engine import Network, Packet

MS = 0.001


@pytest.fixture
def write_trace(tmp_path: Path):  # type: ignore[no-untyped-def]
    """``write_trace([1, 1, 2, ...])`` -> the path of a trace file with those milliseconds."""
    count = 0

    def write(times: Iterable[int], *, text: str | None = None) -> str:
        nonlocal count
        count += 1
        path = tmp_path / f"t{count}.trace"
        path.write_text(text if text is not None else "".join(f"{t}\n" for t in times))
        return str(path)

    return write


def run(
    link: NetemLink, sends: Iterable[tuple[float, int]], *, start: float | None = 0.0
) -> list[tuple[float, int]]:
    """From ``start`` (the trace's clock starts at the first ``now`` a link sees; ``None`` for a link
    already running), send ``(time, size)`` datagrams (each tagged with its index), then collect
    every delivery at its due time: ``[(delivery time, index), ...]`` in delivery order."""
    out: list[tuple[float, int]] = []
    clock = -math.inf
    if start is not None:
        link.deliver(start)
        clock = start

    def collect(until: float) -> None:
        nonlocal clock
        while (due := link.next_delivery()) is not None and due <= until:
            clock = max(clock, due)  # a due time may be past already: collected now, at its time
            out.extend((due, tag) for _, tag in link.deliver(clock))  # type: ignore[misc]

    for i, (t, size) in enumerate(sends):
        collect(t)
        link.send(bytes(size), t, tag=i)
        clock = t
    collect(math.inf)
    return out


def accounted(link: NetemLink) -> bool:
    s = link.stats
    return s.sent + s.duplicated == s.delivered + s.lost + s.queue_dropped + link.pending


# -- the link's semantics ---------------------------------------------------------------------------


def test_constant_rate_one_full_datagram_per_opportunity(write_trace) -> None:  # type: ignore[no-untyped-def]
    # One opportunity a millisecond (12 Mbit/s of 1500-byte packets); five arrive together at 0.5 ms.
    link = NetemLink(parse_netem(f"trace {write_trace(range(1, 11))}"), seed=1)
    out = run(link, [(0.0005, 1500)] * 5)
    assert out == [(pytest.approx(k * MS), k - 1) for k in range(1, 6)]
    assert accounted(link)


def test_small_datagrams_share_an_opportunity_by_bytes(write_trace) -> None:  # type: ignore[no-untyped-def]
    link = NetemLink(parse_netem(f"trace {write_trace(range(1, 11))}"), seed=1)
    # Sixteen 100-byte datagrams waiting: fifteen fill the first 1500 bytes, the last one the next.
    out = run(link, [(0.0002, 100)] * 16)
    times = [t for t, _ in out]
    assert times == [pytest.approx(MS)] * 15 + [pytest.approx(2 * MS)]
    assert [i for _, i in out] == list(range(16))  # FIFO


def test_a_datagram_spans_opportunities_and_leaves_with_its_last_byte(write_trace) -> None:  # type: ignore[no-untyped-def]
    link = NetemLink(parse_netem(f"trace {write_trace(range(1, 11))}"), seed=1)
    # 100 bytes, then 1500 (1400 in the first opportunity, 100 in the second), then 1300 (which
    # fits in the second's 1400 left), then 3100 bytes (the second's last 100, then two more).
    out = run(link, [(0.0001, 100), (0.0001, 1500), (0.0001, 1300), (0.0001, 3100)])
    assert out == [
        (pytest.approx(1 * MS), 0),
        (pytest.approx(2 * MS), 1),
        (pytest.approx(2 * MS), 2),
        (pytest.approx(4 * MS), 3),
    ]


def test_unused_bytes_of_an_opportunity_are_lost(write_trace) -> None:  # type: ignore[no-untyped-def]
    # 100 bytes leave at 1 ms with 1400 unused; a datagram arriving at 1.2 ms cannot use them (no
    # carry-over, as in Mahimahi) and waits for the opportunity at 2 ms.
    link = NetemLink(parse_netem(f"trace {write_trace(range(1, 11))}"), seed=1)
    out = run(link, [(0.0005, 100), (0.0012, 100)])
    assert out == [(pytest.approx(MS), 0), (pytest.approx(2 * MS), 1)]


def test_an_opportunity_at_the_instant_of_arrival_is_already_gone(write_trace) -> None:  # type: ignore[no-untyped-def]
    queue = TraceQueue(load_trace(write_trace([2, 4, 6, 8])), limit=10, origin=0.0)
    assert queue.offer(0.004, 100) == pytest.approx(0.006)
    assert queue.offer(0.0041, 100) == pytest.approx(0.006)  # shares the one it waits for
    assert queue.offer(0.006, 100) == pytest.approx(0.008)


def test_several_opportunities_in_one_millisecond(write_trace) -> None:  # type: ignore[no-untyped-def]
    # Three lines for 1 ms, one for 2 ms: 4500 bytes at 1 ms.
    link = NetemLink(parse_netem(f"trace {write_trace([1, 1, 1, 2])}"), seed=1)
    out = run(link, [(0.0, 1500)] * 4)
    assert [t for t, _ in out] == [pytest.approx(MS)] * 3 + [pytest.approx(2 * MS)]


def test_an_outage_holds_the_queue_until_capacity_returns(write_trace) -> None:  # type: ignore[no-untyped-def]
    # Opportunities at 1..10 ms, none until 100 ms: the link is dead from 10 to 100 ms.
    path = write_trace([*range(1, 11), 100])
    link = NetemLink(parse_netem(f"trace {path} limit 5"), seed=1)
    sends = [(0.020 + k * MS, 100) for k in range(8)]
    out = run(link, sends)
    # Five wait (the limit), three are dropped; the five share the opportunity at 100 ms.
    assert [i for _, i in out] == [0, 1, 2, 3, 4]
    assert all(t == pytest.approx(0.100) for t, _ in out)
    assert link.stats.queue_dropped == 3
    assert accounted(link)


def test_a_step_down_then_up_in_capacity(write_trace) -> None:  # type: ignore[no-untyped-def]
    # 3 opportunities/ms for 10 ms, 1 per ms until 20 ms, then 3/ms again to 30 ms.
    times = [t for t in range(1, 11) for _ in range(3)]
    times += list(range(11, 21))
    times += [t for t in range(21, 31) for _ in range(3)]
    link = NetemLink(parse_netem(f"trace {write_trace(times)}"), seed=1)
    # 2 datagrams of 1500 bytes a millisecond: the link keeps up, then falls behind, then drains.
    sends = [(k * 0.0005 + 0.0001, 1500) for k in range(60)]
    out = run(link, sends)
    delays = [t - sends[i][0] for t, i in out]
    assert max(delays[:18]) < 1.0 * MS  # 3/ms against 2/ms: no queue
    late = max(delays[18:42])
    assert late > 4 * MS  # 1/ms against 2/ms: a queue builds
    assert delays[-1] < 1.0 * MS  # 3/ms again: drained by the end
    assert len(out) == 60


def test_the_trace_loops_at_its_last_timestamp(write_trace) -> None:  # type: ignore[no-untyped-def]
    # Opportunities at 3 ms and 10 ms; period 10 ms: then 13, 20, 23, 30...
    trace = load_trace(write_trace([3, 10]))
    queue = TraceQueue(trace, limit=100, origin=0.0)
    departures = [queue.offer(t, 1500) for t in (0.0, 0.0, 0.0, 0.0, 0.0)]
    assert departures == pytest.approx([0.003, 0.010, 0.013, 0.020, 0.023])
    # Much later, after an idle stretch: the next opportunity in the right loop.
    assert queue.offer(10.0155, 1500) == pytest.approx(10.020)
    assert trace.opportunities_between(0, 100) == 20
    assert trace.mean_rate_bps == pytest.approx(2 * 1500 * 8 / 0.010)


def test_a_first_timestamp_of_zero_recurs_with_the_loop(write_trace) -> None:  # type: ignore[no-untyped-def]
    # As in Mahimahi, 0 ms of the second loop falls at the period: two opportunities there.
    queue = TraceQueue(load_trace(write_trace([0, 5])), limit=100, origin=0.0)
    assert [queue.offer(0.001, 1500) for _ in range(3)] == pytest.approx([0.005, 0.005, 0.010])


def test_offset_starts_the_trace_further_in(write_trace) -> None:  # type: ignore[no-untyped-def]
    path = write_trace([*range(1, 11), 50])  # an outage from 10 to 50 ms
    plain = NetemLink(parse_netem(f"trace {path}"), seed=1)
    shifted = NetemLink(parse_netem(f"trace {path} offset 20ms"), seed=1)
    # At its own 5 ms the plain link has capacity; the shifted one is at 25 ms: in the outage until
    # 50 ms of the trace, 30 ms from its start.
    assert run(plain, [(0.005, 100)])[0][0] == pytest.approx(0.006)
    assert run(shifted, [(0.005, 100)])[0][0] == pytest.approx(0.030)


def test_the_trace_clock_starts_at_the_first_now_the_link_sees(write_trace) -> None:  # type: ignore[no-untyped-def]
    link = NetemLink(parse_netem(f"trace {write_trace([4, 8])}"), seed=1)
    link.deliver(100.0)  # nothing yet, but the trace starts here
    assert run(link, [(100.001, 100)], start=None) == [(pytest.approx(100.004), 0)]


def test_overhead_counts_towards_opportunities_and_limit_bytes(write_trace) -> None:  # type: ignore[no-untyped-def]
    path = write_trace(range(1, 11))
    # 100-byte datagrams with 28 bytes of headers: 128 bytes, eleven fit in 1500 (and a part of
    # the twelfth, which leaves at the next opportunity).
    link = NetemLink(parse_netem(f"trace {path} overhead 28"), seed=1)
    out = run(link, [(0.0001, 100)] * 12)
    assert [t for t, _ in out] == [pytest.approx(MS)] * 11 + [pytest.approx(2 * MS)]
    # limit-bytes 256 holds two of them (<= the limit, as Mahimahi's droptail), not three.
    link = NetemLink(parse_netem(f"trace {path} overhead 28 limit-bytes 256"), seed=1)
    run(link, [(0.0001, 100)] * 3)
    assert link.stats.queue_dropped == 1


def test_limit_bytes_counts_the_waiting_datagrams_not_the_one_being_served(write_trace) -> None:  # type: ignore[no-untyped-def]
    # One opportunity every 10 ms. A 3000-byte datagram takes two opportunities: after the first
    # (10 ms) it is being served and no longer counts against the queue's 3000 bytes.
    path = write_trace(range(10, 101, 10))
    link = NetemLink(parse_netem(f"trace {path} limit-bytes 3000"), seed=1)
    link.deliver(0.0)
    link.send(bytes(3000), 0.001, 0)
    link.send(bytes(1), 0.002, 1)  # 3001 bytes waiting: dropped
    assert link.stats.queue_dropped == 1
    link.send(bytes(3000), 0.011, 2)  # the first is in service now: room for 3000 more
    assert link.stats.queue_dropped == 1
    link.send(bytes(1), 0.012, 3)
    assert link.stats.queue_dropped == 2
    out = run(link, [], start=None)
    assert out == [(pytest.approx(0.020), 0), (pytest.approx(0.040), 2)]


def test_a_datagram_spanning_opportunities_is_in_service_from_the_first(write_trace) -> None:  # type: ignore[no-untyped-def]
    # One opportunity every 10 ms. 100 bytes leave at 10 ms; the 3000 bytes behind them start
    # in the same opportunity (its last 1400 bytes), so from 10 ms on they are being served and the
    # queue's 3000 bytes are free again, although they leave only at 30 ms.
    path = write_trace(range(10, 101, 10))
    link = NetemLink(parse_netem(f"trace {path} limit-bytes 3100"), seed=1)
    link.deliver(0.0)
    link.send(bytes(100), 0.001, 0)
    link.send(bytes(3000), 0.002, 1)
    link.send(bytes(3000), 0.011, 2)  # accepted: the first 3000 are in service
    assert link.stats.queue_dropped == 0
    assert [tag for _, tag in link.deliver(0.011)] == [0]  # it left at 10 ms
    assert run(link, [], start=0.011) == [
        (pytest.approx(0.030), 1),
        (pytest.approx(0.050), 2),
    ]


def test_limit_in_packets_counts_the_trace_queue_not_the_delay_line(write_trace) -> None:  # type: ignore[no-untyped-def]
    # 200 ms of delay after a fast trace: 100 datagrams on the delay line do not fill a 10-packet
    # queue, since the delay is propagation, after the queue.
    link = NetemLink(parse_netem(f"delay 200ms trace {write_trace(range(1, 11))} limit 10"), seed=1)
    out = run(link, [(k * MS + 0.0001, 100) for k in range(100)])
    assert link.stats.queue_dropped == 0
    assert [t - k * MS for k, (t, _) in enumerate(out)] == [pytest.approx(0.201)] * 100


def test_the_delay_comes_after_the_trace_queue(write_trace) -> None:  # type: ignore[no-untyped-def]
    link = NetemLink(parse_netem(f"delay 20ms trace {write_trace([5, 10])}"), seed=1)
    assert run(link, [(0.0, 100), (0.006, 100)]) == [
        (pytest.approx(0.025), 0),
        (pytest.approx(0.030), 1),
    ]


def test_loss_comes_before_the_queue_and_frees_its_room(write_trace) -> None:  # type: ignore[no-untyped-def]
    link = NetemLink(parse_netem(f"loss 100% trace {write_trace([5, 10])} limit 1"), seed=1)
    run(link, [(0.0, 100)] * 3)
    assert (link.stats.lost, link.stats.queue_dropped) == (3, 0)
    assert accounted(link)


def test_jitter_after_the_trace_reorders_as_netem_does(write_trace) -> None:  # type: ignore[no-untyped-def]
    times = [t for t in range(1, 1001) for _ in range(4)]
    link = NetemLink(parse_netem(f"delay 20ms 5ms trace {write_trace(times)}"), seed=3)
    out = run(link, [(k * MS / 2, 100) for k in range(1000)])
    order = [i for _, i in out]
    assert sorted(order) == list(range(1000)) and order != sorted(order)
    assert accounted(link)


def test_duplicates_go_through_the_queue_on_their_own(write_trace) -> None:  # type: ignore[no-untyped-def]
    link = NetemLink(parse_netem(f"duplicate 100% trace {write_trace([1, 2])} limit 3"), seed=1)
    run(link, [(0.0001, 1500), (0.0002, 1500)])
    # Four datagrams for a queue of three: the last copy of the second one is dropped.
    assert (link.stats.duplicated, link.stats.delivered, link.stats.queue_dropped) == (2, 3, 1)
    assert accounted(link)


def test_polling_does_not_change_the_deliveries(write_trace) -> None:  # type: ignore[no-untyped-def]
    rng = random.Random(5)
    times = sorted(rng.randrange(1, 500) for _ in range(300))
    spec = parse_netem(f"delay 10ms 2ms loss 5% trace {write_trace([*times, 500])} limit 20")
    sends = [(k * 0.0007, rng.choice((60, 200, 1400))) for k in range(600)]
    lazy = run(NetemLink(spec, seed=9), sends)
    eager_link = NetemLink(spec, seed=9)
    eager: list[tuple[float, int]] = []
    for i, (t, size) in enumerate(sends):
        for poll in (t - 0.0003, t - 0.0001):  # collect at odd moments in between
            if poll > 0:
                eager += [(poll, tag) for _, tag in eager_link.deliver(poll)]  # type: ignore[misc]
        eager_link.send(bytes(size), t, tag=i)
    eager += run(eager_link, [], start=None)
    assert [i for _, i in eager] == [i for _, i in lazy]
    assert eager_link.stats.queue_dropped > 0 and eager_link.stats.lost > 0
    assert accounted(eager_link)


def test_change_to_the_same_trace_keeps_its_clock_and_queue(write_trace) -> None:  # type: ignore[no-untyped-def]
    path = write_trace([*range(1, 11), 50])
    spec = parse_netem(f"trace {path} limit 5")
    link = NetemLink(spec, seed=1)
    link.deliver(0.0)
    link.send(bytes(100), 0.020, 0)  # in the outage: waits for 50 ms
    link.change(parse_netem(f"loss 100% trace {path} limit 5"))  # an outage on top, same trace
    link.send(bytes(100), 0.021, 1)
    link.change(spec)
    link.send(bytes(100), 0.022, 2)
    assert run(link, [], start=None) == [(pytest.approx(0.050), 0), (pytest.approx(0.050), 2)]


def test_change_to_another_trace_keeps_the_link_fifo(write_trace) -> None:  # type: ignore[no-untyped-def]
    slow = parse_netem(f"trace {write_trace([100])}")
    fast = parse_netem(f"trace {write_trace(range(1, 11))}")
    link = NetemLink(slow, seed=1)
    link.send(bytes(100), 0.0, 0)  # leaves at 100 ms
    link.change(fast)
    link.send(bytes(100), 0.001, 1)  # the fast trace would send it at 2 ms: it follows the first
    out = run(link, [], start=None)
    assert [i for _, i in out] == [0, 1] and out[1][0] > out[0][0]


def test_limit_bytes_without_a_trace_bounds_netems_queue_in_bytes() -> None:
    link = NetemLink(parse_netem("rate 8kbit 28 limit-bytes 300"), seed=1)
    for k in range(4):
        link.send(bytes(100), 0.0, k)  # 128 wire bytes each: two fit in 300, not three
    assert link.stats.queue_dropped == 2
    run(link, [], start=None)
    link.send(bytes(100), 10.0, 4)
    assert link.stats.queue_dropped == 2  # the bytes left with their datagrams


def test_a_long_trace_costs_little_per_datagram(write_trace) -> None:  # type: ignore[no-untyped-def]
    # 1000 s of a 5 Mbit/s trace, with outages; the cursor moves forward only, and an idle link
    # jumps by binary search: serving a datagram never walks the trace from its start.
    rng = random.Random(1)
    times = sorted(rng.randrange(1, 1_000_000) for _ in range(400_000))
    trace = load_trace(write_trace([*times, 1_000_000]))
    calls = 0

    class Counting(TraceQueue):
        def opportunity_time(self, index: int) -> float:
            nonlocal calls
            calls += 1
            return super().opportunity_time(index)

    queue = Counting(trace, limit=10**6, origin=0.0)
    for k in range(2000):
        queue.offer(k * 0.5, 100)  # every half second, far apart
    assert calls < 5 * 2000


# -- parsing --------------------------------------------------------------------------------------------


def test_trace_options_round_trip_through_str(write_trace) -> None:  # type: ignore[no-untyped-def]
    path = write_trace([1, 1, 2, 5])
    for text in (
        f"trace {path}",
        f"delay 20ms trace {path} offset 1.5s overhead 28 limit-bytes 150000",
        f"loss 1% trace {path} offset 250ms limit 40 seed 3",
        "rate 1mbit limit-bytes 15000",
    ):
        spec = parse_netem(text)
        assert str(spec) == text
        assert parse_netem(str(spec)) == spec
        assert hash(parse_netem(str(spec))) == hash(spec)
    assert parse_netem(f"trace {path} overhead 28 offset 2ms") == parse_netem(
        f"trace {path} offset 2ms overhead 28"
    )


def test_a_trace_reads_mahimahis_files(write_trace) -> None:  # type: ignore[no-untyped-def]
    trace = load_trace(write_trace([], text="0\n3\n3\n7\n\n"))  # trailing blank lines are fine
    assert len(trace) == 4 and trace.period_ms == 7
    assert load_trace(trace.path) is trace  # unchanged: not read again


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("", "has no opportunity"),
        ("\n\n", "has no opportunity"),
        ("0\n0\n", "lasts no time"),
        ("1\n2x\n3\n", "line 2 of trace file .* is '2x'"),
        ("1\n\n3\n", "line 2 of trace file .* is an empty line"),
        ("1\n-2\n3\n", "line 2 of trace file .* is '-2'"),
        ("1\n5\n4\n", "line 3 of trace file .* goes back in time"),
    ],
)
def test_bad_trace_files_say_what_is_wrong(write_trace, text: str, says: str) -> None:  # type: ignore[no-untyped-def]
    path = write_trace([], text=text)
    with pytest.raises(TraceFileError, match=says):
        load_trace(path)
    with pytest.raises(NetemSyntaxError, match=f"bad trace .* at token 2 .*{says}"):
        parse_netem(f"trace {path}")


def test_parse_errors_name_the_problem(write_trace, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    path = write_trace([1, 2])
    cases = {
        "trace": "missing trace file at the end",
        f"trace {tmp_path}/missing": "does not exist",
        f"trace {tmp_path}": "is a directory",
        f"trace {path} offset": "missing trace offset",
        f"trace {path} offset 5": "has no unit",
        f"trace {path} offset 1ms offset 2ms": "offset given twice",
        f"trace {path} overhead x": "bad trace overhead",
        f"rate 1mbit trace {path}": "a trace and a rate both set the link's capacity",
        "limit 5 limit-bytes 100": "in packets \\(limit\\) or in bytes \\(limit-bytes\\)",
        "limit-bytes -1": "bad limit-bytes",
        f"trace {path} trace {path}": "given twice",
    }
    for text, says in cases.items():
        with pytest.raises(NetemSyntaxError, match=says):
            parse_netem(text)


def test_spec_classes_validate_trace_options(write_trace, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    trace = load_trace(write_trace([1, 2]))
    with pytest.raises(ValueError, match="offset"):
        TraceSpec(trace, offset=-1.0)
    with pytest.raises(ValueError, match="Trace"):
        TraceSpec("file.trace")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="not both"):
        NetemSpec(trace=TraceSpec(trace), limit=5, limit_bytes=100)
    spaced = tmp_path / "a b.trace"
    spaced.write_text("1\n2\n")
    with pytest.raises(ValueError, match="whitespace"):
        load_trace(spaced)  # netem syntax could not write its path back


# -- the simulator's link ------------------------------------------------------------------------------


def test_the_simulators_trace_link_departs_as_netem_link_does(write_trace) -> None:  # type: ignore[no-untyped-def]
    rng = random.Random(2)
    times = sorted(rng.randrange(1, 300) for _ in range(200))
    spec = f"delay 20ms trace {write_trace([*times, 300])} limit-bytes 3000"
    sizes = [rng.choice((128, 600, 1500)) for _ in range(400)]
    sends = [(k * 0.001, size) for k, size in enumerate(sizes)]

    link = NetemLink(parse_netem(spec), seed=1)
    emulated = run(link, sends)  # both trace clocks start at 0

    net = Network()
    net.connect("A", "B", spec)
    net.compute_routes()
    arrivals: list[tuple[float, int]] = []
    drops: list[int] = []

    class Sink:
        def receive(self, packet: Packet, now: float) -> None:
            arrivals.append((now, packet.payload))  # type: ignore[arg-type]

        def on_drop(self, packet: Packet, now: float) -> None:
            drops.append(packet.payload)  # type: ignore[arg-type]

    sink = Sink()
    net.node("B").bind(1, sink)
    for i, (t, size) in enumerate(sends):
        net.sim.call_at(t, net.node("A").send, Packet("A", 1, "B", 1, size, i, t, sink), t)
    net.run(10.0)
    assert drops and len(drops) == link.stats.queue_dropped
    assert [i for _, i in arrivals] == [i for _, i in emulated]
    assert [t for t, _ in arrivals] == pytest.approx([t for t, _ in emulated], abs=1e-9)
    assert net.links[0].rate_bps == pytest.approx(201 * 1500 * 8 / 0.3)


def test_the_simulator_refuses_a_second_byte_limit_for_a_trace(write_trace) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ValueError, match="limit-bytes"):
        Network().connect("A", "B", f"trace {write_trace([1, 2])}", byte_limit=1500)
    assert math.isfinite(Network().connect("A", "B", "rate 1mbit limit-bytes 3000")[0].rate_bps)
