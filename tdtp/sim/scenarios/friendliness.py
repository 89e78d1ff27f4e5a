"""TCP-friendliness: one TDTP session beside TCP flows on a shared bottleneck, per scheme."""

from __future__ import annotations

import math
import random
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any, ClassVar

from tdtp.control.equations import tcp_friendly_rate
from tdtp.errors import InvalidArgumentError
from tdtp.sim.endpoints import TdtpSession
from tdtp.sim.engine import Network
from tdtp.sim.metrics import mean
from tdtp.sim.readings import SEND_JITTER
from tdtp.sim.scenarios.dumbbell import (
    ROUTER_QUEUE,
    build_dumbbell,
    run_timed,
    start_probe,
)
from tdtp.sim.scenarios.results import ScenarioResult, json_safe, ratio
from tdtp.sim.scenarios.schemes import (
    DEFAULT_SCHEMES,
    Encapsulation,
    connection_config,
    ip_overhead,
    schemes_named,
)
from tdtp.sim.tcp import TcpConfig, TcpFlow


@dataclass
class FriendlinessCase:
    scheme: str
    capacity_mbps: float
    rtt_ms: float
    """Base round-trip time (propagation only)."""
    queue_limit: int
    tdtp_pps: float
    tcp_pps: float
    ratio_pps: float
    """Measured tdtp/TCP, packets per second (what eq. 2 equalises)."""
    ratio_bytes: float
    """Measured tdtp/TCP, bytes on the wire."""
    tdtp_kbps: float
    tcp_kbps: float
    tcp_loss: float
    """Drops / segments sent by TCP."""
    tcp_rtt: float
    """TCP's mean RTT sample, s."""
    tdtp_p: float
    """tdtp sender's mean loss event rate."""
    tdtp_srtt: float
    eq2_tcp_pps: float
    """Eq. 2 at TCP's own loss rate and RTT: the model's TCP rate."""
    eq2_tdtp_pps: float
    """Eq. 2 at the tdtp sender's p and srtt: its TCP-friendly ceiling."""
    eq2_ratio: float
    """``eq2_tdtp_pps / tcp_pps``: the ratio eq. 2 predicts from what tdtp measured."""
    tdtp_loss: float
    wall_time: float


@dataclass
class FriendlinessResult(ScenarioResult):
    scenario: ClassVar[str] = "friendliness"
    params: dict[str, Any]
    cases: list[FriendlinessCase]

    def by_scheme(self) -> dict[str, list[FriendlinessCase]]:
        out: dict[str, list[FriendlinessCase]] = {}
        for case in self.cases:
            out.setdefault(case.scheme, []).append(case)
        return out

    def headline(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for scheme, cases in self.by_scheme().items():
            ratios = [c.ratio_pps for c in cases]
            out[scheme] = {
                "mean_ratio_pps": mean(ratios),
                "min_ratio_pps": min(ratios),
                "max_ratio_pps": max(ratios),
                "mean_eq2_ratio": mean([c.eq2_ratio for c in cases]),
                "mean_ratio_bytes": mean([c.ratio_bytes for c in cases]),
            }
        return json_safe(out)  # type: ignore[no-any-return]

    def details(self) -> dict[str, Any]:
        return {"cases": [asdict(c) for c in self.cases]}


def friendliness(
    *,
    seed: int = 1,
    duration: float = 60.0,
    warmup: float = 10.0,
    capacities_mbps: Sequence[float] = (1.0, 2.0, 4.0),
    rtts_ms: Sequence[float] = (20.0, 60.0, 120.0),
    schemes: Sequence[str] = DEFAULT_SCHEMES,
    tcp_window: int = 1000,
    sample_rate: float = 1000.0,
    encapsulation: Encapsulation = "native",
    send_jitter: float = SEND_JITTER,
) -> FriendlinessResult:
    """One tdtp session and one TCP transfer share a bottleneck in the master-to-slave direction.

    For every capacity and base RTT: the bottleneck delay makes the propagation RTT ``rtt``; the
    DropTail limit is ``max(15, one bandwidth-delay product of 1040-byte packets)``; TCP's window is
    ``tcp_window`` (1000: never the limit, so TCP is congestion-limited, the regime eq. 2 models; ns-2's
    20 would make it window-limited on the larger paths). Measured after ``warmup`` s (at most half
    the run).
    """
    warmup = min(warmup, duration / 2)
    chosen = schemes_named(schemes)
    tcp_cfg = TcpConfig(window=tcp_window)
    cases: list[FriendlinessCase] = []
    access_delay = 0.001
    for capacity in capacities_mbps:
        for rtt_ms in rtts_ms:
            one_way = rtt_ms / 2000.0 - 2 * access_delay
            if one_way <= 0:
                raise InvalidArgumentError(f"rtt {rtt_ms} ms is below the access links' 4 ms")
            bdp = capacity * 1e6 * rtt_ms / 1000.0 / 8 / tcp_cfg.packet_size
            limit = max(ROUTER_QUEUE, math.ceil(bdp))
            for scheme in chosen:
                rng = random.Random(seed)
                net = Network(seed=seed)
                build_dumbbell(
                    net,
                    ["M", "T1"],
                    ["S", "T2"],
                    f"rate {capacity * 1e6:g}bit delay {one_way * 1e6:.0f}us limit {limit}",
                )
                session = TdtpSession.create(
                    net,
                    "M",
                    "S",
                    connection_config(scheme, encapsulation),
                    sample_rate=sample_rate,
                    ip_overhead=ip_overhead(encapsulation),
                    bin_width=1.0,
                    duration=duration,
                    seed=rng.getrandbits(32),
                    send_jitter=send_jitter,
                )
                flow = TcpFlow(
                    net,
                    "T1",
                    "T2",
                    port=5000,
                    config=tcp_cfg,
                    periods=((rng.random() * 0.1, math.inf),),
                    bin_width=1.0,
                    duration=duration,
                )
                probe = start_probe(net.sim, session.master, 0.25, duration)
                wall = run_timed(net, duration)
                tdtp_s = session.ms.summary(warmup, duration)
                tcp_s = flow.data.summary(warmup, duration)
                tcp_rtt = flow.sender.mean_rtt
                tcp_loss = tcp_s.loss_ratio
                p = probe.mean_between("p", warmup, duration)
                srtt = probe.mean_between("srtt", warmup, duration)
                eq2_tcp = tcp_friendly_rate(tcp_rtt, tcp_loss) if tcp_loss > 0 else math.inf
                eq2_tdtp = tcp_friendly_rate(srtt, p) if p > 0 and srtt > 0 else math.inf
                cases.append(
                    FriendlinessCase(
                        scheme=scheme.key,
                        capacity_mbps=capacity,
                        rtt_ms=rtt_ms,
                        queue_limit=limit,
                        tdtp_pps=tdtp_s.delivered_pps,
                        tcp_pps=tcp_s.delivered_pps,
                        ratio_pps=ratio(tdtp_s.delivered_pps, tcp_s.delivered_pps),
                        ratio_bytes=ratio(tdtp_s.throughput_kbps, tcp_s.throughput_kbps),
                        tdtp_kbps=tdtp_s.throughput_kbps,
                        tcp_kbps=tcp_s.throughput_kbps,
                        tcp_loss=tcp_loss,
                        tcp_rtt=tcp_rtt,
                        tdtp_p=p,
                        tdtp_srtt=srtt,
                        eq2_tcp_pps=eq2_tcp,
                        eq2_tdtp_pps=eq2_tdtp,
                        eq2_ratio=ratio(eq2_tdtp, tcp_s.delivered_pps),
                        tdtp_loss=tdtp_s.loss_ratio,
                        wall_time=wall,
                    )
                )
    params = {
        "seed": seed,
        "duration": duration,
        "warmup": warmup,
        "capacities_mbps": list(capacities_mbps),
        "rtts_ms": list(rtts_ms),
        "schemes": list(schemes),
        "sample_rate": sample_rate,
        "encapsulation": encapsulation,
        "send_jitter": send_jitter,
        "tcp": asdict(tcp_cfg),
    }
    return FriendlinessResult(params=params, cases=cases)
