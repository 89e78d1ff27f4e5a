"""Per-flow measurements in time bins, and the summaries scenarios report.

A :class:`FlowRecorder` counts one flow (one direction of a TDTP session, a TCP connection, a UDP
source): what its sender put on the wire, what the network dropped (charged to the bin the packet was
*sent* in, so a bin's loss ratio is a fraction of that bin's packets), what arrived and how late. In
virtual time every clock is the same clock, so one-way delays are exact.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

from tdtp.errors import InvalidArgumentError
from tdtp.sim.engine import Packet

__all__ = [
    "FlowRecorder",
    "FlowSummary",
    "jain_index",
    "mean",
    "percentile",
]


def mean(values: Sequence[float]) -> float:
    return math.fsum(values) / len(values) if values else math.nan


def percentile(values: Sequence[float], q: float) -> float:
    """The ``q``-th percentile (0-100) by linear interpolation between order statistics."""
    if not values:
        return math.nan
    ordered = sorted(values)
    pos = (len(ordered) - 1) * q / 100.0
    low = math.floor(pos)
    high = min(low + 1, len(ordered) - 1)
    return ordered[low] + (ordered[high] - ordered[low]) * (pos - low)


def jain_index(values: Sequence[float]) -> float:
    """Jain's fairness index ``(sum x)^2 / (n sum x^2)``: 1 when all are equal, 1/n when one has all."""
    if not values:
        return math.nan
    total = math.fsum(values)
    squares = math.fsum(v * v for v in values)
    if squares == 0.0:
        return 1.0
    return total * total / (len(values) * squares)


def _finite(value: float) -> float | None:
    """``None`` for NaN/inf, so that JSON stays valid."""
    return value if math.isfinite(value) else None


@dataclass(frozen=True, slots=True)
class FlowSummary:
    """One flow over a time window. Rates are means over the window; delays over its deliveries."""

    name: str
    start: float
    end: float
    seconds: float
    """Length of the window(s) summarised."""
    sent_packets: int
    delivered_packets: int
    dropped_packets: int
    goodput_kbps: float
    """Application bytes delivered (TDTP payload, TCP segment data), kbit/s."""
    throughput_kbps: float
    """Delivered packets' bytes on the wire (IP headers included), kbit/s."""
    delivered_pps: float
    """Packets (samples, segments) delivered per second."""
    sent_kbps: float
    """Bytes the sender put on the wire, kbit/s."""
    loss_ratio: float
    """Packets the network dropped / packets sent, over packets sent in the window."""
    mean_delay: float
    """One-way delay, send to arrival, seconds (NaN when nothing arrived)."""
    p95_delay: float
    mean_age: float
    """TDTP only: sample generation to delivery (includes the wait for the pacer)."""
    p95_age: float

    def to_dict(self) -> dict[str, Any]:
        """The summary as plain data, non-finite figures as ``None`` (for JSON)."""
        data = asdict(self)
        for key, value in data.items():
            if isinstance(value, float):
                data[key] = _finite(value)
        return data


class FlowRecorder:
    """Time-binned counters of one flow. It is also the :class:`~tdtp.sim.engine.DropListener` of the
    packets it sends."""

    def __init__(self, name: str, *, bin_width: float, duration: float) -> None:
        if not bin_width > 0:
            raise InvalidArgumentError(f"bin_width must be positive, got {bin_width!r}")
        self.name = name
        self.bin_width = bin_width
        self.duration = duration
        n = max(1, math.ceil(duration / bin_width - 1e-9))
        self.nbins = n
        self.sent_packets = [0] * n
        self.sent_bytes = [0] * n
        self.dropped_packets = [0] * n
        self.delivered_packets = [0] * n
        self.delivered_bytes = [0] * n
        """Application bytes."""
        self.delivered_wire_bytes = [0] * n
        self.delay_sum = [0.0] * n
        self.delay_times: list[float] = []
        self.delays: list[float] = []
        self.ages: list[float] = []

    def _bin(self, t: float) -> int:
        index = int(t / self.bin_width)
        return index if index < self.nbins else self.nbins - 1

    # -- recording ----------------------------------------------------------------------------

    def on_sent(self, now: float, wire_bytes: int) -> None:
        """A packet of ``wire_bytes`` left at ``now``."""
        index = self._bin(now)
        self.sent_packets[index] += 1
        self.sent_bytes[index] += wire_bytes

    def on_drop(self, packet: Packet, now: float) -> None:
        """``packet`` was dropped (counted in the bin of its send time)."""
        self.dropped_packets[self._bin(packet.sent_at)] += 1

    def on_delivered(
        self,
        now: float,
        sent_at: float,
        app_bytes: int,
        wire_bytes: int,
        age: float | None = None,
    ) -> None:
        """A packet sent at ``sent_at`` was delivered at ``now``: its payload and wire bytes."""
        index = self._bin(now)
        self.delivered_packets[index] += 1
        self.delivered_bytes[index] += app_bytes
        self.delivered_wire_bytes[index] += wire_bytes
        delay = now - sent_at
        self.delay_sum[index] += delay
        self.delay_times.append(now)
        self.delays.append(delay)
        if age is not None:
            self.ages.append(age)

    # -- reading ------------------------------------------------------------------------------

    def bin_times(self) -> list[float]:
        """The middle of every bin."""
        return [(i + 0.5) * self.bin_width for i in range(self.nbins)]

    def series(self) -> dict[str, list[float | None]]:
        """Per-bin series: goodput and throughput (kbit/s), delivered packets/s, loss ratio, mean delay."""
        w = self.bin_width
        goodput: list[float | None] = [b * 8 / w / 1000 for b in self.delivered_bytes]
        throughput: list[float | None] = [b * 8 / w / 1000 for b in self.delivered_wire_bytes]
        pps: list[float | None] = [n / w for n in self.delivered_packets]
        loss: list[float | None] = [
            (d / s if s else None)
            for d, s in zip(self.dropped_packets, self.sent_packets, strict=True)
        ]
        delay: list[float | None] = [
            (total / n if n else None)
            for total, n in zip(self.delay_sum, self.delivered_packets, strict=True)
        ]
        return {
            "time": list(self.bin_times()),
            "goodput_kbps": goodput,
            "throughput_kbps": throughput,
            "delivered_pps": pps,
            "loss_ratio": loss,
            "mean_delay": delay,
        }

    def summary(
        self,
        start: float = 0.0,
        end: float | None = None,
        *,
        windows: Sequence[tuple[float, float]] | None = None,
    ) -> FlowSummary:
        """Totals and means over ``[start, end)``, or over the union of ``windows`` (bin-aligned)."""
        spans = (
            list(windows)
            if windows is not None
            else [(start, self.duration if end is None else end)]
        )
        w = self.bin_width
        bins: list[int] = []
        for a, b in spans:
            first = max(0, round(a / w))
            last = min(self.nbins, max(first, round(min(b, self.duration) / w)))
            bins.extend(range(first, last))
        chosen = sorted(set(bins))
        span = len(chosen) * w
        inside = set(chosen)
        sent = sum(self.sent_packets[i] for i in chosen)
        dropped = sum(self.dropped_packets[i] for i in chosen)
        delivered = sum(self.delivered_packets[i] for i in chosen)
        keep = [self._bin(t) in inside for t in self.delay_times]
        delays = [d for d, k in zip(self.delays, keep, strict=True) if k]
        ages = (
            [a for a, k in zip(self.ages, keep, strict=True) if k]
            if len(self.ages) == len(self.delays)
            else []
        )

        def rate(values: list[int]) -> float:
            return sum(values[i] for i in chosen) * 8 / span / 1000 if span > 0 else math.nan

        return FlowSummary(
            name=self.name,
            start=chosen[0] * w if chosen else math.nan,
            end=(chosen[-1] + 1) * w if chosen else math.nan,
            seconds=span,
            sent_packets=sent,
            delivered_packets=delivered,
            dropped_packets=dropped,
            goodput_kbps=rate(self.delivered_bytes),
            throughput_kbps=rate(self.delivered_wire_bytes),
            delivered_pps=delivered / span if span > 0 else math.nan,
            sent_kbps=rate(self.sent_bytes),
            loss_ratio=dropped / sent if sent else math.nan,
            mean_delay=mean(delays),
            p95_delay=percentile(delays, 95),
            mean_age=mean(ages),
            p95_age=percentile(ages, 95),
        )

    def rate_series(self, smoothing_bins: int = 1) -> list[float]:
        """Goodput per bin in kbit/s, optionally a moving average over ``smoothing_bins`` bins."""
        values = [b * 8 / self.bin_width / 1000 for b in self.delivered_bytes]
        if smoothing_bins <= 1:
            return values
        out = []
        acc = 0.0
        for i, v in enumerate(values):
            acc += v
            if i >= smoothing_bins:
                acc -= values[i - smoothing_bins]
            out.append(acc / min(i + 1, smoothing_bins))
        return out
