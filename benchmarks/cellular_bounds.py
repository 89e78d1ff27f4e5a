"""What a recorded cellular trace leaves any causal sender under issue 32's delay bars, and what
reacting or forecasting senders reach.

``python benchmarks/cellular_bounds.py [--trace verizon tmobile att] [--way ms sm] [--duration S]
[--part bounds predict sprout] [--jobs N] [--hazard PER_S] [--quantile Q] [--stall MS]``

Per trace direction, each over the five offsets of ``benchmarks/cellular.py`` (the same 20 ms each
way and 1 kHz of 100-byte samples, 133 bytes on the wire with the transport header):

* **unavoidable late samples** (``bounds``): a sender learns that its direction stopped delivering
  one feedback lag ``L`` after the link's last delivery at the earliest (the last packet's 20 ms
  there, the peer's stamp's 20 ms back). The samples it generated within ``L`` of the start of a gap
  wait for the gap's end: those that then arrive more than 60 ms (150 ms) after their generation are
  late whatever the sender does, unless it stopped *before* it could know (a forecast). As a share
  of a constant rate's samples, and for a sender paced at the rate the link carried over the last
  100 ms as a share of what the trace allowed: a fraction that does not depend on the rate.
* **the reactive frontier** (``bounds``): a sender with exact, noise-free feedback and latest-value
  samples (a sample that cannot leave is replaced by the next, as tdtp's sender does) that sends
  every sample while the peer keeps up and stops (one probe per 50 ms) as soon as a packet of its
  own is ``S`` ms overdue at the peer, seen 20 ms later. Its share of what the trace allowed, p95
  and p99 for each ``S``. ``S`` = 1000 is a sender that never stops (the ``fixed`` row of
  ``cellular.py``, which it reproduces within a few ms).
* **can a stop be seen coming?** (``predict``): a predictor learnt from the trace's own past
  opportunities (:class:`StopForecast`, judged out of sample), its lift over the base rate of stop
  onsets, and the reactive sender at ``S`` = 20 that also holds when it fires, beside the same holds
  drawn blind; and a reactor that sees the link itself one lag late (:func:`seen_idle`).
* **a Sprout-style forecaster** (``sprout``; Winstein et al., NSDI 2013): a Bayesian belief about
  the link's rate, a cautious forecast of its deliveries, and a sender that keeps queued only what
  the forecast drains within a target (:func:`forecaster`), seeing either the link or only its own
  packets.

The link model is Mahimahi's (byte-counted 1500-byte opportunities, a FIFO, unbounded here: the
150 kB queue never fills at these rates outside the fixed row).
"""

from __future__ import annotations

import argparse
import bisect
import itertools
import math
import random
import statistics
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
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


def unavoidable(
    text: str, lag_ms: float, duration: float, bar: float, hold: Callable[[int], bool] | None = None
) -> int:
    """Samples generated within ``lag_ms`` of a gap's start that arrive later than ``bar`` s (with
    ``hold``: only those generated while it held, which a sender holding then never sends)."""
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
                late += hold is None or hold(k)
    return late


def paced_late(text: str, lag_ms: float, duration: float, bar: float) -> float:
    """:func:`unavoidable` for a sender that never sends faster than the link carried over the
    last 100 ms (nor over 1 kHz): each gap's late samples weighted by that rate over 1 kHz, as a
    percentage of what the trace allowed (the most it can deliver)."""
    trace, offset, propagation = trace_of(text)
    times: list[float] = []
    index = trace.first_after(max(0.0, offset - 100))
    while (t := trace.time_ms(index) - offset) <= duration * 1e3 + 2000:
        times.append(t)
        index += 1
    late = 0.0
    for n, (a, b) in enumerate(itertools.pairwise(times)):
        if b - a <= 0 or a < 0:
            continue
        carried = n + 1 - bisect.bisect_right(times, a - 100)
        rate = min(1.0, carried * OPPORTUNITY_BYTES / WIRE / 100)
        for k in range(math.floor(a) + 1, math.floor(min(b, a + lag_ms)) + 1):
            if k < duration * 1e3 and b - k + propagation > bar * 1e3:
                late += rate
    return 100.0 * late / scenario.allowed(text, start=0.0, duration=duration)


class Link:
    """One direction's link as Mahimahi serves it: a FIFO (unbounded) drained by the trace's
    byte-counted 1500-byte opportunities. Times are the run's milliseconds (the trace's clock minus
    its offset)."""

    def __init__(self, text: str) -> None:
        self.trace, self.offset, self.propagation = trace_of(text)
        self._index, self._left = self.trace.first_after(self.offset), OPPORTUNITY_BYTES

    def send(self, t: int, size: int = WIRE) -> float:
        """Queue ``size`` bytes at millisecond ``t``: the millisecond they leave the link."""
        i, room = self._index, self._left
        if self.trace.time_ms(i) < t + self.offset:
            i, room = self.trace.first_after(t + self.offset), OPPORTUNITY_BYTES
        while size > room:
            size -= room
            i += 1
            room = OPPORTUNITY_BYTES
        self._index, self._left = i, room - size
        return self.trace.time_ms(i) - self.offset

    def opportunities(self, start: float, end: float) -> int:
        """The trace's opportunities in the run's ``(start, end]`` (ms)."""
        return self.trace.opportunities_between(start + self.offset, end + self.offset)


def figures(delays: list[float], allowed: float) -> tuple[float, float, float]:
    """(share % of what the trace allowed, p95 ms, p99 ms) of the delivered samples' delays."""
    ordered = sorted(delays)
    n = len(ordered)
    return 100.0 * n / allowed, ordered[math.ceil(0.95 * n) - 1], ordered[math.ceil(0.99 * n) - 1]


def frontier(
    text: str, stall_ms: float, duration: float, hold: Callable[[int], bool] | None = None
) -> tuple[float, float, float]:
    """The reactive sender of the module's docstring: (share %, p95 ms, p99 ms). With ``hold``, it
    also sends nothing (no probe) at every millisecond ``t`` for which ``hold(t)`` says so: the
    forecasting variant of section "Can a stop be seen coming?"."""
    link = Link(text)
    propagation = link.propagation
    allowed = scenario.allowed(text, start=0.0, duration=duration)
    sent: list[int] = []  # send times (ms) of the packets sent, in order
    arrivals: list[float] = []  # their arrival times at the peer (FIFO: increasing)
    delays: list[float] = []
    last_probe = -math.inf
    for t in range(round(duration * 1e3)):
        known = t - propagation  # the peer's state the sender knows of
        delivered = bisect.bisect_right(arrivals, known)
        stalled = delivered < len(sent) and sent[delivered] + propagation + stall_ms < known
        if hold is not None and hold(t):
            continue  # held: superseded by the next sample
        if stalled and t - last_probe < PROBE_MS:
            continue  # superseded by the next sample
        if stalled:
            last_probe = t
        arrival = link.send(t) + propagation
        sent.append(t)
        arrivals.append(arrival)
        delays.append(arrival - t)
    return figures(delays, allowed)


# ---------------------------------------------------------------- can a stop be seen coming?

GRID_MS = 10
"""The predictor decides every 10 ms of the trace's clock."""
STOP_MS = 100
"""A stop: no delivery opportunity for more than this long."""
SHORT_GAP_MS = 20
SMOOTHING = 20.0
"""Pseudo-observations at the base rate in every cell of the predictor's table."""
BUDGETS = (0.05, 0.10, 0.20, 0.30)
"""Fractions of the time the predictor may fire (it fires on its highest-scored decisions)."""
NEED_PER_100MS = 1000.0 * WIRE / OPPORTUNITY_BYTES / 10
"""Opportunities per 100 ms a 1 kHz stream of samples needs (8.9)."""


def _cell(idle: float, r100: int, r500: int, gaps: int, since_stop: float) -> int:
    """The predictor's features, binned into one cell number (4 x 3 x 3 x 3 x 3 cells)."""
    idle_bin = 0 if idle < 5 else 1 if idle < 15 else 2 if idle < 30 else 3
    trend = (5 * r100 + 1) / (r500 + 1)
    trend_bin = 0 if trend < 0.6 else 1 if trend < 1.2 else 2
    rate_bin = 0 if r100 < NEED_PER_100MS else 1 if r100 < 3 * NEED_PER_100MS else 2
    gap_bin = min(gaps, 2)
    stop_bin = 0 if since_stop < 300 else 1 if since_stop < 2000 else 2
    return (((idle_bin * 3 + trend_bin) * 3 + rate_bin) * 3 + gap_bin) * 3 + stop_bin


class StopForecast:
    """A predictor of stops learnt from one trace and judged on the half it did not learn from.

    Every ``GRID_MS`` of the trace's clock, at ``tau``, it sees every opportunity up to ``tau`` (a
    sender sees them one feedback lag late: ``tau`` is its own time minus the lag) and scores the
    chance that a stop (no opportunity for over ``STOP_MS``) starts in ``(tau, tau + lag]``. Its
    features: the time since the last opportunity, the rate over the last 100 ms against the need
    and against the last 500 ms (a trend), the gaps of over 20 ms in the last 500 ms and the time
    since the last stop ended. A decision's score is the rate of onsets in its cell on the *other*
    half of the trace's period (two-fold, by halves), so every score is out of sample (unless
    ``in_sample``: an upper bound on what these features hold). This is
    more than a sender can know (it sees the link only through its own packets); a stop this
    predictor cannot see coming, no causal sender can.
    """

    def __init__(self, trace: Trace, lag_ms: float, *, in_sample: bool = False) -> None:
        period = trace.period_ms
        one = [trace.time_ms(i) for i in range(len(trace))]
        times = [t + k * period for k in (-1, 0, 1) for t in one]  # windows wrap at the loop
        gaps = [(a, b) for a, b in itertools.pairwise(times) if b - a > SHORT_GAP_MS]
        gap_ends = [b for _, b in gaps]
        stop_ends = [b for a, b in gaps if b - a > STOP_MS]
        onsets = [a for a, b in gaps if b - a > STOP_MS]
        self.period = period
        self.lag = lag_ms
        cells: list[int] = []
        labels: list[bool] = []
        for tau in range(0, period, GRID_MS):
            i = bisect.bisect_right(times, tau)
            r100 = i - bisect.bisect_right(times, tau - 100)
            r500 = i - bisect.bisect_right(times, tau - 500)
            g = bisect.bisect_right(gap_ends, tau) - bisect.bisect_right(gap_ends, tau - 500)
            k = bisect.bisect_right(stop_ends, tau)
            since = tau - stop_ends[k - 1] if k else math.inf
            cells.append(_cell(tau - times[i - 1], r100, r500, g, since))
            j = bisect.bisect_right(onsets, tau)
            labels.append(j < len(onsets) and onsets[j] <= tau + lag_ms)
        self.labels = labels
        self.base = sum(labels) / len(labels)
        half = len(cells) // 2
        folds = (range(half), range(half, len(cells)))
        if in_sample:  # learnt and judged on the same decisions: what the features could give
            folds = (range(len(cells)), range(len(cells)))
        self.scores = [0.0] * len(cells)
        for learn, judge in (folds, folds[::-1]):
            seen: dict[int, list[int]] = {}
            for n in learn:
                count = seen.setdefault(cells[n], [0, 0])
                count[0] += 1
                count[1] += labels[n]
            prior = sum(labels[n] for n in learn) / len(learn)
            for n in judge:
                total, hits = seen.get(cells[n], (0, 0))
                self.scores[n] = (hits + SMOOTHING * prior) / (total + SMOOTHING)

    def fires(self, budget: float, *, blind: bool = False) -> list[bool]:
        """The decisions on which it fires, given that it may fire on ``budget`` of them (ties
        broken at random); ``blind``: as many decisions drawn at random, the control."""
        draw = random.Random(f"{self.period} {budget}")
        keys = [draw.random() for _ in self.scores]
        if blind:
            order = sorted(range(len(keys)), key=keys.__getitem__)
        else:
            order = sorted(range(len(keys)), key=lambda n: (-self.scores[n], keys[n]))
        chosen = [False] * len(order)
        for n in order[: round(budget * len(order))]:
            chosen[n] = True
        return chosen

    def judge(self, chosen: list[bool]) -> tuple[float, float]:
        """(precision, recall): onsets within a lag among its firings, its firings among those."""
        fired = sum(chosen)
        hits = sum(1 for c, y in zip(chosen, self.labels, strict=True) if c and y)
        return hits / max(fired, 1), hits / max(sum(self.labels), 1)

    def hold(self, chosen: list[bool], offset_ms: float) -> Callable[[int], bool]:
        """For a sender of a run starting ``offset_ms`` into the trace: does it hold at ``t``?"""

        def holding(t: int) -> bool:
            tau = (t + offset_ms - self.lag) % self.period
            return tau >= 0 and chosen[int(tau // GRID_MS)]

        return holding


def seen_idle(text: str, lag_ms: float, idle_ms: float) -> Callable[[int], bool]:
    """A hold for a sender that sees every opportunity of its link ``lag_ms`` late (more than any
    sender sees): it holds while the link it sees has delivered nothing for ``idle_ms``. The best a
    *reaction* to the link itself can do (no probes needed, no packet of its own to wait for)."""
    trace, offset, _ = trace_of(text)

    def holding(t: int) -> bool:
        seen = t + offset - lag_ms
        last = trace.time_ms(trace.first_after(seen) - 1) if seen >= trace.time_ms(0) else -math.inf
        return seen - last >= idle_ms

    return holding


# ------------------------------------------------------------------ a Sprout-style forecaster

TICK_MS = 20
"""The forecaster's tick: its receiver observes and forecasts once per tick (Sprout's 20 ms)."""
TICKS = 8
"""Ticks forecast ahead (160 ms)."""
RATE_BINS = 31
MAX_RATE = 300.0
"""Opportunities per second of the top bin (3.4 times the 1 kHz stream's need; the top bin stands
for "at least this": faster is the same to a sender that never needs more)."""
SIGMA = 200.0
"""Volatility of the rate's Brownian walk, opportunities/s per root second (Sprout's)."""
ESCAPE = 1.0
"""Rate (per second) at which an outage (rate 0) ends (Sprout's)."""
COUNT_CAP = 16
"""Opportunities per tick above which counts are lumped (the top bin's mean is 6)."""
QUANTILE = 0.05
"""The cautious forecast: the 5th percentile of the cumulative deliveries (Sprout's)."""
TARGETS_MS = (20, 40, 60, 100)
"""Queueing delays the forecaster keeps within, at that quantile (Sprout's is 100 ms)."""


def _normal_cdf(x: float) -> float:
    return 0.5 * (1.0 + math.erf(x / math.sqrt(2.0)))


class RateModel:
    """Sprout's model of a link, in our terms: the rate of opportunities ``lam`` walks (Brownian,
    ``SIGMA``), sticks at 0 (an outage) until it escapes (``ESCAPE`` per second), and the
    opportunities in a tick are Poisson with mean ``lam`` times the tick. Shared tables only.

    ``hazard`` (per second, 0 in Sprout) adds what Sprout's walk lacks: a stop may begin at any
    rate, a jump to 0 (a stop then ends as an outage does)."""

    def __init__(self, hazard: float = 0.0) -> None:
        dt = TICK_MS / 1e3
        self.hazard = hazard
        jump = 1.0 - math.exp(-hazard * dt)
        step = MAX_RATE / (RATE_BINS - 1)
        self.rates = [k * step for k in range(RATE_BINS)]
        spread = SIGMA * math.sqrt(dt)
        edges = [-math.inf, *(r + step / 2 for r in self.rates[:-1]), math.inf]
        stay = math.exp(-ESCAPE * dt)
        self.into: list[list[tuple[int, float]]] = [[] for _ in self.rates]
        for i, r in enumerate(self.rates):
            moves = [
                _normal_cdf((edges[j + 1] - r) / spread) - _normal_cdf((edges[j] - r) / spread)
                for j in range(RATE_BINS)
            ]
            if i == 0:  # an outage stays one, or escapes to a rate near 0
                rest = sum(moves[1:])
                moves = [stay, *((1 - stay) * m / rest for m in moves[1:])]
            else:  # or the link stops
                moves = [jump + (1 - jump) * moves[0], *((1 - jump) * m for m in moves[1:])]
            for j, m in enumerate(moves):
                if m > 1e-12:
                    self.into[j].append((i, m))
        self.pmf = [
            [math.exp(-r * dt) * (r * dt) ** n / math.factorial(n) for n in range(COUNT_CAP + 1)]
            for r in self.rates
        ]
        self.tail = [  # P(count >= n)
            [max(0.0, 1.0 - sum(row[:n])) for n in range(COUNT_CAP + 1)] for row in self.pmf
        ]
        self.tail[0] = [1.0] + [0.0] * COUNT_CAP
        self.cdf: list[list[list[float]]] = []  # [bin][tick][count]: P(cumulative <= count)
        for b in range(RATE_BINS):
            belief = [float(k == b) for k in range(RATE_BINS)]
            cumulative = [1.0]
            per_tick: list[list[float]] = []
            for _ in range(TICKS):
                tick = [
                    sum(belief[c] * self.pmf[c][n] for c in range(RATE_BINS))
                    for n in range(COUNT_CAP)
                ]
                tick.append(max(0.0, 1.0 - sum(tick)))
                merged = [0.0] * (len(cumulative) + len(tick) - 1)
                for a, pa in enumerate(cumulative):
                    if pa > 1e-15:
                        for n, pn in enumerate(tick):
                            merged[a + n] += pa * pn
                cumulative = merged
                per_tick.append(list(itertools.accumulate(cumulative)))
                belief = self.evolve(belief)
            self.cdf.append(per_tick)

    def evolve(self, belief: list[float]) -> list[float]:
        """The belief one tick later, before its observation."""
        return [sum(m * belief[i] for i, m in row) for row in self.into]


class RateBelief:
    """One receiver's belief about its link's rate: evolved and observed once per tick."""

    def __init__(self, model: RateModel) -> None:
        self.model = model
        self.belief = [1.0 / RATE_BINS] * RATE_BINS

    def tick(self, count: int | None, *, at_least: bool) -> None:
        """One tick: the walk, then the opportunities seen (``count``, or at least ``count`` when
        the link was not kept busy; ``None``: nothing seen)."""
        belief = self.model.evolve(self.belief)
        if count is not None:
            n = min(count, COUNT_CAP)
            table = self.model.tail if at_least or n == COUNT_CAP else self.model.pmf
            belief = [p * row[n] for p, row in zip(belief, table, strict=True)]
        total = sum(belief)
        self.belief = (
            [p / total for p in belief] if total > 1e-300 else [1.0 / RATE_BINS] * RATE_BINS
        )

    def forecast(self, quantile: float) -> list[float]:
        """Cautious cumulative opportunities at 0, 1, ... ``TICKS`` ticks ahead: each the
        ``quantile`` of the cumulative count's distribution under the belief."""
        active = [(p, self.model.cdf[b]) for b, p in enumerate(self.belief) if p > 1e-9]
        out = [0.0]
        for k in range(TICKS):
            lo, hi = 0, len(active[0][1][k]) - 1
            while lo < hi:
                mid = (lo + hi) // 2
                if sum(p * cdf[k][mid] for p, cdf in active) >= quantile:
                    hi = mid
                else:
                    lo = mid + 1
            out.append(float(lo))
        return out


def _at(forecast: list[float], ms: float) -> float:
    """The cautious cumulative bytes ``ms`` after the forecast's time (linear between ticks)."""
    x = min(ms / TICK_MS, float(TICKS))
    k = min(int(x), TICKS - 1)
    return OPPORTUNITY_BYTES * (forecast[k] + (x - k) * (forecast[k + 1] - forecast[k]))


def forecaster(
    text: str,
    target_ms: float,
    duration: float,
    *,
    sees_link: bool,
    quantile: float = QUANTILE,
    model: RateModel | None = None,
    stall_ms: float = math.inf,
) -> tuple[float, float, float]:
    """A Sprout-style sender with exact feedback: (share %, p95 ms, p99 ms).

    Its receiver closes a tick of the link's time every ``TICK_MS``: it walks its belief on, then
    observes that tick's opportunities: every one (``sees_link``: as if it kept the link busy, more
    than a 1 kHz stream can see) or only what its own packets show (``sees_link`` False: the bytes
    of ours the link carried; a count when our queue stayed busy through the tick, "at least" when
    it emptied, nothing when it held nothing of ours). The forecast reaches the sender two
    propagation delays after the tick's end with the exact bytes of ours still queued then. The
    sender sends the newest sample whenever its estimate of our queue now (what was queued at the
    forecast's time, plus what it sent since, less the cautious deliveries since) plus the sample
    fits in the cautious deliveries of the next ``target_ms``; otherwise the sample is superseded
    (one probe per ``PROBE_MS`` goes anyway, so the receiver keeps seeing the link). With
    ``stall_ms`` it also stops as the reactive sender does, when a packet of its own is that
    overdue."""
    link = Link(text)
    propagation = link.propagation
    allowed = scenario.allowed(text, start=0.0, duration=duration)
    belief = RateBelief(model or RateModel())
    forecast, as_of = belief.forecast(quantile), 0.0
    closes = float(TICK_MS)  # the end of the next tick the receiver closes
    sends: list[int] = []
    departures: list[float] = []  # FIFO: non-decreasing
    busy: list[list[float]] = []  # the periods our queue held something: [start, end)
    delays: list[float] = []
    last = -math.inf
    for t in range(round(duration * 1e3)):
        while closes + 2 * propagation <= t:
            start = closes - TICK_MS
            count: int | None
            at_least = False
            if sees_link:
                count = link.opportunities(start - 1, closes - 1)
            else:
                ours = bisect.bisect_left(departures, closes) - bisect.bisect_left(
                    departures, start
                )
                seen = ours * WIRE / OPPORTUNITY_BYTES
                count = max(1, round(seen)) if seen > 0 else 0
                k = bisect.bisect_right(busy, [start, math.inf]) - 1
                kept_busy = k >= 0 and busy[k][0] <= start and busy[k][1] >= closes
                if not kept_busy:
                    at_least = True
                    count = count or None
            belief.tick(count, at_least=at_least)
            forecast, as_of = belief.forecast(quantile), closes
            closes += TICK_MS
        elapsed = t - as_of
        before = bisect.bisect_left(sends, as_of)
        queued = max(0, before - bisect.bisect_left(departures, as_of)) * WIRE
        since = (len(sends) - before) * WIRE
        estimate = max(0.0, queued + since - _at(forecast, elapsed))
        room = _at(forecast, elapsed + target_ms) - _at(forecast, elapsed)
        heard = bisect.bisect_right(departures, t - 2 * propagation)
        stalled = heard < len(sends) and sends[heard] + 2 * propagation + stall_ms < t
        if (stalled or estimate + WIRE > room) and t - last < PROBE_MS:
            continue  # superseded by the next sample
        last = t
        departure = link.send(t)
        if departure > t:
            if busy and busy[-1][1] >= t:
                busy[-1][1] = max(busy[-1][1], departure)
            else:
                busy.append([float(t), departure])
        sends.append(t)
        departures.append(departure)
        delays.append(departure + propagation - t)
    return figures(delays, allowed)


Row = tuple[float, float, float]


def _meets(row: Row) -> str:
    share, p95, p99 = row
    return "yes" if share >= 90.0 and p95 <= 60.0 and p99 <= 150.0 else "no"


def _median(rows: list[Row]) -> Row:
    return (
        statistics.median(r[0] for r in rows),
        statistics.median(r[1] for r in rows),
        statistics.median(r[2] for r in rows),
    )


def _show(row: Row) -> str:
    return f"{row[0]:.1f} / {row[1]:.0f} / {row[2]:.0f}"


def _predicted(job: tuple[str, float, float, bool]) -> tuple[Row, int, int]:
    """One held reactive run (in a worker): its figures and the late samples the holds caught."""
    text, budget, duration, blind = job
    trace, offset, _ = trace_of(text)
    predictor = _predictor(trace)
    hold = predictor.hold(predictor.fires(budget, blind=blind), offset)
    late = unavoidable(text, LAG_MS, duration, BARS[0])
    caught = unavoidable(text, LAG_MS, duration, BARS[0], hold)
    return frontier(text, HELD_STALL_MS, duration, hold), late, caught


_predictors: dict[str, StopForecast] = {}


def _predictor(trace: Trace) -> StopForecast:
    if trace.path not in _predictors:
        _predictors[trace.path] = StopForecast(trace, LAG_MS)
    return _predictors[trace.path]


def _seen(job: tuple[str, float, float]) -> Row:
    text, idle, duration = job
    return frontier(text, HELD_STALL_MS, duration, seen_idle(text, LAG_MS, idle))


SEEN_IDLE_MS = (2, 5, 10, 20)
"""Idle times of the link (seen a lag late) at which the link-watching reactor holds."""


def _sprout(job: tuple[str, float, float, bool, float, float, float]) -> Row:
    text, target, duration, sees_link, hazard, quantile, stall = job
    return forecaster(
        text,
        target,
        duration,
        sees_link=sees_link,
        quantile=quantile,
        model=_model(hazard),
        stall_ms=stall,
    )


_models: dict[float, RateModel] = {}


def _model(hazard: float) -> RateModel:
    if hazard not in _models:
        _models[hazard] = RateModel(hazard)
    return _models[hazard]


LAG_MS = 40
"""The feedback lag of the predictor's sender (the two 20 ms paths)."""
HELD_STALL_MS = 20
"""The reactive sender the predictor's holds are added to: the stop that meets most bars."""


def bounds(texts: list[str], label: str, duration: float) -> None:
    """The unavoidable late samples and the reactive frontier of one direction."""
    generated = duration * 1e3
    for lag in LAGS_MS:
        counts = [[unavoidable(t, lag, duration, bar) for t in texts] for bar in BARS]
        print(
            f"{label}: late whatever a sender with a {lag} ms feedback lag does, > 60 ms: "
            f"{statistics.median(counts[0]):.0f} {counts[0]} "
            f"({100 * statistics.median(counts[0]) / generated:.2f} % of a constant rate), "
            f"> 150 ms: {statistics.median(counts[1]):.0f} {counts[1]} "
            f"({100 * statistics.median(counts[1]) / generated:.2f} %)"
        )
    paced = [[paced_late(t, LAG_MS, duration, bar) for t in texts] for bar in BARS]
    print(
        f"{label}: the same ({LAG_MS} ms) for a sender at the rate the link carried over the last "
        f"100 ms, % of what the trace allowed: > 60 ms {statistics.median(paced[0]):.2f} "
        f"[{' '.join(f'{x:.2f}' for x in paced[0])}], > 150 ms "
        f"{statistics.median(paced[1]):.2f} [{' '.join(f'{x:.2f}' for x in paced[1])}]"
    )
    for stall in STALLS_MS:
        rows = [frontier(t, stall, duration) for t in texts]
        med = _median(rows)
        each = " ".join(f"{s:.1f}/{a:.0f}/{b:.0f}" for s, a, b in rows)
        print(
            f"{label}: reactive, stop {stall} ms overdue: share {med[0]:.1f} %, "
            f"p95 {med[1]:.0f} ms, p99 {med[2]:.0f} ms [{each}]"
        )


def predictability(
    texts: list[str], label: str, duration: float, pool: ProcessPoolExecutor
) -> None:
    """How well a stop can be seen coming on one direction, and what holding on it buys."""
    trace, _, _ = trace_of(texts[0])
    predictor = _predictor(trace)
    print(
        f"\n{label}: stops (> {STOP_MS} ms) starting within {LAG_MS} ms of a decision: "
        f"{100 * predictor.base:.2f} % of decisions"
    )
    fitted = StopForecast(trace, LAG_MS, in_sample=True)
    lifts = [fitted.judge(fitted.fires(b))[0] / fitted.base for b in BUDGETS]
    print(
        "(in sample, learnt on the decisions it is judged on, the lift at "
        + ", ".join(f"{100 * b:.0f} % is {x:.2f}" for b, x in zip(BUDGETS, lifts, strict=True))
        + ")"
    )
    print(
        "| fires on | precision | lift | recall | late > 60 ms caught (held / blind) "
        f"| reactive {HELD_STALL_MS} ms + holds | same, blind holds |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- |")
    base = _median([frontier(t, HELD_STALL_MS, duration) for t in texts])
    print(f"| 0 % | | | | | {_show(base)} ({_meets(base)}) | |")
    for budget in BUDGETS:
        precision, recall = predictor.judge(predictor.fires(budget))
        runs = {
            blind: list(pool.map(_predicted, [(t, budget, duration, blind) for t in texts]))
            for blind in (False, True)
        }
        caught = {
            blind: 100 * sum(c for _, _, c in r) / max(1, sum(n for _, n, _ in r))
            for blind, r in runs.items()
        }
        held, blind_row = (_median([row for row, _, _ in runs[b]]) for b in (False, True))
        print(
            f"| {100 * budget:.0f} % | {100 * precision:.2f} % | {precision / predictor.base:.2f} "
            f"| {100 * recall:.0f} % | {caught[False]:.0f} % / {caught[True]:.0f} % "
            f"| {_show(held)} ({_meets(held)}) | {_show(blind_row)} |"
        )
    print(
        f"\nReactive {HELD_STALL_MS} ms that also sees the link {LAG_MS} ms late and holds "
        "while it has been idle for:"
    )
    print("| idle (ms) | share % / p95 / p99 |")
    print("| --- | --- |")
    for idle in SEEN_IDLE_MS:
        rows = list(pool.map(_seen, [(t, idle, duration) for t in texts]))
        med = _median(rows)
        each = " ".join(f"{s:.1f}/{a:.0f}/{b:.0f}" for s, a, b in rows)
        print(f"| {idle} | {_show(med)} ({_meets(med)}) [{each}] |")


def sprout(
    texts: list[str],
    label: str,
    duration: float,
    pool: ProcessPoolExecutor,
    hazard: float,
    quantile: float,
    stall: float,
) -> None:
    """The Sprout-style forecaster on one direction, each target, both ways of seeing the link."""
    print(
        f"\n{label}: Sprout-style forecaster (quantile {quantile:g}, stop hazard {hazard:g}/s"
        + (f", and the reactor's stop {stall:g} ms overdue" if math.isfinite(stall) else "")
        + "), share % / p95 / p99 (medians of the offsets)"
    )
    print("| target (ms) | sees the link | sees its own packets |")
    print("| --- | --- | --- |")
    for target in TARGETS_MS:
        cells = []
        for sees_link in (True, False):
            rows = list(
                pool.map(
                    _sprout,
                    [(t, target, duration, sees_link, hazard, quantile, stall) for t in texts],
                )
            )
            med = _median(rows)
            each = " ".join(f"{s:.1f}/{a:.0f}/{b:.0f}" for s, a, b in rows)
            cells.append(f"{_show(med)} ({_meets(med)}) [{each}]")
        print(f"| {target} | {cells[0]} | {cells[1]} |")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--trace", nargs="+", choices=sorted(TRACES), default=list(TRACES))
    p.add_argument("--way", nargs="+", choices=("ms", "sm"), default=["ms", "sm"])
    p.add_argument("--duration", type=float, default=60.0, help="seconds per run (60)")
    p.add_argument("--traces", type=Path, default=find_traces(), help="folder of the traces")
    p.add_argument(
        "--part",
        nargs="+",
        choices=("bounds", "predict", "sprout"),
        default=["bounds", "predict", "sprout"],
        help="what to compute (all three)",
    )
    p.add_argument("--jobs", type=int, default=1, help="worker processes (1)")
    p.add_argument(
        "--hazard",
        type=float,
        default=0.0,
        help="the forecaster's stops per second that begin at any rate (0, as Sprout)",
    )
    p.add_argument(
        "--quantile",
        type=float,
        default=QUANTILE,
        help="the forecaster's cautious quantile of the deliveries (0.05, as Sprout)",
    )
    p.add_argument(
        "--stall",
        type=float,
        default=math.inf,
        help="the forecaster also stops as the reactive sender does, this many ms overdue (never)",
    )
    args = p.parse_args()
    if args.traces is None or not args.traces.is_dir():
        p.error("--traces: give the folder holding the recorded traces (../shared/traces)")
    if args.jobs < 1:
        p.error("--jobs: give 1 or more")
    if not 0.0 <= args.hazard < 1000.0:
        p.error("--hazard: give stops per second, 0 or more")
    if not 0.0 < args.quantile < 1.0:
        p.error("--quantile: give a fraction between 0 and 1, e.g. 0.05")
    if not args.stall > 0.0:
        p.error("--stall: give milliseconds above 0, e.g. 20")
    print(
        "Medians over offsets", ", ".join(f"{o:g}" for o in OFFSETS), "s; per offset in brackets."
    )
    with ProcessPoolExecutor(args.jobs) as pool:
        for name in args.trace:
            for way in args.way:
                texts = [spec(args.traces, name, way, 150_000, o, 0) for o in OFFSETS]
                label = f"{name} {'M->S' if way == 'ms' else 'S->M'}"
                if "bounds" in args.part:
                    bounds(texts, label, args.duration)
                if "predict" in args.part:
                    predictability(texts, label, args.duration, pool)
                if "sprout" in args.part:
                    sprout(
                        texts, label, args.duration, pool, args.hazard, args.quantile, args.stall
                    )


if __name__ == "__main__":
    main()
