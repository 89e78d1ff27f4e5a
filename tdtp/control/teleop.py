"""The teleop controller: TDTP's default, judged by queueing delay and loss together (docs/CONTROL.md 9).

A teleoperation loop wants its full rate while the path has room and short queues when it has not.
Loss alone cannot say which: random loss and reordering look like congestion, and a deep buffer hides
congestion until it holds seconds of data. So this controller watches the queue.

* **Queue delay.** Time is cut into *control intervals* of ``max(srtt, interval)``. The smallest RTT
  sample of an interval is its *standing* RTT (the queue every packet of it waited behind; jitter lifts
  single samples, not the floor: Copa's ``RTT_standing``), and the smallest sample of the last
  ``base_window`` seconds is the path's base RTT. Their difference is the queue delay.
* **Decisions, once per interval.** Queue delay above ``target_queue_delay`` and not already falling
  fast: the rate drops to ``delay_decrease`` times what the peer received in the interval (GCC's
  ``0.85 x`` the receive rate), which drains the queue. Queue delay below half the target: the rate
  grows, doubling per interval until the first sign of congestion, then by ``probe_gain`` per interval
  (GCC's multiplicative and additive increase). In between, or while it is rising, the rate holds.
* **Loss.** A loss event while the queue delay is above half the target, or rising, is congestion:
  the rate in use is cut by ``loss_decrease`` (at most once per srtt). Any other loss is random loss
  or reordering on a path with room and does not change the rate, up to a loss event rate of
  ``heavy_loss`` (GCC holds its rate between 2 % and 10 % loss); above it each interval takes
  ``p / 2`` off the rate.
* **TCP-friendly ceiling, in bytes.** Once ``p > 0`` the flow's bytes on the wire (datagram plus
  ``ip_overhead``) never exceed what a TCP with ``tcp_segment``-byte segments carries at the same ``p``
  and srtt (RFC 5348's equation, ``t_RTO = 4 srtt``): TFRC-SP's argument (RFC 4828) without its
  100 packets/s cap.
* **Floor, opt-in.** ``min_rate`` (0 = off) is a rate the controller never goes below, whatever the
  path says: for dedicated links only; it gives up fairness.

The application-limited guard (an allowance of at most ``app_headroom`` times what the application
sends), the blackout back-off and the outage resume are trinomial's (docs/CONTROL.md 3.4, 3.5), and
the trinomial pacer spaces the packets. :attr:`TeleopController.rate_limit` says what limits the rate.
"""

from __future__ import annotations

import math
from typing import ClassVar, Final

from mypy_extensions import mypyc_attr

from tdtp.control.base import PacingSchedule, RateController
from tdtp.control.competition import BASE_HOLD, Competition
from tdtp.control.competition import LOSS_DECREASE as COMPETE_LOSS
from tdtp.control.competition import OVERFLOW_DECREASE as COMPETE_OVERFLOW
from tdtp.control.equations import padhye_rate
from tdtp.control.one_way_signal import OneWaySignal
from tdtp.control.send_meter import GAP_GAIN, SendMeter
from tdtp.control.start_window import StartWindow
from tdtp.control.teleop_config import TeleopConfig, positive_finite

__all__ = [
    "LIMIT_APPLICATION",
    "LIMIT_BLACKOUT",
    "LIMIT_FLOOR",
    "LIMIT_LOSS",
    "LIMIT_PROBING",
    "LIMIT_QUEUE_DELAY",
    "LIMIT_STALLED",
    "LIMIT_TCP_FRIENDLY",
    "TeleopConfig",
    "TeleopController",
]


MIN_SAMPLES: Final = 16
"""RTT samples a control interval needs before it judges the queue: the smallest of fewer would
read jitter as queue. An interval without them is stretched, up to ``MAX_STRETCH`` times its length."""
MIN_ONE_WAY_SAMPLES: Final = 4
"""The same for one-way samples, which come one per peer stamp (every few ms) and carry the jitter
of one direction only."""
DRAIN_FLOOR: Final = 0.25
"""A drain sends at least this fraction of the delivered rate (a deeper queue drains for longer)."""
DRAIN_LONGEST: Final = 4.0
"""A drain lasts at most this many base round trips (it ends earlier when the queue is gone)."""
CRUISE: Final = 0.95
"""After a drain the rate is this fraction of what the link delivered while the queue built."""
OWD_PROBE: Final = 0.01
"""With one-way delays: the first probe step above what the link carried, as a fraction of the rate
(at least ``initial_rate``); it doubles with each interval the queue stays short."""
GROWING: Final = 0.1
"""With one-way delays: a standing queue that grew by this fraction of the target in each of two
intervals in a row stops the probe (it holds the rate)."""
BLIND_SHARE: Final = 0.5
"""A direction whose peer went silent holds this share of what its receiver last received (one
halving, as a loss would cost, then no more for ``blind_hold``)."""
WINDOW_QUEUE: Final = 0.03
"""Seconds of queue (at the rate the link delivers) the window allows at least, above the lag of
the feedback; more when the queue-delay target is higher (twice it)."""
WINDOW_MIN: Final = 4.0
"""Packets the window allows at least."""
WINDOW_PROBE: Final = 0.05
"""A full window still lets a packet go this often (or once per lag, if longer)."""
LAG_GAIN: Final = 0.125
DRAIN_RATE: Final = 20.0
"""Packets/s a drain keeps sending at least (enough to see the queue go within 50 ms)."""
MAX_STRETCH: Final = 8.0
NOISE_GAIN: Final = 0.125
"""Gain of the moving average of the standing RTT's interval-to-interval change."""
NOISE_CAP: Final = 0.005
"""One interval's change counts at most this much (s) in it: a queue building up is not noise."""
DEEP_QUEUE: Final = 3.0
"""A queue this many times the threshold is congestion at once, without a second interval."""
JITTER_GAIN: Final = 1.0 / 16.0
"""Gain of the moving average of the difference between consecutive RTT samples (RFC 3550's
interarrival jitter, on round trips)."""
JITTER_SHARE: Final = 1.5
"""Standing delay tolerated per unit of that jitter: a FIFO whose packets draw random delays (netem
with a rate, a radio link's scheduler) holds each one behind slower ones, which lifts the floor of a
fast flow's RTT samples by up to the jitter's range although nothing queues for lack of capacity."""
JITTER_CAP: Final = 0.020
"""The jitter's share of the target is at most this (s)."""

LIMIT_APPLICATION: Final = "application"
"""The application sends less than it is allowed: nothing on the path holds it back."""
LIMIT_QUEUE_DELAY: Final = "queue delay"
"""The last decrease answered a queue above the target delay."""
LIMIT_LOSS: Final = "loss"
"""The last decrease answered loss with a growing queue, or loss above ``heavy_loss``."""
LIMIT_TCP_FRIENDLY: Final = "tcp-friendly ceiling"
"""The rate sits at the byte-based TCP-friendly ceiling."""
LIMIT_FLOOR: Final = "floor"
"""The rate sits at the opt-in ``min_rate`` floor, below what the path signals."""
LIMIT_BLACKOUT: Final = "no feedback"
"""No acknowledgement for several RTTs: the rate backs off until feedback returns."""
LIMIT_PROBING: Final = "probing"
"""The pacer holds the sender and the rate is still growing towards what the path carries."""
LIMIT_STALLED: Final = "window full"
"""Our packets in flight fill the window (the link delivers less than we send, or nothing): more
would only queue; they leave as the peer reports arrivals, and a probe now and then."""
LIMIT_COMPETING: Final = "competing (tcp-fair)"
"""Another flow keeps the queue full whatever this one does (a loss-based TCP, BBR): the rate
follows TCP's congestion avoidance in bytes (docs/CONTROL.md 9.9)."""
LIMIT_HOLDING: Final = "no feedback, holding"
"""Nothing arrives from the peer (the way back is out): the rate its receiver last reported holds,
for ``blind_hold`` seconds."""


@mypyc_attr(allow_interpreted_subclasses=True)
class TeleopController(RateController):
    """Delay- and loss-based rate control for teleoperation; see the module docstring."""

    name: ClassVar[str] = "teleop"
    judges_one_way_delay: ClassVar[bool] = True

    def __init__(self, config: TeleopConfig | None = None) -> None:
        cfg = config if config is not None else TeleopConfig()
        self._cfg = cfg
        self._floor = max(cfg.lowest_rate, cfg.min_rate)
        self._rate = max(cfg.initial_rate, self._floor)
        self._srtt = cfg.initial_rtt
        self._schedule = PacingSchedule()
        self._p = 0.0
        self._mean_size = 0.0  # moving average of datagram sizes, bytes
        # The TCP-friendly ceiling: the rate it cut (restored as the ceiling rises again), and the
        # rate in use at the first loss event (the ceiling's floor until the second one).
        self._capped_from: float | None = None
        self._loss_events = 0
        self._first_loss_rate = 0.0
        # Base RTT: the minimum over two half-windows (the older one expires as a whole).
        self._base_now = math.inf
        self._base_old = math.inf
        self._base_since = 0.0
        # The control interval under way.
        self._started = False
        self._iv_start = 0.0
        self._iv_end = 0.0
        self._iv_min_rtt = math.inf
        self._iv_min_sent = 0.0  # (one-way samples) when the interval's smallest was sent
        self._iv_samples = 0
        self._iv_acked = 0
        self._last_sample = math.nan  # the previous RTT sample, for the jitter
        self._jitter = 0.0
        self._queue_delay = 0.0
        self._prev_queue_delay = 0.0
        self._prev2_queue_delay = 0.0
        self._noise = 0.0
        self._rate_before_decrease = 0.0
        self._next_drain = cfg.drain_every
        self._draining_from: float | None = None  # the rate to restore after a drain interval
        self._loss_since_drain = False  # a loss event since the last drain interval
        self._last_congestion = -math.inf
        self._congested_once = False
        self._last_decrease = -math.inf
        self._reason = LIMIT_APPLICATION
        # The application-limited guard.
        self._sending = SendMeter()
        # Blackout and outage.
        self._nf_deadline: float | None = None
        self._blackout = False
        self._rate_before_blackout = self._rate
        self._resume_rate: float | None = None
        # One-way delays (docs/CONTROL.md 9.7): once the peer's stamps time our direction, its queue
        # alone is judged; the round trip then only sets the interval and the drain's horizon.
        self._owd = False
        self._signal = OneWaySignal()
        self._min_rtt = math.inf  # the smallest RTT sample (the drain's horizon)
        self._drain_until = -math.inf  # a drain under way sends less until then
        self._drain_from = -math.inf  # ...since then
        self._drain_queue = 0.0  # ...to empty this queue
        self._drain_peak = 0.0  # ...the link delivering this meanwhile, at the most
        self._cruise = 0.0  # ...and what it delivered when the drain began
        # The window (one-way delays): our packets not known to have arrived, and their bound.
        self._in_flight = 0
        self._window = math.inf
        self._blocked = False
        self._lag = 0.0  # moving average of feedback's lag behind our sends, our queue excepted
        self._blind_until = -math.inf
        self._holding = False
        self._competition = Competition()
        self._start = StartWindow(cfg.start_window)  # (docs/CONTROL.md 9.10)
        self._owd_min = math.inf  # the smallest one-way sample (what the start's queue is above)
        self._ups = 0  # increases in a row (one-way delays: the probe's step doubles with them)
        # Counters, for tests and statistics.
        self._delay_decreases = 0
        self._loss_decreases = 0
        self._losses_ignored = 0
        self._increases = 0

    # ------------------------------------------------------------------ read-only state

    @property
    def config(self) -> TeleopConfig:
        """The configuration this controller runs with."""
        return self._cfg

    @property
    def rate(self) -> float:
        return self._rate

    @property
    def queue_delay(self) -> float:
        """The queue delay the last control interval measured, seconds."""
        return self._queue_delay

    @property
    def base_rtt(self) -> float:
        """The smallest RTT sample of the last ``base_window`` (``inf`` before any)."""
        return min(self._base_now, self._base_old)

    @property
    def ceiling(self) -> float:
        """The byte-based TCP-friendly ceiling in packets/s (``inf`` before any loss)."""
        return self._ceiling()

    @property
    def rate_limit(self) -> str:
        """What limits the rate now: one of the ``LIMIT_*`` strings, ``queue delay`` with the delay
        (``"queue delay 7.2 ms"``)."""
        if self._cfg.min_rate > 0.0 and self._rate <= self._cfg.min_rate:
            return LIMIT_FLOOR
        if self._blocked:
            return LIMIT_STALLED
        if self._holding:
            return LIMIT_HOLDING
        if self._competition.active and not self._sending.app_limited:
            return LIMIT_COMPETING
        if self._blackout:
            return LIMIT_BLACKOUT
        if self._rate >= self._ceiling() * (1.0 - 1e-9):
            return LIMIT_TCP_FRIENDLY
        if self._sending.app_limited:
            return LIMIT_APPLICATION
        if self._reason == LIMIT_QUEUE_DELAY:
            way = "one way" if self._owd else "round trip"
            return f"{LIMIT_QUEUE_DELAY} {self._queue_delay * 1e3:.1f} ms {way}"
        return self._reason

    @property
    def delay_decrease_count(self) -> int:
        """Decreases for a queue that kept growing (queueing delay above the target)."""
        return self._delay_decreases

    @property
    def loss_decrease_count(self) -> int:
        """Decreases for loss: loss with a growing queue, or above ``heavy_loss``."""
        return self._loss_decreases

    @property
    def losses_ignored(self) -> int:
        """Loss events on a path whose queue was not growing: held, not answered."""
        return self._losses_ignored

    @property
    def increase_count(self) -> int:
        """Rate increases so far."""
        return self._increases

    @property
    def in_blackout(self) -> bool:
        """True while no feedback has arrived for the no-feedback timeout (the rate is held down)."""
        return self._blackout

    # ------------------------------------------------------------------ RateController

    def next_send_time(self) -> float:
        departure = self._schedule.next_departure
        if self._blocked:
            # The window is full: wait for feedback, probing now and then (a link that lost what
            # it held would otherwise never answer).
            last = self._sending.last_send
            if last is not None:
                probe = last + (self._lag if self._lag > WINDOW_PROBE else WINDOW_PROBE)
                if probe > departure:
                    return probe
        return departure

    def get_timer(self) -> float | None:
        if not self._started:
            return None
        deadline = self._nf_deadline
        if self.sample_waiting and (deadline is None or self._iv_end < deadline):
            deadline = self._iv_end
        return deadline

    def on_timer(self, *, now: float) -> None:
        self._advance(now)

    def on_packet_sent(self, *, now: float, size: int, paced: bool = True) -> None:
        self._advance(now)
        start = self._start
        # (A packet the start's window held was held by the path's silence, not by the pacer: the
        # application still sets the pace, and decreases start from what it sends.)
        self._sending.on_departure(now, paced and not start.active)
        mean = self._mean_size
        self._mean_size = float(size) if mean == 0.0 else mean + GAP_GAIN * (size - mean)
        if self._nf_deadline is None:
            self._nf_deadline = now + self._no_feedback_timeout()
        self._schedule.on_departure(now, self._rate)
        self._in_flight += 1
        if start.active:
            if start.on_sent():
                self._blocked = True
        elif (
            self._in_flight >= self._window
            and self._owd
            and not self._holding
            and not self._competition.active
        ):
            self._blocked = True

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
        self._advance(now)
        if positive_finite(srtt):
            self._srtt = srtt
            # An interval lasts one current srtt: the first samples cut short the one begun under
            # initial_rtt.
            end = self._iv_start + self._nominal_interval()
            if end < self._iv_end:
                self._iv_end = end
        if not math.isnan(loss_event_rate):
            self._set_p(loss_event_rate)
        if rtt_sample is not None and rtt_sample > 0.0:
            self._on_rtt_sample(now, rtt_sample)
        self._iv_acked += max(acked, 0)
        start = self._start
        if start.active:
            start.on_acked(acked)
            if start.active:
                self._blocked = start.full()
            else:
                self._end_start()
        self._nf_deadline = None  # re-armed by the next packet sent
        if self._blackout:
            self._blackout = False
            self._start_interval(now)
        self._apply_ceiling(now)

    def on_loss_event(self, *, now: float, srtt: float, loss_event_rate: float) -> None:
        self._advance(now)
        if positive_finite(srtt):
            self._srtt = srtt
        if not math.isnan(loss_event_rate):
            self._set_p(loss_event_rate)
        self._loss_since_drain = True
        self._loss_events += 1
        self._competition.last_loss = now
        target = self._target()
        # As the last complete interval measured the queue (a part of one has too few samples to
        # see through jitter): standing above half the target, or grown by a quarter of it.
        queue = self._queue_delay
        previous = self._prev_queue_delay
        earlier = self._prev2_queue_delay
        growing = (
            queue > target
            or (
                queue > 0.5 * target
                and queue > previous > earlier
                and queue - earlier > 0.5 * target
            )
            or self._competition.active  # (competing: every loss is congestion, as for TCP)
        )
        if growing and now - self._last_decrease >= self._srtt:
            factor = COMPETE_LOSS if self._competition.active else self._cfg.loss_decrease
            self._decrease(now, self._rate_in_use() * factor)
            self._loss_decreases += 1
            self._last_decrease = self._last_congestion = now
            self._congested_once = True
            self._reason = LIMIT_LOSS
            self._start_interval(now)
        elif not growing:
            self._losses_ignored += 1
        self._apply_ceiling(now)

    def on_peer_silent(self, *, now: float) -> None:
        self._advance(now)
        before = self._rate_before_blackout if self._blackout else self._rate
        self._resume_rate = max(before, self._resume_rate or 0.0)
        if self._owd and self._cfg.blind_hold > 0.0:
            # Nothing at all arrives: the way back may be what failed, and our direction was
            # delivering when last heard of. Hold what it delivered (docs/CONTROL.md 9.8).
            self._holding = True
            self._blocked = False
            self._blind_until = now + self._cfg.blind_hold
            delivered = self._signal.rate
            hold = BLIND_SHARE * (min(before, delivered) if delivered > 0.0 else before)
            self._blackout = False
            self._set_rate(now, hold)
            self._nf_deadline = self._blind_until

    def on_peer_resumed(self, *, now: float, silent_for: float) -> None:
        """After an outage, resume at half the rate from before it (as trinomial does)."""
        resume, self._resume_rate = self._resume_rate, None
        if self._holding or self._owd:
            # What was sent into the silence may still be queued: judge what is sent from now on.
            self._holding = False
            self._blind_until = -math.inf
            self._signal.gate(now)
        if resume is None:
            return
        self._advance(now)
        target = min(0.5 * resume, self._cfg.max_rate, self._ceiling())
        if target > self._rate:
            self._set_rate(now, target)
            self._blackout = False
            self._nf_deadline = None
            self._start_interval(now)

    def on_one_way_delay(
        self, *, now: float, delay: float, sent_at: float, seq: int, hold: float, unacked: int
    ) -> None:
        self._advance(now)
        self._in_flight = unacked
        if unacked < self._window and not self._start.active:
            self._blocked = False
        if not self._owd:
            # From now on the queue is our direction's alone: the round trip's base and minima,
            # which carry the way back's queue too, are dropped.
            self._owd = True
            self._base_now = self._base_old = math.inf
            self._iv_min_rtt = math.inf
            self._iv_samples = 0
        signal = self._signal
        timed = not math.isnan(delay)  # (NaN: the stamp timed none of our packets)
        if timed:
            signal.add(delay, sent_at, seq, hold)
            if delay < self._owd_min:
                self._owd_min = delay
            if self._start.active:
                floor = signal.queue_floor()  # (inf until RECENT samples)
                if floor < math.inf and floor - self._owd_min > self._target():
                    self._end_start()  # a queue: the start overshot what the path carries
            if delay < self._iv_min_rtt:
                self._iv_min_rtt = delay
                self._iv_min_sent = sent_at
            self._iv_samples += 1
        base = self.base_rtt
        if base == math.inf or not timed:
            return
        # The window: what the link delivers times the lag of our feedback (everything but our
        # own queue) plus the queue we allow. Sending beyond it only queues (docs/CONTROL.md 9.7).
        queue = delay - base
        lag = now - sent_at - (queue if queue > 0.0 else 0.0)
        self._lag = lag if self._lag == 0.0 else self._lag + LAG_GAIN * (lag - self._lag)
        delivered = signal.peak  # (the highest of the last half second: a window sized by the
        # current rate alone would shrink with every pause of a bursty link, and hold it there)
        if delivered > 0.0:
            allowance = 2.0 * self._target()
            if allowance < WINDOW_QUEUE:
                allowance = WINDOW_QUEUE
            window = delivered * (self._lag + allowance)
            self._window = window if window > WINDOW_MIN else WINDOW_MIN
            if self._start.active:
                return  # (the start's window holds the sender until it ends)
            self._blocked = (
                unacked >= self._window and not self._holding and not self._competition.active
            )
        target = self._target()
        floor = signal.queue_floor() - base
        if floor == math.inf:
            return  # fewer than RECENT samples since the last decision
        if now < self._drain_until:
            # A drain is under way, and this packet was sent since it began. A queue worse than
            # the one it drains calls for another (the link slowed down again); a short one ends
            # it (the link delivered faster than it did when the queue built).
            if floor > self._drain_queue + target:
                self._drain(now, floor, sent_at)
                return
            if floor > 0.5 * target:
                # The queue still holds packets: what arrives now is the link's rate.
                if signal.rate > self._drain_peak:
                    self._drain_peak = signal.rate
            else:
                self._drain_until = now
                self._end_drain(now)
        elif floor > DEEP_QUEUE * target and not self._competition.active:
            self._drain(now, floor, sent_at)

    def _end_start(self) -> None:
        """The start is over: from now on the window of section 9.7 (if any) holds the sender."""
        self._start.end()
        self._blocked = self._owd and self._in_flight >= self._window

    def _end_drain(self, now: float) -> None:
        """The drain is over: on at ``CRUISE`` times what the link delivered, as it delivered
        while the queue built or, if faster, while the drain emptied it."""
        delivered = self._cruise if self._cruise > self._drain_peak else self._drain_peak
        self._cruise = 0.0
        self._rate_before_decrease = delivered
        self._set_rate(now, min(CRUISE * delivered, self._cfg.max_rate, self._ceiling()))
        self._signal.gate(now)
        self._start_interval(now)

    def _drain(self, now: float, queue: float, sent_at: float) -> None:
        """Empty a queue of ``queue`` seconds, seen by a packet sent at ``sent_at``, in about one
        base round trip: send below what the link delivers for as long as that takes, then at
        ``CRUISE`` times it (docs/CONTROL.md 9.7)."""
        delivered = self._signal.rate
        use = self._rate_in_use()
        if delivered <= 0.0:
            delivered = use
        if use > delivered:
            # What we sent since the sampled packet, faster than the link took it, queued too
            # (counted up to what twice the link's rate would have queued).
            queue += (now - sent_at) * min(use / delivered - 1.0, 1.0)
        excess = queue - 0.5 * self._target()
        if excess <= 0.0:
            return
        horizon = self._min_rtt if self._min_rtt < math.inf else self._srtt
        if horizon < self._cfg.interval:
            horizon = self._cfg.interval
        fraction = max(1.0 - excess / horizon, DRAIN_FLOOR)
        self._decrease(now, max(delivered * fraction, DRAIN_RATE), carried=delivered)
        # The drain's length if the link keeps delivering what it did; it ends earlier when the
        # packets sent since show the queue gone (a link that recovered empties it faster).
        self._drain_until = now + min(excess / (1.0 - fraction), DRAIN_LONGEST * horizon)
        self._drain_from = now
        self._drain_queue = queue
        self._drain_peak = 0.0
        self._cruise = delivered
        self._delay_decreases += 1
        self._last_decrease = self._last_congestion = now
        self._congested_once = True
        self._reason = LIMIT_QUEUE_DELAY
        self._queue_delay = queue
        self._signal.gate(now)
        self._start_interval(now)

    # ------------------------------------------------------------------ internals

    def _on_standing_rtt(self, now: float, standing: float) -> None:
        """The base RTT is the smallest standing RTT of the last ``base_window``: a statistic of the
        same kind as the one it is compared with (the smallest of many raw samples would sit below
        every interval's floor by the jitter's whole range). Competing, it keeps ``BASE_HOLD``."""
        half = BASE_HOLD if self._competition.active else 0.5 * self._cfg.base_window
        if now - self._base_since >= half:
            self._base_old = self._base_now
            self._base_now = math.inf
            self._base_since = now
        if standing < self._base_now:
            self._base_now = standing

    def _on_rtt_sample(self, now: float, sample: float) -> None:
        if sample < self._min_rtt:
            self._min_rtt = sample
        if self._owd:
            return  # the queue is judged on our direction's one-way delays
        if sample < self._iv_min_rtt:
            self._iv_min_rtt = sample
        self._iv_samples += 1
        last = self._last_sample
        if not math.isnan(last):
            # Random delays make consecutive samples differ by about the delays' spread; a queue
            # building up moves them by a packet's transmit time at a time, and adds almost nothing.
            self._jitter += JITTER_GAIN * (abs(sample - last) - self._jitter)
        self._last_sample = sample

    def _advance(self, now: float) -> None:
        if not self._started:
            self._started = True
            self._base_since = now
            self._next_drain = now + self._cfg.drain_every
            self._start_interval(now)
            return
        deadline = self._nf_deadline
        if deadline is not None and now >= deadline and now < self._blind_until:
            deadline = self._nf_deadline = self._blind_until
        if deadline is not None and now >= deadline:
            self._holding = False
            timeout = self._no_feedback_timeout()
            missed = min(1 + int((now - deadline) // timeout), 64)
            if not self._blackout:
                self._rate_before_blackout = self._rate
            self._blackout = True
            self._capped_from = None
            self._set_rate(now, self._rate * 0.5**missed)
            self._nf_deadline = now + self._no_feedback_timeout()
            self._start_interval(now)
        if now >= self._drain_until and self._cruise > 0.0:
            self._end_drain(now)
        if now >= self._iv_end:
            self._end_interval(now)

    def _target(self) -> float:
        """The queue delay that counts as congestion: the configured target, plus twice the
        interval-to-interval noise of the standing RTT, plus ``JITTER_SHARE`` times the path's RTT
        jitter (at most ``JITTER_CAP``): on a jittery FIFO path a fast flow's standing RTT sits
        above a slow flow's by up to the jitter's range with no queue for capacity (docs/CONTROL.md
        9.2)."""
        jitter = JITTER_SHARE * (self._signal.jitter if self._owd else self._jitter)
        return (
            self._cfg.target_queue_delay
            + 2.0 * self._noise
            + (jitter if jitter < JITTER_CAP else JITTER_CAP)
        )

    @property
    def jitter(self) -> float:
        """The moving average of the difference between consecutive RTT samples (s)."""
        return self._jitter

    def _nominal_interval(self) -> float:
        """One srtt, at least ``interval``; at most twice the base RTT once it is known: a queue
        that stretches the RTT must not slow down the very decisions that would drain it."""
        srtt = self._srtt
        cap = 2.0 * min(self._base_now, self._base_old)
        return max(srtt if srtt < cap else cap, self._cfg.interval)

    def _start_interval(self, now: float) -> None:
        self._iv_start = now
        self._iv_end = now + self._nominal_interval()
        self._iv_min_rtt = math.inf
        self._iv_min_sent = now
        self._iv_samples = 0
        self._iv_acked = 0

    def _end_interval(self, now: float) -> None:
        cfg = self._cfg
        duration = now - self._iv_start
        if self._iv_samples < (MIN_ONE_WAY_SAMPLES if self._owd else MIN_SAMPLES):
            if self._blackout or not self._iv_samples:
                self._start_interval(now)  # nothing to judge (the blackout timer acts)
                return
            if duration < MAX_STRETCH * self._nominal_interval():
                self._iv_end = now + self._nominal_interval() / 2.0  # wait for more samples
                return
            # Stretched as far as it goes (a slow sender): judge on what there is.
        if duration <= 0.0:
            self._start_interval(now)
            return
        restore = self._draining_from
        if restore is not None:
            # The drain interval's standing RTT is the best view of the empty path; it judges
            # nothing else (the flow held itself back), and the rate returns to what it was.
            self._draining_from = None
            self._on_standing_rtt(now, self._iv_min_rtt)
            self._set_rate(now, max(restore, self._rate))
            self._start_interval(now)
            return
        self._on_standing_rtt(now, self._iv_min_rtt)
        queue = max(self._iv_min_rtt - self.base_rtt, 0.0)
        previous = self._queue_delay
        self._prev2_queue_delay = self._prev_queue_delay
        self._prev_queue_delay = previous
        self._queue_delay = queue
        # How much the standing RTT wanders from one interval to the next on its own (jitter the
        # interval's minimum did not filter out): the threshold sits this much above the target.
        self._noise += NOISE_GAIN * (min(abs(queue - previous), NOISE_CAP) - self._noise)
        target = self._target()
        delivered = self._iv_acked / duration
        if self._owd and self._signal.rate > 0.0:
            delivered = self._signal.rate  # measured on the peer's clock
        competition = self._competition
        if competition.active:
            self._compete(now, queue, target, duration)
            self._start_interval(now)
            return
        compete_from = competition.observe(now, queue, target, self._rate, self._srtt)
        if compete_from > 0.0:
            # The queue stayed up whatever this flow did: another keeps it (docs/CONTROL.md 9.9).
            self._drain_until = -math.inf
            self._cruise = 0.0
            self._blocked = False
            self._capped_from = None
            self._set_rate(now, max(compete_from, self._rate))
            self._start_interval(now)
            return
        if now < self._drain_until:
            self._start_interval(now)  # a drain sets the rate until it ends
            return
        ups = self._ups
        self._ups = 0  # (kept by an increase)
        if queue > target:
            self._last_congestion = now
            self._congested_once = True
            draining = queue < previous - 0.5 * target
            # Two intervals in a row: not one jittery floor; or one so far above the target (a
            # start-up that overshot a bottleneck) that no jitter the margin allows explains it.
            sustained = previous > target or queue > DEEP_QUEUE * target
            if sustained and not draining and self._owd:
                self._drain(now, queue, self._iv_min_sent)
            elif sustained and not draining and now - self._last_decrease >= self._srtt:
                base = self._rate_in_use()
                if delivered > 0.0:
                    base = min(base, delivered)
                self._decrease(now, base * cfg.delay_decrease, carried=base)
                self._delay_decreases += 1
                self._last_decrease = now
                self._reason = LIMIT_QUEUE_DELAY
        elif (
            self._owd
            and queue > 0.25 * target
            and queue > previous + GROWING * target
            and previous > self._prev2_queue_delay + GROWING * target
        ):
            # The standing queue grew in each of the last two intervals (still short): the probe
            # went past what the link delivers. Hold, before the queue reaches the target.
            pass
        elif queue <= 0.5 * target or queue <= previous:
            if self._p > cfg.heavy_loss:
                self._capped_from = None
                self._set_rate(now, self._rate * (1.0 - 0.5 * self._p))
                self._last_decrease = now
                self._reason = LIMIT_LOSS
            else:
                self._ups = ups
                self._increase(now)
        self._start_interval(now)
        if (
            self._loss_since_drain
            and now >= self._next_drain
            and now - self._last_decrease >= self._srtt
        ):
            # A drain interval, twice as long as the others: the queue it drains shows in the RTT
            # samples one round trip later.
            self._next_drain = now + cfg.drain_every
            self._loss_since_drain = False
            self._draining_from = self._rate
            self._capped_from = None
            self._set_rate(now, self._rate_in_use() * cfg.drain_fraction)
            self._iv_end = now + 2.0 * self._nominal_interval()

    def _compete(self, now: float, queue: float, target: float, duration: float) -> None:
        """An interval of the competitive mode: TCP's additive increase in bytes, or a check
        whether the competitor is still there (the loss rule does the halving)."""
        competition = self._competition
        if competition.probing:
            restore = competition.during_probe(now, queue, target)
            if restore == 0.0:
                self._ups = 0  # the queue was ours: back to the delay mode from here
            elif restore > 0.0:
                self._set_rate(now, restore)
            return
        probe = competition.probe_due(now, self._rate_in_use(), self._srtt)
        if probe > 0.0:
            self._capped_from = None
            self._set_rate(now, probe)
            return
        if competition.full(now, queue):
            if now - self._last_decrease >= self._srtt:
                self._decrease(now, self._rate_in_use() * COMPETE_OVERFLOW)
                self._last_decrease = now
            return
        cfg = self._cfg
        size = (self._mean_size if self._mean_size > 0.0 else 100.0) + cfg.ip_overhead
        rate = self._rate
        ceiling = min(cfg.max_rate, self._ceiling())
        if self._sending.app_limited:
            ceiling = min(ceiling, max(rate, cfg.app_headroom * self._sending.send_rate()))
        step = competition.step(self._srtt, duration, size, cfg.tcp_segment)
        if ceiling > rate:
            self._set_rate(now, min(rate + step, ceiling))

    def _increase(self, now: float) -> None:
        cfg = self._cfg
        ramp = not self._congested_once or now - self._last_congestion >= cfg.ramp_reset
        gain = cfg.ramp_gain if ramp else cfg.probe_gain
        rate = self._rate
        ceiling = min(cfg.max_rate, self._ceiling())
        if self._sending.app_limited:
            ceiling = min(ceiling, max(rate, cfg.app_headroom * self._sending.send_rate()))
        if ceiling > rate * (1.0 + 1e-9):
            # Below the rate a decrease started from, close half the distance per interval (the
            # path carried it a moment ago); beyond it, probe.
            # The probe is additive below initial_rate (a fixed step for every flow, so that flows
            # sharing a queue converge to equal rates, as AIMD does) and proportional above it.
            grow = gain * rate if ramp else gain * max(rate, cfg.initial_rate)
            if self._owd and not ramp:
                # One-way delays show a queue early and exactly: probe in small steps that double
                # while the queue stays short (Copa's velocity), from 1 % up to 32 %.
                ups = self._ups
                grow = OWD_PROBE * max(rate, cfg.initial_rate) * (1 << min(max(ups - 1, 0), 5))
            step = max(grow, 0.5 * (self._rate_before_decrease - rate))
            self._set_rate(now, min(rate + step, ceiling))
            self._increases += 1
            self._ups += 1
            if not self._sending.app_limited:
                self._reason = LIMIT_PROBING

    def _rate_in_use(self) -> float:
        """The allowed rate, or what the application sends when it sets the pace (trinomial's
        ``decrease_in_use``: a decrease slows the sender down from what it sends)."""
        rate = self._rate
        if self._sending.app_limited:
            sending = self._sending.send_rate()
            if sending > 0.0:
                rate = min(rate, sending)
        return rate

    def _ceiling(self) -> float:
        """What a TCP with ``tcp_segment``-byte segments carries at this p and srtt, in bytes per
        second, divided by this flow's bytes per packet on the wire.

        Until the second loss event it is never below the rate in use at the first: p then rests
        on one interval that began at an arbitrary point (the connection's start), so a loss in the
        first few packets would read as p = 1/3. RFC 5348 (6.3.1) synthesises that first interval
        from the receive rate for the same reason."""
        p = self._p
        if p <= 0.0:
            return math.inf
        cfg = self._cfg
        srtt = self._srtt
        tcp_bytes = cfg.tcp_segment * padhye_rate(srtt, p, 4.0 * srtt)
        size = self._mean_size if self._mean_size > 0.0 else float(cfg.tcp_segment)
        ceiling = tcp_bytes / (size + cfg.ip_overhead)
        if self._loss_events < 2 and ceiling < self._first_loss_rate:
            return self._first_loss_rate
        return ceiling

    def _set_p(self, loss_event_rate: float) -> None:
        p = min(max(loss_event_rate, 0.0), 1.0)
        if p > 0.0 and self._p <= 0.0 and self._first_loss_rate <= 0.0:
            # The ceiling's floor for now; during the start, what the application offers (the start's
            # window, not the path, held the sender).
            used = self._rate_in_use()
            start = self._cfg.initial_rate if self._start.active else 0.0
            self._first_loss_rate = used if used > start else start
        self._p = p

    def _apply_ceiling(self, now: float) -> None:
        """Hold the rate under the ceiling; as p falls (the open loss interval grows) and the
        ceiling rises, give back what the ceiling took, at once (TFRC follows its equation up the
        same way): the ceiling is a bound on the rate, not a congestion signal."""
        ceiling = min(self._cfg.max_rate, self._ceiling())
        rate = self._rate
        if rate > ceiling:
            capped = self._capped_from
            self._capped_from = rate if capped is None or rate > capped else capped
            self._set_rate(now, ceiling)
        else:
            capped = self._capped_from
            if capped is not None and ceiling > rate:
                if ceiling >= capped:
                    self._capped_from = None
                    self._set_rate(now, capped)
                else:
                    self._set_rate(now, ceiling)

    def _decrease(self, now: float, rate: float, carried: float | None = None) -> None:
        """A decrease for congestion: remember where from, so that recovery aims back at it (not
        at a rate the ceiling had cut: the path has spoken since). ``carried``: what the path
        delivered while the queue built, when known; recovery aims no higher (after the start-up's
        doubling the allowed rate can be twice what the path ever carried)."""
        self._capped_from = None
        if self._start.active:
            self._end_start()
        self._rate_before_decrease = self._rate if carried is None else min(self._rate, carried)
        self._set_rate(now, rate)

    def _set_rate(self, now: float, rate: float) -> None:
        rate = min(max(rate, self._floor), self._cfg.max_rate)
        if rate == self._rate:
            return
        self._rate = rate
        self._schedule.reschedule(now, rate)

    def _no_feedback_timeout(self) -> float:
        timeout = max(self._cfg.no_feedback_rtts * self._srtt, 2.0 / self._rate)
        if self._owd and timeout < self.silence_timeout:
            # Silence first: whether the way back or ours failed decides what to do (9.8).
            timeout = self.silence_timeout
        return timeout + self.feedback_delay
