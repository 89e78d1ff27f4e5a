"""Live and final statistics for the command line: per-direction meters, latency, a terminal display."""

from __future__ import annotations

import math
import re
import shutil
import sys
import textwrap
from collections import deque
from dataclasses import dataclass, field
from typing import TextIO

from tdtp.session.stats import ConnectionStats

MAX_LATENCY_SAMPLES = 200_000
"""Latencies kept for the final percentiles (a bounded reservoir: the first ones of a long run)."""


def percentile(sorted_values: list[float], fraction: float) -> float:
    """Nearest-rank percentile of an already sorted list (NaN when empty)."""
    if not sorted_values:
        return math.nan
    rank = min(len(sorted_values) - 1, max(0, math.ceil(fraction * len(sorted_values)) - 1))
    return sorted_values[rank]


@dataclass(slots=True)
class LatencyRecorder:
    """One-way latencies in seconds: all of them (bounded) and those of the current display window."""

    all: list[float] = field(default_factory=list)
    window: deque[float] = field(default_factory=lambda: deque(maxlen=10_000))

    def add(self, latency: float) -> None:
        if len(self.all) < MAX_LATENCY_SAMPLES:
            self.all.append(latency)
        self.window.append(latency)

    def take_window(self) -> list[float]:
        values = sorted(self.window)
        self.window.clear()
        return values

    def summary_ms(self) -> dict[str, float] | None:
        if not self.all:
            return None
        values = sorted(self.all)
        return {
            "p50": round(percentile(values, 0.50) * 1e3, 4),
            "p99": round(percentile(values, 0.99) * 1e3, 4),
            "max": round(values[-1] * 1e3, 4),
        }


def age_text(receiver: ConnectionStats) -> str | None:
    """``"age p50 20.1 ms p99 24.3 ms"``: the receiving end's sample ages so far (PROTOCOL.md 3.6),
    or ``None`` before it has an estimate."""
    if not receiver.samples_delivered or receiver.sample_age_p50 <= 0.0:
        return None
    return f"age p50 {receiver.sample_age_p50 * 1e3:6.2f} ms p99 {receiver.sample_age_p99 * 1e3:6.2f} ms"


@dataclass(slots=True)
class DirectionMeter:
    """Turns cumulative counters into per-interval figures for the live display.

    The counters are a session's: a reconnecting endpoint starts a new session with new counters
    from zero, so the meter starts over from zero whenever it is handed another session's
    statistics (otherwise the first interval after a reconnect would show a negative rate)."""

    label: str
    last_received: int = 0
    last_lost: int = 0
    last_sent: int = 0
    last_reordered: int = 0
    source: ConnectionStats | None = None
    """The statistics the ``last_*`` figures were read from."""

    def line(
        self,
        sender: ConnectionStats,
        received_total: int,
        interval: float,
        latency: list[float] | None,
        note: str | None = None,
        receiver: ConnectionStats | None = None,
        session: str | None = None,
    ) -> str:
        """One line of figures for the last ``interval``; the sample age the ``receiver`` estimates
        and ``note`` (e.g. the watchdog's) are appended. ``session``: there is no session (closed,
        or reconnecting), and this is what the line says instead of a closed link's figures."""
        if sender is not self.source:
            self.source = sender
            self.last_received = self.last_lost = self.last_sent = self.last_reordered = 0
        if session is not None:
            self.last_received = received_total
            self.last_lost = sender.packets_lost
            self.last_sent = sender.sent.data_packets
            self.last_reordered = sender.packets_reordered
            return f"{self.label}  {session}" + (f"  {note}" if note else "")
        received = received_total - self.last_received
        lost = sender.packets_lost - self.last_lost
        sent = sender.sent.data_packets - self.last_sent
        reordered = sender.packets_reordered - self.last_reordered
        self.last_received = received_total
        self.last_lost = sender.packets_lost
        self.last_sent = sender.sent.data_packets
        self.last_reordered = sender.packets_reordered
        allowed = "unlimited" if math.isinf(sender.rate) else f"{sender.rate:8.0f}/s"
        parts = [
            f"{self.label}",
            f"{received / interval:7.0f} pkt/s",
            f"lost {lost:4d} ({(lost / sent * 100) if sent else 0.0:5.2f}%)",
            f"srtt {sender.srtt * 1e3:7.3f} ms",
            f"p {sender.loss_event_rate:6.4f}",
            f"allowed {allowed}",
            f"superseded {sender.samples_superseded:6d}",
        ]
        if reordered:
            parts.insert(3, f"reordered {reordered:4d}")  # late, not lost: apart from the losses
        if sender.rate_limit:
            parts.append(f"limit: {sender.rate_limit}")
        if sender.timestamps:
            # This direction's own queue, from the receiver's send times (PROTOCOL.md 5.13).
            parts.append(f"queue {sender.queue_delay_out * 1e3:5.1f} ms")
        if latency:
            parts.append(
                f"latency p50 {percentile(latency, 0.5) * 1e3:6.3f} ms"
                f" p99 {percentile(latency, 0.99) * 1e3:6.3f} ms"
            )
        age = age_text(receiver) if receiver is not None else None
        if age:
            parts.append(age)
        if note:
            parts.append(note)
        return "  ".join(parts)


def receive_line(
    label: str,
    received_total: int,
    meter: DirectionMeter,
    interval: float,
    latency: LatencyRecorder,
    receiver: ConnectionStats | None = None,
) -> str:
    """A direction seen only from its receiving end (the sender is another process), with the
    sample age the ``receiver`` estimates."""
    received = received_total - meter.last_received
    meter.last_received = received_total
    window = latency.take_window()
    text = f"{label}  {received / interval:7.0f} pkt/s received"
    if window:
        text += (
            f"  latency p50 {percentile(window, 0.5) * 1e3:6.3f} ms"
            f" p99 {percentile(window, 0.99) * 1e3:6.3f} ms"
        )
    if receiver is not None and receiver.timestamps:
        text += f"  queue {receiver.queue_delay_in * 1e3:5.1f} ms"
    age = age_text(receiver) if receiver is not None else None
    if age:
        text += "  " + age
    return text


FIELD_SEPARATOR = "  "
"""Status lines separate their fields with two spaces; a narrow terminal breaks lines there."""
_FIELD_BREAK = re.compile(r"(?<=\S) {2}(?=\S)")
"""Exactly two spaces between two fields; wider runs are padding inside a field (``lost    0``)."""
CONTINUATION = "    "


def fit_to_width(line: str, width: int) -> list[str]:
    """``line`` as terminal rows of at most ``width`` columns, broken between fields (two spaces),
    or between words inside a field wider than a row; continuation rows are indented."""
    if len(line) <= width:
        return [line]
    rows: list[str] = []
    current = ""
    for part in (p for p in _FIELD_BREAK.split(line) if p):
        candidate = part if not current else current + FIELD_SEPARATOR + part
        if len(candidate) <= width:
            current = candidate
            continue
        if current:
            rows.append(current)
        pieces = textwrap.wrap(
            part.strip(),
            width,
            initial_indent=CONTINUATION if rows else "",
            subsequent_indent=CONTINUATION,
        )
        rows.extend(pieces[:-1])
        current = pieces[-1] if pieces else ""
    if current:
        rows.append(current)
    return rows


class LiveDisplay:
    """Prints a block of status lines once per update: redrawn in place on a terminal, appended
    otherwise (a log file or a pipe gets one block per update).

    On a terminal every line is fitted to its width (broken between fields): a line the terminal
    wrapped by itself would take two rows, and redrawing the block in place would garble it.
    """

    def __init__(self, stream: TextIO | None = None, *, width: int | None = None) -> None:
        self._stream = stream if stream is not None else sys.stdout
        self._interactive = self._stream.isatty()
        self._width = width
        self._drawn = 0

    def _rows(self, lines: list[str]) -> list[str]:
        if not self._interactive and self._width is None:
            return lines
        width = self._width if self._width is not None else shutil.get_terminal_size().columns
        width = max(width, 20)
        return [row for line in lines for row in fit_to_width(line, width)]

    def update(self, lines: list[str]) -> None:
        stream = self._stream
        rows = self._rows(lines)
        if self._interactive and self._drawn:
            stream.write(f"\x1b[{self._drawn}F")  # cursor to the start of the block
        for row in rows:
            stream.write(("\x1b[2K" if self._interactive else "") + row + "\n")
        self._drawn = len(rows)
        stream.flush()

    def message(self, text: str) -> None:
        """A line that stays (printed below the block, which is then redrawn beneath it)."""
        for row in self._rows([text]):
            self._stream.write(row + "\n")
        self._drawn = 0
        self._stream.flush()
