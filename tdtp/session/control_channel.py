"""The reliable control channel: small application messages, exactly once and in order, beside the
latest-value sample stream of the same session (docs/PROTOCOL.md section 5.10).

Samples are never retransmitted: a newer one supersedes a lost one. Some messages must not be lost or
superseded (an emergency stop, a mode change, a gripper command), so a session also carries a second,
independent stream of **control messages** in CONTROL packets (codes MESSAGE and MESSAGE_ACK):

* each side numbers its messages consecutively (16 bits on the wire, full numbers here) from a first
  number derived from its initial data sequence number, which both ends know from the opening;
* every MESSAGE carries the cumulative acknowledgement of the peer's messages (the next number
  expected); a MESSAGE_ACK carries it alone when no message of ours leaves in the same flush; both
  carry the master's nonce, as a KEEPALIVE does, and one with another nonce is dropped before
  anything in it is read (``nonce_mismatch``): a blind attacker can neither inject nor acknowledge
  a message, however many numbers it tries;
* a message is retransmitted when its acknowledgement has not come within the session's loss delay
  (the RTT estimator of :mod:`tdtp.session.recovery`, RFC 6298 style, plus the reorder allowance and the
  peer's ACK delay), backing off exponentially; while backed off only the oldest message is sent
  again (a probe, as TCP's retransmission timeout), so an outage costs one datagram per interval;
* the receiver buffers messages that arrive ahead of a gap and delivers them in order as
  :class:`~tdtp.session.events.ControlReceived` events; duplicates are dropped and acknowledged again.

The channel never holds up a sample: samples keep their own slot, pacer and sequence numbers, and a
message waiting for its acknowledgement waits beside them.

Everything is bounded: at most ``control_window`` messages of ours unacknowledged (one more raises
:class:`~tdtp.errors.ControlQueueFullError`), at most ``control_window`` of the peer's held (out of
order, or delivered and not yet read), MESSAGE datagrams at most ``control_max_rate`` a second
(retransmissions included), and a message not acknowledged within ``control_timeout`` is given up
with every one after it (:class:`~tdtp.session.events.ControlExpired`). A peer that never acknowledges
therefore costs a fixed amount of memory and, after the timeout, nothing.
"""

from __future__ import annotations

import math
import struct
from collections import deque
from typing import Final

from tdtp.config import ConnectionConfig
from tdtp.errors import (
    ControlChannelFailedError,
    ControlQueueFullError,
    EmptyPayloadError,
    PayloadTooLargeError,
    PayloadTypeError,
)
from tdtp.session.event_queue import EventQueue
from tdtp.session.events import Address, ControlExpired, ControlReceived
from tdtp.session.outbox import Datagrams, Outbox
from tdtp.session.recovery import LossRecovery
from tdtp.session.stats import ConnectionStats, DropReason
from tdtp.session.timer_hint import TimerHint
from tdtp.wire.control import (
    MESSAGE_ACK_BODY_SIZE,
    MESSAGE_NONCE_OFFSET,
    MESSAGE_NUMBERS_OFFSET,
    MESSAGE_PREFIX_SIZE,
    NONCE_SIZE,
    ControlCode,
)
from tdtp.wire.header import HEADER_SIZE, PacketType, encode_header
from tdtp.wire.hold import HOLD_NO_ACK

FIRST_MESSAGE_BASE: Final = 0xF000
"""A side's first message number is ``0xF000 | its initial data sequence number`` (12 bits): known to
both ends from the opening, different in every session, and within 4096 messages of the 16-bit wrap,
so that every implementation crosses the wrap early in its life instead of after hours."""
CONTROL_BURST: Final = 8
"""MESSAGE datagrams that may leave back to back before ``control_max_rate`` paces them."""
MAX_RETRANSMIT_INTERVAL: Final = 1.0
"""The exponential back-off stops doubling here (unless the loss delay itself is longer): after an
outage the channel's probe is at most a second away."""

_CONTROL: Final = int(PacketType.CONTROL)
_MESSAGE: Final = int(ControlCode.MESSAGE)
_MESSAGE_PREFIX: Final = bytes((ControlCode.MESSAGE,))
_MESSAGE_ACK_PREFIX: Final = bytes((ControlCode.MESSAGE_ACK,))
_NUMBERS: Final = struct.Struct(">HH")
_ACK_FIELD: Final = struct.Struct(">H")
_NONCE_START: Final = HEADER_SIZE + MESSAGE_NONCE_OFFSET
_NONCE_END: Final = _NONCE_START + NONCE_SIZE
_NUMBERS_START: Final = HEADER_SIZE + MESSAGE_NUMBERS_OFFSET
_HALF: Final = 1 << 15
_ONE_TOKEN: Final = 1.0 - 1e-9  # a token refilled up to rounding counts as one
_TOKEN_SLACK: Final = 1e-9  # so that the refill deadline is never the instant that found it short


DROPPED: Final = 0
"""What :meth:`ControlChannel.receive` found: dropped and counted, and no sign of life."""
ALIVE: Final = 1
"""Dropped and counted, but well formed and (keyed) authentic: a sign of life from the peer."""
TAKEN: Final = 2
"""Taken in."""


def largest_message_body(config: ConnectionConfig) -> int:
    """Bytes after the base header of the largest MESSAGE ``config`` accepts (protection aside)."""
    return MESSAGE_PREFIX_SIZE + config.control_max_message


def expand_message_number(value: int, expected: int) -> int:
    """The full message number whose low 16 bits are ``value``, nearest to ``expected`` (within
    -32768..+32767 of it; RFC 1982 serial arithmetic)."""
    base = expected - _HALF
    return base + ((value - base) & 0xFFFF)


class _Outgoing:
    """One message of ours not yet acknowledged."""

    __slots__ = ("number", "payload", "queued_at", "sent_at", "transmissions")

    def __init__(self, number: int, payload: bytes, queued_at: float) -> None:
        self.number = number
        self.payload = payload
        self.queued_at = queued_at
        self.sent_at = 0.0
        self.transmissions = 0


class ControlChannel:
    """Both directions of the control channel: our messages until acknowledged, the peer's until
    delivered in order, and the acknowledgement we owe."""

    def __init__(
        self,
        config: ConnectionConfig,
        *,
        stats: ConnectionStats,
        outbox: Outbox,
        events: EventQueue,
        recovery: LossRecovery,
        hint: TimerHint,
    ) -> None:
        self._max_message = config.control_max_message
        self._window = config.control_window
        self._rate = config.control_max_rate
        self._timeout = config.control_timeout
        self._stats = stats
        self._outbox = outbox
        self._events = events
        self._recovery = recovery
        self._hint = hint
        # Sending.
        self._first = 0  # our first message number (set at the open)
        self._next = 0  # the number of the next message the application sends
        self._next_sent = 0  # one past the highest number transmitted at least once
        self._acked_below = 0  # every message of ours below this is acknowledged
        self._unacked: deque[_Outgoing] = deque()
        self._backoff = 0  # retransmission timeouts in a row without progress
        self._tokens = float(CONTROL_BURST)
        self._tokens_at = 0.0
        self._due = math.inf  # when a transmission is next due (the timer's share)
        self.emit_at = math.inf
        """:meth:`emit` has nothing to send before this (``-inf`` while an acknowledgement is owed,
        else when a transmission is next due): the connection asks it only from then on."""
        self.failed: str | None = None
        """Why the channel gave up (it then takes no more messages), else ``None``."""
        self._nonce = bytes(NONCE_SIZE)  # the master's (set at the open)
        # Receiving.
        self._peer_first = 0
        self._expected = 0  # the next message number expected from the peer
        self._held: dict[int, bytes] = {}  # arrived ahead of a gap
        self._ack_owed = False
        self._ack_owed_at = 0.0
        self.app_unread = 0
        """Delivered messages a driver holds that its application has not read yet (they count
        against the receive bound like those still in the event queue)."""

    # ------------------------------------------------------------------ the session

    def open(self, own_initial_seq: int, peer_initial_seq: int, nonce: bytes) -> None:
        """The session opened: both first message numbers follow from the initial data sequence
        numbers (``FIRST_MESSAGE_BASE``); every message carries the master's ``nonce``."""
        self._nonce = nonce
        self._first = self._next = self._next_sent = self._acked_below = (
            FIRST_MESSAGE_BASE | own_initial_seq
        )
        self._peer_first = self._expected = FIRST_MESSAGE_BASE | peer_initial_seq

    @property
    def unacked(self) -> int:
        """Messages of ours the peer has not acknowledged (queued or in flight)."""
        return len(self._unacked)

    # ------------------------------------------------------------------ the application's side

    def send(self, payload: bytes | bytearray | memoryview, now: float) -> None:
        """Queue one message; it leaves with the next flush the rate cap allows."""
        if self.failed is not None:
            raise ControlChannelFailedError(self.failed)
        if type(payload) is not bytes:
            if not isinstance(payload, bytes | bytearray | memoryview):
                hint = "; encode text first, e.g. text.encode()" if isinstance(payload, str) else ""
                raise PayloadTypeError(
                    "a control message must be bytes-like (bytes, bytearray or memoryview), got "
                    f"{type(payload).__name__}{hint}"
                )
            payload = bytes(payload)
        if not payload:
            raise EmptyPayloadError("a control message must have at least one byte")
        if len(payload) > self._max_message:
            raise PayloadTooLargeError(
                f"control message of {len(payload)} bytes exceeds control_max_message "
                f"({self._max_message} bytes); send less or raise it on both ends"
            )
        unacked = self._unacked
        if len(unacked) >= self._window:
            raise ControlQueueFullError(
                f"the control channel holds {len(unacked)} messages the peer has not acknowledged "
                f"(control_window); send again once it acknowledges some"
            )
        unacked.append(_Outgoing(self._next, payload, now))
        self._next += 1
        self._stats.control_sent += 1
        self._reschedule(now)

    # ------------------------------------------------------------------ input

    def receive(self, data: bytes, established: bool, now: float) -> int:
        """A MESSAGE or MESSAGE_ACK (header and code byte included, protection removed): TAKEN
        (counted as a control packet received; the connection counts the rest), or dropped and
        counted by reason in ``drops`` and ``control_dropped``, ALIVE if a sign of life all the
        same, DROPPED if not."""
        stats = self._stats
        if not established:
            stats.count_drop(DropReason.NOT_ESTABLISHED)
            return DROPPED
        refused = self._take(data, now)
        if refused is None:
            stats.received.control_packets += 1
            return TAKEN
        stats.count_drop(refused)
        dropped = stats.control_dropped
        dropped[refused.value] = dropped.get(refused.value, 0) + 1
        if (
            refused is DropReason.BAD_CONTROL
            or refused is DropReason.OVERSIZED
            or refused is DropReason.NONCE_MISMATCH
        ):
            return DROPPED
        return ALIVE

    def _take(self, data: bytes, now: float) -> DropReason | None:
        """Why ``data`` is dropped, or ``None`` if it is taken in."""
        size = len(data)
        nonce = data[_NONCE_START:_NONCE_END]
        if data[HEADER_SIZE] != _MESSAGE:
            if size != HEADER_SIZE + MESSAGE_ACK_BODY_SIZE:
                return DropReason.BAD_CONTROL
            if nonce != self._nonce:
                return DropReason.NONCE_MISMATCH
            if not self._on_ack(_ACK_FIELD.unpack_from(data, _NUMBERS_START)[0], now):
                return DropReason.OPTIMISTIC_ACK
            return None
        start = HEADER_SIZE + MESSAGE_PREFIX_SIZE
        length = size - start
        if length <= 0:
            return DropReason.BAD_CONTROL
        if length > self._max_message:
            return DropReason.OVERSIZED
        # Another session's, or a blind forgery: nothing in it is read (PROTOCOL.md 5.10).
        if nonce != self._nonce:
            return DropReason.NONCE_MISMATCH
        wire_seq, wire_ack = _NUMBERS.unpack_from(data, _NUMBERS_START)
        if not self._on_ack(wire_ack, now):
            return DropReason.OPTIMISTIC_ACK
        # Whatever becomes of the message, the peer learns where we stand: a duplicate means our
        # acknowledgement was lost.
        if not self._ack_owed:
            self._ack_owed = True
            self._ack_owed_at = now
            self.emit_at = -math.inf
            self._hint.value = -math.inf
        expected = self._expected
        number = expand_message_number(wire_seq, expected)
        held = self._held
        if number < expected or number in held:
            return DropReason.DUPLICATE
        if number >= expected + self._window:
            return DropReason.CONTROL_WINDOW
        if len(held) + self._events.control_pending + self.app_unread >= self._window:
            return DropReason.CONTROL_BACKLOG
        held[number] = data[start:]
        stats = self._stats
        events = self._events
        peer_first = self._peer_first
        while expected in held:
            events.push_control(ControlReceived(held.pop(expected), expected - peer_first, now))
            stats.control_delivered += 1
            expected += 1
        self._expected = expected
        return None

    def _on_ack(self, wire_ack: int, now: float) -> bool:
        """The peer's cumulative acknowledgement; False if it acknowledges a message never sent."""
        acked_below = self._acked_below
        full = expand_message_number(wire_ack, acked_below)
        if full > self._next_sent:
            return False
        if full <= acked_below:
            return True  # nothing new (a repeat, or reordered behind a newer one)
        unacked = self._unacked
        for _ in range(full - acked_below):
            unacked.popleft()
        self._stats.control_acked += full - acked_below
        self._acked_below = full
        self._backoff = 0
        self._reschedule(now)
        return True

    # ------------------------------------------------------------------ output

    def emit(self, out: Datagrams, data_seq: int, peer: Address, now: float, held: bool) -> None:
        """What is due at ``now``: new messages and retransmissions (within the rate cap), each
        carrying our acknowledgement, or a MESSAGE_ACK alone if we owe one. Nothing while ``held``
        (a new path not validated yet: PROTOCOL.md 5.8)."""
        if held:
            return
        if now >= self._due:
            self._transmit(out, data_seq, peer, now)
        if self._ack_owed:
            self._ack_owed = False
            self.emit_at = self._due
            outbox = self._outbox
            datagram = outbox.protect(
                encode_header(_CONTROL, data_seq, 0, 0, HOLD_NO_ACK) + _MESSAGE_ACK_PREFIX,
                self._nonce + _ACK_FIELD.pack(self._expected & 0xFFFF),
            )
            outbox.emit_control(out, datagram, peer, now, outbox.overhead, True)

    def _transmit(self, out: Datagrams, data_seq: int, peer: Address, now: float) -> None:
        self._refill(now)
        interval = self._interval()
        backoff = self._backoff
        outbox = self._outbox
        stats = self._stats
        header = encode_header(_CONTROL, data_seq, 0, 0, HOLD_NO_ACK) + _MESSAGE_PREFIX
        timed_out = False
        for index, message in enumerate(self._unacked):
            if self._tokens < _ONE_TOKEN or (backoff and index):
                break  # out of tokens; or backed off: only the oldest message goes (a probe)
            if message.transmissions:
                if now < message.sent_at + interval:
                    continue
                if index == 0:
                    timed_out = True
                stats.control_retransmits += 1
            elif backoff:
                break  # backed off: new messages wait until the probe is acknowledged
            ack = self._expected & 0xFFFF
            datagram = outbox.protect(
                header, self._nonce + _NUMBERS.pack(message.number & 0xFFFF, ack) + message.payload
            )
            outbox.emit_control(out, datagram, peer, now, outbox.overhead, True)
            stats.control_transmissions += 1
            self._tokens -= 1.0
            self._ack_owed = False  # it carried the acknowledgement
            self.emit_at = self._due
            message.sent_at = now
            message.transmissions += 1
            if message.number >= self._next_sent:
                self._next_sent = message.number + 1
        if timed_out:
            self._backoff += 1
        self._reschedule(now)

    def _refill(self, now: float) -> None:
        tokens = self._tokens + (now - self._tokens_at) * self._rate
        self._tokens = tokens if tokens < CONTROL_BURST else float(CONTROL_BURST)
        self._tokens_at = now

    def _interval(self) -> float:
        """How long a transmission waits for its acknowledgement: the session's loss delay, doubled
        per timeout in a row, up to ``MAX_RETRANSMIT_INTERVAL`` (or the loss delay if longer)."""
        base = self._recovery.loss_delay
        if not self._backoff:
            return base
        return min(base * (1 << min(self._backoff, 16)), max(base, MAX_RETRANSMIT_INTERVAL))

    def _reschedule(self, now: float) -> None:
        """Recompute when a transmission is next due (after anything that changes it)."""
        due = math.inf
        unacked = self._unacked
        if unacked:
            interval = self._interval()
            if self._backoff:
                first = unacked[0]
                due = first.sent_at + interval if first.transmissions else now
            else:
                for message in unacked:
                    if not message.transmissions:
                        due = min(due, now)
                        break
                    due = min(due, message.sent_at + interval)
            if due < math.inf and self._tokens < _ONE_TOKEN:
                due = max(due, self._tokens_at + (1.0 - self._tokens) / self._rate + _TOKEN_SLACK)
        self._due = due
        if not self._ack_owed:
            self.emit_at = due
        if due < self._hint.value:
            self._hint.value = due

    # ------------------------------------------------------------------ timers

    def deadline(self, deadline: float) -> float:
        """The earlier of ``deadline`` and the channel's own: a transmission, an acknowledgement
        owed, or the give-up time of the oldest message."""
        if self._ack_owed and self._ack_owed_at < deadline:
            deadline = self._ack_owed_at
        if self._due < deadline:
            deadline = self._due
        unacked = self._unacked
        if unacked:
            expiry = unacked[0].queued_at + self._timeout
            if expiry < deadline:
                deadline = expiry
        return deadline

    def abandon(self, detail: str, now: float) -> None:
        """The session ended: report the messages the peer never acknowledged (one
        ``ControlExpired``, oldest first) instead of dropping them unsaid (PROTOCOL.md 5.10,
        sender rule 6). Nothing is reported when every message was acknowledged."""
        unacked = self._unacked
        if not unacked:
            return
        payloads = tuple(message.payload for message in unacked)
        self._stats.control_given_up += len(payloads)
        first = unacked[0].number - self._first
        unacked.clear()
        self.failed = detail
        self._due = math.inf
        self._events.push(ControlExpired(first, payloads, detail, now))

    def expire(self, now: float) -> None:
        """Give up, at ``control_timeout``, on the oldest unacknowledged message and all after it."""
        unacked = self._unacked
        if not unacked or now < unacked[0].queued_at + self._timeout:
            return
        first = unacked[0]
        payloads = tuple(message.payload for message in unacked)
        detail = (
            f"control message {first.number - self._first} was not acknowledged within "
            f"{self._timeout:g} s; it and the {len(payloads) - 1} after it were given up, and the "
            "control channel takes no more messages (open a new connection)"
        )
        self.failed = detail
        self._stats.control_given_up += len(payloads)
        unacked.clear()
        self._due = math.inf
        if not self._ack_owed:
            self.emit_at = math.inf
        self._events.push(ControlExpired(first.number - self._first, payloads, detail, now))
        self._hint.value = -math.inf
