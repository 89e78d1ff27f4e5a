"""What we owe the peer in acknowledgements, and when (docs/PROTOCOL.md section 3).

Every datagram we send piggybacks an acknowledgement of the peer's newest data (bidirectional mode):
the highest sequence number, the SACK bits below it and how long we held it. When no datagram of ours
is due within ``ack_delay`` of an unreported arrival, a separate ACK goes out; when a newer packet jumps
so far ahead that the SACK bits can no longer cover an unreported one, that report goes out first, at
once (the jump rule). In separate-ACK mode (Trinomial's) every arrival is acknowledged by its own ACK.

:class:`AckScheduler` owns the :class:`~tdtp.session.receive_window.ReceiveWindow` of the peer's data,
the ACK mode the session runs and the queue of separate ACKs; it classifies arrivals, builds the ACK
fields and says when the next ACK is due. The connection decides what an arrival means for the
application (delivered or dropped).
"""

from __future__ import annotations

import math
from collections import deque
from typing import Final

from tdtp.config import AckMode, ConnectionConfig
from tdtp.session.events import Address
from tdtp.session.outbox import Datagrams, Outbox
from tdtp.session.receive_window import (
    LATE,
    NEW,
    SACK_SPAN,
    Arrival,
    ReceiveWindow,
)
from tdtp.session.stats import ConnectionStats
from tdtp.session.timer_hint import TimerHint
from tdtp.wire.hold import HOLD_NO_ACK, encode_hold

NO_ACK: Final = (0, 0, HOLD_NO_ACK)
# Enum members as module constants for the per-packet paths: reading one off its class goes through
# the enum metaclass (about 0.1 us in either build on Python 3.11), a module constant does not.
_BIDIRECTIONAL: Final = AckMode.BIDIRECTIONAL
_SEPARATE: Final = AckMode.SEPARATE


class AckScheduler:
    """The receive window, the ACK mode, and the ACKs owed to the peer."""

    def __init__(
        self, config: ConnectionConfig, *, stats: ConnectionStats, hint: TimerHint
    ) -> None:
        self.mode = config.ack_mode
        """The mode in force: the master's choice, adopted by the slave at the open."""
        self.window: ReceiveWindow | None = None
        """The peer's data as it arrived, from the open on."""
        self.separate: deque[tuple[int, float]] = deque()
        """Separate-ACK mode: (sequence number, arrival time) of every arrival still to acknowledge."""
        self.due = math.inf
        """Bidirectional mode: no ACK is owed (:meth:`emit_due` sends none) before ``due``; it is
        set at each arrival (``-inf`` when the full rule owes one at once) and may be earlier than
        the truth, never later. The connection asks :meth:`emit_due` only from then on."""
        self._ack_delay = config.ack_delay
        self._plain = config.plain_acks
        self._silence_guard = config.silence_timeout
        self._stats = stats
        self._hint = hint

    def open(self, initial_seq: int, keyed: bool) -> None:
        """The peer's data starts at ``initial_seq`` (its OPEN's or OPEN_ACK's header); an unkeyed
        session checks that a new packet is no further ahead than the peer can have sent."""
        self.due = math.inf
        self.window = ReceiveWindow(
            initial_seq,
            coverage=self.mode is AckMode.BIDIRECTIONAL,
            silence_guard=self._silence_guard,
            guard_jumps=not keyed,
        )

    def on_arrival(self, window: ReceiveWindow, seq: int, now: float) -> Arrival:
        """A data packet arrived: classify it and schedule its acknowledgement."""
        quiet = window.unreported_since is None
        arrival = window.classify(seq, now)
        since = window.unreported_since
        if window.held:
            self._hint.value = -math.inf  # an ACK is due at once
        elif quiet and since is not None:
            due = now + self._ack_delay  # an ACK is due by then
            hint = self._hint
            if due < hint.value:
                hint.value = due
        if since is not None:
            # When emit_due's rules next owe an ACK (only an arrival changes them).
            low = window.pending_low
            if low is not None and window.highest - low >= SACK_SPAN:
                self.due = -math.inf
            else:
                self.due = since + self._ack_delay
        if arrival is NEW and window.last_gap:
            self._stats.peer_gaps += window.last_gap
        if self.mode is _SEPARATE and (arrival is NEW or arrival is LATE):
            # Trinomial acknowledges every arrival, whether or not the sample is delivered.
            self.separate.append((window.last_seq, now))
            self._hint.value = -math.inf
        return arrival

    def piggyback(self, window: ReceiveWindow, now: float) -> tuple[int, int, int]:
        """ACK fields reporting the newest peer data (or none before any arrived, or in
        separate-ACK mode)."""
        if self.mode is not _BIDIRECTIONAL or not window.has_data:
            return NO_ACK
        return window.report(now)

    def deadline(self, deadline: float) -> float:
        """The earlier of ``deadline`` and when the next ACK is due."""
        window = self.window
        if window is None:
            return deadline
        if self.mode is _BIDIRECTIONAL:
            since = window.unreported_since
            if since is not None and since + self._ack_delay < deadline:
                deadline = since + self._ack_delay
            if window.held and window.highest_arrival < deadline:
                deadline = window.highest_arrival  # due since the jump
        elif self.separate:
            candidate = self.separate[0][1]
            if candidate < deadline:
                deadline = candidate
        return deadline

    def emit_held(
        self, out: Datagrams, outbox: Outbox, seq: int, peer: Address, now: float
    ) -> None:
        """The jump rule (section 3.2): report what a newer packet put out of reach, first."""
        window = self.window
        if window is not None and self.mode is _BIDIRECTIONAL and window.held:
            for held in window.take_held():
                hold = encode_hold(now - held.arrival)
                outbox.emit_ack(out, seq, held.ack, held.sack, hold, peer, now)

    def emit_due(self, out: Datagrams, outbox: Outbox, seq: int, peer: Address, now: float) -> None:
        """The ACK the delay rule owes (bidirectional), or every separate ACK."""
        window = self.window
        assert window is not None
        if self.mode is _BIDIRECTIONAL:
            since = window.unreported_since
            # (window.coverage_exhausted(), inline: this runs after every datagram received.)
            low = window.pending_low
            if since is not None and (
                now >= since + self._ack_delay
                or (low is not None and window.highest - low >= SACK_SPAN)
            ):
                # self.piggyback(window, now), inline: the mode is bidirectional, and an arrival
                # not reported yet means the window has data.
                ack, sack, hold = window.report(now)
                outbox.emit_ack(out, seq, ack, sack, hold, peer, now)
        else:
            acks = self.separate
            plain = self._plain
            while acks:
                acked, arrival = acks.popleft()
                sack = 0 if plain else window.sack_below(acked)  # plain: this packet only
                outbox.emit_ack(out, seq, acked, sack, encode_hold(now - arrival), peer, now)
