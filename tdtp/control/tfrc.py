"""TFRC (RFC 5348) as a sender-side rate controller fed by TDTP's piggybacked acknowledgements.

The connection measures the loss event rate ``p`` with RFC 5348's loss intervals and passes it in
:meth:`TfrcController.on_ack` / :meth:`TfrcController.on_loss_event`; this module does not
recompute it. What RFC 5348 leaves to the receiver's report, the receive rate ``X_recv``, is
measured here from the ``acked`` counts over windows of at least one RTT. Rates are in packets per
second, so the throughput equation is used with ``s = 1`` (eq. 1 with ``t_RTO = 4 R``); the mean
packet size only matters for the initial window ``W_init = min(4 s, max(2 s, 4380 bytes))``.

Simplifications against the RFC, all documented in docs/CONTROL.md: the data-limited test is
"fewer than half the allowed packets were sent in the measurement window", the receiver's 0.85
decay of ``X_recv`` in a data-limited interval with a new loss is applied at the end of the
window, and the optional oscillation reduction (section 4.5) is not implemented.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

from mypy_extensions import mypyc_attr

from tdtp.control.base import PacingSchedule, RateController
from tdtp.control.equations import padhye_rate

__all__ = ["TfrcConfig", "TfrcController"]

_W_INIT_BYTES = 4380.0
_DATA_LIMITED_FRACTION = 0.5
_SIZE_GAIN = 1.0 / 16.0
_PACED_GAIN = 1.0 / 8.0
"""Gain of the moving share of departures the pacer held back (about the last eight packets)."""


def _check_field(ok: bool, message: str) -> None:
    if not ok:
        raise ValueError(f"TfrcConfig.{message}")


@mypyc_attr(native_class=False)  # a plain class: __post_init__ judges the types
@dataclass(frozen=True, slots=True)
class TfrcConfig:
    """Configuration of :class:`TfrcController` (RFC 5348 defaults)."""

    initial_rate: float = 1.0
    """Packets/s before the first feedback (RFC 5348 section 4.2: one packet per second)."""
    min_rate: float = 1.0 / 64.0
    """Floor, packets/s: ``s / t_mbi`` with ``t_mbi = 64 s``."""
    max_rate: float = 100_000.0
    """Ceiling, packets/s."""
    packet_size: int | None = None
    """Bytes per packet for ``W_init``; ``None`` uses a running mean of the sizes sent."""
    initial_no_feedback_timeout: float = 2.0
    """Seconds before the first no-feedback halving when no RTT is known (RFC 5348: 2 s)."""
    data_limited_decrease: float | None = 0.85
    """RFC 5348 section 4.3 step 4 for a loss in a data-limited interval: ``X_recv_set`` is halved,
    the new receive-rate sample multiplied by this (the RFC's 0.85), and ``recv_limit`` is
    ``max(X_recv_set)``, not twice it, until a window without a new loss. ``None`` turns the rule off:
    ``recv_limit`` is always ``2 X_recv`` and only a sender using less than half its allowance counts
    as data-limited; an application-limited sender whose equation rate is above what it sends then
    never slows down, which locked TCP out (docs/CONTROL.md, section 5.1). Kept to reproduce that."""

    def __post_init__(self) -> None:
        need = _check_field  # module-level: mypyc compiles no closures inside a plain class
        # Whatever the caller passed, read untyped (compiled code would check the declared type).
        packet_size = object.__getattribute__(self, "packet_size")

        need(
            0.0 < self.min_rate < math.inf,
            f"min_rate must be a positive, finite rate in packets/s, got {self.min_rate!r}",
        )
        need(
            self.min_rate <= self.max_rate < math.inf,
            f"max_rate must be finite and at least min_rate ({self.min_rate!r}), "
            f"got {self.max_rate!r}",
        )
        need(
            self.min_rate <= self.initial_rate <= self.max_rate,
            f"initial_rate must lie between min_rate ({self.min_rate!r}) and max_rate "
            f"({self.max_rate!r}), got {self.initial_rate!r}",
        )
        need(
            packet_size is None or (isinstance(packet_size, int) and packet_size > 0),
            f"packet_size must be None (measure it) or a positive number of bytes, "
            f"got {packet_size!r}",
        )
        need(
            self.data_limited_decrease is None or 0.0 < self.data_limited_decrease <= 1.0,
            f"data_limited_decrease must be None or in (0, 1], got {self.data_limited_decrease!r}",
        )
        need(
            0.0 < self.initial_no_feedback_timeout < math.inf,
            f"initial_no_feedback_timeout must be a positive, finite number of seconds, "
            f"got {self.initial_no_feedback_timeout!r}",
        )


@mypyc_attr(allow_interpreted_subclasses=True)
class TfrcController(RateController):
    """RFC 5348 sender: slow start while ``p == 0``, then ``X = max(min(X_eq, 2 X_recv), s/t_mbi)``."""

    name: ClassVar[str] = "tfrc"

    def __init__(self, config: TfrcConfig | None = None) -> None:
        cfg = config if config is not None else TfrcConfig()
        self._cfg = cfg
        self._x = cfg.initial_rate
        self._r: float | None = None
        self._p = 0.0
        self._mean_size: float | None = (
            float(cfg.packet_size) if cfg.packet_size is not None else None
        )
        self._schedule = PacingSchedule()
        self._had_feedback = False
        self._t_ld = -math.inf  # time of the last slow-start doubling
        # X_recv_set: (time, packets/s) samples; RFC 5348 starts it as {Infinity}.
        self._recv_set: list[tuple[float, float]] = [(-math.inf, math.inf)]
        # The receive-rate measurement window under way.
        self._win_start: float | None = None
        self._win_acked = 0
        self._win_sent = 0
        self._win_allowance = 0.0
        self._win_mark = 0.0
        self._win_p = 0.0
        self._paced_avg = 1.0  # moving share of departures the pacer held back
        self._recv_factor = 2.0  # recv_limit = this x max(X_recv_set) (RFC 5348 4.3 step 4)
        self._loss_unreported = False  # a loss event not yet in a closed receive-rate window
        # No-feedback timer.
        self._nf_deadline: float | None = None
        self._sent_since_nf = False
        self._backoffs = 0

    # ------------------------------------------------------------------ read-only state

    @property
    def config(self) -> TfrcConfig:
        """The configuration this controller runs with."""
        return self._cfg

    @property
    def rate(self) -> float:
        return self._x

    @property
    def x_recv(self) -> float:
        """The largest receive rate in ``X_recv_set`` (packets/s; ``inf`` before a measurement)."""
        return max(value for _, value in self._recv_set)

    @property
    def in_slow_start(self) -> bool:
        """True until the first loss event (the loss-event rate is still 0)."""
        return self._p == 0.0

    @property
    def backoff_count(self) -> int:
        """Halvings of the rate for lack of feedback (RFC 5348's no-feedback timer)."""
        return self._backoffs

    # ------------------------------------------------------------------ RateController

    def next_send_time(self) -> float:
        return self._schedule.next_departure

    def get_timer(self) -> float | None:
        return self._nf_deadline

    def on_timer(self, *, now: float) -> None:
        self._advance(now)

    def on_packet_sent(self, *, now: float, size: int, paced: bool = True) -> None:
        self._advance(now)
        if self._cfg.packet_size is None and size > 0:
            mean = self._mean_size
            self._mean_size = float(size) if mean is None else mean + (size - mean) * _SIZE_GAIN
        self._win_sent += 1
        self._paced_avg += _PACED_GAIN * ((1.0 if paced else 0.0) - self._paced_avg)
        self._sent_since_nf = True
        if self._nf_deadline is None:
            self._nf_deadline = now + self._cfg.initial_no_feedback_timeout
        self._schedule.on_departure(now, self._x)

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
        self._set_r(srtt)
        self._set_p(loss_event_rate)
        r = self._r if self._r is not None else self._cfg.initial_no_feedback_timeout / 4.0
        self._measure_receive_rate(now, max(acked, 0), r, new_loss=self._loss_unreported)
        if not self._had_feedback:
            # First feedback: start from the RFC 3390 initial window per RTT.
            self._had_feedback = True
            self._set_rate(now, max(self._x, self._initial_window() / r))
            self._t_ld = now
        elif self._p > 0.0:
            self._set_rate(now, self._equation_rate(r))
        elif now - self._t_ld >= r:
            recv_limit = 2.0 * self.x_recv
            self._set_rate(now, max(min(2.0 * self._x, recv_limit), self._initial_window() / r))
            self._t_ld = now
        self._nf_deadline = now + max(4.0 * r, 2.0 / self._x) + self.feedback_delay
        self._sent_since_nf = False

    def on_loss_event(self, *, now: float, srtt: float, loss_event_rate: float) -> None:
        self._advance(now)
        self._set_r(srtt)
        self._set_p(loss_event_rate)
        if self._p > 0.0 and self._r is not None:
            # RFC 5348 receivers report a new loss event at once; act on it as on that report.
            # The report also closes the receive-rate interval under way: the feedback that
            # revealed the loss does so in on_ack.
            self._loss_unreported = self._cfg.data_limited_decrease is not None
            self._set_rate(now, self._equation_rate(self._r))

    # ------------------------------------------------------------------ internals

    def _equation_rate(self, r: float) -> float:
        """``max(min(X_eq, recv_limit), s/t_mbi)`` in packets/s (RFC 5348 section 4.3 step 4)."""
        x_eq = padhye_rate(r, self._p, 4.0 * r)
        return max(min(x_eq, self._recv_factor * self.x_recv), self._cfg.min_rate)

    def _initial_window(self) -> float:
        """RFC 3390's initial window in packets: ``min(4 s, max(2 s, 4380)) / s``."""
        s = self._mean_size if self._mean_size is not None else 1.0
        return min(4.0 * s, max(2.0 * s, _W_INIT_BYTES)) / s

    def _measure_receive_rate(
        self, now: float, acked: int, r: float, *, new_loss: bool = False
    ) -> None:
        """Close a receive-rate window once it spans an RTT (or at once when it reports a new loss
        event), update ``X_recv_set`` and ``recv_limit`` (RFC 5348 section 4.3 step 4)."""
        if self._win_start is None:
            self._win_start = self._win_mark = now
            self._win_p = self._p
            self._win_acked = acked
            self._win_sent = 0
            self._win_allowance = 0.0
            return
        self._win_acked += acked
        duration = now - self._win_start
        if duration < r and not new_loss:
            return
        self._integrate(now)
        decrease = self._cfg.data_limited_decrease
        # A window shorter than a quarter RTT (a loss reported just after a window closed) is too
        # short to measure a rate; its loss still counts.
        sample = self._win_acked / duration if duration >= 0.25 * r else None
        data_limited = self._win_sent < _DATA_LIMITED_FRACTION * self._win_allowance
        if decrease is not None:
            # The application, not the pacer, set the pace: most packets left as offered.
            data_limited = data_limited or self._paced_avg < 0.5
        if data_limited:
            values = [value for _, value in self._recv_set if value < math.inf]
            loss = new_loss or self._p > self._win_p
            if loss:
                # A loss in a data-limited interval: halve the history, decay the new sample.
                values = [value / 2.0 for value in values]
                if sample is not None:
                    sample *= decrease if decrease is not None else 0.85
            if sample is not None:
                values.append(sample)
            top = max(values) if values else math.inf
            self._recv_set = [(now, top)]
            if decrease is not None:
                self._recv_factor = 1.0 if loss else 2.0
        elif sample is not None:
            self._recv_set = [
                (t, value) for t, value in self._recv_set if t >= now - 2.0 * r and value < math.inf
            ]
            self._recv_set.append((now, sample))
            self._recv_factor = 2.0
        else:
            return  # a loss too soon after the last window closed, while the pacer sets the pace
        self._win_start = self._win_mark = now
        self._win_p = self._p
        self._win_acked = 0
        self._win_sent = 0
        self._win_allowance = 0.0
        self._loss_unreported = False

    def _advance(self, now: float) -> None:
        deadline = self._nf_deadline
        if deadline is None or now < deadline:
            return
        self._on_no_feedback(now)

    def _on_no_feedback(self, now: float) -> None:
        """RFC 5348 section 4.4: the no-feedback timer expired."""
        cfg = self._cfg
        r = self._r
        idle = not self._sent_since_nf
        recover_rate = self._initial_window() / r if r is not None else cfg.initial_rate
        x_recv = self.x_recv
        if not self._had_feedback:
            if not idle:
                self._halve(now, self._x / 2.0)
        elif idle and (
            (self._p > 0.0 and x_recv < recover_rate)
            or (self._p == 0.0 and self._x < 2.0 * recover_rate)
        ):
            pass  # idle below the restart rate: keep it
        elif self._p == 0.0 or r is None:
            self._halve(now, self._x / 2.0)
        else:
            x_eq = padhye_rate(r, self._p, 4.0 * r)
            limit = x_recv if x_eq > 2.0 * x_recv else x_eq / 2.0
            limit = max(limit, cfg.min_rate)
            self._recv_set = [(now, limit / 2.0)]
            self._halve(now, min(x_eq, limit))
        timeout = max(4.0 * r, 2.0 / self._x) if r is not None else cfg.initial_no_feedback_timeout
        self._nf_deadline = now + timeout + self.feedback_delay
        self._sent_since_nf = False

    def _halve(self, now: float, rate: float) -> None:
        self._backoffs += 1
        self._set_rate(now, rate)

    def _set_rate(self, now: float, rate: float) -> None:
        cfg = self._cfg
        rate = min(max(rate, cfg.min_rate), cfg.max_rate)
        if rate == self._x:
            return
        self._integrate(now)
        self._x = rate
        self._schedule.reschedule(now, rate)

    def _integrate(self, now: float) -> None:
        if self._win_start is not None and now > self._win_mark:
            self._win_allowance += (now - self._win_mark) * self._x
            self._win_mark = now

    def _set_r(self, srtt: float) -> None:
        if 0.0 < srtt < math.inf:
            self._r = srtt

    def _set_p(self, p: float) -> None:
        if not math.isnan(p):
            self._p = min(max(p, 0.0), 1.0)
