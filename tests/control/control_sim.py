"""A small fake-time path model that drives a RateController's hooks directly (no connection).

One sender, one path with a fixed round-trip time ``rtt``:

* the application offers a sample every ``1 / demand`` seconds (``demand = inf``: always backlogged);
  a sample waiting for the pacer is replaced by the next one (latest-sample semantics, as in the
  connection), and the packet leaves at ``max(sample time, controller.next_send_time())``;
* a packet is lost when ``loss(seq, send_time)`` says so, or when it or its acknowledgement falls in
  a blackout window; otherwise it is acknowledged (``on_ack`` with ``acked=1``) one ``rtt`` later;
* a lost packet is detected ``detect_delay`` after it was sent (default ``1.25 * rtt``: three later
  packets reported, or the timeout); losses of packets sent within one ``rtt`` of the first loss of
  an event belong to that event, so ``on_loss_event`` is called once per event;
* the loss event rate ``p`` is RFC 5348's: loss intervals in packets between the first losses of
  consecutive events, the last eight averaged with weights 1, 1, 1, 1, 0.8, 0.6, 0.4, 0.2, the open
  interval counted when it raises the mean;
* ``controller.get_timer()`` is served on time; the model fails if a served timer does not move on;
* ``report_p`` replaces the estimated ``p`` by a constant (for tests that want ``p`` held exactly).

Everything is deterministic: loss patterns are functions, random ones take a seeded ``Random``.
"""

from __future__ import annotations

import functools
import itertools
import math
import random
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from tdtp.control import NO_LIMIT, RateController

WEIGHTS = (1.0, 1.0, 1.0, 1.0, 0.8, 0.6, 0.4, 0.2)

LossFn = Callable[[int, float], bool]


def no_loss(seq: int, t: float) -> bool:
    return False


def bernoulli(p: float, seed: int) -> LossFn:
    rng = random.Random(seed)
    return lambda seq, t: rng.random() < p


def periodic(every: int) -> LossFn:
    """Lose one packet in every ``every`` (deterministic steady loss)."""
    return lambda seq, t: seq % every == every - 1


def until(stop: float, inner: LossFn) -> LossFn:
    """``inner`` for packets sent before ``stop``, no loss after."""
    return lambda seq, t: t < stop and inner(seq, t)


class LossIntervals:
    """RFC 5348 section 5.4 loss event rate over packet sequence numbers."""

    def __init__(self) -> None:
        self.starts: list[int] = []  # sequence number of the first loss of each event

    def on_event(self, seq: int) -> None:
        self.starts.append(seq)

    def p(self, highest_seq: int) -> float:
        starts = self.starts
        if not starts:
            return 0.0
        closed = [b - a for a, b in itertools.pairwise(starts)][::-1][:8]
        if not closed:
            closed = [max(starts[0], 1)]  # first interval: packets before the first loss
        open_interval = max(highest_seq - starts[-1] + 1, 1)
        n = len(closed)
        weights = WEIGHTS[:n]
        i_tot1 = sum(w * i for w, i in zip(weights, closed, strict=True))
        with_open = [open_interval, *closed][:n]
        i_tot0 = sum(w * i for w, i in zip(weights, with_open, strict=True))
        mean = max(i_tot0, i_tot1) / sum(weights)
        return 1.0 / mean


@dataclass
class Change:
    time: float
    hook: str
    before: float
    after: float


@dataclass
class Trace:
    sends: list[float] = field(default_factory=list)
    acks: list[float] = field(default_factory=list)
    loss_events: list[float] = field(default_factory=list)
    loss_p: list[float] = field(default_factory=list)  # p passed with each loss event
    lost: int = 0
    changes: list[Change] = field(default_factory=list)
    samples: list[tuple[float, float]] = field(default_factory=list)  # (time, rate) each rtt
    p_final: float = 0.0

    def sent_between(self, a: float, b: float) -> int:
        return sum(1 for t in self.sends if a <= t < b)

    def rate_at(self, t: float) -> float:
        """The allowed rate in force at time ``t`` (from the recorded changes)."""
        rate = self.samples[0][1] if self.samples else math.nan
        for change in self.changes:
            if change.time > t:
                break
            rate = change.after
        return rate


@dataclass
class Path:
    rtt: float
    loss: LossFn = no_loss
    demand: float = math.inf
    size: int = 125
    blackouts: tuple[tuple[float, float], ...] = ()
    detect_delay: float | None = None
    report_p: float | None = None

    def dark(self, t: float) -> bool:
        return any(a <= t < b for a, b in self.blackouts)


def run(
    controller: RateController,
    path: Path,
    duration: float,
    *,
    start: float = 0.0,
    trace: Trace | None = None,
    observe: Callable[[float, str], None] | None = None,
) -> Trace:
    """Drive ``controller`` over ``path`` from ``start`` for ``duration`` seconds of fake time."""
    trace = trace if trace is not None else Trace()
    end = start + duration
    rtt = path.rtt
    detect = path.detect_delay if path.detect_delay is not None else 1.25 * rtt
    acks: deque[tuple[float, int]] = deque()  # (arrival time, seq)
    detections: deque[tuple[float, int, float]] = deque()  # (detection time, seq, send time)
    intervals = LossIntervals()
    event_first_send = -math.inf
    highest_acked = -1
    seq = 0
    sample_index = 0
    now = start
    next_sample = start if path.demand < math.inf else -math.inf
    next_rate_sample = start
    changes = trace.changes

    def call(hook: str, fn: Callable[[], None], t: float) -> None:
        before = controller.rate
        fn()
        after = controller.rate
        if after != before:
            changes.append(Change(t, hook, before, after))
        if observe is not None:
            observe(t, hook)

    while True:
        if path.demand < math.inf:
            nst = controller.next_send_time()
            t_send = max(next_sample, nst if nst != NO_LIMIT else next_sample)
        else:
            nst = controller.next_send_time()
            t_send = max(now, nst) if nst != NO_LIMIT else now
        t_ack = acks[0][0] if acks else math.inf
        t_det = detections[0][0] if detections else math.inf
        timer = controller.get_timer()
        t_timer = timer if timer is not None else math.inf
        t = min(t_send, t_ack, t_det, t_timer)
        if t >= end:
            break
        now = max(now, t)
        while next_rate_sample <= now:
            trace.samples.append((next_rate_sample, controller.rate))
            next_rate_sample += rtt
        if t_timer <= t:
            call("timer", functools.partial(controller.on_timer, now=now), now)
            after = controller.get_timer()
            if after is not None and after <= now:
                raise AssertionError(f"timer {after} did not move past now={now} after on_timer")
        elif t_ack <= t:
            _, acked_seq = acks.popleft()
            highest_acked = max(highest_acked, acked_seq)
            trace.acks.append(now)
            p = intervals.p(highest_acked) if path.report_p is None else path.report_p
            call(
                "ack",
                functools.partial(
                    controller.on_ack,
                    now=now,
                    acked=1,
                    rtt_sample=rtt,
                    srtt=rtt,
                    rttvar=0.0,
                    loss_event_rate=p,
                ),
                now,
            )
        elif t_det <= t:
            _, lost_seq, send_time = detections.popleft()
            trace.lost += 1
            if send_time > event_first_send + rtt:
                event_first_send = send_time
                intervals.on_event(lost_seq)
                trace.loss_events.append(now)
                p = intervals.p(max(highest_acked, lost_seq))
                p = p if path.report_p is None else path.report_p
                trace.loss_p.append(p)
                call(
                    "loss",
                    functools.partial(
                        controller.on_loss_event, now=now, srtt=rtt, loss_event_rate=p
                    ),
                    now,
                )
        else:
            # Paced: the pacer, not the application, held this packet (as the connection reports it).
            paced = path.demand == math.inf or (nst != NO_LIMIT and nst > next_sample)
            call(
                "send",
                functools.partial(controller.on_packet_sent, now=now, size=path.size, paced=paced),
                now,
            )
            trace.sends.append(now)
            if path.demand < math.inf:
                # The sample is consumed; the next one is the first sample time after now.
                sample_index = max(sample_index + 1, math.floor(now * path.demand + 1e-9) + 1)
                next_sample = sample_index / path.demand
            lost = path.loss(seq, now) or path.dark(now) or path.dark(now + rtt)
            if lost:
                detections.append((now + detect, seq, now))
            else:
                acks.append((now + rtt, seq))
            seq += 1
    trace.p_final = intervals.p(highest_acked)
    return trace
