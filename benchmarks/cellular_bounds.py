"""What a recorded cellular trace leaves any reacting sender: the lower bound under issue 32's delay bars.

``python benchmarks/cellular_bounds.py [--trace verizon tmobile att] [--way ms sm] [--duration S]``

Two figures per trace direction, computed from the trace alone (no controller, no simulator), each over
the five offsets of ``benchmarks/cellular.py`` (the same 20 ms each way and 1 kHz of 100-byte samples,
133 bytes on the wire with the transport header):

* **unavoidable late samples**: a sender learns that its direction stopped delivering one feedback
  lag ``L`` after the link's last delivery at the earliest (the last packet's 20 ms there, the peer's
  stamp's 20 ms back). The samples it generated within ``L`` of the start of a gap wait for the gap's
  end: those that then arrive more than 60 ms (150 ms) after their generation are late whatever the
  sender does, unless it stopped *before* it could know (a forecast).
* **the reactive frontier**: a sender with exact, noise-free feedback and latest-value samples (a
  sample that cannot leave is replaced by the next, as tdtp's sender does) that sends every sample
  while the peer keeps up and stops (one probe per 50 ms) as soon as a packet of its own is ``S`` ms
  overdue at the peer, seen 20 ms later. Its share of what the trace allowed, p95 and p99 for each
  ``S``: how much share a reacting sender gives up for shorter tails on this link. ``S`` = 1000 is a
  sender that never stops (the ``fixed`` row of ``cellular.py``, which it reproduces within a few ms).

The link model is Mahimahi's (byte-counted 1500-byte opportunities, a FIFO, unbounded here: the
150 kB queue never fills at these rates outside the fixed row).
"""

from __future__ import annotations

import argparse
import bisect
import itertools
import math
import statistics
from pathlib import Path

from cellular import TRACES, find_traces, spec

from tdtp.netem import OPPORTUNITY_BYTES, Trace, parse_netem
from tdtp.sim.scenarios import cellular as scenario

WIRE = 133
"""Bytes of one sample on the wire: 100 of payload, tdtp's 5-byte header, IPv4 + UDP."""
OFFSETS = (0.0, 20.0, 40.0, 60.0, 80.0)
LAGS_MS = (40, 50)
STALLS_MS = (10, 20, 30, 60, 1000)
PROBE_MS = 50
BARS = (0.060, 0.150)


def trace_of(text: str) -> tuple[Trace, float, float]:
    """The direction's trace, its offset (ms) and its propagation delay (ms)."""
    parsed = parse_netem(text)
    assert parsed.trace is not None and parsed.delay is not None  # spec() writes both
    return parsed.trace.trace, parsed.trace.offset * 1e3, parsed.delay.delay * 1e3


def unavoidable(text: str, lag_ms: float, duration: float, bar: float) -> int:
    """Samples generated within ``lag_ms`` of a gap's start that arrive later than ``bar`` s."""
    trace, offset, propagation = trace_of(text)
    times: list[float] = []
    index = trace.first_after(offset)
    while (t := trace.time_ms(index) - offset) <= duration * 1e3 + 2000:
        times.append(t)
        index += 1
    late = 0
    for a, b in itertools.pairwise(times):
        for k in range(math.floor(a) + 1, math.floor(min(b, a + lag_ms)) + 1):
            if k < duration * 1e3 and b - k + propagation > bar * 1e3:
                late += 1
    return late


def frontier(text: str, stall_ms: float, duration: float) -> tuple[float, float, float]:
    """The reactive sender of the module's docstring: (share %, p95 ms, p99 ms)."""
    trace, offset, propagation = trace_of(text)
    allowed = scenario.allowed(text, start=0.0, duration=duration)
    index, left = trace.first_after(offset), OPPORTUNITY_BYTES
    sent: list[int] = []  # send times (ms) of the packets sent, in order
    arrivals: list[float] = []  # their arrival times at the peer (FIFO: increasing)
    delays: list[float] = []
    last_probe = -math.inf
    for t in range(round(duration * 1e3)):
        known = t - propagation  # the peer's state the sender knows of
        delivered = bisect.bisect_right(arrivals, known)
        stalled = delivered < len(sent) and sent[delivered] + propagation + stall_ms < known
        if stalled and t - last_probe < PROBE_MS:
            continue  # superseded by the next sample
        if stalled:
            last_probe = t
        i, room = index, left
        if trace.time_ms(i) < t + offset:
            i, room = trace.first_after(t + offset), OPPORTUNITY_BYTES
        size = WIRE
        while size > room:
            size -= room
            i += 1
            room = OPPORTUNITY_BYTES
        index, left = i, room - size
        arrival = trace.time_ms(i) - offset + propagation
        sent.append(t)
        arrivals.append(arrival)
        delays.append(arrival - t)
    delays.sort()
    n = len(delays)
    return 100.0 * n / allowed, delays[math.ceil(0.95 * n) - 1], delays[math.ceil(0.99 * n) - 1]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--trace", nargs="+", choices=sorted(TRACES), default=list(TRACES))
    p.add_argument("--way", nargs="+", choices=("ms", "sm"), default=["ms", "sm"])
    p.add_argument("--duration", type=float, default=60.0, help="seconds per run (60)")
    p.add_argument("--traces", type=Path, default=find_traces(), help="folder of the traces")
    args = p.parse_args()
    if args.traces is None or not args.traces.is_dir():
        p.error("--traces: give the folder holding the recorded traces (../shared/traces)")
    print(
        "Medians over offsets", ", ".join(f"{o:g}" for o in OFFSETS), "s; per offset in brackets."
    )
    for name in args.trace:
        for way in args.way:
            texts = [spec(args.traces, name, way, 150_000, o, 0) for o in OFFSETS]
            label = f"{name} {'M->S' if way == 'ms' else 'S->M'}"
            for lag in LAGS_MS:
                counts = [[unavoidable(t, lag, args.duration, bar) for t in texts] for bar in BARS]
                print(
                    f"{label}: late whatever a sender with a {lag} ms feedback lag does, > 60 ms: "
                    f"{statistics.median(counts[0]):.0f} {counts[0]}, > 150 ms: "
                    f"{statistics.median(counts[1]):.0f} {counts[1]}"
                )
            for stall in STALLS_MS:
                rows = [frontier(t, stall, args.duration) for t in texts]
                med = [statistics.median(r[k] for r in rows) for k in range(3)]
                each = " ".join(f"{s:.1f}/{a:.0f}/{b:.0f}" for s, a, b in rows)
                print(
                    f"{label}: reactive, stop {stall} ms overdue: share {med[0]:.1f} %, "
                    f"p95 {med[1]:.0f} ms, p99 {med[2]:.0f} ms [{each}]"
                )


if __name__ == "__main__":
    main()
