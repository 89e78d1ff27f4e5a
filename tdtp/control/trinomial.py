"""The trinomial controller: TDTP's default flow control (paper section 3.2; docs/CONTROL.md).

The state is the inter-packet gap (IPG). Time is cut into *increase intervals*, each
``max(srtt, 2 / rate)`` long. At the start of an interval the controller chooses ``alpha`` (packets
per RTT) and ``W = srtt / alpha``; at its end, if the interval saw feedback, no loss event, and the
sender used its allowance, the gap shrinks by eq. 9, ``IPG' = IPG * W / (IPG + W)`` (the rate grows
by ``alpha / srtt``). A loss event lengthens the gap by eq. 10, ``IPG' = IPG / beta``, at most once
per srtt, applied to the gap in use: an application sending less than it is allowed is slowed down
from what it sends, not from its unused allowance. The rate never exceeds eq. 2 (or eq. 1 with
``use_padhye``) for the loss event rate the connection reports, nor ``max_rate``, and never falls
below ``min_rate``.

``alpha`` is where the paper's gamma enters: below the TCP-friendly cap an interval closes the
fraction ``gamma`` of the distance to the cap (at least ``alpha_min`` packets per RTT, at most
``max_increase`` times the rate); with no cap (no loss yet, or a loss history that a long loss-free
run has made stale) it multiplies the rate by ``max_increase`` per interval, like slow start.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, Final

from mypy_extensions import mypyc_attr

from tdtp.control.base import PacingSchedule, RateController
from tdtp.control.equations import padhye_rate, tcp_friendly_rate
from tdtp.control.send_meter import SendMeter

__all__ = [
    "RECOVERY_RTTS",
    "TrinomialConfig",
    "TrinomialController",
    "recovery_intervals",
]


def _positive_finite(value: float) -> bool:
    return 0.0 < value < math.inf


def _check_field(ok: bool, message: str) -> None:
    if not ok:
        raise ValueError(f"TrinomialConfig.{message}")


@mypyc_attr(native_class=False)  # a plain class: __post_init__ judges the types
@dataclass(frozen=True, slots=True)
class TrinomialConfig:
    """Configuration of :class:`TrinomialController`; docs/CONTROL.md justifies every default."""

    initial_rate: float = 1000.0
    """Packets/s before any feedback: a 1 kHz teleoperation loop is not throttled at start."""
    min_rate: float = 4.0
    """Floor, packets/s: one packet per 250 ms keeps RTT samples and ACKs flowing in a blackout."""
    max_rate: float = 100_000.0
    """Ceiling, packets/s."""
    alpha_min: float = 1.0
    """Smallest increase per interval, packets per RTT (RAP's alpha: TCP's additive increase)."""
    beta: float = 0.5
    """Eq. 10's decrease factor (RAP and TCP: halve)."""
    gamma: float = 0.5
    """Fraction of the distance to the TCP-friendly cap that one increase interval closes."""
    max_increase: float = 2.0
    """An increase interval multiplies the rate by at most this (2 = slow start's doubling)."""
    app_limited_fraction: float = 0.5
    """No increase unless at least this fraction of the interval's allowance was sent (RAP)."""
    app_headroom: float = 2.0
    """An increase never lifts the rate above this multiple of the measured send rate."""
    stale_loss_intervals: float = 6.0
    """The cap is lifted after ``this / p`` packets acknowledged without a loss event..."""
    stale_min_rtts: float = 4.0
    """...and at least this many srtts after the last loss event (``inf``: never lift)."""
    no_feedback_rtts: float = 4.0
    """Blackout: halve the rate after ``max(this * srtt, 2 / rate)`` without feedback (RFC 5348)."""
    initial_rtt: float = 0.5
    """srtt assumed before the first feedback (gives RFC 5348's initial 2 s no-feedback timer)."""
    use_padhye: bool = False
    """Cap with eq. 1 (Padhye, ``t_RTO = 4 * srtt``) instead of eq. 2."""
    decrease_in_use: bool = True
    """Eq. 10 lengthens the gap *in use*: it decreases the smaller of the allowed rate and the measured
    send rate. ``False`` decreases the allowance alone; an application-limited sender, allowed up to
    ``app_headroom`` times what it sends, then does not slow down at all, and a 1 kHz loop that fills
    a link locks TCP out (docs/CONTROL.md, section 3.8). Kept to reproduce that."""

    def __post_init__(self) -> None:
        need = _check_field  # module-level: mypyc compiles no closures inside a plain class
        # Whatever the caller passed, read untyped (compiled code would check the declared type).
        use_padhye = object.__getattribute__(self, "use_padhye")

        need(
            _positive_finite(self.min_rate),
            f"min_rate must be a positive, finite rate in packets/s, got {self.min_rate!r}",
        )
        need(
            _positive_finite(self.max_rate) and self.max_rate >= self.min_rate,
            f"max_rate must be finite and at least min_rate ({self.min_rate!r}), "
            f"got {self.max_rate!r}; use FixedConfig(rate=math.inf) for an unpaced sender",
        )
        need(
            self.min_rate <= self.initial_rate <= self.max_rate,
            f"initial_rate must lie between min_rate ({self.min_rate!r}) and max_rate "
            f"({self.max_rate!r}), got {self.initial_rate!r}",
        )
        need(
            _positive_finite(self.alpha_min),
            f"alpha_min must be a positive number of packets per RTT, got {self.alpha_min!r}",
        )
        need(
            0.0 < self.beta < 1.0,
            f"beta must be strictly between 0 and 1 (eq. 10 divides the IPG by it), "
            f"got {self.beta!r}; 0.5 halves the rate",
        )
        need(
            0.0 < self.gamma <= 1.0,
            f"gamma must be in (0, 1] (the fraction of the gap to the cap closed per RTT), "
            f"got {self.gamma!r}",
        )
        need(
            1.0 < self.max_increase < math.inf,
            f"max_increase must be a finite factor above 1, got {self.max_increase!r}",
        )
        need(
            0.0 <= self.app_limited_fraction <= 1.0,
            f"app_limited_fraction must be in [0, 1] (0 disables the check), "
            f"got {self.app_limited_fraction!r}",
        )
        need(
            self.app_headroom >= 1.0,
            f"app_headroom must be at least 1 (math.inf disables it), got {self.app_headroom!r}",
        )
        need(
            self.stale_loss_intervals >= 1.0,
            f"stale_loss_intervals must be at least 1 (math.inf keeps the cap until the next "
            f"loss), got {self.stale_loss_intervals!r}",
        )
        need(
            self.stale_min_rtts >= 0.0,
            f"stale_min_rtts must be a non-negative number of RTTs, got {self.stale_min_rtts!r}",
        )
        need(
            1.0 <= self.no_feedback_rtts < math.inf,
            f"no_feedback_rtts must be a finite number of RTTs, at least 1, "
            f"got {self.no_feedback_rtts!r}",
        )
        need(
            _positive_finite(self.initial_rtt),
            f"initial_rtt must be a positive, finite number of seconds, got {self.initial_rtt!r}",
        )
        need(
            isinstance(use_padhye, bool),
            f"use_padhye must be True or False, got {use_padhye!r}",
        )
        need(
            isinstance(self.decrease_in_use, bool),
            f"decrease_in_use must be True or False, got {self.decrease_in_use!r}",
        )


def recovery_intervals(config: TrinomialConfig) -> int:
    """Increase intervals from the moment the cap lifts until the rate reaches any target up to
    ``max_rate`` from any rate down to ``min_rate``: one interval already under way, then one
    ``max_increase`` step per interval (docs/CONTROL.md, "Recovery bound")."""
    steps = math.log(config.max_rate / config.min_rate) / math.log(config.max_increase)
    return 1 + math.ceil(steps - 1e-9)


RECOVERY_RTTS: Final[int] = recovery_intervals(TrinomialConfig())
"""The recovery bound N for the default configuration (16): once the loss history is stale, the
allowed rate reaches the application's demand (or ``max_rate``) within N increase intervals, each
one srtt long while at least two packets fit in an srtt."""


@mypyc_attr(allow_interpreted_subclasses=True)
class TrinomialController(RateController):
    """IPG controller with eqs. 9 and 10, capped by eq. 2; see the module docstring."""

    name: ClassVar[str] = "trinomial"

    def __init__(self, config: TrinomialConfig | None = None) -> None:
        cfg = config if config is not None else TrinomialConfig()
        self._cfg = cfg
        # What the per-packet hooks read, copied from the (frozen, plain-class) config: compiled,
        # an attribute of the config is a dictionary lookup and a float boxed and unboxed.
        self._max_rate: float = cfg.max_rate
        self._max_increase: float = cfg.max_increase
        self._gamma: float = cfg.gamma
        self._alpha_min: float = cfg.alpha_min
        self._no_feedback_rtts: float = cfg.no_feedback_rtts
        self._app_limited_fraction: float = cfg.app_limited_fraction
        self._app_headroom: float = cfg.app_headroom
        self._rate = cfg.initial_rate  # the state is the IPG, 1 / rate; kept as a rate so that
        # the bounds (min_rate, max_rate, the cap) hold exactly rather than to within rounding
        self._srtt = cfg.initial_rtt
        self._schedule = PacingSchedule()
        # Loss history.
        self._p = 0.0
        self._p_at_loss = 0.0
        self._last_loss: float | None = None
        self._acked_since_loss = 0
        self._cap_lifted = False
        self._last_decrease = -math.inf
        # The increase interval under way.
        self._started = False
        self._iv_start = 0.0
        self._iv_end = 0.0
        self._iv_alpha = cfg.alpha_min
        self._iv_w = math.inf
        self._iv_sent = 0
        self._last_hook = -math.inf  # the now of the last hook, when _advance last ran
        self._sending = SendMeter()  # the application-limited guard's measurements
        self._iv_acks = 0
        self._iv_allowance = 0.0  # packets the allowed rate permitted since _iv_start...
        self._iv_mark = 0.0  # ...integrated up to this time
        # Blackout.
        self._nf_deadline: float | None = None
        self._blackout = False
        self._rate_before_blackout = self._rate
        self._resume_rate: float | None = None  # what the path carried before a peer silence
        # Counters, for tests and statistics.
        self._increases = 0
        self._decreases = 0
        self._backoffs = 0

    # ------------------------------------------------------------------ read-only state

    @property
    def config(self) -> TrinomialConfig:
        """The configuration this controller runs with."""
        return self._cfg

    @property
    def rate(self) -> float:
        return self._rate

    @property
    def ipg(self) -> float:
        """The inter-packet gap in seconds (``1 / rate``)."""
        return 1.0 / self._rate

    @property
    def alpha(self) -> float:
        """The alpha chosen at the start of the increase interval under way (packets per RTT)."""
        return self._iv_alpha

    @property
    def cap(self) -> float:
        """The TCP-friendly ceiling now in force (packets/s); ``math.inf`` when there is none."""
        return self._cap()

    @property
    def in_blackout(self) -> bool:
        """True from the first no-feedback back-off until feedback returns."""
        return self._blackout

    @property
    def increase_count(self) -> int:
        """Eq. 9 increases so far (one per increase interval at most)."""
        return self._increases

    @property
    def decrease_count(self) -> int:
        """Eq. 10 decreases (one per loss event at most; blackout back-offs are counted apart)."""
        return self._decreases

    @property
    def backoff_count(self) -> int:
        """Halvings for lack of feedback."""
        return self._backoffs

    # ------------------------------------------------------------------ RateController

    def next_send_time(self) -> float:
        return self._schedule.next_departure

    def get_timer(self) -> float | None:
        if not self._started:
            return None
        deadline = self._nf_deadline
        # The end of an increase interval is settled lazily by the next hook, at the interval's
        # own end (see _advance), unless that could change what happens before the hook: an
        # interval without packets never increases, and the increase at its end can only bring
        # forward a departure, which matters only to a sample waiting for one.
        if self._iv_sent and self.sample_waiting and (deadline is None or self._iv_end < deadline):
            deadline = self._iv_end
        return deadline

    def on_timer(self, *, now: float) -> None:
        self._advance(now)

    def on_packet_sent(self, *, now: float, size: int, paced: bool = True) -> None:
        self._advance(now)
        self._sending.on_departure(now, paced)
        self._iv_sent += 1
        if self._nf_deadline is None:
            self._nf_deadline = now + self._no_feedback_timeout()
        self._schedule.on_departure(now, self.rate)

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
        self._set_srtt(srtt)
        self._set_p(loss_event_rate, now)
        self._acked_since_loss += max(acked, 0)
        self._iv_acks += 1
        self._nf_deadline = None  # re-armed by the next packet sent
        self._refresh_stale(now)
        self._apply_ceiling(now)
        if self._blackout:
            self._blackout = False
            self._start_interval(now)  # recovery starts with a whole interval of fresh feedback

    def on_loss_event(self, *, now: float, srtt: float, loss_event_rate: float) -> None:
        self._advance(now)
        self._set_srtt(srtt)
        self._set_p(loss_event_rate, now)
        self._p_at_loss = self._p
        self._last_loss = now
        self._acked_since_loss = 0
        self._cap_lifted = False
        if now - self._last_decrease >= self._srtt:
            rate = self.rate
            if self._cfg.decrease_in_use and self._sending.app_limited:
                # The application sets the pace (most packets left as soon as offered): the gap
                # in use is the application's, not the unused allowance. (A paced sender's gap in
                # use is the allowed one; its moving average would lag behind a recent increase.)
                sending = self._sending.send_rate()
                if sending > 0.0:
                    rate = min(rate, sending)
            self._set_rate(now, rate * self._cfg.beta)  # eq. 10: IPG / beta
            self._decreases += 1
            self._last_decrease = now
        self._apply_ceiling(now)
        self._start_interval(now)  # no increase until a whole loss-free interval has passed

    def on_peer_silent(self, *, now: float) -> None:
        # The no-feedback timer may already have halved the rate a few times: remember what the
        # path carried before the blackout began.
        self._advance(now)
        before = self._rate_before_blackout if self._blackout else self.rate
        self._resume_rate = max(before, self._resume_rate or 0.0)

    def on_peer_resumed(self, *, now: float, silent_for: float) -> None:
        """After an outage, resume at ``beta`` times the rate from before it (docs/CONTROL.md 3.5).

        The back-off during the silence answered a lack of feedback, not congestion: the path carried
        nothing and its queues drained. One ``beta`` decrease stands for the loss event the outage
        is, as TCP's fast recovery would take; the increase rules climb from there. Without this the
        rate would climb from ``min_rate``, whose first increase interval alone lasts ``2 / min_rate``
        (0.5 s).
        """
        resume, self._resume_rate = self._resume_rate, None
        if resume is None:
            return
        self._advance(now)
        target = min(self._cfg.beta * resume, self._cfg.max_rate, self._cap())
        if target > self.rate:
            self._set_rate(now, target)
            self._blackout = False
            self._nf_deadline = None  # re-armed by the next packet sent
            self._start_interval(now)

    # ------------------------------------------------------------------ internals

    def _advance(self, now: float) -> None:
        """Settle whatever fell due by ``now`` (timers may be served late, or not at all)."""
        if not self._started:
            self._started = True
            self._last_hook = now
            self._start_interval(now)
            return
        deadline = self._nf_deadline
        iv_end = self._iv_end
        if self._iv_sent and iv_end <= now and (deadline is None or iv_end < deadline):
            # An interval with packets ends at its own end, whenever the hook comes: as if its
            # timer had fired on time (get_timer leaves it untimed when nothing depends on it),
            # which is never before the hook that last moved it (a new srtt shortens it).
            self._end_interval(iv_end if iv_end > self._last_hook else self._last_hook)
        self._last_hook = now
        if deadline is not None and now >= deadline:
            timeout = self._no_feedback_timeout()
            missed = min(1 + int((now - deadline) // timeout), 64)
            self._backoffs += missed
            if not self._blackout:
                self._rate_before_blackout = self.rate
            self._blackout = True
            self._set_rate(now, self.rate * 0.5**missed)
            self._nf_deadline = now + self._no_feedback_timeout()
            self._start_interval(now)
        if now >= self._iv_end:
            self._end_interval(now)

    def _start_interval(self, now: float) -> None:
        """Begin an increase interval and choose its alpha (hence W) from the state at its start."""
        self._refresh_stale(now)
        rate = self.rate
        srtt = self._srtt
        cap = self._cap()
        most = (self._max_increase - 1.0) * rate
        step = most if cap == math.inf else min(self._gamma * max(cap - rate, 0.0), most)
        self._iv_alpha = max(self._alpha_min, step * srtt)
        self._iv_w = srtt / self._iv_alpha
        self._iv_start = self._iv_mark = now
        self._iv_end = now + max(srtt, 2.0 / rate)
        self._iv_sent = 0
        self._iv_acks = 0
        self._iv_allowance = 0.0

    def _end_interval(self, now: float) -> None:
        self._integrate(now)
        duration = now - self._iv_start
        if (
            duration > 0.0
            and self._iv_acks > 0
            and not self._blackout
            and self._iv_sent >= self._app_limited_fraction * self._iv_allowance
        ):
            rate = self.rate
            ceiling = min(self._max_rate, self._cap())
            if self._sending.app_limited:
                # Most recent packets left as soon as offered: the application sets the pace, so
                # the allowance grows only to headroom x its rate. (A share, not any one packet:
                # a jittery 1 kHz loop has the odd pair of samples 0.3 ms apart.)
                ceiling = min(ceiling, max(rate, self._app_headroom * self._sending.send_rate()))
            if ceiling > rate * (1.0 + 1e-9):  # not for a rounding error in the measured rate
                ipg, w = self.ipg, self._iv_w
                self._set_rate(now, min(1.0 / (ipg * w / (ipg + w)), ceiling))  # eq. 9
                self._increases += 1
        self._start_interval(now)

    def _cap(self) -> float:
        p = self._p
        if p <= 0.0 or self._cap_lifted:
            return math.inf
        if self._cfg.use_padhye:
            return padhye_rate(self._srtt, p, 4.0 * self._srtt)
        return tcp_friendly_rate(self._srtt, p)

    def _refresh_stale(self, now: float) -> None:
        """Lift the cap once the loss-free run is several times longer than the loss history."""
        if (
            not self._cap_lifted
            and self._last_loss is not None
            and self._p_at_loss > 0.0
            and self._acked_since_loss * self._p_at_loss >= self._cfg.stale_loss_intervals
            and now - self._last_loss >= self._cfg.stale_min_rtts * self._srtt
        ):
            self._cap_lifted = True

    def _apply_ceiling(self, now: float) -> None:
        ceiling = min(self._max_rate, self._cap())
        if self.rate > ceiling:
            self._set_rate(now, ceiling)

    def _set_rate(self, now: float, rate: float) -> None:
        cfg = self._cfg
        rate = min(max(rate, cfg.min_rate), cfg.max_rate)
        if rate == self.rate:
            return
        self._integrate(now)
        self._rate = rate
        self._schedule.reschedule(now, rate)

    def _integrate(self, now: float) -> None:
        if now > self._iv_mark:
            self._iv_allowance += (now - self._iv_mark) * self.rate
            self._iv_mark = now

    def _set_srtt(self, srtt: float) -> None:
        if _positive_finite(srtt):
            self._srtt = srtt
            # An interval lasts one current srtt (two packet gaps at least), so the first RTT sample
            # shortens the interval begun under initial_rtt.
            self._iv_end = self._iv_start + max(srtt, 2.0 / self._rate)

    def _set_p(self, p: float, now: float) -> None:
        if math.isnan(p):
            return
        self._p = min(max(p, 0.0), 1.0)
        if self._p > 0.0 and self._last_loss is None:
            # Feedback reports a loss rate before any loss event was signalled: start the history.
            self._p_at_loss = self._p
            self._last_loss = now

    def _no_feedback_timeout(self) -> float:
        return max(self._no_feedback_rtts * self._srtt, 2.0 / self.rate) + self.feedback_delay
