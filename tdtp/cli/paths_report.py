"""What ``--json`` says of continuity and of a multipath session's paths, per direction.

* ``dropouts_100ms``: 100 ms windows of the receiving application's timeline, from the first sample
  on, in which no sample arrived (a robot's watchdog would have tripped), counted as the run goes,
  with no list of arrivals kept;
* ``duplicates``: copies of the peer's samples the receiver dropped because an earlier copy had been
  taken (a multipath session; a network that duplicates in any session);
* ``paths``: the sender's paths, each ``{id, sent, first_delivered, srtt_ms, state, loss,
  one_way_delay_ms, one_way_queue_ms}`` (what it sent on the path, how many of those were the first
  copy to reach the peer, by the peer's reports; the last, the queue in our direction alone, from
  the clocks of those reports).
"""

from __future__ import annotations

import math
from typing import Any

from tdtp.aio.endpoint import Endpoint
from tdtp.session.stats import ConnectionStats

WINDOW = 0.100
"""A window of the receiver's timeline this long without a sample is a dropout."""


class DropoutCounter:
    """Counts the 100 ms windows without an arrival, from the first arrival to the last reading."""

    __slots__ = ("_first", "_last", "dropouts")

    def __init__(self) -> None:
        self._first = math.nan
        self._last = -1
        self.dropouts = 0

    def arrived(self, at: float) -> None:
        if self._first != self._first:  # (nan: the first arrival)
            self._first = at
        window = int((at - self._first) / WINDOW)
        if window > self._last + 1:
            self.dropouts += window - self._last - 1
        if window > self._last:
            self._last = window

    def until(self, end: float) -> int | None:
        """Dropouts up to ``end`` (the windows after the last arrival included); ``None`` before
        any arrival."""
        if self._first != self._first:
            return None
        window = int((end - self._first) / WINDOW)
        return self.dropouts + max(0, window - self._last - 1)


def duplicates(receiver: ConnectionStats | None) -> int | None:
    return None if receiver is None else receiver.drops.get("duplicate", 0)


def paths_view(sender: Endpoint | None) -> list[dict[str, Any]] | None:
    """The sender's paths (``None`` for a single-path session, or where this is not the sender)."""
    if sender is None or sender.connection.multipath is None:
        return None
    return [
        {
            "id": path.path_id,
            "sent": path.sent,
            "first_delivered": path.first_delivered,
            "srtt_ms": round(path.srtt * 1e3, 3),
            "state": path.state,
            "loss": round(path.loss, 4),
            "one_way_delay_ms": round(path.one_way_delay * 1e3, 3),
            "one_way_queue_ms": round(path.one_way_queue * 1e3, 3),
        }
        for path in sender.paths
    ]


def continuity(
    *,
    sender: Endpoint | None,
    receiver: ConnectionStats | None,
    counter: DropoutCounter | None,
    end: float,
) -> dict[str, Any]:
    """The entries a direction's report gets from this module."""
    return {
        "dropouts_100ms": None if counter is None else counter.until(end),
        "duplicates": duplicates(receiver),
        "paths": paths_view(sender),
    }
