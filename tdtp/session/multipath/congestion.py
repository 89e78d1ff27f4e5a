"""Congestion control per path for a multipath session's copies, coupled (docs/CONTROL.md 11).

A single-path session's rate controller (``teleop`` by default) cannot run a multipath session: the
acknowledgement of a sample comes from whichever copy arrived first, so its round trips mix the
paths, and when the best path fails the next one's longer round trip reads as a queue that never
drains (measured: a 60 ms path failing onto a 90 ms one took the sample rate from 1000/s to 270/s in
1.5 s). So a multipath session replaces it with :class:`MultipathController`, which lets a sample
leave when at least one usable path's pacer allows a copy, and each path has a :class:`PathPacer`
of its own, fed by that path's MP_REPORTs (the copies that arrived, those that did not, the path's
own round trip), which decides whether a copy may go on the path now:

* **Start.** A path starts unpaced: the application's loop sets the pace (a 1 kHz loop is not held
  back, as ``teleop`` starts at 1000/s), and the first congestion gives it a rate.
* **Decrease, per path.** Once per interval (the path's smoothed RTT, at least two report intervals),
  a queue above ``target_delay`` (the interval's lowest RTT over the path's lowest), or a loss while
  the queue is above half of it, sets the path's rate to 0.85 times what it delivered in the interval
  and marks it congested for the interval.
* **Increase, coupled.** A paced path's rate grows by ``GROWTH`` per interval times its share of the
  paths' summed rates, so the copies together grow no faster than one flow would (RFC 6356's coupled
  increase, in its simplest equal-RTT form). Once it allows twice what is offered to it, the path is
  unpaced again.
* **At most one copy into congestion.** A sample goes on every path the scheduler names whose pacer
  allows it, but on only one *congested* path (the best), and always on at least one path (the best
  that allows it, else the best): on a bottleneck the paths share, which congests them all, the
  session then puts one paced flow, never several copies. On disjoint paths a congested one carries
  its copies at its own rate while the others carry theirs.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Final

from tdtp.config import MultipathConfig
from tdtp.control.base import NO_LIMIT, PacingSchedule, RateController
from tdtp.control.send_meter import SendMeter

DECREASE: Final = 0.85
"""A congested path's rate becomes this times what it delivered in the interval (GCC's factor)."""
GROWTH: Final = 0.25
"""A congested path grows by this fraction per interval, times its share of the summed rates."""
HEADROOM: Final = 2.0
"""A path allowing this many times the rate copies are offered to it is unpaced again."""
MIN_RATE: Final = 4.0
"""Copies per second a congested path always allows: it keeps reporting."""


class Coupling:
    """The session's path pacers, for the coupled increase."""

    __slots__ = ("pacers",)

    def __init__(self) -> None:
        self.pacers: list[PathPacer] = []

    def total(self) -> float:
        """The summed rates of the paced paths (an unpaced one counts its offered rate)."""
        total = 0.0
        for pacer in self.pacers:
            total += pacer.rate if pacer.rate < math.inf else pacer.offered
        return total


class PathPacer:
    """One path's allowance for copies: unpaced until congestion, then a paced, coupled rate."""

    __slots__ = (
        "_coupling",
        "_delivered",
        "_interval_min",
        "_interval_start",
        "_lost",
        "_meter",
        "_report_interval",
        "_schedule",
        "_target",
        "congested_until",
        "rate",
    )

    def __init__(self, config: MultipathConfig, coupling: Coupling) -> None:
        self.rate = math.inf
        """Copies per second the path allows (``inf``: unpaced, the application sets the pace)."""
        self.congested_until = -math.inf
        self._coupling = coupling
        self._schedule = PacingSchedule()
        self._meter = SendMeter()
        self._target = config.target_delay
        self._report_interval = config.report_interval
        self._interval_start: float | None = None
        self._interval_min = math.inf
        self._delivered = 0
        self._lost = 0
        coupling.pacers.append(self)

    @property
    def offered(self) -> float:
        """Copies per second offered to the path lately."""
        rate = self._meter.send_rate()
        return rate if rate < math.inf else 0.0

    def allows(self, now: float) -> bool:
        """Whether a copy may go on the path now (asked once per sample the scheduler offers it)."""
        self._meter.on_departure(now, False)
        return self.rate == math.inf or now >= self._schedule.next_departure

    @property
    def next_departure(self) -> float:
        """When the path allows its next copy (:data:`NO_LIMIT` while unpaced)."""
        return NO_LIMIT if self.rate == math.inf else self._schedule.next_departure

    def congested(self, now: float) -> bool:
        return now < self.congested_until

    def on_sent(self, now: float) -> None:
        self._schedule.on_departure(now, self.rate)

    def reset(self) -> None:
        """The path came back from an outage: unpaced, a fresh interval (its losses in the outage
        were no congestion)."""
        self.rate = math.inf
        self.congested_until = -math.inf
        self._schedule.reset()
        self._interval_start = None
        self._interval_min = math.inf
        self._delivered = 0
        self._lost = 0

    def detach(self) -> None:
        """The path is gone: it no longer counts in the coupled sum."""
        pacers = self._coupling.pacers
        if self in pacers:
            pacers.remove(self)

    def on_feedback(
        self,
        now: float,
        delivered: int,
        lost: int,
        rtt_sample: float | None,
        srtt: float,
        min_rtt: float,
    ) -> None:
        """A report from the path: ``delivered`` copies arrived, ``lost`` did not."""
        start = self._interval_start
        if start is None:
            self._interval_start = start = now
        self._delivered += delivered
        self._lost += lost
        if rtt_sample is not None and rtt_sample < self._interval_min:
            self._interval_min = rtt_sample
        length = now - start
        if length < max(srtt, 2.0 * self._report_interval):
            return
        self._decide(now, length, min_rtt)
        self._interval_start = now
        self._interval_min = math.inf
        self._delivered = 0
        self._lost = 0

    def _decide(self, now: float, length: float, min_rtt: float) -> None:
        sample = self._interval_min
        queue = sample - min_rtt if sample < math.inf and min_rtt > 0.0 else 0.0
        target = self._target
        if queue > target or (self._lost and queue > target / 2.0):
            delivered_rate = self._delivered / length if length > 0.0 else 0.0
            self.rate = max(MIN_RATE, DECREASE * delivered_rate)
            self.congested_until = now + length
            self._schedule.reschedule(now, self.rate)
            return
        if self.rate == math.inf or queue >= target / 2.0 or self._lost:
            return
        total = self._coupling.total()
        share = self.rate / total if total > 0.0 else 1.0
        self.rate *= 1.0 + GROWTH * share
        offered = self.offered
        if offered > 0.0 and self.rate >= HEADROOM * offered:
            self.rate = math.inf
        self._schedule.reschedule(now, self.rate)


class MultipathController(RateController):
    """The session's rate controller in a multipath session: a sample may leave once some usable
    path's pacer allows a copy (``pacers`` names theirs, best first); the acknowledgements of the
    first copies, which mix the paths, move nothing (each path's pacer hears its own reports)."""

    name = "multipath"

    def __init__(self, pacers: Callable[[], list[PathPacer]]) -> None:
        self._pacers = pacers

    @property
    def rate(self) -> float:
        best = 0.0
        for pacer in self._pacers():
            if pacer.rate > best:
                best = pacer.rate
        return best if best > 0.0 else math.inf

    @property
    def rate_limit(self) -> str:
        pacers = self._pacers()
        if not pacers or any(pacer.rate == math.inf for pacer in pacers):
            return "application"
        return "paths congested"

    def next_send_time(self) -> float:
        earliest = math.inf
        for pacer in self._pacers():
            due = pacer.next_departure
            if due < earliest:
                earliest = due
        return NO_LIMIT if earliest == math.inf else earliest

    def on_packet_sent(self, *, now: float, size: int, paced: bool = True) -> None:
        pass  # each path's pacer counts its copies (Multipath.route)

    def on_ack(
        self,
        *,
        now: float,
        acked: int,
        rtt_sample: float | None,
        srtt: float,
        rttvar: float,
        loss_event_rate: float,
    ) -> None:
        pass

    def on_loss_event(self, *, now: float, srtt: float, loss_event_rate: float) -> None:
        pass

    def get_timer(self) -> float | None:
        return None

    def on_timer(self, *, now: float) -> None:
        pass
