"""The rate-controller interface: what the connection tells a controller and what it asks back.

A controller is sans-IO like the rest of the core: it never reads a clock; every hook takes ``now=`` (seconds
on the caller's monotonic clock) as a keyword argument. The connection calls

* :meth:`RateController.on_packet_sent` for every data packet that leaves (not for ACK or control packets);
* :meth:`RateController.on_ack` once per datagram whose acknowledgement newly reported data packets as
  received, with the RTT estimator's state and the current loss-event rate;
* :meth:`RateController.on_loss_event` once per loss event (all losses within one RTT are one event);
* :meth:`RateController.on_timer` when ``now`` reaches :meth:`RateController.get_timer`;
* :meth:`RateController.on_peer_silent` and :meth:`RateController.on_peer_resumed` when nothing at all
  has arrived from the peer for ``silence_timeout`` (an outage, not congestion), and when it is heard
  again (optional: the default does nothing);
* :meth:`RateController.on_one_way_delay` when the peer's send time, stamped on one of its packets,
  timed our own direction alone (sessions with timestamps, docs/PROTOCOL.md 5.13; optional);

and asks :meth:`RateController.next_send_time` (the earliest moment the next data packet may leave) and
:attr:`RateController.rate` (the allowed rate, packets per second).
"""

from __future__ import annotations

import abc
import math
from typing import ClassVar, Final

from mypy_extensions import mypyc_attr

NO_LIMIT: Final = -math.inf
"""What :meth:`RateController.next_send_time` returns when nothing holds the next packet back."""


@mypyc_attr(allow_interpreted_subclasses=True)
class PacingSchedule:
    """Turns an allowed rate into departure times on an absolute schedule that does not drift.

    The next departure is ``previous deadline + 1/rate``. A packet that leaves late (a late timer
    wake-up) does not push the schedule back, so the long-run rate is the allowed rate; the catch-up
    is limited to one extra gap so that a long stall never turns into a burst: over any window of
    length ``T`` at most ``rate * T + 2`` packets leave (the ``+ 2`` is the packet on the window's edge
    plus the one catch-up packet after a stall or an idle period).
    """

    __slots__ = ("_anchor", "_next")

    def __init__(self) -> None:
        self._next = NO_LIMIT
        self._anchor = NO_LIMIT  # the slot the last departure was booked in; _next = _anchor + gap

    @property
    def next_departure(self) -> float:
        """When the next packet may leave (``NO_LIMIT``: at once)."""
        return self._next

    def on_departure(self, now: float, rate: float) -> None:
        """Record a departure at ``now`` under the allowed ``rate`` (packets/s; ``inf`` = no pacing)."""
        if rate == math.inf:
            self._next = self._anchor = NO_LIMIT
            return
        gap = 1.0 / rate
        self._anchor = max(self._next, now - gap)
        self._next = self._anchor + gap

    def reschedule(self, now: float, rate: float) -> None:
        """Re-aim a pending deadline after the rate changed, so the new rate takes effect at once.

        The pending deadline is moved to ``slot of the last departure + 1/rate``: later after a
        decrease, earlier after an increase (a packet held back 250 ms by ``min_rate`` need not wait
        out the old gap once the rate has recovered), never earlier than ``now``. A deadline already
        reached is left alone.
        """
        if rate == math.inf:
            self._next = self._anchor = NO_LIMIT
        elif self._next > now:
            self._next = max(now, self._anchor + 1.0 / rate)

    def reset(self) -> None:
        """Forget the schedule: the next packet may leave at once."""
        self._next = self._anchor = NO_LIMIT


@mypyc_attr(allow_interpreted_subclasses=True)
class RateController(abc.ABC):
    """Decides how fast data packets may leave. Subclasses register under a name in ``registry.py``."""

    name: ClassVar[str]

    judges_one_way_delay: ClassVar[bool] = False
    """The controller reads :meth:`on_one_way_delay`: a master running it opens its sessions with
    timestamps (``ConnectionConfig.timestamp_interval``)."""

    feedback_delay: float = 0.0
    """Longest the peer may hold an acknowledgement before it leaves (the peer's ``ack_delay``): the
    connection sets it. A feedback gap this much longer than the RTT is not yet a blackout, so
    no-feedback timers add it."""

    silence_timeout: float = 0.1
    """How long the connection waits, with nothing at all from the peer, before it calls
    :meth:`on_peer_silent` (its ``silence_timeout``): the connection sets it."""

    sample_waiting: bool = True
    """Whether a sample is waiting to leave (held by the pacer, or by a full socket buffer): the
    connection keeps it up to date. A controller may leave a deadline untimed while nothing waits,
    if settling it at the next hook, at the deadline's own time, gives the same result (trinomial's
    interval ends). ``True`` by default: a controller driven on its own times everything."""

    @property
    @abc.abstractmethod
    def rate(self) -> float:
        """The allowed sending rate in data packets per second (``math.inf`` when unlimited)."""

    @property
    def rate_limit(self) -> str:
        """What limits the rate now, in a few words for statistics and the command line
        (``"application"``, ``"queue delay 7.2 ms"``, ``"loss"``, ``"tcp-friendly ceiling"``,
        ``"floor"``, ...); empty when the controller does not say."""
        return ""

    @abc.abstractmethod
    def next_send_time(self) -> float:
        """Earliest absolute time the next data packet may leave; :data:`NO_LIMIT` if any time."""

    @abc.abstractmethod
    def on_packet_sent(self, *, now: float, size: int, paced: bool = True) -> None:
        """A data packet of ``size`` bytes (header included) left at ``now``.

        ``paced`` says whether the pacer held it back: the application offered it before the
        controller allowed it to leave (or offered a newer one meanwhile). ``False`` means it left as
        soon as it was offered, so the application, not the controller, set the pace.
        """

    @abc.abstractmethod
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
        """Feedback arrived: ``acked`` data packets newly reported received.

        ``rtt_sample`` is this datagram's RTT sample (hold time already removed) or ``None``; ``srtt`` and
        ``rttvar`` are the smoothed estimates after it; ``loss_event_rate`` is RFC 5348's p (0 before
        the first loss event).
        """

    @abc.abstractmethod
    def on_loss_event(self, *, now: float, srtt: float, loss_event_rate: float) -> None:
        """A new loss event began (one call per event, however many packets it lost)."""

    @abc.abstractmethod
    def get_timer(self) -> float | None:
        """The controller's own next deadline (absolute), or ``None``."""

    @abc.abstractmethod
    def on_timer(self, *, now: float) -> None:
        """``now`` reached :meth:`get_timer` (it may be called late, or when nothing is due)."""

    def on_peer_silent(self, *, now: float) -> None:  # noqa: B027 -- optional hook, no-op default
        """Nothing at all, data, acknowledgement or keep-alive, has arrived from the peer for the
        connection's ``silence_timeout``: the path is out (or the peer stalled). Unlike missing
        acknowledgements alone, which may mean congestion, a total silence says nothing about the
        path's capacity."""

    def on_one_way_delay(  # noqa: B027 -- optional hook, no-op default
        self, *, now: float, delay: float, sent_at: float, seq: int, hold: float, unacked: int
    ) -> None:
        """The peer timed the arrival of our data packet ``seq``, sent at ``sent_at``: ``delay`` is
        its one-way delay plus a constant (the two clocks' offset; only differences and minima
        mean something), so a queue in the other direction does not show in it. ``hold`` is how
        long the packet had been the newest of ours at the peer when the peer's stamp left: the
        time the peer had heard nothing newer from us; ``math.inf`` (and ``delay`` NaN) when that
        was longer than the header's HOLD can say (31.7 ms). ``unacked`` counts the data packets
        we sent after ``seq``: on their way, queued or lost."""

    def on_peer_resumed(self, *, now: float, silent_for: float) -> None:  # noqa: B027
        """The peer is heard again after :meth:`on_peer_silent`, ``silent_for`` seconds after its
        last datagram. A controller that backed off for lack of feedback during the outage may
        restore what the path carried before it (the default does nothing).

        The packets sent during the outage that turn out lost form one loss event: it counts in the
        ``loss_event_rate`` passed to :meth:`on_ack`, but it is not reported through
        :meth:`on_loss_event`, because this hook is the response to the outage.
        """
