"""Each path's delay in our own direction, from the clock the peer's MP_REPORTs carry (PROTOCOL.md 5.11).

A path's round trip is the sum of its two directions, and on a cellular path they fail apart: a
queue on the way back (the reports' way) lifts the round trip while our copies pass freely. Judged
from round trips, a path's controller then holds back copies the path would carry. So every
MP_REPORT carries the reporter's clock when it left, and the report names a packet of ours and how
long before that (HOLD) it arrived. With ``T`` that clock (unwrapped to seconds by
:class:`~tdtp.session.one_way.PeerClock`, as send timestamps are), ``h`` the hold and ``t_s`` our
send time of the named packet,

``T - h - t_s = d_out + theta``

the packet's one-way delay plus the (unknown, constant) offset of the two clocks. Its smallest over
:data:`~tdtp.session.one_way.BASE_WINDOW` is the path's base in our direction plus that offset, and
the difference is our direction's queue on that path alone (LEDBAT's base delay, as the
single-path stamps of section 5.13). The path's controller gets every sample through
``on_one_way_delay`` and paces, windows and drains on it as a single-path session does on its
stamps; ``T - h`` is also the peer's clock of arrival, which times what the path delivered.

**Bad input.** A real sample lies at most the path's smallest round trip below the base (plus a
tolerance for HOLD's rounding and drift) and its queue is at most the round trip it came with.
Others are not used (``MultipathStats.report_clocks_rejected``); after
:data:`~tdtp.session.one_way.RESET_AFTER` in a row the base starts over (the peer's clock jumped).
Keyed, reports are authenticated; unkeyed, a forger who read the nonce can mislead a path's
controller as it can with the report's other fields (section 5.11), and adaptive's choice of its
lone path (which compares the paths by these samples), within the bounds above: a path made to look
at most its smallest round trip faster, which the stall test then judges like any other.
"""

from __future__ import annotations

import math
from typing import Final

from tdtp.session.one_way import BASE_WINDOW, RESET_AFTER, TOLERANCE, WindowMin

QUEUE_GAIN: Final = 0.125
"""Gain of the moving average of a path's outbound queue (what its stats show)."""


class PathDelay:
    """One path's outbound delay samples: their base, the queue above it, and the bounds a real
    sample respects."""

    __slots__ = ("_base", "_rejected_run", "at", "queue", "rejected", "samples")

    def __init__(self) -> None:
        self._base = WindowMin(BASE_WINDOW)
        self._rejected_run = 0
        self.queue = 0.0
        """Our copies' queue on their way along the path, seconds (moving average)."""
        self.samples = 0
        self.rejected = 0
        self.at = -math.inf
        """When the last sample was used."""

    def outbound(self, now: float, fresh: float) -> float:
        """Our copies' recent delay along the path plus the clocks' offset (the base plus the
        queue above it), if a sample was used within ``fresh`` seconds; ``inf`` otherwise. The
        offset is the same on every path (one peer clock), so the paths compare by it."""
        base = self._base.value
        if now - self.at > fresh or base == math.inf:
            return math.inf
        return base + self.queue

    @property
    def base(self) -> float:
        """The smallest sample of the base window (``inf`` before the first)."""
        return self._base.value

    def take(self, delay: float, echo: float, min_rtt: float, now: float) -> bool:
        """A sample ``delay`` (one-way delay plus the clocks' offset) from a report whose round
        trip was ``echo``, on a path whose smallest round trip is ``min_rtt``: whether it is used
        (within the bounds a real one respects)."""
        base = self._base.value
        if base < math.inf:
            margin = (min_rtt if min_rtt > 0.0 else 0.0) + TOLERANCE
            if delay < base - margin or delay - base > echo + TOLERANCE:
                self.rejected += 1
                self._rejected_run += 1
                if self._rejected_run >= RESET_AFTER:
                    self._rejected_run = 0
                    self._base.reset()
                return False
        self._rejected_run = 0
        self._base.add(now, delay)
        self.at = now
        self.samples += 1
        self.queue += QUEUE_GAIN * (delay - self._base.value - self.queue)
        return True
