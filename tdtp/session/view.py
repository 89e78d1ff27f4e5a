"""What a connection shows of itself: :class:`ConnectionView`, the read-only properties of
:class:`~tdtp.session.connection.Connection` (state, peer, mode, keys, watchdog, counters).

The connection's pieces (:mod:`tdtp.session`) are declared here and created by the connection; this
class only reads them, so the state machine in :mod:`tdtp.session.connection` stays about what changes.
"""

from __future__ import annotations

import math

from tdtp.admission.admission import Admission
from tdtp.config import AckMode, ConnectionConfig, Role
from tdtp.control.base import RateController
from tdtp.protection.keys import PresharedKey
from tdtp.session.ack_scheduler import AckScheduler
from tdtp.session.control_channel import ControlChannel
from tdtp.session.delivery import SampleDelivery
from tdtp.session.event_queue import EventQueue
from tdtp.session.events import Address, ConnectionClosed, DataReceived
from tdtp.session.handshake import Handshake
from tdtp.session.liveness import Liveness
from tdtp.session.path import PeerPath
from tdtp.session.recovery import LossRecovery
from tdtp.session.sample_age import SampleAgeHistogram
from tdtp.session.sender import SampleSender
from tdtp.session.state import State
from tdtp.session.stats import ConnectionStats
from tdtp.session.timer_hint import TimerHint


class ConnectionView:
    """The read-only face of a :class:`~tdtp.session.connection.Connection` (its base class)."""

    config: ConnectionConfig
    role: Role
    dials: bool
    _state: State
    _peer: Address | None
    _stats: ConnectionStats
    _liveness: Liveness
    _handshake: Handshake
    _controller: RateController
    _hint: TimerHint
    _recovery: LossRecovery
    _acks: AckScheduler
    _sender: SampleSender
    _events: EventQueue
    _channel: ControlChannel
    _close_event: ConnectionClosed | None
    _ages: SampleAgeHistogram
    _delivery: SampleDelivery
    _path: PeerPath

    # ------------------------------------------------------------------ introspection

    @property
    def state(self) -> State:
        """Where the session is in its life (:class:`~tdtp.State`)."""
        return self._state

    @property
    def peer(self) -> Address | None:
        """The peer's address once known (the master's at ``connect``, the slave's at the OPEN)."""
        return self._peer

    @property
    def master_nonce(self) -> bytes:
        """The master's 128-bit nonce: names this session in every control packet."""
        return self._handshake.master_nonce

    @property
    def migratable(self) -> bool:
        """An established listener: may follow its dialer to a new address (PROTOCOL.md 5.8)."""
        return not self.dials and self._state is State.ESTABLISHED

    def _peer_address(self) -> Address:
        peer = self._peer
        assert peer is not None  # set by connect() or at the OPEN
        return peer

    def quiet_for(self, now: float) -> float:
        """Seconds since the last datagram from the peer's address."""
        return now - self._liveness.last_receive

    @property
    def live_gap(self) -> float:
        """The longest a live peer is silent: it sends at least once per keep-alive interval, which
        takes up to an RTT (with margin) to arrive (PROTOCOL.md 5.1 rule 5, 5.8)."""
        return self._liveness.keepalive + 2.0 * self._recovery.rtt.srtt

    @property
    def ack_mode(self) -> AckMode:
        """The mode in force: the master's choice, adopted by the slave at the open."""
        return self._acks.mode

    @property
    def max_send_payload(self) -> int:
        """The largest payload :meth:`send` accepts: the smaller of ours and the peer's maximum."""
        return self._sender.limit

    @property
    def controller(self) -> RateController:
        """The rate controller deciding when data packets may leave."""
        return self._controller

    @property
    def keyed(self) -> bool:
        """Whether the session is keyed (every datagram authenticated, and encrypted if
        :attr:`encrypted`). A listening slave with keys answers keyed OPENs only."""
        return self._handshake.keyed

    @property
    def encrypted(self) -> bool:
        """Whether a keyed session encrypts its payloads (the master's choice)."""
        return self._handshake.keyed and self._handshake.encrypt

    @property
    def key(self) -> PresharedKey | None:
        """The session's pre-shared key: the master's own, or the one a slave found in its ring for
        this master (its :attr:`~tdtp.protection.PresharedKey.name` says which master it is)."""
        return self._handshake.key

    @property
    def admission(self) -> Admission | None:
        """A slave's front door (cookie, rate limits, keys); ``None`` for a master."""
        return self._handshake.admission

    @property
    def peer_silent(self) -> bool:
        """True while the watchdog finds the peer silent (between :class:`~tdtp.session.events.PeerSilent`
        and :class:`~tdtp.session.events.PeerResumed`), and for good once the connection is closed:
        nothing will be heard from the peer again, so a display or a safety check built on it
        never shows a closed link as a live one."""
        return self._liveness.silent_since is not None or self._state is State.CLOSED

    @property
    def silent_since(self) -> float | None:
        """The ``now`` of the peer's last datagram while it is silent, else ``None``."""
        return self._liveness.silent_since

    @property
    def close_event(self) -> ConnectionClosed | None:
        """Why the connection ended, once it has (the same event :meth:`next_event` reports)."""
        return self._close_event

    @property
    def timer_hint(self) -> float:
        """A bound on what has moved since :meth:`get_timer` was last called (which resets it to
        ``math.inf``): no deadline of this connection moved earlier than ``timer_hint``.

        A caller that keeps one timer armed at the connection's deadline, and re-arms it only for an
        earlier one (a later deadline just wakes it early, which is harmless: :meth:`handle_timer`
        does nothing and the timer is re-armed), needs :meth:`get_timer` only when ``timer_hint``
        is earlier than the armed deadline, instead of after every input. ``-math.inf`` means
        anything may have changed."""
        return self._hint.value

    @property
    def pending_events(self) -> int:
        """Events waiting for :meth:`next_event`."""
        return self._events.count()

    def take_challenge(self, now: float) -> bool:
        """Unkeyed slave: may a PATH_CHALLENGE go out on this session's behalf (its share, a token
        of its bucket: PROTOCOL.md 5.8)? (Changes only that bucket.)"""
        return self._path.take_challenge(now)

    def control_held(self, count: int) -> None:
        """A driver's count of delivered control messages its application has not read yet: they
        count against the control channel's receive bound (``control_window``). (The one call here
        that changes anything; it only tells the channel.)"""
        self._channel.app_unread = count

    @property
    def newest_held(self) -> DataReceived | None:
        """The newest sample that has arrived but waits in the reorder wait behind a gap, when it
        is newer than every sample delivered (``None`` otherwise): what a latest-value reader wants
        now. It is still delivered in order later, as a :class:`DataReceived` event like any other."""
        return self._delivery.newest_held

    @property
    def control_unacked(self) -> int:
        """Control messages of ours the peer has not acknowledged yet (queued or in flight)."""
        return self._channel.unacked

    @property
    def transmit_errors(self) -> int:
        """Datagrams whose ``transmit`` in :meth:`send_direct` raised :class:`OSError` (lost like
        any other)."""
        return self._sender.transmit_errors

    @property
    def sending_paused(self) -> bool:
        """True between :meth:`pause_sending` and :meth:`resume_sending`."""
        return self._sender.paused

    @property
    def stats(self) -> ConnectionStats:
        """Live counters; the derived figures (srtt, p, rate) are refreshed on each access. Once
        the connection is closed they read as closed: ``closed`` True, ``srtt`` and ``rttvar``
        NaN (there is no path to measure), ``rate`` 0 and ``rate_limit`` ``"closed"``; the
        counters and ``min_rtt`` keep the session's history."""
        stats = self._stats
        self._recovery.refresh(stats)
        ages = self._ages
        stats.sample_age_p50 = ages.quantile(0.5)
        stats.sample_age_p99 = ages.quantile(0.99)
        if self._state is State.CLOSED:
            stats.closed = True
            stats.srtt = stats.rttvar = math.nan
            stats.rate = 0.0
            stats.rate_limit = "closed"
        else:
            stats.rate = self._controller.rate
            stats.rate_limit = self._controller.rate_limit
        one_way = self._sender.one_way
        stats.timestamps = one_way.enabled
        stats.queue_delay_out = one_way.queue_out
        stats.queue_delay_in = one_way.queue_in
        stats.stamps_rejected = one_way.stamps_rejected
        return stats
