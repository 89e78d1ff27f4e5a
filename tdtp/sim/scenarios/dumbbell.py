"""The simulated topology (a dumbbell: hosts, two routers, one bottleneck) and the probes runs take."""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Final

from tdtp.sim.endpoints import TdtpEndpoint
from tdtp.sim.engine import Network, Simulator
from tdtp.sim.metrics import mean

ACCESS_RATE: Final = "100mbit"
ACCESS_DELAY: Final = "1ms"
HOST_QUEUE: Final = 50
"""Hosts' own output queues: ns-2's default ``Queue set limit_ 50`` (the paper sets the routers' only)."""
ROUTER_QUEUE: Final = 15
"""The paper's DropTail limit at R1 and R2, packets."""


def build_dumbbell(
    net: Network,
    left: Sequence[str],
    right: Sequence[str],
    bottleneck: str,
    *,
    access_delay: str = ACCESS_DELAY,
    byte_limit: int | None = None,
) -> None:
    """Hosts ``left`` behind router R1, ``right`` behind R2, R1-R2 the ``bottleneck`` (netem syntax,
    both directions alike). Access links: 100 Mbit/s, host queues 50 packets, router queues 15.
    ``byte_limit`` makes the bottleneck's queues count bytes (the access links never queue)."""
    up = f"rate {ACCESS_RATE} delay {access_delay} limit {HOST_QUEUE}"
    down = f"rate {ACCESS_RATE} delay {access_delay} limit {ROUTER_QUEUE}"
    for host in left:
        net.connect(host, "R1", up, down)
    for host in right:
        net.connect(host, "R2", up, down)
    net.connect("R1", "R2", bottleneck, byte_limit=byte_limit)
    net.compute_routes()


@dataclass(slots=True)
class Probe:
    """Samples of one endpoint's controller state."""

    times: list[float] = field(default_factory=list)
    rate: list[float] = field(default_factory=list)
    """Allowed rate, packets/s."""
    srtt: list[float] = field(default_factory=list)
    p: list[float] = field(default_factory=list)
    """Loss event rate."""

    def mean_between(self, name: str, start: float, end: float) -> float:
        values: list[float] = getattr(self, name)
        return mean([v for t, v in zip(self.times, values, strict=True) if start <= t < end])


def start_probe(sim: Simulator, endpoint: TdtpEndpoint, interval: float, until: float) -> Probe:
    probe = Probe()

    def sample() -> None:
        stats = endpoint.conn.stats
        probe.times.append(sim.now)
        probe.rate.append(stats.rate)
        probe.srtt.append(stats.srtt)
        probe.p.append(stats.loss_event_rate)
        if sim.now + interval <= until:
            sim.call_later(interval, sample)

    sim.call_at(interval, sample)
    return probe


def connection_stats(endpoint: TdtpEndpoint) -> dict[str, Any]:
    stats = endpoint.conn.stats
    return {
        "samples_offered": endpoint.samples_offered,
        "samples_superseded": stats.samples_superseded,
        "data_packets_sent": stats.sent.data_packets,
        "ack_packets_sent": stats.sent.ack_packets,
        "packets_acked": stats.packets_acked,
        "packets_lost": stats.packets_lost,
        "spurious_losses": stats.spurious_losses,
        "loss_events": stats.loss_events,
        "loss_event_rate": stats.loss_event_rate,
        "srtt": stats.srtt,
        "rate": stats.rate,
        "closed": endpoint.closed.cause.value if endpoint.closed is not None else None,
        "closed_at": endpoint.closed_at,
    }


def run_timed(net: Network, until: float) -> float:
    """Run the simulation to ``until``; returns the wall-clock seconds it took."""
    start = time.perf_counter()
    net.run(until)
    return time.perf_counter() - start
