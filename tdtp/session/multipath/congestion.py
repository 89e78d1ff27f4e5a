"""Congestion control per path for a multipath session's copies, coupled (docs/CONTROL.md 11).

A single-path session's rate controller cannot run a multipath session as it is: the
acknowledgement of a sample comes from whichever copy arrived first, so its round trips mix the
paths, and when the best path fails the next one's longer round trip reads as a queue that never
drains (measured: a 60 ms path failing onto a 90 ms one took the sample rate from 1000/s to 270/s in
1.5 s). So a multipath session replaces it with :class:`MultipathController`, which lets a sample
leave when at least one usable path allows a copy, and gives each path a :class:`PathPacer`: a
controller of the session's own kind (``teleop`` by default, the same configuration), fed by that
path's MP_REPORTs alone (the copies that arrived, those that did not, the path's own round trip), so
that each path's copies are paced as a single-path session on that path would pace its samples.

**Coupled, by bottleneck.** Copies of one sample on two paths that cross the same bottleneck put
twice the flow into it. RFC 6356 couples the paths' increases so that together they take no more
than one flow; copies allow something simpler and stricter: a sample goes on at most one *congested*
path of each group of paths that share a bottleneck (:class:`Bottlenecks`: their queueing delays
rise and fall together), so there the session is one flow, paced by that path's controller, never
several. Congested paths that do not share a bottleneck each carry their copies at their own rate:
on independent radio links both are often congested at once, and that is when the copies matter.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from typing import Final

from tdtp.control.base import NO_LIMIT, RateController
from tdtp.control.send_meter import SendMeter
from tdtp.session.loss_rate import LossIntervalEstimator

CONGESTED_SHARE: Final = 0.9
"""A path is congested while its controller allows fewer copies than this share of those offered."""
BIN: Final = 0.1
"""Seconds of queueing delay averaged into one point of a path's series (:class:`Bottlenecks`)."""
WINDOW: Final = 30
"""Points of each path's series compared (the last three seconds)."""
MIN_COMMON: Final = 10
"""Points two paths need in common before they can be judged to share a bottleneck."""
MIN_SPREAD: Final = 0.002
"""A path whose queueing delay varies by less than this (s, standard deviation) shows no queue to
compare: it shares nothing."""
SHARED: Final = 0.6
"""Correlation of two paths' queueing delays above which they share a bottleneck."""
STALL_MARGIN: Final = 0.02
"""Seconds beyond the round trip and two report intervals after which copies that no report has
acknowledged mean a stalled path (:meth:`PathPacer.stalled`)."""
STALL_PROBE: Final = 0.05
"""Seconds between the copies a stalled path still takes (to learn that it delivers again)."""
LONG_STALL: Final = 1.0
"""Seconds of a stall after which the report that ends it restarts the path's controller, as a
path heard again after a failure restarts: a stall that long is our way out's failure (what its
probes lost was the outage's)."""


class Bottlenecks:
    """Which of the session's paths seem to share a bottleneck: those whose queueing delays, in
    :data:`BIN`-second points over the last :data:`WINDOW`, are correlated above :data:`SHARED`
    (delays of flows through one queue move together; through independent queues they do not:
    Rubenstein, Kurose and Towsley's cross-correlation test, simplified)."""

    __slots__ = ("_verdicts", "pacers")

    def __init__(self) -> None:
        self.pacers: list[PathPacer] = []
        self._verdicts: dict[tuple[int, int], tuple[int, bool]] = {}

    def shared(self, a: PathPacer, b: PathPacer, now: float) -> bool:
        """Whether ``a`` and ``b`` share a bottleneck (judged again once per point)."""
        point = int(now / BIN)
        key = (id(a), id(b)) if id(a) < id(b) else (id(b), id(a))
        cached = self._verdicts.get(key)
        if cached is not None and cached[0] == point:
            return cached[1]
        verdict = _correlation(a.series, b.series) >= SHARED
        self._verdicts[key] = (point, verdict)
        return verdict

    def forget(self, pacer: PathPacer) -> None:
        if pacer in self.pacers:
            self.pacers.remove(pacer)
        self._verdicts = {k: v for k, v in self._verdicts.items() if id(pacer) not in k}


def _correlation(a: deque[list[float]], b: deque[list[float]]) -> float:
    """Pearson correlation of two series of ``[point, sum, count]`` over their common points (0 with
    too few, or when either hardly varies)."""
    mine = {int(p): s / n for p, s, n in a}
    xs: list[float] = []
    ys: list[float] = []
    for p, s, n in b:
        x = mine.get(int(p))
        if x is not None:
            xs.append(x)
            ys.append(s / n)
    count = len(xs)
    if count < MIN_COMMON:
        return 0.0
    mx = sum(xs) / count
    my = sum(ys) / count
    sxx = sum((x - mx) ** 2 for x in xs)
    syy = sum((y - my) ** 2 for y in ys)
    floor = count * MIN_SPREAD * MIN_SPREAD
    if sxx < floor or syy < floor:
        return 0.0
    sxy = sum((x - mx) * (y - my) for x, y in zip(xs, ys, strict=True))
    return sxy / math.sqrt(sxx * syy)


class PathPacer:
    """One path's allowance for copies: a controller of the session's kind, fed by the path's
    reports, and the path's queueing delay series for :class:`Bottlenecks`."""

    __slots__ = (
        "_bottlenecks",
        "_feedback_delay",
        "_held",
        "_last_copy",
        "_losses",
        "_make",
        "_now",
        "_offered",
        "_stall_after",
        "_unreported_since",
        "controller",
        "series",
    )

    def __init__(
        self,
        make: Callable[[], RateController],
        feedback_delay: float,
        bottlenecks: Bottlenecks,
    ) -> None:
        self._make = make
        self._feedback_delay = feedback_delay
        self._bottlenecks = bottlenecks
        self.controller = self._new_controller()
        self._offered = SendMeter()
        self._held = False
        self._losses = LossIntervalEstimator(0)
        self._unreported_since = math.inf  # the first copy sent since a report showed progress
        self._last_copy = -math.inf
        self._stall_after = math.inf
        self._now = -math.inf  # the latest time a hook told
        self.series: deque[list[float]] = deque(maxlen=WINDOW)
        """The path's queueing delay: ``[point, sum, count]`` per :data:`BIN` seconds."""
        bottlenecks.pacers.append(self)

    def _new_controller(self) -> RateController:
        controller = self._make()
        controller.feedback_delay = self._feedback_delay  # the peer's report interval
        controller.sample_waiting = False  # its interval ends are settled at its next hook
        return controller

    @property
    def rate(self) -> float:
        """Copies per second the path's controller allows."""
        return self.controller.rate

    @property
    def offered(self) -> float:
        """Copies per second offered to the path lately."""
        rate = self._offered.send_rate()
        return rate if rate < math.inf else 0.0

    def allows(self, now: float) -> bool:
        """Whether a copy may go on the path now (asked once per sample the scheduler offers it).
        While the path is not congested every copy may: its controller allows more than is
        offered, and spacing a burst of samples (a late tick and the next) would only take the copy
        of one of them off this path, not delay it."""
        self._now = now
        self._offered.on_departure(now, False)
        if self.stalled(now):
            if self.probe_due(now):
                return True
            self._held = True
            return False
        if now >= self.controller.next_send_time() or not self.congested():
            return True
        self._held = True
        return False

    def probe_due(self, now: float) -> bool:
        """Whether a path that takes probes only (stalled, or failed: nothing heard on it) is due
        its next copy: one per :data:`STALL_PROBE`."""
        return now - self._last_copy >= STALL_PROBE

    @property
    def next_probe(self) -> float:
        """When such a path is due its next copy."""
        return self._last_copy + STALL_PROBE

    @property
    def next_departure(self) -> float:
        """When the path allows its next copy (:data:`NO_LIMIT` if now)."""
        if self.stalled(self._now):
            return self._last_copy + STALL_PROBE  # its next probe
        return self.controller.next_send_time() if self.congested() else NO_LIMIT

    def stalled(self, now: float) -> bool:
        """Whether the path has stopped delivering our copies: the first copy sent since its
        last report that showed progress went out longer ago than the path's round trip, two of
        the peer's report intervals and :data:`STALL_MARGIN` (a path that delivers, however
        slowly, is reported every interval). The peer reports a path only when our copies arrive
        on it, and reports travel on it, so while the path's way back works (the path is not
        failed) silence there means our way is out: a link in an outage, which would hold every
        copy for the outage's length. A stalled path takes one copy per :data:`STALL_PROBE`, as
        a single-path session's full window does (CONTROL.md 11.2)."""
        return now - self._unreported_since > self._stall_after

    def congested(self) -> bool:
        """Whether the path's controller holds copies back: it allows fewer than
        :data:`CONGESTED_SHARE` of those offered."""
        return self.controller.rate < CONGESTED_SHARE * self.offered

    def shares_bottleneck(self, other: PathPacer, now: float) -> bool:
        return self._bottlenecks.shared(self, other, now)

    def on_sent(self, size: int, now: float) -> None:
        # Paced: the path held a copy back since its last one (a newer sample went instead).
        self.controller.on_packet_sent(now=now, size=size, paced=self._held)
        self._held = False
        self._now = self._last_copy = now
        if self._unreported_since == math.inf:
            self._unreported_since = now

    def reset(self) -> None:
        """The path came back from an outage: a fresh controller (what was lost in the outage says
        nothing about the path's capacity), fresh loss intervals and delay series."""
        self.controller = self._new_controller()
        self._losses = LossIntervalEstimator(0)
        self.series.clear()
        self._held = False
        # (Not the stall: a path heard from again says nothing of our way out; a report does.)

    def detach(self) -> None:
        """The path is gone: it no longer counts among the session's bottlenecks."""
        self._bottlenecks.forget(self)

    def get_timer(self) -> float | None:
        deadline = self.controller.get_timer()
        stall = self._unreported_since + self._stall_after
        if stall > self._now and stall < math.inf and (deadline is None or stall < deadline):
            deadline = stall  # (the path stalls then unless a report comes first)
        return deadline

    def on_timer(self, now: float) -> None:
        self._now = now
        self.controller.on_timer(now=now)

    def on_feedback(
        self,
        now: float,
        delivered: int,
        lost: int,
        rtt_sample: float | None,
        srtt: float,
        rttvar: float,
        min_rtt: float,
        reported: int,
    ) -> None:
        """A report from the path: ``delivered`` copies arrived, ``lost`` did not, of the first
        ``reported`` copies sent on it."""
        controller = self.controller
        losses = self._losses
        self._now = now
        stalled_for = now - self._unreported_since - self._stall_after
        self._stall_after = srtt + 2.0 * self._feedback_delay + STALL_MARGIN
        if delivered > 0:
            self._unreported_since = math.inf  # progress: what was sent since is on its way
            if stalled_for > LONG_STALL:
                self.reset()  # (its controller, without feedback all along, is at its floor)
                return
        if lost > 0 and losses.on_packet_lost(reported - lost, now - srtt, srtt, reported):
            controller.on_loss_event(now=now, srtt=srtt, loss_event_rate=losses.loss_event_rate)
        controller.on_ack(
            now=now,
            acked=delivered,
            rtt_sample=rtt_sample,
            srtt=srtt,
            rttvar=rttvar,
            loss_event_rate=losses.update(reported),
        )
        if rtt_sample is not None and min_rtt > 0.0:
            point = float(int(now / BIN))
            series = self.series
            queue = max(0.0, rtt_sample - min_rtt)
            if series and series[-1][0] == point:
                last = series[-1]
                last[1] += queue
                last[2] += 1.0
            else:
                series.append([point, queue, 1.0])

    def on_one_way(
        self, now: float, delay: float, sent_at: float, copies: int, hold: float, unacked: int
    ) -> None:
        """A report timed our copy's arrival on the peer's clock: ``delay`` is its one-way delay
        plus the clocks' offset (report_clock.py), ``copies`` the copy's number among the path's
        own, ``unacked`` the copies sent on the path since. The controller judges the path's
        queue in our direction alone, and what the path delivered, from these."""
        self.controller.on_one_way_delay(
            now=now, delay=delay, sent_at=sent_at, seq=copies, hold=hold, unacked=unacked
        )


class MultipathController(RateController):
    """The session's rate controller in a multipath session: a sample may leave once some usable
    path's pacer allows a copy (``pacers`` names theirs, best first) or a failed path is due a
    probe copy (``probing``: theirs); the acknowledgements of the first copies, which mix the
    paths, move nothing (each path's pacer hears its own reports). Its timer is the paths'
    (``deadline``, ``on_timer``)."""

    name = "multipath"

    def __init__(
        self,
        pacers: Callable[[], list[PathPacer]],
        deadline: Callable[[], float | None],
        on_timer: Callable[[float], None],
        probing: Callable[[], list[PathPacer]] = list,
    ) -> None:
        self._pacers = pacers
        self._probing = probing
        self._deadline = deadline
        self._on_timer = on_timer

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
        if not pacers or not all(pacer.congested() for pacer in pacers):
            return "application"
        return "paths congested"

    def next_send_time(self) -> float:
        earliest = math.inf
        for pacer in self._pacers():
            due = pacer.next_departure
            if due < earliest:
                earliest = due
        for pacer in self._probing():
            due = pacer.next_probe
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
        """The paths' own deadline (probes, reports, failures, their controllers'): the
        connection folds a controller's timer into its own, so multipath needs no timer hook of
        its own."""
        return self._deadline()

    def on_timer(self, *, now: float) -> None:
        self._on_timer(now)
