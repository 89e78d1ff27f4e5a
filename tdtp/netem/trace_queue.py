"""A link whose capacity follows a recorded trace: a DropTail queue served at the trace's opportunities.

This is Mahimahi's ``mm-link`` (``src/frontend/link_queue.cc``, with its ``droptail`` queue) in
continuous time and sans-IO. Each delivery opportunity of the :class:`~tdtp.netem.trace_file.Trace`
carries :data:`~tdtp.netem.trace_file.OPPORTUNITY_BYTES` (1500) bytes, counted in bytes:

* the datagrams waiting when an opportunity comes share its 1500 bytes in order, so fourteen
  100-byte datagrams leave at one opportunity;
* a datagram that does not fit in what is left takes the rest and carries on at the next
  opportunity: it leaves at the opportunity that carries its last byte (a 1500-byte datagram behind
  a 100-byte one leaves at the second opportunity, and 100 bytes of that one are used);
* bytes of an opportunity that no waiting datagram uses are **lost**: they do not carry over to a
  datagram that arrives later, not even within the same millisecond. Mahimahi does the same (its
  ``rationalize()`` burns every opportunity up to now before an arriving packet is queued), and so
  does a real radio link, whose grant goes unused when the buffer is empty;
* an opportunity at the very instant a datagram arrives is gone already (Mahimahi's order again): the
  datagram waits for a later one.

The queue is FIFO, so a datagram's departure depends only on the datagrams before it and on the
trace: :meth:`TraceQueue.offer` computes it when the datagram arrives, like netem's rate rule, and the
caller schedules it. The cursor only moves forward, and when the link has been idle it jumps to the
next opportunity with one binary search, so a datagram costs O(1) amortised, whatever the trace's
length.

**DropTail**, as Mahimahi's ``droptail`` queue: a datagram is dropped on arrival when the queue would
then hold more than ``limit`` datagrams, or (with ``limit_bytes``) more than ``limit_bytes`` bytes.
The queue holds the datagrams that no opportunity has started to serve yet; the one being served,
partly sent, no longer counts. Sizes are the datagram's bytes plus ``overhead`` (the headers the link
would also carry), both for the opportunities and for ``limit_bytes``.

The trace's clock starts at ``origin`` (the first ``now`` seen, unless given), at ``offset`` seconds
into the trace.
"""

from __future__ import annotations

import math
from collections import deque
from typing import TYPE_CHECKING

from tdtp.errors import InvalidArgumentError
from tdtp.netem.trace_file import OPPORTUNITY_BYTES, Trace

if TYPE_CHECKING:
    from tdtp.netem.spec import NetemSpec

__all__ = ["TraceQueue"]


class TraceQueue:
    """The departure time of each datagram offered to a trace-driven DropTail link, or a drop."""

    __slots__ = (
        "_bytes",
        "_index",
        "_index_time",
        "_left",
        "_not_before",
        "_offset_ms",
        "_trace",
        "_waiting",
        "last_departure",
        "limit",
        "limit_bytes",
        "origin",
        "overhead",
    )

    def __init__(
        self,
        trace: Trace,
        *,
        offset: float = 0.0,
        overhead: int = 0,
        limit: int,
        limit_bytes: int | None = None,
        origin: float | None = None,
        not_before: float = -math.inf,
    ) -> None:
        if not (math.isfinite(offset) and offset >= 0):
            raise InvalidArgumentError(
                f"offset must be a non-negative time in seconds, got {offset!r}"
            )
        self._trace = trace
        self._offset_ms = offset * 1000.0
        self.overhead = overhead
        self.limit = limit
        self.limit_bytes = limit_bytes
        self.origin = origin
        """When the trace's clock started (the first ``now`` offered, unless given)."""
        self._not_before = not_before
        """Departures never come before this: a queue taking over from another stays FIFO."""
        self._index = -1  # the opportunity the last datagram finished in (-1: none yet)
        self._index_time = -math.inf
        self._left = 0  # its bytes not used yet
        self._waiting: deque[tuple[float, int]] = deque()  # (start of service, size), FIFO
        self._bytes = 0
        self.last_departure = -math.inf
        """Departure of the latest datagram accepted."""

    @classmethod
    def of(
        cls, spec: NetemSpec, *, origin: float | None = None, not_before: float = -math.inf
    ) -> TraceQueue:
        """The queue of ``spec``'s trace (its offset and overhead), sized by its ``limit`` or
        ``limit_bytes``."""
        trace = spec.trace
        if trace is None:
            raise InvalidArgumentError(f"a trace queue needs a spec with a trace, got {spec}")
        return cls(
            trace.trace,
            offset=trace.offset,
            overhead=trace.overhead,
            limit=spec.limit,
            limit_bytes=spec.limit_bytes,
            origin=origin,
            not_before=not_before,
        )

    @property
    def trace(self) -> Trace:
        """The recorded trace whose delivery opportunities serve this queue."""
        return self._trace

    def queued(self, now: float) -> tuple[int, int]:
        """Datagrams and bytes waiting at ``now`` (none of their bytes served yet); a look that
        changes nothing, for a display."""
        count, size = len(self._waiting), self._bytes
        for start, wire in self._waiting:
            if start > now:
                break
            count -= 1
            size -= wire
        return count, size

    def opportunity_time(self, index: int) -> float:
        """When the ``index``-th opportunity since the trace's start comes, on the caller's clock."""
        origin = self.origin if self.origin is not None else 0.0
        return origin + (self._trace.time_ms(index) - self._offset_ms) / 1000.0

    def offer(self, now: float, size: int) -> float | None:
        """A datagram of ``size`` bytes arrives at ``now``: its departure time, or ``None`` when the
        queue is full (a drop). ``now`` must not go backwards between calls."""
        if self.origin is None:
            self.origin = now
        waiting = self._waiting
        while waiting and waiting[0][0] <= now:  # their service has begun: out of the queue
            self._bytes -= waiting.popleft()[1]
        wire = size + self.overhead
        if wire < 0:
            wire = 0
        if self.limit_bytes is not None:
            if self._bytes + wire > self.limit_bytes:
                return None
        elif len(waiting) >= self.limit:
            return None
        current, left = self._index_time, self._left
        if current > now:  # the datagram before us is still waiting: we follow it
            if left > 0 and wire <= left:  # share the opportunity it finished in
                self._left = left - wire
                return self._accept(current, wire, current)
            need = wire - left
            index = self._index + 1
            start = current if left > 0 else None
        else:
            need = wire
            index = self._first_after(max(now, self._not_before))
            start = None
        extra = (need - 1) // OPPORTUNITY_BYTES if need > 0 else 0  # more than one opportunity
        first = self.opportunity_time(index)
        departure = first if not extra else self.opportunity_time(index + extra)
        self._index = index + extra
        self._index_time = departure
        self._left = (extra + 1) * OPPORTUNITY_BYTES - need
        return self._accept(first if start is None else start, wire, departure)

    def _accept(self, start: float, wire: int, departure: float) -> float:
        self._waiting.append((start, wire))
        self._bytes += wire
        self.last_departure = departure
        return departure

    def _first_after(self, now: float) -> int:
        """The first opportunity strictly after ``now`` and after the last one used."""
        origin = self.origin if self.origin is not None else 0.0
        ms = max(0.0, (now - origin) * 1000.0 + self._offset_ms)
        index = max(self._trace.first_after(ms), self._index + 1)
        while self.opportunity_time(index) <= now:  # float rounding at a boundary
            index += 1
        return index
