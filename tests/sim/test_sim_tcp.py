"""The TCP cross-traffic model: slow start, halving on loss, Tahoe vs NewReno vs Reno recovery, RTO
backoff, filling a bottleneck alone, switching the FTP source off and on."""

from __future__ import annotations

import itertools
import math

import pytest

from tdtp.sim.engine import Network, Node, Packet
from tdtp.sim.metrics import FlowRecorder
from tdtp.sim.tcp import TcpConfig, TcpFlow, TcpSender, TcpSink


class Dropper(Node):
    """A router that drops the data segments named in ``drop`` (first transmission only), or every
    packet once ``blackout_from`` has passed."""

    def __init__(
        self, net: Network, name: str, drop: set[int], blackout_from: float = math.inf
    ) -> None:
        super().__init__(net.sim, name)
        net.nodes[name] = self
        self.drop = set(drop)
        self.blackout_from = blackout_from
        self._sim = net.sim

    def receive(self, packet: Packet, now: float) -> None:
        if now >= self.blackout_from:
            return
        if packet.size > 100 and packet.payload in self.drop:
            self.drop.discard(packet.payload)  # type: ignore[arg-type]
            return
        super().receive(packet, now)


def path(
    drop: set[int] = frozenset(),  # type: ignore[assignment]
    blackout_from: float = math.inf,
    rate: str = "100mbit",
    delay: str = "25ms",
    limit: int = 1000,
) -> Network:
    """A - D - B, each hop ``delay`` (so the RTT is 4 * delay), through a dropping router D."""
    net = Network()
    Dropper(net, "D", drop, blackout_from)
    spec = f"rate {rate} delay {delay} limit {limit}"
    net.connect("A", "D", spec)
    net.connect("D", "B", spec)
    net.compute_routes()
    return net


def sender_on(net: Network, config: TcpConfig) -> tuple[TcpSender, FlowRecorder]:
    data = FlowRecorder("tcp", bin_width=0.1, duration=60.0)
    TcpSink(net.node("B"), 5, config, data)
    sender = TcpSender(net, net.node("A"), 5, ("B", 5), config, data, trace_cwnd=True)
    return sender, data


def test_slow_start_doubles_every_rtt() -> None:
    net = path()
    sender, data = sender_on(net, TcpConfig(window=1000))
    net.sim.call_at(0.0, sender.start, 0.0)
    net.run(0.6)
    rtt = 0.1
    per_round = [
        sum(data.sent_packets[round(k * rtt / 0.1) : round((k + 1) * rtt / 0.1)]) for k in range(6)
    ]
    assert per_round == [2, 4, 8, 16, 32, 64]
    assert sender.counters.retransmissions == 0


def test_one_loss_halves_the_window_by_fast_retransmit() -> None:
    net = path(drop={40})
    cfg = TcpConfig(window=1000)
    sender, _ = sender_on(net, cfg)
    sender.ssthresh = (
        30.0  # congestion avoidance from 30 packets, so the window is known at the loss
    )
    net.sim.call_at(0.0, sender.start, 0.0)
    net.run(5.0)
    counters = sender.counters
    assert counters.fast_retransmits == 1 and counters.timeouts == 0
    assert counters.retransmissions == 1
    trace = sender.counters.cwnd_trace
    drop_at = next(i for i in range(1, len(trace)) if trace[i][1] < trace[i - 1][1])
    before = trace[drop_at - 1][1]
    assert sender.ssthresh == max(int(before) // 2, 2) or sender.cwnd > 0
    # Fast recovery: ssthresh + 3 (inflated), then back to ssthresh when the loss is repaired.
    halved = max(int(before) // 2, 2)
    assert trace[drop_at][1] == halved + 3
    after = next(c for _, c in trace[drop_at:] if c < halved + 3)
    assert after == halved


@pytest.mark.parametrize(("variant", "timeouts"), [("newreno", 0), ("reno", 1)])
def test_newreno_repairs_two_losses_of_a_window_without_a_timeout(
    variant: str, timeouts: int
) -> None:
    # (With three, the third partial ACK comes 3 RTTs = 0.3 s after the fast retransmit, later than
    # the 0.2 s RTO restarted at the first one: ns-2's "impatient" NewReno times out there too.)
    net = path(drop={40, 43})
    sender, _data = sender_on(net, TcpConfig(window=1000, variant=variant))  # type: ignore[arg-type]
    sender.ssthresh = 30.0
    net.sim.call_at(0.0, sender.start, 0.0)
    net.run(5.0)
    assert sender.counters.timeouts == timeouts
    assert sender.counters.fast_retransmits >= 1
    assert sender.highest_ack > 100  # the transfer went on


def test_rto_backs_off_exponentially() -> None:
    net = path(blackout_from=1.0)
    cfg = TcpConfig(window=20)
    sender, _ = sender_on(net, cfg)
    fired: list[float] = []
    original = sender._on_timeout

    def spy(now: float) -> None:
        fired.append(now)
        original(now)

    sender._timer._callback = spy  # observe the retransmission timer
    net.sim.call_at(0.0, sender.start, 0.0)
    net.run(20.0)  # 0.2 s, doubled five times: 12.8 s, the 64 x cap, would come next
    assert len(fired) == 6
    gaps = [b - a for a, b in itertools.pairwise(fired)]
    for shorter, longer in itertools.pairwise(gaps):
        assert longer == pytest.approx(2 * shorter, rel=1e-6)
    assert fired[1] - fired[0] == pytest.approx(cfg.min_rto * 2)  # minrto_, doubled once
    assert sender.cwnd == 1.0 and sender.ssthresh == 2.0


def test_rto_is_rfc6298_on_the_tick_clock_with_ns2_minimum() -> None:
    net = path(delay="5ms")
    sender, _ = sender_on(net, TcpConfig())
    net.sim.call_at(0.0, sender.start, 0.0)
    net.run(2.0)
    assert sender.srtt is not None
    assert sender.srtt == pytest.approx(0.02, abs=0.0101)  # 20 ms on a 10 ms clock
    assert sender.rto() == pytest.approx(0.2)  # below minrto_: the minimum applies


def test_fills_a_bottleneck_alone() -> None:
    net = Network()
    net.connect("A", "R1", "rate 100mbit delay 1ms limit 50")
    net.connect("R1", "R2", "rate 1mbit delay 10ms limit 15")
    net.connect("R2", "B", "rate 100mbit delay 1ms limit 15")
    net.compute_routes()
    flow = TcpFlow(net, "A", "B", port=5, duration=30.0, bin_width=1.0)
    net.run(30.0)
    summary = flow.data.summary(5.0, 30.0)
    assert summary.throughput_kbps > 950  # of 1000 on the wire
    assert flow.sender.counters.timeouts <= 2
    assert 0 < summary.loss_ratio < 0.05  # window_ 20 > 15 + pipe: DropTail does drop


def test_ftp_source_off_sends_nothing_new_and_restarts_slowly() -> None:
    net = path()
    flow = TcpFlow(
        net, "A", "B", port=5, periods=((0.0, 2.0), (5.0, 8.0)), duration=10.0, bin_width=0.5
    )
    net.run(10.0)
    sent = flow.data.sent_packets
    assert sum(sent[5:10]) == 0  # 2.5 s to 5 s: off, all acknowledged long before
    assert sum(sent[10:16]) > 0
    # idle for longer than an RTO: slow-start restart from windowInit_
    assert sent[10] <= 2 + 4 + 8 + 16 + 32


def test_tahoe_restarts_from_one_segment_and_goes_back_n() -> None:
    net = path(drop={40})
    sender, data = sender_on(net, TcpConfig(window=1000, variant="tahoe"))
    sender.ssthresh = 30.0
    net.sim.call_at(0.0, sender.start, 0.0)
    net.run(5.0)
    counters = sender.counters
    assert counters.fast_retransmits == 1 and counters.timeouts == 0
    trace = counters.cwnd_trace
    drop_at = next(i for i in range(1, len(trace)) if trace[i][1] < trace[i - 1][1])
    halved = max(int(trace[drop_at - 1][1]) // 2, 2)
    # ns-2's tahoe_action: cwnd 1, ssthresh half the window, no fast recovery (no inflation)...
    assert trace[drop_at][1] == 1.0
    assert all(c <= halved + 1 for _, c in trace[drop_at : drop_at + halved])
    # ...and slow start again from the first unacknowledged segment: only the lost one is resent,
    # because its ACK covers everything the sink held beyond it.
    assert counters.retransmissions == 1
    assert sender.ssthresh >= halved or sender.cwnd > halved  # slow start up to ssthresh, then on
    assert data.summary(0.0, 5.0).dropped_packets == 0  # the drop was the test's router
    assert sender.highest_ack > 100  # the transfer went on


def test_tahoe_go_back_n_duplicates_do_not_cut_the_window_again() -> None:
    # A 1 Mbit/s hop with a deep queue: when the 3rd duplicate ACK arrives, most of the window is
    # still queued. Tahoe goes back to the first unacknowledged segment and resends segments that
    # are on their way; the sink answers their copies with duplicate ACKs at exactly `recover`,
    # which must not start another fast retransmit (ns-2's bug_fix_, `highest_ack > recover`).
    # Counting them (>=) turned this one loss into a hundred window cuts in 10 s.
    net = path(drop={40}, rate="1mbit", delay="10ms", limit=1000)
    sender, _ = sender_on(net, TcpConfig(window=30, variant="tahoe"))
    net.sim.call_at(0.0, sender.start, 0.0)
    net.run(10.0)
    assert sender.counters.fast_retransmits == 1
    assert sender.counters.timeouts <= 1
    assert sender.highest_ack > 1000  # ~1170 segments fit in 10 s at 1 Mbit/s


def test_config_is_validated() -> None:
    with pytest.raises(ValueError, match="variant"):
        TcpConfig(variant="vegas")  # type: ignore[arg-type]
    assert TcpConfig(variant="tahoe").variant == "tahoe"
    with pytest.raises(ValueError, match="window"):
        TcpConfig(window=0)
    assert TcpConfig().packet_size == 1040
