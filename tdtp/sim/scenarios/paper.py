"""The paper's experiment: figures 6, 7 and 8 (TCP cross traffic that pauses, 100 s, a 1 Mbit/s bottleneck)."""

from __future__ import annotations

import math
import random
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any, ClassVar, Final

from tdtp.sim.endpoints import TdtpSession
from tdtp.sim.engine import Network, describe
from tdtp.sim.metrics import FlowRecorder, FlowSummary
from tdtp.sim.readings import DEFAULT_READING, NS2_MEAN_PACKET_SIZE, Reading
from tdtp.sim.readings import reading as reading_named
from tdtp.sim.scenarios.dumbbell import (
    ACCESS_DELAY,
    HOST_QUEUE,
    ROUTER_QUEUE,
    build_dumbbell,
    connection_stats,
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
class PaperRun(ScenarioResult):
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
class PaperResult(ScenarioResult):
    scenario: ClassVar[str] = "paper"
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
        return json_safe(out)  # type: ignore[no-any-return]

    def details(self) -> dict[str, Any]:
        return {"ratios": self.ratios, "runs": {k: r.to_dict() for k, r in self.runs.items()}}


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
    chosen = schemes_named(schemes)
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
            "master": start_probe(net.sim, session.master, bin_width, duration),
            "slave": start_probe(net.sim, session.slave, bin_width, duration),
        }
        wall = run_timed(net, duration)
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
            connection={
                "master": connection_stats(session.master),
                "slave": connection_stats(session.slave),
            },
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
                    d: ratio(run.summaries[d][w].goodput_kbps, base.summaries[d][w].goodput_kbps)
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
