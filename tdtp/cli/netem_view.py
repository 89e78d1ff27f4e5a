"""What the emulated links of ``tdtp demo`` hold: a line for the live display and a report for ``--json``.

The truth the controllers estimate: with a ``trace``, how many bytes wait in each direction's queue and
how long the newest datagram will wait there (its departure is known on arrival); without one, the
datagrams in flight; and what each link dropped.
"""

from __future__ import annotations

from typing import Any, Protocol

from tdtp.aio.timer import monotonic
from tdtp.netem import NetemLink


class _Impaired(Protocol):
    @property
    def netem_link(self) -> NetemLink | None: ...


def netem_lines(master: _Impaired, slave: _Impaired) -> list[str]:
    """``["emulated  M->S queue 12.3 kB, 95 ms, dropped 0 ...   S->M ..."]``, or none without netem."""
    parts = [
        f"{label} {_text(link)}"
        for label, link in (("M->S", master.netem_link), ("S->M", slave.netem_link))
        if link is not None
    ]
    return ["emulated  " + "   ".join(parts)] if parts else []


def _text(link: NetemLink) -> str:
    stats = link.stats
    queue = link.trace_queue
    if queue is not None:
        now = monotonic()
        _, size = queue.queued(now)
        wait = max(0.0, queue.last_departure - now) * 1e3
        held = f"queue {size / 1000:.1f} kB, {wait:.0f} ms"
    else:
        held = f"in flight {link.in_flight}"
    return f"{held}, dropped {stats.queue_dropped}, lost {stats.lost}"


def netem_report(endpoint: _Impaired) -> dict[str, Any] | None:
    """The emulated link's counters (and its trace queue at the end), or ``None`` without netem."""
    link = endpoint.netem_link
    if link is None:
        return None
    report: dict[str, Any] = {**link.stats.as_dict(), "pending": link.pending}
    queue = link.trace_queue
    if queue is not None:
        count, size = queue.queued(monotonic())
        report["trace_queue_at_end"] = {"datagrams": count, "bytes": size}
    return report
