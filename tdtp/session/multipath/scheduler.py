"""Which paths a sample goes on (docs/PROTOCOL.md 5.11, docs/CONTROL.md 11).

* ``redundant``: every usable path (validated, not failed), best first. The first copy to arrive wins
  at the receiver, so a sample is as late as the fastest path made it and lost only if every path lost
  it.
* ``adaptive``: the best path alone while it behaves, every usable path while it does not (the 5G
  study's partial duplication). The best path here is the one whose copies take the least time to
  the peer (the reports' clocks, our direction alone; :func:`rank`'s order until every path has such
  a sample). It
  *behaves* while its recent loss is at most ``loss_bound``, its recent one-way delay is within
  ``delay_bound`` of the lowest it has shown, and the samples it carried are acknowledged in time: the
  newest of the samples it carried alone that was acknowledged left no longer ago than such a
  sample's acknowledgement usually takes (a round trip and the peer's hold) plus the usual gap
  between them (each a mean and four deviations) and 10 ms. That last test reacts within one round
  trip to a path that stalls (a radio's capacity outage), long before any report could say so. A
  stall is not a breach until it has lasted ``adaptive_hold`` beyond that limit: until then each
  sample goes on every path while the acknowledgements are overdue, and the first late one ends the
  copies (no hold: most stalls of a radio link are shorter than a round trip, and a hold after each
  cost 3-6 % of the bytes of one path for no better p99, CONTROL.md 11.3). Once a bound is broken
  every path carries the samples for at least ``adaptive_hold``, and so they do while the best path
  has been usable for less than that (just validated, or back from a failure).
  While the best path carries the samples alone, one sample per ``probe_interval`` goes on every
  path anyway, so that each path's lag behind the first copy and its round trip stay measured and
  its controller fed.

Everything else (stand-alone ACKs, keep-alives, control messages) goes on the best path, and a control
message sent again goes on the second best, so that one path's outage costs a retransmission, not the
message.
"""

from __future__ import annotations

import math
from typing import Final

from tdtp.config import MultipathConfig
from tdtp.session.multipath.copies import SentRing
from tdtp.session.multipath.path import Path
from tdtp.session.recovery import LossRecovery

STALL_MARGIN: Final = 0.001
"""The least margin beyond ``srtt + 4 rttvar`` and the feedback's usual gaps before an
unacknowledged sample counts as stalled..."""
STALL_SHARE: Final = 0.2
"""... plus this share of the usual wait: a radio link's delivery comes in bursts, and with 1 ms
alone the recorded cellular links of benchmarks/multipath.py (45 ms round trips) broke it twice a
second, each a spell of copies, for no better p99 than with 10 ms (CONTROL.md 11)."""
GAP_GAIN: Final = 0.125
"""Gain of the averages of acknowledgement ages and gaps (RFC 6298's alpha)."""
AGE_GAIN: Final = 0.25
"""Gain of their deviations (RFC 6298's beta)."""


OUTBOUND_FRESH: Final = 1.0
"""Seconds a path's last delay sample from the reports' clocks stays good for ranking it."""


def rank(paths: list[Path], now: float) -> list[Path]:
    """The usable paths, best (lowest one-way delay estimate, then lowest id) first."""
    usable = [path for path in paths if path.usable]
    usable.sort(key=lambda path: (path.one_way_delay(now), path.path_id))
    return usable


def fastest_out(ranked: list[Path], now: float) -> list[Path]:
    """``ranked`` ordered by the delay of our copies along each path (the reports' clocks: our
    direction alone, report_clock.py; one peer clock, so one offset for all), then the lowest id,
    while every path has a recent sample of it; else ``ranked`` as it is."""
    if len(ranked) < 2:
        return ranked
    outbound = [path.delay.outbound(now, OUTBOUND_FRESH) for path in ranked]
    if max(outbound) == math.inf:
        return ranked
    order = sorted(range(len(ranked)), key=lambda i: (outbound[i], ranked[i].path_id))
    return [ranked[i] for i in order]


class Scheduler:
    """The scheduling policy, and (adaptive) whether the best path carries the samples alone now."""

    __slots__ = (
        "_acked",
        "_acked_at",
        "_age",
        "_age_dev",
        "_alone_path",
        "_alone_since",
        "_config",
        "_delivered",
        "_gap",
        "_gap_at",
        "_gap_dev",
        "_hold_until",
        "_probe_at",
        "_probe_every",
        "_recovery",
        "_ring",
        "adaptive",
        "breaches",
        "reason",
        "single_samples",
        "spread_samples",
        "stall_samples",
    )

    def __init__(
        self,
        config: MultipathConfig,
        recovery: LossRecovery,
        ring: SentRing,
    ) -> None:
        self._config = config
        self._acked = recovery.sent.largest_acked
        self._acked_at = -math.inf
        self._gap = 0.0
        self._gap_dev = 0.0
        self._gap_at = -math.inf
        self._age = 0.0
        self._age_dev = 0.0
        self._probe_at = -math.inf
        self._probe_every = config.probe_interval
        self._delivered: dict[int, float] = {}  # path id -> newest of its lone samples acknowledged
        self._alone_path = -1  # the path carrying the samples alone now (-1: none)
        self._alone_since = -math.inf
        self.adaptive = config.scheduler == "adaptive"
        self._recovery = recovery
        self._ring = ring
        self._hold_until = -math.inf
        self.breaches = 0
        """Adaptive: times the best path broke a bound and every path took the samples."""
        self.reason = ""
        """Adaptive: the last bound broken (``loss``, ``delay``, ``stall``, ``unmeasured``)."""
        self.single_samples = 0
        """Samples sent on one path only."""
        self.spread_samples = 0
        """Samples sent on several paths."""
        self.stall_samples = 0
        """Adaptive: samples sent on every path because the best path's acknowledgements were
        overdue (a short stall: no breach, no hold)."""

    def candidates(self, ranked: list[Path], now: float) -> list[Path]:
        """The paths a sample should go on now (``ranked``: the usable paths, best first)."""
        if self.adaptive:
            self._feedback(now)
        if not self.adaptive or len(ranked) < 2:
            return ranked
        ranked = fastest_out(ranked, now)
        best = ranked[0]
        if self._alone(best, now):
            if self._alone_path != best.path_id:
                self._alone_path = best.path_id
                self._alone_since = now
                self._gap_at = -math.inf  # the gaps that count are those while alone
            if now < self._probe_at + self._probe_every:
                return ranked[:1]
        elif self._hold_until > now or self.reason != "stall":
            self._alone_path = -1  # (a short stall keeps the path's evidence: it ends the stall)
        self._probe_at = now
        return ranked

    def _alone(self, best: Path, now: float) -> bool:
        config = self._config
        reason = ""
        if not best.rtt.has_sample or now - best.state_since < config.adaptive_hold:
            self.reason = "unmeasured"  # (or just validated, or just back: not trusted alone yet)
            return False
        if best.loss > config.loss_bound:
            reason = "loss"
        elif (
            best.delay.queue if best.delay.samples else best.queue_delay / 2.0
        ) > config.delay_bound:
            reason = "delay"
        else:
            overdue = self._overdue(best, now)
            if overdue > config.adaptive_hold:
                reason = "stall"  # a long stall: a breach, as a broken bound
            elif overdue > 0.0:
                # A short stall: this sample goes on every path, no hold. Its end (the late
                # acknowledgement of a sample the best path carried alone) ends the copies.
                self.reason = "stall"
                self.stall_samples += 1
                return False
        if reason:
            if now >= self._hold_until:
                self.breaches += 1
            self._hold_until = now + config.adaptive_hold
            self.reason = reason
            return False
        return now >= self._hold_until

    def _overdue(self, best: Path, now: float) -> float:
        """How long ago the newest sample the best path carried alone that was acknowledged
        should have been followed by another, given the usual wait for an acknowledgement and the
        usual gap between them (<= 0: not overdue). The samples every path carried prove nothing
        about the best one: their acknowledgements may have come the other way."""
        if self._alone_path != best.path_id:
            return 0.0  # not alone on it yet
        evidence = max(self._delivered.get(best.path_id, -math.inf), self._alone_since)
        return now - evidence - self._limit()

    def _feedback(self, now: float) -> None:
        """A new largest acknowledged sample that one path carried alone: evidence that the path
        delivers. How old such a sample is when its acknowledgement arrives (a round trip plus the
        peer's hold), and the gaps between them (the peer's cadence, a bursty path's batches), are
        averaged with their deviations as RFC 6298 averages round trips."""
        largest = self._recovery.sent.largest_acked
        if largest == self._acked:
            return
        self._acked = largest
        mask = self._ring.paths(largest)
        sent_at = self._ring.send_time(largest)
        if not mask or mask & (mask - 1) or sent_at is None:
            return
        self._delivered[mask.bit_length() - 1] = sent_at
        age = now - sent_at
        gap = now - self._gap_at
        if age + gap > self._limit() and self._acked_at > -math.inf:
            # Beyond what a stall is judged by: itself a sign of trouble, not a lesson in what
            # is usual (a cut path's last samples, acknowledged the other way).
            self._gap_at = now
            return
        if self._acked_at == -math.inf:
            self._age, self._age_dev = age, age / 2.0
        else:
            self._age_dev += AGE_GAIN * (abs(age - self._age) - self._age_dev)
            self._age += GAP_GAIN * (age - self._age)
        self._acked_at = now
        if self._gap_at > -math.inf:
            self._gap_dev += AGE_GAIN * (abs(gap - self._gap) - self._gap_dev)
            self._gap += GAP_GAIN * (gap - self._gap)
        self._gap_at = now

    def _limit(self) -> float:
        """How long after its send the newest acknowledged lone sample may be before a stall."""
        age = self._age
        margin = STALL_MARGIN + STALL_SHARE * age
        return age + 4.0 * self._age_dev + self._gap + 4.0 * self._gap_dev + margin

    def deadline(self) -> float | None:
        """Adaptive: when the hold ends (the best path may carry the samples alone again)."""
        return self._hold_until if self.adaptive and self._hold_until > -math.inf else None
