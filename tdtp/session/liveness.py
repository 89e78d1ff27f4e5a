"""The session's liveness timers: when we last heard the peer and last spoke to it.

Two clocks drive a session that carries no data. Our side must be heard at least once per keep-alive
interval (a KEEPALIVE goes out when nothing else did), and the peer must be: nothing from it for
``silence_timeout`` makes it *silent* (the watchdog, docs/PROTOCOL.md section 5.2), and nothing for
``idle_timeout`` ends the session. :class:`Liveness` holds those times and the outage in progress (or the
last one, which loss recovery needs to count packets lost together in it as one loss event). It decides
*when*; what a silence or a resumption sets off (events, the controller's hooks, the statistics) is the
connection's business, so this module imports nothing of the session.
"""

from __future__ import annotations

from tdtp.config import ConnectionConfig


class Liveness:
    """Last receive and last send times, the watchdog's silence and outage, and their deadlines.

    The connection writes :attr:`last_receive` and :attr:`last_send` directly on its per-packet paths
    (a plain store is the cheapest thing there) and asks this class the questions that involve the
    configured intervals.
    """

    def __init__(self, config: ConnectionConfig) -> None:
        self.last_receive = 0.0
        """``now`` of the peer's last datagram (or of the open, before any)."""
        self.last_send = 0.0
        """``now`` of our last session datagram: a KEEPALIVE is due one interval later."""
        self.keepalive = config.effective_keepalive_interval
        self.silence = config.silence_timeout
        self.idle_timeout = config.idle_timeout
        self.silent_since: float | None = None
        """While the peer is silent: the ``now`` of its last datagram before the silence."""
        self.last_outage: tuple[float, float] | None = None
        """(since, resumed at) of the last silence that ended."""

    def deadline(self) -> float:
        """The earlier of the watchdog's deadline (the silence timeout until the peer is silent, then
        the idle timeout) and the keep-alive's."""
        deadline = self.last_receive + (
            self.silence if self.silent_since is None else self.idle_timeout
        )
        keepalive = self.last_send + self.keepalive
        return keepalive if keepalive < deadline else deadline

    def watchdog_deadline(self) -> float:
        """The watchdog's deadline alone (the silence timeout, or the idle timeout while silent)."""
        return self.last_receive + (
            self.silence if self.silent_since is None else self.idle_timeout
        )

    def idle_expired(self, now: float) -> bool:
        """Nothing heard from the peer for the idle timeout: the session is over."""
        return now >= self.last_receive + self.idle_timeout

    def check_silence(self, now: float) -> bool:
        """True when the peer has just become silent at ``now`` (once per silence)."""
        if self.silent_since is None and now >= self.last_receive + self.silence:
            self.silent_since = self.last_receive
            return True
        return False

    def resume(self, now: float) -> float:
        """The silent peer was heard at ``now``: end the outage; how long it lasted."""
        since = self.silent_since
        assert since is not None
        self.silent_since = None
        self.last_outage = (since, now)
        return now - since

    def outage(self, now: float) -> tuple[float, float] | None:
        """The outage in progress (until ``now``), else the last one, else ``None``."""
        since = self.silent_since
        return self.last_outage if since is None else (since, now)

    def silent_for_watchdog(self, now: float) -> bool:
        """Nothing from the peer for ``silence_timeout``: what the watchdog calls silent (only the
        timer's :meth:`check_silence` reports it; this asks, at any ``now``)."""
        return now - self.last_receive >= self.silence

    def keepalive_due(self, now: float) -> bool:
        return now >= self.last_send + self.keepalive

    def silent_longer_than_live(self, now: float, srtt: float) -> bool:
        """Silent longer than a live peer ever is: it sends at least one datagram per keep-alive
        interval, which takes up to an RTT (with margin) to arrive."""
        return now - self.last_receive > self.keepalive + 2.0 * srtt
