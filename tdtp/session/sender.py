"""The send path for samples: the newest sample, waiting for the pacer or the socket, and its departure.

Supermedia data goes stale: a sample that cannot leave yet waits in one slot, and a newer one replaces
it (counted as superseded) instead of queueing behind it; nothing is retransmitted. The rate controller's
pacer says when the slot may empty; the socket can pause it (a full send buffer). A sample that may
leave at once, with nothing else due, takes the short way (:meth:`SampleSender.send_direct`): encoded,
sealed and handed to the transport before any bookkeeping.

:class:`SampleSender` owns the slot, the pause and the session's send limit. It frames the data packet
with the ACK fields the :class:`~tdtp.session.ack_scheduler.AckScheduler` owes, takes its sequence
number from loss recovery's sent log, and counts it; the connection checks the state first.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Final

from tdtp.config import AckMode, ConnectionConfig
from tdtp.control.base import RateController
from tdtp.errors import EmptyPayloadError, PayloadTooLargeError, PayloadTypeError
from tdtp.session.ack_scheduler import AckScheduler
from tdtp.session.events import Address
from tdtp.session.liveness import Liveness
from tdtp.session.one_way import OneWayDelay
from tdtp.session.outbox import Datagrams, Outbox
from tdtp.session.recovery import LossRecovery
from tdtp.session.stats import ConnectionStats
from tdtp.session.timer_hint import TimerHint
from tdtp.wire.control import RESET_ECHO_SIZE, ControlCode, encode_timestamp
from tdtp.wire.header import HEADER_SIZE, SEQ_MASK, PacketType, encode_header, pack_header_words
from tdtp.wire.hold import HOLD_NO_ACK

_DATA = int(PacketType.DATA)
_CONTROL = int(PacketType.CONTROL)
_TIMED_DATA: Final = ControlCode.TIMED_DATA
_BIDIRECTIONAL: Final = (
    AckMode.BIDIRECTIONAL
)  # a module constant: no enum metaclass lookup per sample


class SampleSender:
    """The pending sample, whether the pacer held it, the socket's pause, the send limit."""

    def __init__(
        self,
        config: ConnectionConfig,
        *,
        controller: RateController,
        stats: ConnectionStats,
        recovery: LossRecovery,
        outbox: Outbox,
        acks: AckScheduler,
        liveness: Liveness,
        hint: TimerHint,
    ) -> None:
        self.pending: bytes | None = None
        self._pending_paced = False  # the pending sample had to wait for the pacer
        self.paused = False
        """True between Connection.pause_sending and resume_sending."""
        self.limit = config.max_payload
        """The largest payload accepted: the smaller of ours and the peer's maximum."""
        self.transmit_errors = 0
        self._controller = controller
        controller.sample_waiting = False  # kept up to date from here on
        self._stats = stats
        self._recovery = recovery
        self._outbox = outbox
        self._acks = acks
        self._liveness = liveness
        self._hint = hint
        self.one_way = outbox.one_way = OneWayDelay(config, controller, recovery, stats)
        """Our stamps and the peer's (PROTOCOL.md 5.13): TIMED_DATA leaves from here."""
        self._one_way = self.one_way

    def offer(self, payload: bytes | bytearray | memoryview, now: float) -> None:
        """Connection.send on an established session: the newest sample takes the slot."""
        if type(payload) is not bytes:
            payload = _as_payload(payload)
        if not payload:
            raise EmptyPayloadError(
                "a sample must have at least one byte (TDTP sends no empty DATA packet; the "
                "connection acknowledges and keeps itself alive on its own)"
            )
        if len(payload) > self.limit:
            raise PayloadTooLargeError(
                f"payload of {len(payload)} bytes exceeds the connection's maximum of "
                f"{self.limit} bytes (the smaller of both ends' max_payload); send less "
                "or raise max_payload on both ends"
            )
        stats = self._stats
        stats.samples_offered += 1
        if self.pending is not None:
            stats.samples_superseded += 1
            if self.paused:
                stats.samples_blocked += 1
            self._pending_paced = True
        else:
            controller = self._controller
            due = controller.next_send_time()
            if now < due:
                # The controller may owe a settlement that brings the departure forward (trinomial
                # settles an increase interval's end lazily while no sample waits): settle it, as
                # its timer would have, before deciding that the pacer holds this sample.
                controller.on_timer(now=now)
                due = controller.next_send_time()
            self._pending_paced = paced = now < due
            hint = self._hint
            if paced and due < hint.value:
                hint.value = due  # the pacer's deadline for it
            controller.sample_waiting = True
            hint.check_controller()
        self.pending = payload

    def send_direct(
        self,
        payload: bytes | bytearray | memoryview,
        transmit: Callable[[bytes, Address | None], object],
        peer: Address,
        connected: bool,
        now: float,
    ) -> bool:
        """Connection.send_direct on an established session (see there)."""
        acks = self._acks
        window = acks.window
        controller = self._controller
        if (
            type(payload) is not bytes
            or not 0 < (length := len(payload)) <= self.limit
            or self.paused
            or self._outbox.control
            or acks.separate
            or now < controller.next_send_time()
            or window is None
            or window.held
            or now >= self._one_way.data_due  # a stamp is due: take_due sends TIMED_DATA
        ):
            self.offer(payload, now)
            return False
        stats = self._stats
        stats.samples_offered += 1
        paced = False
        if self.pending is not None:
            # A held sample the pacer would let go now: the newer one wins.
            stats.samples_superseded += 1
            paced = True
            self.pending = None
            controller.sample_waiting = False
        recovery = self._recovery
        # encode_header(_DATA, seq, ack, sack, hold), inline (DATA's type bits are zero)
        seq = recovery.sent.next_seq & SEQ_MASK
        if acks.mode is _BIDIRECTIONAL and window.has_data:
            ack, sack, hold = window.report(now)
            header = pack_header_words(
                seq >> 6, ((seq & 0x3F) << 26) | ((ack & SEQ_MASK) << 14) | (sack << 8) | hold
            )
        else:
            header = pack_header_words(seq >> 6, ((seq & 0x3F) << 26) | HOLD_NO_ACK)
        outbox = self._outbox
        sealer = outbox.sealer
        datagram = header + payload if sealer is None else sealer.seal(header, payload)
        try:
            transmit(datagram, None if connected else peer)
        except OSError:
            self.transmit_errors += 1
        guard = outbox.reset_guard
        if guard is not None:
            guard.recent.append(datagram[:RESET_ECHO_SIZE])  # ResetGuard.record, inline
        # Bookkeeping, after the datagram has left.
        size = len(datagram)
        recovery.on_sent(now, size)
        controller.on_packet_sent(now=now, size=size, paced=paced)
        counts = stats.sent
        counts.data_packets += 1
        counts.payload_bytes += length
        counts.datagrams += 1
        counts.bytes += size
        counts.header_bytes += HEADER_SIZE
        counts.protection_bytes += outbox.overhead
        self._liveness.last_send = now
        self._hint.check_controller()
        return True

    def take_due(self, out: Datagrams, peer: Address, now: float) -> None:
        """Connection.datagrams_to_send: the pending sample, if the pacer and the socket let it go."""
        payload = self.pending
        controller = self._controller
        if payload is None or self.paused or now < controller.next_send_time():
            return
        self.pending = None
        controller.sample_waiting = False
        acks = self._acks
        window = acks.window
        assert window is not None
        recovery = self._recovery
        ack, sack, hold = acks.piggyback(window, now)
        outbox = self._outbox
        one_way = self._one_way
        seq = recovery.sent.next_seq
        if now >= one_way.data_due:
            # TIMED_DATA (PROTOCOL.md 5.13): the header as DATA's, the send time before the sample.
            stamp = encode_timestamp(_TIMED_DATA, one_way.stamp(now))
            datagram = outbox.protect(
                encode_header(_CONTROL, seq, ack, sack, hold) + stamp[:1], stamp[1:] + payload
            )
        else:
            datagram = outbox.protect(encode_header(_DATA, seq, ack, sack, hold), payload)
        size = len(datagram)
        recovery.on_sent(now, size)
        controller.on_packet_sent(now=now, size=size, paced=self._pending_paced)
        outbox.emit_data(out, datagram, len(payload), peer, now)
        self._hint.check_controller()

    def deadline(self, deadline: float) -> float:
        """The earlier of ``deadline`` and the pacer's for the pending sample."""
        if self.pending is not None and not self.paused:
            candidate = self._controller.next_send_time()
            if candidate < deadline:
                return candidate
        return deadline

    def pause(self) -> None:
        if not self.paused:
            self.paused = True
            self._stats.send_pauses += 1

    def resume(self) -> None:
        self.paused = False
        self._hint.value = -math.inf

    def drop(self) -> None:
        """The session ended: the pending sample goes."""
        self.pending = None
        self._controller.sample_waiting = False


def _as_payload(payload: object) -> bytes:
    if isinstance(payload, bytes | bytearray | memoryview):
        return bytes(payload)
    hint = "; encode text first, e.g. text.encode()" if isinstance(payload, str) else ""
    raise PayloadTypeError(
        "a sample must be bytes-like (bytes, bytearray or memoryview), got "
        f"{type(payload).__name__}{hint}"
    )
