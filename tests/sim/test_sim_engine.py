"""The simulator's engine: event order, timers, link serialisation and propagation, DropTail, routing,
and the TDTP endpoint adapter's exact one-way delays."""

from __future__ import annotations

import pytest

from tdtp.config import ConnectionConfig
from tdtp.netem import parse_netem
from tdtp.sim.endpoints import TdtpEndpoint, TdtpSession
from tdtp.sim.engine import Link, Network, Node, Packet, Simulator, Timer, link_spec, split_spec


class Collector:
    def __init__(self) -> None:
        self.arrivals: list[tuple[float, Packet]] = []
        self.drops: list[Packet] = []

    def receive(self, packet: Packet, now: float) -> None:
        self.arrivals.append((now, packet))

    def on_drop(self, packet: Packet, now: float) -> None:
        self.drops.append(packet)


def two_nodes(spec: str) -> tuple[Network, Collector]:
    net = Network()
    net.connect("A", "B", spec)
    net.compute_routes()
    sink = Collector()
    net.node("B").bind(1, sink)
    return net, sink


def packet(
    size: int, now: float = 0.0, owner: Collector | None = None, tag: object = None
) -> Packet:
    return Packet("A", 1, "B", 1, size, tag, now, owner)


def test_events_run_in_time_order_and_ties_in_scheduling_order() -> None:
    sim = Simulator()
    seen: list[str] = []
    for when, name in ((3.0, "c"), (1.0, "a1"), (2.0, "b"), (1.0, "a2"), (1.0, "a3")):
        sim.call_at(when, seen.append, name)
    sim.run(10.0)
    assert seen == ["a1", "a2", "a3", "b", "c"]
    assert sim.now == 10.0


def test_events_scheduled_while_running_keep_the_order() -> None:
    sim = Simulator()
    seen: list[tuple[float, str]] = []

    def first() -> None:
        seen.append((sim.now, "first"))
        sim.call_at(sim.now, lambda: seen.append((sim.now, "same instant, later")))
        sim.call_later(0.5, lambda: seen.append((sim.now, "later")))

    sim.call_at(1.0, first)
    sim.call_at(1.0, lambda: seen.append((sim.now, "second")))
    sim.run(2.0)
    assert seen == [
        (1.0, "first"),
        (1.0, "second"),
        (1.0, "same instant, later"),
        (1.5, "later"),
    ]


def test_scheduling_in_the_past_is_refused() -> None:
    sim = Simulator()
    sim.run(5.0)
    with pytest.raises(ValueError, match="virtual time only moves forward"):
        sim.call_at(4.0, lambda: None)


def test_run_stops_at_until() -> None:
    sim = Simulator()
    seen: list[float] = []
    sim.call_at(1.0, lambda: seen.append(1.0))
    sim.call_at(2.0, lambda: seen.append(2.0))
    sim.run(1.5)
    assert seen == [1.0] and sim.now == 1.5
    sim.run(3.0)
    assert seen == [1.0, 2.0]


def test_timer_moves_later_and_earlier_and_cancels() -> None:
    sim = Simulator()
    fired: list[float] = []
    timer = Timer(sim, fired.append)
    timer.set(1.0)
    timer.set(2.0)  # later: no new event, the early one re-schedules itself
    sim.run(1.5)
    assert fired == []
    timer.set(1.75)  # earlier again
    sim.run(3.0)
    assert fired == [1.75]
    timer.set(4.0)
    timer.cancel()
    sim.run(5.0)
    assert fired == [1.75]
    assert len(sim._heap) == 0


def test_serialisation_and_propagation_time() -> None:
    net, sink = two_nodes("rate 1mbit delay 10ms limit 15")
    link = net.link("A", "B")
    link.send(packet(1250), 0.0)  # 10 ms on the wire at 1 Mbit/s
    link.send(packet(1250), 0.0)  # waits for the first
    net.run(1.0)
    assert [t for t, _ in sink.arrivals] == pytest.approx([0.020, 0.030], abs=1e-12)


def test_an_idle_link_starts_serialising_at_the_arrival() -> None:
    net, sink = two_nodes("rate 1mbit delay 5ms")
    link = net.link("A", "B")
    net.run(0.5)
    link.send(packet(125, now=0.5), 0.5)  # 1 ms
    net.run(1.0)
    assert sink.arrivals[0][0] == pytest.approx(0.506, abs=1e-12)


def test_droptail_counts_waiting_packets_not_those_propagating() -> None:
    # 15 packets fit (the one being serialised included), the 16th to 20th are dropped.
    net, sink = two_nodes("rate 1mbit delay 10ms limit 15")
    link = net.link("A", "B")
    owner = Collector()
    for i in range(20):
        link.send(packet(125, owner=owner, tag=i), 0.0)
    net.run(1.0)
    assert [p.payload for _, p in sink.arrivals] == list(range(15))
    assert [p.payload for p in owner.drops] == list(range(15, 20))
    assert link.stats.dropped == 5 and link.stats.max_queue == 15
    # Paced at the link rate, nothing queues: a long delay line does not count against the limit.
    net, sink = two_nodes("rate 1mbit delay 500ms limit 2")
    link = net.link("A", "B")
    for i in range(100):
        now = i * 0.0011  # 1 ms of serialisation every 1.1 ms
        net.run(now)
        link.send(packet(125, now=now, owner=owner, tag=i), now)
    net.run(2.0)
    assert len(sink.arrivals) == 100
    assert link.stats.max_queue == 1


def test_byte_counted_droptail_charges_bytes_not_slots() -> None:
    # ns-2's queue_in_bytes_: an arrival is dropped when the bytes waiting (the packet being
    # serialised not counted) plus its own reach the limit.
    net = Network()
    net.connect("A", "B", "rate 1mbit delay 10ms", byte_limit=3000)
    net.compute_routes()
    sink = Collector()
    net.node("B").bind(1, sink)
    link = net.link("A", "B")
    assert link.byte_limit == 3000 and net.link("B", "A").byte_limit == 3000
    owner = Collector()
    link.send(packet(1040, owner=owner, tag="first"), 0.0)  # on the wire at once: not counted
    link.send(packet(1040, owner=owner, tag="a"), 0.0)  # 1040 waiting
    link.send(packet(1040, owner=owner, tag="b"), 0.0)  # 2080 waiting
    link.send(packet(1040, owner=owner, tag="c"), 0.0)  # 2080 + 1040 >= 3000: dropped
    for i in range(20):  # ...but 40-byte packets still fit, up to 2080 + 40 k < 3000
        link.send(packet(40, owner=owner, tag=i), 0.0)
    net.run(1.0)
    assert [p.payload for p in owner.drops] == ["c"]  # 2080 + 20 x 40 < 3000: every small one fits
    assert [p.payload for _, p in sink.arrivals][:3] == ["first", "a", "b"]
    assert link.stats.dropped == 1 and link.stats.delivered == 23
    # The same queue counted in packets (limit 3) drops the 40-byte packets too.
    net2, sink2 = two_nodes("rate 1mbit delay 10ms limit 3")
    link2 = net2.link("A", "B")
    for i in range(10):
        link2.send(packet(40 if i else 1040, tag=i), 0.0)
    net2.run(1.0)
    assert len(sink2.arrivals) == 3
    with pytest.raises(ValueError, match="byte_limit"):
        Network().connect("A", "B", "rate 1mbit", byte_limit=0)


def test_random_loss_before_the_queue() -> None:
    net, sink = two_nodes("rate 100mbit delay 1ms loss 20%")
    owner = Collector()
    link = net.link("A", "B")
    for i in range(2000):
        net.run(i * 0.001)
        link.send(packet(100, now=i * 0.001, owner=owner, tag=i), i * 0.001)
    net.run(3.0)
    assert len(owner.drops) + len(sink.arrivals) == 2000
    assert 0.17 < len(owner.drops) / 2000 < 0.23
    with pytest.raises(ValueError, match="uncorrelated random loss"):
        split_spec(parse_netem("rate 1mbit loss 1% 25%"))
    with pytest.raises(ValueError, match="uncorrelated random loss"):
        split_spec(parse_netem("rate 1mbit loss gemodel 1% 10%"))


def test_link_spec_is_split_into_queue_and_propagation() -> None:
    queue, delay = split_spec(parse_netem("rate 2mbit delay 7ms limit 9"))
    assert delay == 0.007 and queue.delay is None and queue.limit == 9
    assert link_spec(2e6, 0.007, 9) == parse_netem("rate 2mbit delay 7ms limit 9")
    with pytest.raises(ValueError, match="jitter"):
        split_spec(parse_netem("rate 1mbit delay 10ms 2ms"))
    with pytest.raises(ValueError, match="needs a rate"):
        split_spec(parse_netem("delay 10ms"))
    with pytest.raises(ValueError, match="reorder"):
        split_spec(parse_netem("rate 1mbit delay 10ms reorder 5%"))


def test_static_routes_forward_through_routers() -> None:
    net = Network()
    net.connect("A", "R1", "rate 100mbit delay 1ms")
    net.connect("R1", "R2", "rate 1mbit delay 10ms")
    net.connect("R2", "B", "rate 100mbit delay 1ms")
    net.compute_routes()
    assert net.node("A").routes["B"] is net.link("A", "R1")
    assert net.node("R1").routes["B"] is net.link("R1", "R2")
    assert net.node("B").routes["A"] is net.link("B", "R2")
    sink = Collector()
    net.node("B").bind(7, sink)
    net.node("A").send(Packet("A", 7, "B", 7, 1000, None, 0.0), 0.0)
    net.run(1.0)
    expected = (0.001 + 1000 * 8 / 100e6) + (0.010 + 1000 * 8 / 1e6) + (0.001 + 1000 * 8 / 100e6)
    assert sink.arrivals[0][0] == pytest.approx(expected, abs=1e-12)


def test_a_node_without_route_says_so() -> None:
    node = Node(Simulator(), "lonely")
    with pytest.raises(LookupError, match="no route"):
        node.send(Packet("lonely", 1, "X", 1, 100, None, 0.0), 0.0)


def test_link_refuses_a_second_binding() -> None:
    net, sink = two_nodes("rate 1mbit")
    with pytest.raises(ValueError, match="already bound"):
        net.node("B").bind(1, sink)
    assert isinstance(net.link("A", "B"), Link)


def test_tdtp_one_way_delay_is_exact_on_an_idle_path() -> None:
    # 100-byte samples at 100/s, each one stamped (one stamp per 4 ms at most: PROTOCOL.md 5.13):
    # 130 bytes on the wire, 1.04 ms at 1 Mbit/s, plus 10 ms: every sample, 11.04 ms.
    net = Network()
    net.connect("M", "S", "rate 1mbit delay 10ms limit 15")
    net.compute_routes()
    session = TdtpSession.create(
        net, "M", "S", ConnectionConfig(), sample_rate=100.0, duration=5.0, bin_width=1.0
    )
    net.run(5.0)
    for recorder in (session.ms, session.sm):
        summary = recorder.summary(1.0, 5.0)
        assert summary.delivered_pps == pytest.approx(100.0, abs=1.0)
        assert summary.dropped_packets == 0
        assert summary.mean_delay == pytest.approx(0.01104, abs=1e-9)
        assert summary.p95_delay == pytest.approx(0.01104, abs=1e-9)
        assert summary.mean_age == pytest.approx(0.01104, abs=1e-9)  # never held by the pacer
    assert session.master.ack_packets <= 2 and session.slave.ack_packets <= 2


def test_identical_runs_are_identical() -> None:
    def run() -> list[float]:
        net = Network(seed=3)
        net.connect("M", "R", "rate 10mbit delay 1ms limit 15")
        net.connect("R", "S", "rate 300kbit delay 20ms limit 5")
        net.compute_routes()
        session = TdtpSession.create(net, "M", "S", ConnectionConfig(), duration=4.0, seed=9)
        net.run(4.0)
        return session.ms.delays + session.sm.delays

    first = run()
    assert first == run()
    assert len(first) > 100


def test_skipping_the_flush_after_held_samples_changes_nothing(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # A session squeezed through 300 kbit/s: most samples wait for the pacer. The endpoint's
    # shortcut for them must give exactly the run that flushing after every sample gives.
    def run() -> tuple[list[float], int, int]:
        net = Network(seed=5)
        net.connect("M", "R", "rate 10mbit delay 1ms limit 15")
        net.connect("R", "S", "rate 300kbit delay 20ms limit 8")
        net.compute_routes()
        session = TdtpSession.create(net, "M", "S", ConnectionConfig(), duration=6.0, seed=2)
        net.run(6.0)
        stats = session.master.conn.stats
        return session.ms.delays + session.sm.delays, stats.packets_lost, net.sim.events_run

    fast = run()
    monkeypatch.setattr(TdtpEndpoint, "fast_ticks", False)
    slow = run()
    assert fast[:2] == slow[:2]
    assert fast[1] > 0  # congested: the pacer held samples back
    assert fast[2] == slow[2]
