"""Teleoperation over recorded cellular links, in virtual time: what an operator gets, and what the
trace allowed.

A master and a slave exchange 100-byte samples at 1 kHz each way over two trace-driven directions
(``"delay 20ms trace Verizon-LTE-short.down limit-bytes 150000"`` master to slave, the ``.up`` trace
back: the robot's uplink). :func:`run_tdtp` runs the real :class:`~tdtp.session.connection.Connection`
with any registered controller at both ends; :func:`run_udp` a fixed 1 kHz stream each way with no
transport header and no feedback (what raw UDP does); :func:`ideal` computes, from the trace itself,
what a sender that knew the link could deliver.

Every direction is judged by :func:`direction_figures`, from the samples generated in the measured
window and when each one arrived:

* **samples/s** delivered (a sample arriving any time after the window still counts; its delay says
  how late), against what the trace **allowed** (:func:`allowed`): min(offered, capacity) in every
  100 ms window, summed, the capacity counted in whole samples of 100 bytes plus IPv4 + UDP headers;
* **one-way delay** p50/p95/p99/max, from the sample's generation by the application to its delivery
  to the other application (the wait for the pacer included);
* **dropouts**: 100 ms windows of the receiver's timeline (from the window's start plus the path's
  propagation delay) in which no sample arrived, and the longest gap between arrivals;
* **age** p50/p99 of the newest sample, read every millisecond: what a controller acting on the
  freshest sample sees.

**The ideal** (:func:`ideal`: Pantheon's way of judging a scheme against its link, "the trace's own
capacity, nothing queued"): every delivery opportunity carries the newest samples generated before
it, as many as its 1500 bytes hold at ``ideal_wire`` bytes each (the sample and its IPv4 + UDP
headers, no transport header: the best any transport could do); older samples that did not fit are
skipped, never queued, and bytes an opportunity could not fill with a whole sample carry over to the
next while samples are left waiting (as a datagram spans opportunities on the link). Its delay is the
wait for an opportunity plus the propagation delay: the floor of what any sender can reach. Skipping
rather than queueing costs it samples where the capacity comes in bursts (an opportunity after a
20 ms gap carries 11 of the 20 samples waiting), so it delivers less than :func:`allowed`: a scheme
that queues a little delivers more, at some delay.

**The deadline oracle** (:func:`deadline`): the most samples any sender could deliver with every one
within ``bound`` of its generation, had it known the trace's future. Each opportunity carries the
oldest samples not yet sent that can still arrive within the bound (earliest deadline first, which
maximises the count when every sample has the same relative deadline); older ones are given up. It
answers "is this bar reachable at all on this trace": where it delivers less than a target share at a
60 ms bound, no sender can meet both.
"""

from __future__ import annotations

import itertools
import math
import random
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from tdtp.config import ConnectionConfig
from tdtp.netem import OPPORTUNITY_BYTES, NetemSpec, Trace, parse_netem
from tdtp.sim.endpoints import IP_HEADER, UDP_HEADER, CbrSource, TdtpSession
from tdtp.sim.engine import Network
from tdtp.sim.metrics import FlowRecorder
from tdtp.sim.readings import SEND_JITTER

__all__ = [
    "DROPOUT_WINDOW",
    "Arrivals",
    "CellularRun",
    "allowed",
    "deadline",
    "direction_figures",
    "ideal",
    "run_tdtp",
    "run_udp",
]

DROPOUT_WINDOW = 0.100
"""A window of the receiver's timeline this long without a sample is a dropout."""
AGE_CADENCE = 0.001
DRAIN = 5.0
"""Seconds the run goes on after the last sample was generated, so that queued samples arrive."""
MASTER, SLAVE = "master", "slave"
SAMPLE_SIZE = 100
UDP_IP = IP_HEADER + UDP_HEADER


@dataclass
class Arrivals:
    """One direction: the samples generated in ``[start, end)`` and when each delivered one arrived."""

    start: float
    end: float
    offered: int
    generated: list[float] = field(default_factory=list)
    """Generation time of each delivered sample, in arrival order."""
    arrived: list[float] = field(default_factory=list)
    """Its arrival time at the receiving application."""


def direction_figures(arrivals: Arrivals, *, propagation: float) -> dict[str, Any]:
    """The figures of one direction (see the module's docstring); times in ms, rates per second."""
    span = arrivals.end - arrivals.start
    delays = sorted(a - g for g, a in zip(arrivals.generated, arrivals.arrived, strict=True))
    times = sorted(arrivals.arrived)
    first = arrivals.start + propagation
    windows = max(1, round(span / DROPOUT_WINDOW))
    busy = {
        int((t - first) // DROPOUT_WINDOW)
        for t in times
        if first <= t < first + windows * DROPOUT_WINDOW
    }
    edges = [first, *(t for t in times if first <= t <= first + span), first + span]
    longest = max(b - a for a, b in itertools.pairwise(edges))

    def pct(values: Sequence[float], q: float) -> float:
        if not values:
            return math.nan
        return 1e3 * values[min(len(values) - 1, max(0, math.ceil(q * len(values)) - 1))]

    return {
        "offered": arrivals.offered,
        "delivered": len(delays),
        "samples_per_s": len(delays) / span,
        "delay_ms": {
            "p50": pct(delays, 0.50),
            "p95": pct(delays, 0.95),
            "p99": pct(delays, 0.99),
            "max": 1e3 * delays[-1] if delays else math.nan,
        },
        "dropouts": windows - len(busy),
        "windows": windows,
        "longest_gap_ms": 1e3 * max(longest, 0.0),
        "age_ms": _ages(arrivals, first, first + span),
    }


def _ages(arrivals: Arrivals, start: float, end: float) -> dict[str, float]:
    """Percentiles of ``now - generation of the newest sample received by now``, every ms."""
    order = sorted(range(len(arrivals.arrived)), key=arrivals.arrived.__getitem__)
    newest = -math.inf
    ages: list[float] = []
    i, n = 0, len(order)
    steps = int((end - start) / AGE_CADENCE)
    for k in range(steps):
        now = start + k * AGE_CADENCE
        while i < n and arrivals.arrived[order[i]] <= now:
            newest = max(newest, arrivals.generated[order[i]])
            i += 1
        if newest > -math.inf:
            ages.append(now - newest)
    ages.sort()
    if not ages:
        return {"p50": math.nan, "p99": math.nan}
    return {
        "p50": 1e3 * ages[len(ages) // 2],
        "p99": 1e3 * ages[min(len(ages) - 1, math.ceil(0.99 * len(ages)) - 1)],
    }


def _split(spec: str | NetemSpec) -> tuple[NetemSpec, float]:
    parsed = parse_netem(spec) if isinstance(spec, str) else spec
    if parsed.trace is None:
        raise ValueError(f"a cellular direction needs a trace, got {parsed}")
    return parsed, parsed.delay.delay if parsed.delay is not None else 0.0


def _trace_of(spec: str | NetemSpec) -> tuple[Trace, float, float]:
    """The direction's trace, its offset in ms and its propagation delay in seconds."""
    parsed, propagation = _split(spec)
    assert parsed.trace is not None  # _split insists
    return parsed.trace.trace, parsed.trace.offset * 1e3, propagation


def ideal(
    spec: str | NetemSpec,
    *,
    start: float,
    duration: float,
    rate: float = 1000.0,
    ideal_wire: int = SAMPLE_SIZE + UDP_IP,
    origin: float = 0.0,
) -> Arrivals:
    """What a sender that knew the link would deliver with nothing queued (see the module's
    docstring): samples generated at ``rate`` from ``start`` for ``duration``, the trace's clock
    started at ``origin`` (at its offset)."""
    return _serve(spec, start, duration, rate, ideal_wire, origin, None)


def deadline(
    spec: str | NetemSpec,
    *,
    start: float,
    duration: float,
    bound: float,
    rate: float = 1000.0,
    ideal_wire: int = SAMPLE_SIZE + UDP_IP,
    origin: float = 0.0,
) -> Arrivals:
    """The deadline oracle (see the module's docstring): samples generated at ``rate`` from
    ``start`` for ``duration``, each delivered within ``bound`` seconds or not at all."""
    return _serve(spec, start, duration, rate, ideal_wire, origin, bound)


def _serve(
    spec: str | NetemSpec,
    start: float,
    duration: float,
    rate: float,
    ideal_wire: int,
    origin: float,
    bound: float | None,
) -> Arrivals:
    """The trace's opportunities, in order, each carrying what fits of the samples waiting: the
    newest (the rest skipped) with no ``bound``, else the oldest still able to arrive within it."""
    trace, offset_ms, propagation = _trace_of(spec)
    count = round(duration * rate)
    out = Arrivals(start, start + duration, count)
    index = trace.first_after(max(0.0, (start - origin) * 1e3 + offset_ms))
    oldest = 0  # samples [0, oldest) were sent, skipped or given up
    carry = 0
    horizon = start + duration + (DRAIN if bound is None else bound)
    while oldest < count:
        when = origin + (trace.time_ms(index) - offset_ms) / 1e3
        if when >= horizon:
            break
        index += 1
        made = min(count, math.ceil((when - start) * rate - 1e-9))  # generated before `when`
        if bound is not None:  # (sample k arrives within the bound iff k >= this)
            oldest = max(oldest, math.ceil((when + propagation - bound - start) * rate - 1e-9))
        waiting = made - oldest
        if waiting <= 0:
            carry = 0
            continue
        budget = OPPORTUNITY_BYTES + carry
        fit = min(waiting, budget // ideal_wire)
        first = made - fit if bound is None else oldest
        for k in range(first, first + fit):
            out.generated.append(start + k / rate)
            out.arrived.append(when + propagation)
        carry = budget - fit * ideal_wire if waiting > fit else 0
        oldest = made if bound is None else oldest + fit
    return out


def allowed(
    spec: str | NetemSpec,
    *,
    start: float,
    duration: float,
    rate: float = 1000.0,
    ideal_wire: int = SAMPLE_SIZE + UDP_IP,
    origin: float = 0.0,
    window: float = DROPOUT_WINDOW,
) -> float:
    """Samples the trace allowed in ``[start, start + duration)``: for each ``window``, the smaller of
    the samples generated in it and the samples its opportunities carry (``ideal_wire`` bytes each,
    fractions counted), summed. The trace's clock starts at ``origin``, at its offset."""
    trace, offset_ms, _ = _trace_of(spec)
    total = 0.0
    for k in range(max(1, round(duration / window))):
        a = (start + k * window - origin) * 1e3 + offset_ms
        carried = trace.opportunities_between(max(0.0, a), max(0.0, a + window * 1e3))
        total += min(window * rate, carried * OPPORTUNITY_BYTES / ideal_wire)
    return total


@dataclass
class CellularRun:
    """One run: each direction's arrivals and figures, and what the senders and links counted."""

    ms: Arrivals
    sm: Arrivals
    figures: dict[str, dict[str, Any]]
    """``{"ms": direction_figures(...), "sm": ...}``."""
    links: dict[str, dict[str, int]]
    senders: dict[str, dict[str, Any]] = field(default_factory=dict)


def _network(ms: str | NetemSpec, sm: str | NetemSpec, seed: int) -> tuple[Network, float, float]:
    ms_spec, ms_delay = _split(ms)
    sm_spec, sm_delay = _split(sm)
    net = Network(seed=seed)
    net.connect(MASTER, SLAVE, ms_spec, sm_spec)
    net.compute_routes()
    return net, ms_delay, sm_delay


def _arrivals(recorder: FlowRecorder, start: float, end: float, rate: float) -> Arrivals:
    """The samples generated in ``[start, end)`` that ``recorder`` saw delivered."""
    out = Arrivals(start, end, round((end - start) * rate))
    ages = recorder.ages if len(recorder.ages) == len(recorder.delays) else recorder.delays
    for now, age in zip(recorder.delay_times, ages, strict=True):
        generated = now - age
        if start <= generated < end:
            out.generated.append(generated)
            out.arrived.append(now)
    return out


def _judged(
    net: Network,
    ms: tuple[Arrivals, float],
    sm: tuple[Arrivals, float],
    senders: dict[str, dict[str, Any]],
) -> CellularRun:
    """The run's arrivals (each with its direction's propagation delay) and their figures."""
    figures = {
        key: direction_figures(arrivals, propagation=delay)
        for key, (arrivals, delay) in (("ms", ms), ("sm", sm))
    }
    return CellularRun(ms[0], sm[0], figures, _link_counts(net), senders)


def _link_counts(net: Network) -> dict[str, dict[str, int]]:
    counts = {}
    for key, link in (("ms", net.link(MASTER, SLAVE)), ("sm", net.link(SLAVE, MASTER))):
        s = link.stats
        counts[key] = {
            "packets": s.packets,
            "delivered": s.delivered,
            "dropped": s.dropped,
            "max_queue": s.max_queue,
        }
    return counts


def run_tdtp(
    ms: str | NetemSpec,
    sm: str | NetemSpec,
    controller: str,
    *,
    duration: float,
    seed: int = 0,
    rate: float = 1000.0,
    config: ConnectionConfig | None = None,
) -> CellularRun:
    """A tdtp session over the two directions (each spec needs a ``trace``; packets are counted with
    IPv4 + UDP headers, so write no ``overhead``): both sides offer a sample every ``1 / rate`` s
    from their establishment for ``duration`` seconds, which is the measured window."""
    net, ms_delay, sm_delay = _network(ms, sm, seed)
    total = duration + DRAIN + 2.0
    cfg = config or ConnectionConfig(controller=controller, min_peer_payload=SAMPLE_SIZE)  # type: ignore[arg-type]
    session = TdtpSession.create(
        net,
        MASTER,
        SLAVE,
        cfg,
        sample_rate=rate,
        payload_size=SAMPLE_SIZE,
        ip_overhead=UDP_IP,
        duration=total,
        bin_width=1.0,
        seed=seed,
        send_jitter=SEND_JITTER,
    )
    # Sampling stops `duration` after each side's establishment (known once it happened).
    net.run(2.0)
    for endpoint in (session.master, session.slave):
        if endpoint.established_at is None:
            raise RuntimeError(f"the session did not open within 2 s ({controller}, seed {seed})")
        endpoint.app_stop = endpoint.established_at + endpoint.app_phase + duration
    net.run(total)
    m0 = session.master.established_at or 0.0
    s0 = (session.slave.established_at or 0.0) + session.slave.app_phase
    ms_arrivals = _arrivals(session.ms, m0, m0 + duration, rate)
    sm_arrivals = _arrivals(session.sm, s0, s0 + duration, rate)
    senders = {}
    for key, endpoint in (("ms", session.master), ("sm", session.slave)):
        stats = endpoint.conn.stats
        senders[key] = {
            "samples_offered": endpoint.samples_offered,
            "data_packets": stats.sent.data_packets,
            "datagrams": stats.sent.datagrams,
            "ack_packets": endpoint.ack_packets,
            "packets_lost": stats.packets_lost,
        }
    return _judged(net, (ms_arrivals, ms_delay), (sm_arrivals, sm_delay), senders)


def run_udp(
    ms: str | NetemSpec,
    sm: str | NetemSpec,
    *,
    duration: float,
    seed: int = 0,
    rate: float = 1000.0,
    start: float = 0.1,
) -> CellularRun:
    """A fixed ``rate`` stream of 100-byte samples each way over UDP (no header, no feedback), both
    from ``start`` for ``duration`` seconds, the slave's at a random phase (``seed``)."""
    net, ms_delay, sm_delay = _network(ms, sm, seed)
    size = SAMPLE_SIZE + UDP_IP
    total = start + duration + DRAIN
    phase = random.Random(seed).random() / rate
    streams = {}
    for key, src, dst, begin in (
        ("ms", MASTER, SLAVE, start),
        ("sm", SLAVE, MASTER, start + phase),
    ):
        streams[key] = CbrSource(
            net,
            src,
            dst,
            rate_bps=size * 8 * rate,
            size=size,
            port=9000 if key == "ms" else 9001,
            periods=((begin, begin + duration - 0.5 / rate),),
            bin_width=1.0,
            duration=total,
            name=f"udp {key}",
        )
    net.run(total)
    ms_arrivals = _arrivals(streams["ms"].recorder, start, start + duration, rate)
    sm_arrivals = _arrivals(streams["sm"].recorder, start + phase, start + phase + duration, rate)
    return _judged(net, (ms_arrivals, ms_delay), (sm_arrivals, sm_delay), {})
