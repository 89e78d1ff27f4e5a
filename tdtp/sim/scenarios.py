"""The simulated experiments: the paper's figures 7 and 8, TCP-friendliness, fairness and best effort.

Each scenario is a function returning a result dataclass with ``to_dict()``/``to_json()``; a run is a
pure function of its arguments (``seed`` included). Every scenario runs each *scheme*:

* ``tdtp``: TDTP as the paper proposes it, acknowledgements piggybacked, trinomial control;
* ``trinomial``: the paper's comparison, the same controller with one separate ACK packet per data
  packet, padded so that it is 40 bytes on the wire (``ack_size`` 20 in the native encapsulation);
* ``tfrc``: TDTP's piggybacked acknowledgements with the TFRC controller (the paper's future work).

Packets are counted at their IP size: the paper's native encapsulation (IP 20 + TDTP 5 + data) unless
``encapsulation="udp"`` (IP 20 + UDP 8 + TDTP 5 + data).
"""

from __future__ import annotations

import json
import math
import random
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, Final, Literal

from tdtp.config import AckMode, ConnectionConfig, ControllerName
from tdtp.control.equations import tcp_friendly_rate
from tdtp.errors import InvalidArgumentError
from tdtp.sim.endpoints import IP_HEADER, UDP_HEADER, CbrSource, TdtpEndpoint, TdtpSession
from tdtp.sim.engine import Network, Simulator, describe
from tdtp.sim.metrics import FlowRecorder, FlowSummary, jain_index, mean
from tdtp.sim.readings import DEFAULT_READING, NS2_MEAN_PACKET_SIZE, SEND_JITTER, Reading
from tdtp.sim.readings import reading as reading_named
from tdtp.sim.tcp import TcpConfig, TcpFlow
from tdtp.wire.header import HEADER_SIZE

__all__ = [
    "MS",
    "SCENARIOS",
    "SCHEMES",
    "SM",
    "STARVATION_SHARE",
    "WINDOWS",
    "BestEffortResult",
    "FairnessResult",
    "FriendlinessResult",
    "PaperResult",
    "PaperRun",
    "Scheme",
    "TcpOutcome",
    "best_effort",
    "connection_config",
    "fairness",
    "friendliness",
    "paper",
    "paper_windows",
    "tail_window",
    "tcp_pause",
]

Encapsulation = Literal["native", "udp"]

ACCESS_RATE: Final = "100mbit"
ACCESS_DELAY: Final = "1ms"
HOST_QUEUE: Final = 50
"""Hosts' own output queues: ns-2's default ``Queue set limit_ 50`` (the paper sets the routers' only)."""
ROUTER_QUEUE: Final = 15
"""The paper's DropTail limit at R1 and R2, packets."""
ACK_WIRE_BYTES: Final = 40
"""The paper's Trinomial ACK packets: 40 bytes."""


# -- schemes -------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Scheme:
    key: str
    label: str
    ack_mode: AckMode
    controller: ControllerName


SCHEMES: Final[dict[str, Scheme]] = {
    "tdtp": Scheme(
        "tdtp", "TDTP (piggybacked ACKs, trinomial)", AckMode.BIDIRECTIONAL, "trinomial"
    ),
    "trinomial": Scheme(
        "trinomial", "Trinomial (separate 40-byte ACKs)", AckMode.SEPARATE, "trinomial"
    ),
    "tfrc": Scheme("tfrc", "TDTP with TFRC (piggybacked ACKs)", AckMode.BIDIRECTIONAL, "tfrc"),
    "teleop": Scheme(
        "teleop",
        "TDTP with teleop, the default (piggybacked ACKs)",
        AckMode.BIDIRECTIONAL,
        "teleop",
    ),
}
DEFAULT_SCHEMES: Final = ("tdtp", "trinomial", "tfrc")


def ip_overhead(encapsulation: Encapsulation) -> int:
    """Bytes below the TDTP header on the wire."""
    if encapsulation == "native":
        return IP_HEADER
    if encapsulation == "udp":
        return IP_HEADER + UDP_HEADER
    raise InvalidArgumentError(f"encapsulation must be 'native' or 'udp', got {encapsulation!r}")


def connection_config(
    scheme: Scheme,
    encapsulation: Encapsulation = "native",
    *,
    plain_acks: bool = False,
    controller_config: object | None = None,
) -> ConnectionConfig:
    """The connection configuration of a scheme: the controllers' defaults unless
    ``controller_config`` says otherwise; ``plain_acks`` for Trinomial's one-report-per-packet ACKs."""
    ack_size = HEADER_SIZE
    separate = scheme.ack_mode is AckMode.SEPARATE
    if separate:
        ack_size = max(HEADER_SIZE, ACK_WIRE_BYTES - ip_overhead(encapsulation))
    return ConnectionConfig(
        ack_mode=scheme.ack_mode,
        ack_size=ack_size,
        plain_acks=plain_acks and separate,
        controller=scheme.controller,
        controller_config=controller_config,
    )


def _schemes(keys: Sequence[str]) -> list[Scheme]:
    unknown = [k for k in keys if k not in SCHEMES]
    if unknown:
        raise InvalidArgumentError(f"unknown scheme(s) {unknown}; known: {', '.join(SCHEMES)}")
    return [SCHEMES[k] for k in keys]


# -- shared pieces ---------------------------------------------------------------------------------


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def _clean(data: Any) -> Any:
    """Make a structure JSON-safe: NaN and infinities become ``None``."""
    if isinstance(data, float):
        return _finite(data)
    if isinstance(data, dict):
        return {k: _clean(v) for k, v in data.items()}
    if isinstance(data, list | tuple):
        return [_clean(v) for v in data]
    return data


class _JsonResult:
    def to_dict(self) -> dict[str, Any]:
        raise NotImplementedError

    def to_json(self, *, indent: int | None = None) -> str:
        """The whole result as JSON (NaN and infinities as ``null``)."""
        return json.dumps(_clean(self.to_dict()), indent=indent, allow_nan=False)

    def headline(self) -> dict[str, Any]:
        raise NotImplementedError


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


def _probe(sim: Simulator, endpoint: TdtpEndpoint, interval: float, until: float) -> Probe:
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


def _conn_stats(endpoint: TdtpEndpoint) -> dict[str, Any]:
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


def _run_timed(net: Network, until: float) -> float:
    """Run the simulation to ``until``; returns the wall-clock seconds it took."""
    start = time.perf_counter()
    net.run(until)
    return time.perf_counter() - start


# -- the paper: figures 6, 7 and 8 -------------------------------------------------------------------

MS, SM = "M->S", "S->M"
WINDOWS: Final = ("all", "tcp_on", "tcp_off")
"""Summary windows of the paper scenario: the whole run, the time the master-to-slave TCP is on
(0-20 s and 30-100 s of 100 s) and the time it is paused (20-30 s). Both directions use the same
windows, so a direction without TCP of its own still shows what the other direction's TCP does to it
(its ACKs share the path)."""
STARVATION_SHARE: Final = 0.1
"""A TCP flow starves when, over the last 50 s (or the part after the pause, if shorter), it carries
less than this fraction of its fair share of the bottleneck (capacity / flows in its direction)."""
BOTTLENECK_BPS: Final = 1_000_000


def tcp_pause(duration: float) -> tuple[float, float]:
    """When the master-to-slave TCP pauses: 20-30 % of the run (20-30 s of the paper's 100 s)."""
    return (0.2 * duration, 0.3 * duration)


def paper_windows(
    duration: float, pause: tuple[float, float] | None = None
) -> dict[str, list[tuple[float, float]]]:
    """The windows of :data:`WINDOWS` for a run of ``duration`` s with the TCP ``pause``."""
    pause = pause if pause is not None else tcp_pause(duration)
    return {
        "all": [(0.0, duration)],
        "tcp_on": [(0.0, pause[0]), (pause[1], duration)],
        "tcp_off": [pause],
    }


def tail_window(duration: float, pause: tuple[float, float] | None = None) -> tuple[float, float]:
    """Where starvation is judged: the last 50 s, never earlier than the end of the pause."""
    pause = pause if pause is not None else tcp_pause(duration)
    return (max(duration - 50.0, pause[1]), duration)


@dataclass(frozen=True, slots=True)
class TcpOutcome:
    """What the TCP cross traffic of one direction got: over the run, before the master-to-slave
    pause and over :func:`tail_window`."""

    direction: str
    goodput_kbps: float
    share_before: float
    """Its wire throughput over ``[0, pause)`` as a fraction of the bottleneck's capacity."""
    share_after: float
    """...over :func:`tail_window`."""
    fair_share: float
    """``1 / (flows sharing its direction)``: TCP and the TDTP data flow in the literal reading."""
    starved: bool
    """``share_after < STARVATION_SHARE * fair_share``."""

    @property
    def share_ratio(self) -> float:
        """``share_after / share_before``: 1 when TCP gets back what it had before the pause."""
        return self.share_after / self.share_before if self.share_before > 0 else math.nan

    def to_dict(self) -> dict[str, Any]:
        return asdict(self) | {"share_ratio": self.share_ratio}


@dataclass
class PaperRun(_JsonResult):
    """One scheme on figure 6's topology."""

    scheme: str
    label: str
    wall_time: float
    events: int
    summaries: dict[str, dict[str, FlowSummary]]
    """By direction (``M->S``, ``S->M``), then window (:data:`WINDOWS`)."""
    acks: dict[str, FlowSummary]
    """The ACK/control packets each side sent (by the direction they travel)."""
    tcp: dict[str, FlowSummary]
    """TCP data by direction (an empty flow in a direction without TCP)."""
    tcp_outcome: dict[str, TcpOutcome]
    """By direction, for the directions that carry TCP."""
    connection: dict[str, dict[str, Any]]
    """Counters of the master's and the slave's connection at the end."""
    series: dict[str, dict[str, list[float | None]]]
    """Per-bin series by direction (see :meth:`FlowRecorder.series`), and ``tcp M->S``/``tcp S->M``."""
    probes: dict[str, dict[str, list[float]]]
    """The master's and slave's allowed rate, srtt and loss event rate over time."""
    links: list[dict[str, Any]]

    @property
    def starved(self) -> list[str]:
        """Directions whose TCP starved (see :data:`STARVATION_SHARE`)."""
        return [d for d, o in self.tcp_outcome.items() if o.starved]

    def to_dict(self) -> dict[str, Any]:
        return {
            "scheme": self.scheme,
            "label": self.label,
            "wall_time": self.wall_time,
            "events": self.events,
            "summaries": {
                d: {w: s.to_dict() for w, s in windows.items()}
                for d, windows in self.summaries.items()
            },
            "acks": {d: s.to_dict() for d, s in self.acks.items()},
            "tcp": {d: s.to_dict() for d, s in self.tcp.items()},
            "tcp_outcome": {d: o.to_dict() for d, o in self.tcp_outcome.items()},
            "connection": self.connection,
            "links": self.links,
            "series": self.series,
            "probes": self.probes,
        }


@dataclass
class PaperResult(_JsonResult):
    params: dict[str, Any]
    runs: dict[str, PaperRun]
    ratios: dict[str, dict[str, dict[str, float]]]
    """``"tdtp/trinomial"`` -> window -> direction -> goodput ratio."""

    def headline(self) -> dict[str, Any]:
        """What the JSON summary leads with: mean goodput, loss and delay per scheme and direction."""
        out: dict[str, Any] = {"reading": self.params["reading"]["description"]}
        for key, run in self.runs.items():
            per: dict[str, Any] = {"wall_time_s": round(run.wall_time, 2)}
            for direction, windows in run.summaries.items():
                s = windows["all"]
                sender = run.connection["master" if direction == MS else "slave"]
                per[direction] = {
                    "goodput_kbps": round(s.goodput_kbps, 1),
                    "samples_per_s": round(s.delivered_pps, 1),
                    "goodput_tcp_on_kbps": round(windows["tcp_on"].goodput_kbps, 1),
                    "goodput_tcp_off_kbps": round(windows["tcp_off"].goodput_kbps, 1),
                    "loss_ratio": round(s.loss_ratio, 4),
                    "mean_delay_ms": round(s.mean_delay * 1000, 1),
                    "p95_delay_ms": round(s.p95_delay * 1000, 1),
                    "dropped_by_network": s.dropped_packets,
                    "declared_lost_by_sender": sender["packets_lost"],
                    "ack_packets": sender["ack_packets_sent"],
                }
            per["tcp_goodput_kbps"] = {
                d: round(o.goodput_kbps, 1) for d, o in run.tcp_outcome.items()
            }
            per["tcp_starved"] = run.starved
            out[key] = per
        out["ratios"] = {
            pair: {w: {d: round(v, 3) for d, v in dirs.items()} for w, dirs in windows.items()}
            for pair, windows in self.ratios.items()
        }
        return _clean(out)  # type: ignore[no-any-return]

    def to_dict(self) -> dict[str, Any]:
        return {
            "scenario": "paper",
            "params": self.params,
            "headline": self.headline(),
            "ratios": self.ratios,
            "runs": {k: r.to_dict() for k, r in self.runs.items()},
        }


def paper(
    *,
    seed: int = 1,
    reading: Reading | str = DEFAULT_READING,
    duration: float = 100.0,
    schemes: Sequence[str] = DEFAULT_SCHEMES,
    bin_width: float = 0.5,
    tcp_flows: int = 1,
    sample_rate: float = 1000.0,
    payload_size: int = 100,
    bottleneck_delay: str = "10ms",
    encapsulation: Encapsulation = "native",
    tcp_config: TcpConfig | None = None,
    controller_configs: Mapping[str, object] | None = None,
    pause: tuple[float, float] | None = None,
) -> PaperResult:
    """Figure 6: M - R1 - R2 - S, R1-R2 1 Mbit/s, access 100 Mbit/s, DropTail 15 at the routers.

    Cross traffic: ``tcp_flows`` FTP/TCP transfers from host T1 (behind R1) to T2 (behind R2), the
    master-to-slave direction, on all the time except during ``pause`` (default ``[0.2, 0.3) *
    duration``, 20-30 s of 100 s); with a ``both`` reading as many from T2 to T1, on all the time. TCP starts are spread over
    the first 100 ms by ``seed``. Both ends sample ``sample_rate`` times per second, ``payload_size``
    bytes. ``reading`` (a :class:`~tdtp.sim.readings.Reading` or its name) settles what the paper
    leaves open; ``tcp_config`` overrides the TCP parameters (its variant included) and
    ``controller_configs`` the controllers' (by controller name: ``{"trinomial": TrinomialConfig(...)}``).
    """
    chosen = _schemes(schemes)
    how = reading if isinstance(reading, Reading) else reading_named(reading)
    pause = pause if pause is not None else tcp_pause(duration)
    if not 0.0 < pause[0] < pause[1] < duration:
        raise ValueError(f"the TCP pause {pause} must lie inside the run (0-{duration} s)")
    windows = paper_windows(duration, pause)
    tail = tail_window(duration, pause)
    tcp_cfg = tcp_config if tcp_config is not None else TcpConfig(variant=how.tcp_variant)  # type: ignore[arg-type]
    byte_limit = ROUTER_QUEUE * NS2_MEAN_PACKET_SIZE if how.queue_unit == "bytes" else None
    fair_share = 1.0 / (tcp_flows + 1)
    runs: dict[str, PaperRun] = {}
    for scheme in chosen:
        rng = random.Random(seed)
        net = Network(seed=seed)
        build_dumbbell(
            net,
            ["M", "T1"],
            ["S", "T2"],
            f"rate 1mbit delay {bottleneck_delay} limit {ROUTER_QUEUE}",
            byte_limit=byte_limit,
        )
        config = connection_config(
            scheme,
            encapsulation,
            plain_acks=how.ack_form == "plain",
            controller_config=(controller_configs or {}).get(scheme.controller),
        )
        session = TdtpSession.create(
            net,
            "M",
            "S",
            config,
            sample_rate=sample_rate,
            payload_size=payload_size,
            ip_overhead=ip_overhead(encapsulation),
            bin_width=bin_width,
            duration=duration,
            seed=rng.getrandbits(32),
            send_jitter=how.send_jitter,
        )
        flows: dict[str, list[TcpFlow]] = {MS: [], SM: []}
        for i in range(tcp_flows):
            ms_start, sm_start = rng.random() * 0.1, rng.random() * 0.1
            flows[MS].append(
                TcpFlow(
                    net,
                    "T1",
                    "T2",
                    port=5000 + i,
                    config=tcp_cfg,
                    periods=((ms_start, pause[0]), (pause[1], math.inf)),
                    bin_width=bin_width,
                    duration=duration,
                    name=f"tcp M->S {i}",
                )
            )
            if how.tcp_both_ways:
                flows[SM].append(
                    TcpFlow(
                        net,
                        "T2",
                        "T1",
                        port=6000 + i,
                        config=tcp_cfg,
                        periods=((sm_start, math.inf),),
                        bin_width=bin_width,
                        duration=duration,
                        name=f"tcp S->M {i}",
                    )
                )
        probes = {
            "master": _probe(net.sim, session.master, bin_width, duration),
            "slave": _probe(net.sim, session.slave, bin_width, duration),
        }
        wall = _run_timed(net, duration)
        recorders = {MS: session.ms, SM: session.sm}
        summaries = {
            d: {w: recorders[d].summary(windows=spans) for w, spans in windows.items()}
            for d in (MS, SM)
        }
        tcp_data = {
            d: _merge(f"tcp {d}", [f.data for f in flows[d]])
            if flows[d]
            else FlowRecorder(f"tcp {d}", bin_width=bin_width, duration=duration)
            for d in (MS, SM)
        }
        outcome: dict[str, TcpOutcome] = {}
        for d in (MS, SM):
            if not flows[d]:
                continue
            rec = tcp_data[d]
            before = rec.summary(0.0, pause[0]).throughput_kbps * 1000 / BOTTLENECK_BPS
            after = rec.summary(*tail).throughput_kbps * 1000 / BOTTLENECK_BPS
            outcome[d] = TcpOutcome(
                direction=d,
                goodput_kbps=rec.summary().goodput_kbps,
                share_before=before,
                share_after=after,
                fair_share=fair_share,
                starved=after < STARVATION_SHARE * fair_share,
            )
        series: dict[str, dict[str, list[float | None]]] = {
            MS: session.ms.series(),
            SM: session.sm.series(),
            "tcp M->S": tcp_data[MS].series(),
            "tcp S->M": tcp_data[SM].series(),
        }
        runs[scheme.key] = PaperRun(
            scheme=scheme.key,
            label=scheme.label,
            wall_time=wall,
            events=net.sim.events_run,
            summaries=summaries,
            acks={MS: session.ms_other.summary(), SM: session.sm_other.summary()},
            tcp={d: tcp_data[d].summary() for d in (MS, SM)},
            tcp_outcome=outcome,
            connection={"master": _conn_stats(session.master), "slave": _conn_stats(session.slave)},
            series=series,
            probes={k: asdict(v) for k, v in probes.items()},
            links=describe(net.links),
        )
    ratios: dict[str, dict[str, dict[str, float]]] = {}
    if "trinomial" in runs:
        base = runs["trinomial"]
        for key, run in runs.items():
            if key == "trinomial":
                continue
            ratios[f"{key}/trinomial"] = {
                w: {
                    d: _div(run.summaries[d][w].goodput_kbps, base.summaries[d][w].goodput_kbps)
                    for d in (MS, SM)
                }
                for w in WINDOWS
            }
    params = {
        "seed": seed,
        "reading": how.to_dict(),
        "duration": duration,
        "schemes": list(schemes),
        "bin_width": bin_width,
        "tcp_flows_each_way" if how.tcp_both_ways else "tcp_flows_master_to_slave": tcp_flows,
        "tcp_ms_paused": list(pause),
        "starvation_window": list(tail),
        "sample_rate": sample_rate,
        "payload_size": payload_size,
        "encapsulation": encapsulation,
        "bottleneck": f"1 Mbit/s, {bottleneck_delay}, DropTail {ROUTER_QUEUE} "
        + ("packets" if byte_limit is None else f"x {NS2_MEAN_PACKET_SIZE} = {byte_limit} bytes"),
        "access": f"100 Mbit/s, {ACCESS_DELAY}, DropTail {ROUTER_QUEUE} (routers) / {HOST_QUEUE} (hosts)",
        "tcp": asdict(tcp_cfg),
        "controller_configs": {
            name: asdict(cfg)  # type: ignore[call-overload]
            for name, cfg in (controller_configs or {}).items()
        },
    }
    return PaperResult(params=params, runs=runs, ratios=ratios)


def _merge(name: str, recorders: Sequence[FlowRecorder]) -> FlowRecorder:
    """One recorder adding up several (same bins)."""
    first = recorders[0]
    merged = FlowRecorder(name, bin_width=first.bin_width, duration=first.duration)
    for rec in recorders:
        for attr in (
            "sent_packets",
            "sent_bytes",
            "dropped_packets",
            "delivered_packets",
            "delivered_bytes",
            "delivered_wire_bytes",
            "delay_sum",
        ):
            total = getattr(merged, attr)
            for i, v in enumerate(getattr(rec, attr)):
                total[i] += v
        merged.delay_times.extend(rec.delay_times)
        merged.delays.extend(rec.delays)
    order = sorted(range(len(merged.delay_times)), key=merged.delay_times.__getitem__)
    merged.delay_times = [merged.delay_times[i] for i in order]
    merged.delays = [merged.delays[i] for i in order]
    return merged


# -- TCP-friendliness --------------------------------------------------------------------------------


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
class FriendlinessResult(_JsonResult):
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
        return _clean(out)  # type: ignore[no-any-return]

    def to_dict(self) -> dict[str, Any]:
        return {
            "scenario": "friendliness",
            "params": self.params,
            "headline": self.headline(),
            "cases": [asdict(c) for c in self.cases],
        }


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
    chosen = _schemes(schemes)
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
                probe = _probe(net.sim, session.master, 0.25, duration)
                wall = _run_timed(net, duration)
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
                        ratio_pps=_div(tdtp_s.delivered_pps, tcp_s.delivered_pps),
                        ratio_bytes=_div(tdtp_s.throughput_kbps, tcp_s.throughput_kbps),
                        tdtp_kbps=tdtp_s.throughput_kbps,
                        tcp_kbps=tcp_s.throughput_kbps,
                        tcp_loss=tcp_loss,
                        tcp_rtt=tcp_rtt,
                        tdtp_p=p,
                        tdtp_srtt=srtt,
                        eq2_tcp_pps=eq2_tcp,
                        eq2_tdtp_pps=eq2_tdtp,
                        eq2_ratio=_div(eq2_tdtp, tcp_s.delivered_pps),
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


def _div(a: float, b: float) -> float:
    return a / b if b and math.isfinite(a) and math.isfinite(b) else math.nan


# -- fairness -----------------------------------------------------------------------------------------


@dataclass
class FairnessRun:
    scheme: str
    flows: int
    starts: list[float]
    converged_from: float
    jain_times: list[float]
    jain_ms: list[float | None]
    """Jain's index of the active flows' master-to-slave goodput, per bin."""
    jain_sm: list[float | None]
    mean_jain_ms: float
    """Mean of the per-bin index after convergence."""
    min_jain_ms: float
    jain_of_means_ms: float
    """Jain's index of each flow's mean goodput after convergence."""
    mean_jain_sm: float
    per_flow_kbps: list[float]
    """Each flow's mean M->S goodput after convergence."""
    wall_time: float


@dataclass
class FairnessResult(_JsonResult):
    params: dict[str, Any]
    runs: list[FairnessRun]

    def headline(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for run in self.runs:
            out.setdefault(run.scheme, {})[f"N={run.flows}"] = {
                "mean_jain": run.mean_jain_ms,
                "min_jain": run.min_jain_ms,
                "jain_of_means": run.jain_of_means_ms,
                "mean_jain_S->M": run.mean_jain_sm,
            }
        return _clean(out)  # type: ignore[no-any-return]

    def to_dict(self) -> dict[str, Any]:
        return {
            "scenario": "fairness",
            "params": self.params,
            "headline": self.headline(),
            "runs": [asdict(r) for r in self.runs],
        }


def fairness(
    *,
    seed: int = 1,
    flow_counts: Sequence[int] = (2, 4, 8),
    schemes: Sequence[str] = DEFAULT_SCHEMES,
    capacity_mbps: float = 1.0,
    stagger: float = 5.0,
    settle: float = 40.0,
    convergence: float = 10.0,
    bin_width: float = 1.0,
    sample_rate: float = 1000.0,
    encapsulation: Encapsulation = "native",
    send_jitter: float = SEND_JITTER,
) -> FairnessResult:
    """N sessions (M_i behind R1, S_i behind R2) share a ``capacity_mbps`` bottleneck (10 ms, DropTail
    15); session i opens at ``i * stagger`` s; the run lasts ``settle`` s after the last start, and the
    flows count as converged ``convergence`` s after it (at most half of ``settle``). Jain's index per
    ``bin_width`` s bin."""
    convergence = min(convergence, settle / 2)
    chosen = _schemes(schemes)
    runs: list[FairnessRun] = []
    for n in flow_counts:
        duration = (n - 1) * stagger + settle
        converged = (n - 1) * stagger + convergence
        for scheme in chosen:
            rng = random.Random(seed)
            net = Network(seed=seed)
            build_dumbbell(
                net,
                [f"M{i}" for i in range(n)],
                [f"S{i}" for i in range(n)],
                f"rate {capacity_mbps * 1e6:g}bit delay 10ms limit {ROUTER_QUEUE}",
            )
            starts = [i * stagger + rng.random() * 0.01 for i in range(n)]
            sessions = [
                TdtpSession.create(
                    net,
                    f"M{i}",
                    f"S{i}",
                    connection_config(scheme, encapsulation),
                    name=f"flow {i}",
                    sample_rate=sample_rate,
                    ip_overhead=ip_overhead(encapsulation),
                    start=starts[i],
                    bin_width=bin_width,
                    duration=duration,
                    seed=rng.getrandbits(32),
                    send_jitter=send_jitter,
                )
                for i in range(n)
            ]
            wall = _run_timed(net, duration)
            nbins = sessions[0].ms.nbins
            times = [(b + 0.5) * bin_width for b in range(nbins)]
            jain_ms = _jain_series([x.ms for x in sessions], starts, bin_width)
            jain_sm = _jain_series([x.sm for x in sessions], starts, bin_width)
            after_ms = [
                j for t, j in zip(times, jain_ms, strict=True) if t >= converged and j is not None
            ]
            after_sm = [
                j for t, j in zip(times, jain_sm, strict=True) if t >= converged and j is not None
            ]
            per_flow = [s.ms.summary(converged, duration).goodput_kbps for s in sessions]
            runs.append(
                FairnessRun(
                    scheme=scheme.key,
                    flows=n,
                    starts=starts,
                    converged_from=converged,
                    jain_times=times,
                    jain_ms=jain_ms,
                    jain_sm=jain_sm,
                    mean_jain_ms=mean(after_ms),
                    min_jain_ms=min(after_ms) if after_ms else math.nan,
                    jain_of_means_ms=jain_index(per_flow),
                    mean_jain_sm=mean(after_sm),
                    per_flow_kbps=per_flow,
                    wall_time=wall,
                )
            )
    params = {
        "seed": seed,
        "flow_counts": list(flow_counts),
        "schemes": list(schemes),
        "capacity_mbps": capacity_mbps,
        "stagger": stagger,
        "settle": settle,
        "convergence": convergence,
        "bin_width": bin_width,
        "sample_rate": sample_rate,
        "encapsulation": encapsulation,
        "send_jitter": send_jitter,
    }
    return FairnessResult(params=params, runs=runs)


def _jain_series(
    recorders: Sequence[FlowRecorder], starts: Sequence[float], bin_width: float
) -> list[float | None]:
    """Jain's index per bin over the flows started at least two bins before it (None below two)."""
    out: list[float | None] = []
    for b in range(recorders[0].nbins):
        t0 = b * bin_width
        active = [
            r for r, start in zip(recorders, starts, strict=True) if start + 2 * bin_width <= t0
        ]
        out.append(jain_index([r.delivered_bytes[b] for r in active]) if len(active) >= 2 else None)
    return out


# -- best effort -------------------------------------------------------------------------------------


@dataclass
class BestEffortRun:
    scheme: str
    free_level_kbps: float
    """tdtp M->S goodput over the last half of the free period."""
    congested_level_kbps: float
    """...over the last half of the first period with the UDP source on."""
    fill_time_50: float | None
    """Seconds after the UDP source stopped until tdtp's goodput (0.5 s average) first reached the
    middle between its congested and free levels."""
    fill_time_90: float | None
    """...90 % of the way from the congested to the free level."""
    give_back_time: float | None
    """Seconds after the UDP source restarted until tdtp's goodput fell back below what is left
    for it plus 10 % of the capacity."""
    cbr_loss_after_restart: float
    """Loss ratio of the UDP source in the first 2 s after it restarted."""
    cbr_loss_steady: float
    """...in its last 5 s on."""
    wall_time: float
    series_time: list[float]
    tdtp_kbps: list[float]
    """tdtp M->S goodput per bin."""
    cbr_kbps: list[float]
    tdtp_sm_kbps: list[float]


@dataclass
class BestEffortResult(_JsonResult):
    params: dict[str, Any]
    runs: list[BestEffortRun]

    def headline(self) -> dict[str, Any]:
        return _clean(  # type: ignore[no-any-return]
            {
                r.scheme: {
                    "congested_level_kbps": r.congested_level_kbps,
                    "free_level_kbps": r.free_level_kbps,
                    "fill_time_50_s": r.fill_time_50,
                    "fill_time_90_s": r.fill_time_90,
                    "give_back_time_s": r.give_back_time,
                    "cbr_loss_after_restart": r.cbr_loss_after_restart,
                    "cbr_loss_steady": r.cbr_loss_steady,
                }
                for r in self.runs
            }
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "scenario": "best-effort",
            "params": self.params,
            "headline": self.headline(),
            "runs": [asdict(r) for r in self.runs],
        }


def best_effort(
    *,
    seed: int = 1,
    duration: float = 60.0,
    schemes: Sequence[str] = DEFAULT_SCHEMES,
    capacity_mbps: float = 1.0,
    cbr_kbps: float = 600.0,
    bin_width: float = 0.1,
    sample_rate: float = 1000.0,
    encapsulation: Encapsulation = "native",
    send_jitter: float = SEND_JITTER,
) -> BestEffortResult:
    """One session on a ``capacity_mbps`` bottleneck (10 ms, DropTail 15). An unresponsive UDP source
    of ``cbr_kbps`` (1000-byte packets) crosses it master-to-slave during the first and the last third
    of the run and is off in the middle third: capacity freed, then taken back."""
    chosen = _schemes(schemes)
    third = duration / 3
    runs: list[BestEffortRun] = []
    smooth = max(1, round(0.5 / bin_width))
    for scheme in chosen:
        rng = random.Random(seed)
        net = Network(seed=seed)
        build_dumbbell(
            net,
            ["M", "U1"],
            ["S", "U2"],
            f"rate {capacity_mbps * 1e6:g}bit delay 10ms limit {ROUTER_QUEUE}",
        )
        session = TdtpSession.create(
            net,
            "M",
            "S",
            connection_config(scheme, encapsulation),
            sample_rate=sample_rate,
            ip_overhead=ip_overhead(encapsulation),
            bin_width=bin_width,
            duration=duration,
            seed=rng.getrandbits(32),
            send_jitter=send_jitter,
        )
        cbr = CbrSource(
            net,
            "U1",
            "U2",
            rate_bps=cbr_kbps * 1000,
            periods=((0.0, third), (2 * third, duration)),
            bin_width=bin_width,
            duration=duration,
        )
        wall = _run_timed(net, duration)
        rec = session.ms
        smoothed = rec.rate_series(smooth)
        times = rec.bin_times()
        congested = rec.summary(third / 2, third).goodput_kbps
        free_level = rec.summary(1.5 * third, 2 * third).goodput_kbps

        window = smooth * bin_width
        mid = congested + 0.5 * (free_level - congested)
        high = congested + 0.9 * (free_level - congested)
        fill50 = _first_crossing(times, smoothed, window, third, 2 * third, above=mid)
        fill90 = _first_crossing(times, smoothed, window, third, 2 * third, above=high)
        capacity_kbps = capacity_mbps * 1000
        give_back_level = (capacity_kbps - cbr_kbps) + 0.1 * capacity_kbps
        give_back = _first_crossing(
            times, smoothed, window, 2 * third, duration, below=give_back_level
        )
        runs.append(
            BestEffortRun(
                scheme=scheme.key,
                free_level_kbps=free_level,
                congested_level_kbps=congested,
                fill_time_50=fill50,
                fill_time_90=fill90,
                give_back_time=give_back,
                cbr_loss_after_restart=cbr.recorder.summary(2 * third, 2 * third + 2.0).loss_ratio,
                cbr_loss_steady=cbr.recorder.summary(duration - 5.0, duration).loss_ratio,
                wall_time=wall,
                series_time=times,
                tdtp_kbps=rec.rate_series(),
                cbr_kbps=cbr.recorder.rate_series(),
                tdtp_sm_kbps=session.sm.rate_series(),
            )
        )
    params = {
        "seed": seed,
        "duration": duration,
        "schemes": list(schemes),
        "capacity_mbps": capacity_mbps,
        "cbr_kbps": cbr_kbps,
        "cbr_on": [[0.0, third], [2 * third, duration]],
        "bin_width": bin_width,
        "sample_rate": sample_rate,
        "encapsulation": encapsulation,
        "send_jitter": send_jitter,
    }
    return BestEffortResult(params=params, runs=runs)


def _first_crossing(
    times: Sequence[float],
    averaged: Sequence[float],
    window: float,
    after: float,
    until: float,
    *,
    above: float | None = None,
    below: float | None = None,
) -> float | None:
    """Seconds from ``after`` until the first moving average (over ``window`` s, ending with its bin)
    that lies entirely after ``after`` and is at least ``above`` (or at most ``below``)."""
    half = (times[1] - times[0]) / 2 if len(times) > 1 else 0.0
    for t, value in zip(times, averaged, strict=True):
        end = t + half
        if end - window < after - 1e-9 or end > until + 1e-9:
            continue
        if (above is not None and value >= above) or (below is not None and value <= below):
            return round(end - after, 6)
    return None


SCENARIOS: Final[dict[str, Callable[..., _JsonResult]]] = {
    "paper": paper,
    "friendliness": friendliness,
    "fairness": fairness,
    "best-effort": best_effort,
}
