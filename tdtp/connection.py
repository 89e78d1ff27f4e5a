"""The sans-IO TDTP connection: a state machine that never touches a socket or reads a clock.

The caller owns I/O and time. It feeds datagrams in with :meth:`Connection.receive_datagram`, timer expiries
with :meth:`Connection.handle_timer` and samples with :meth:`Connection.send`, always passing ``now``
(seconds on one monotonic clock). After every input it collects :meth:`Connection.datagrams_to_send` and
re-arms a single timer at :meth:`Connection.get_timer`. What happened comes out of
:meth:`Connection.next_event`. The asyncio endpoints, the impairment emulator and the virtual-time simulator
all drive this one class.

Peer input never raises: anything malformed, unexpected or hostile is dropped and counted in
``stats.drops`` by reason. Misuse by the caller raises a :class:`~tdtp.errors.TdtpError` subclass.
"""

from __future__ import annotations

import enum
import random
from collections import deque

from tdtp.config import AckMode, ConnectionConfig, Role
from tdtp.control.base import RateController
from tdtp.control.registry import create_controller
from tdtp.errors import ConnectionClosedError, ConnectionStateError, PayloadTooLargeError
from tdtp.events import (
    Address,
    CloseCause,
    ConnectionClosed,
    ConnectionEstablished,
    DataReceived,
    Event,
)
from tdtp.loss_rate import LossIntervalEstimator
from tdtp.receive_window import Arrival, ReceiveWindow
from tdtp.rtt import RttEstimator
from tdtp.sent_log import LostPacket, SentPacketLog
from tdtp.stats import ConnectionStats, DropReason
from tdtp.wire.control import (
    PROTOCOL_VERSION,
    CloseBody,
    CloseReason,
    ControlCode,
    OpenBody,
    OpenFlags,
    decode_control,
    encode_close,
    encode_keepalive,
    encode_open,
)
from tdtp.wire.errors import MalformedPacketError
from tdtp.wire.header import HEADER_SIZE, PacketType, decode_header, encode_header
from tdtp.wire.hold import HOLD_NO_ACK, decode_hold, encode_hold
from tdtp.wire.seqnum import SEQ_MODULUS

_DATA = int(PacketType.DATA)
_ACK = int(PacketType.ACK)
_CONTROL = int(PacketType.CONTROL)
_NO_ACK = (0, 0, HOLD_NO_ACK)
LOSS_DELAY_SRTT = 1.2
LOSS_DELAY_RTTVAR = 4.0
TIMER_GRANULARITY = 0.001
"""Slack for timers firing late (RFC 9002's kGranularity)."""


class State(enum.Enum):
    IDLE = "idle"
    """A master that has not called :meth:`Connection.connect` yet."""
    LISTENING = "listening"
    """A slave waiting for its master's OPEN."""
    OPENING = "opening"
    """A master whose OPEN is not answered yet."""
    ESTABLISHED = "established"
    CLOSED = "closed"


class Connection:
    """One TDTP association between a master and a slave.

    ``rng`` supplies the connection nonce and the initial sequence number; pass a seeded
    :class:`random.Random` for reproducible runs (the default draws from the OS).
    """

    def __init__(
        self,
        config: ConnectionConfig | None = None,
        *,
        role: Role,
        rng: random.Random | None = None,
    ) -> None:
        if not isinstance(role, Role):
            raise TypeError(f"role must be Role.MASTER or Role.SLAVE, got {role!r}")
        self.config = config if config is not None else ConnectionConfig()
        self.role = role
        rng = rng if rng is not None else random.SystemRandom()
        self._state = State.IDLE if role is Role.MASTER else State.LISTENING
        self._peer: Address | None = None
        self._nonce = rng.getrandbits(64)
        self._ack_mode = self.config.ack_mode
        self._send_limit = self.config.max_payload
        self._controller: RateController = create_controller(
            self.config.controller, self.config.controller_config
        )
        # The peer holds ACKs up to its ack_delay; not negotiated, so ours stands for it.
        self._controller.feedback_delay = self.config.ack_delay
        first_seq = rng.randrange(SEQ_MODULUS)
        self._sent = SentPacketLog(
            first_seq,
            reorder_threshold=self.config.reorder_threshold,
            max_tracked=self.config.max_tracked_packets,
        )
        self._rtt = RttEstimator(self.config.initial_rtt)
        self._loss = LossIntervalEstimator(first_seq)
        self._window: ReceiveWindow | None = None
        self._pending: bytes | None = None
        self._pending_paced = False  # the pending sample had to wait for the pacer
        self._control_out: list[tuple[bytes, Address]] = []
        self._separate_acks: deque[tuple[int, float]] = deque()
        self._event_seq = 0
        self._data_events: deque[tuple[int, Event]] = deque()
        self._other_events: deque[tuple[int, Event]] = deque()
        self._last_send = 0.0
        self._last_receive = 0.0
        self._open_deadline = 0.0
        self._open_next = 0.0
        self._lost: list[LostPacket] = []
        self._stats = ConnectionStats()

    # ------------------------------------------------------------------ introspection

    @property
    def state(self) -> State:
        return self._state

    @property
    def peer(self) -> Address | None:
        """The peer's address once known (the master's at ``connect``, the slave's at the OPEN)."""
        return self._peer

    @property
    def ack_mode(self) -> AckMode:
        """The mode in force: the master's choice, adopted by the slave at the open."""
        return self._ack_mode

    @property
    def max_send_payload(self) -> int:
        """The largest payload :meth:`send` accepts: the smaller of ours and the peer's maximum."""
        return self._send_limit

    @property
    def controller(self) -> RateController:
        return self._controller

    @property
    def stats(self) -> ConnectionStats:
        """Live counters; the derived figures (srtt, p, rate) are refreshed on each access."""
        stats = self._stats
        rtt = self._rtt
        stats.srtt = rtt.srtt if rtt.has_sample else 0.0
        stats.rttvar = rtt.rttvar if rtt.has_sample else 0.0
        stats.min_rtt = rtt.min_rtt if rtt.has_sample else 0.0
        stats.loss_event_rate = self._loss.loss_event_rate
        stats.packets_unreported = self._sent.unknown
        stats.rate = self._controller.rate
        return stats

    # ------------------------------------------------------------------ caller API

    def connect(self, addr: Address, *, now: float) -> None:
        """Master only: start opening towards the slave at ``addr``."""
        if self.role is not Role.MASTER:
            raise ConnectionStateError(
                "connect() is for the master; a slave connection opens when its master's OPEN "
                "arrives through receive_datagram()"
            )
        if self._state is not State.IDLE:
            raise ConnectionStateError(
                f"connect() was already called (state {self._state.value}); "
                "create a new Connection for another association"
            )
        self._peer = addr
        self._state = State.OPENING
        self._open_deadline = now + self.config.open_timeout
        self._open_next = now
        self._last_receive = now

    def send(self, payload: bytes, *, now: float) -> None:
        """Offer the newest sample. It replaces any sample still waiting for the pacer (which is
        counted as superseded): stale supermedia data is never queued or retransmitted."""
        state = self._state
        if state is not State.ESTABLISHED:
            if state is State.CLOSED:
                raise ConnectionClosedError(
                    "the connection is closed; open a new one to send again"
                )
            raise ConnectionStateError(
                f"cannot send while {state.value}: wait for the ConnectionEstablished event"
            )
        if len(payload) > self._send_limit:
            raise PayloadTooLargeError(
                f"payload of {len(payload)} bytes exceeds the connection's maximum of "
                f"{self._send_limit} bytes (the smaller of both ends' max_payload); send less "
                "or raise max_payload on both ends"
            )
        stats = self._stats
        stats.samples_offered += 1
        if self._pending is not None:
            stats.samples_superseded += 1
            self._pending_paced = True
        else:
            self._pending_paced = now < self._controller.next_send_time()
        self._pending = bytes(payload)

    def close(self, *, now: float) -> None:
        """End the connection: a CLOSE goes out with the next :meth:`datagrams_to_send`."""
        if self._state is State.CLOSED:
            return
        if self._state in (State.OPENING, State.ESTABLISHED) and self._peer is not None:
            self._queue_close(CloseReason.NORMAL, self._peer)
        self._terminate(CloseCause.LOCAL_CLOSE, "closed by the application")

    def next_event(self) -> Event | None:
        """The oldest event not yet taken, or ``None``."""
        data, other = self._data_events, self._other_events
        if data and (not other or data[0][0] < other[0][0]):
            return data.popleft()[1]
        if other:
            return other.popleft()[1]
        return None

    # ------------------------------------------------------------------ input

    def receive_datagram(self, data: bytes, addr: Address, *, now: float) -> None:
        """Take one datagram from the network. Never raises on its content."""
        stats = self._stats
        stats.datagrams_in += 1
        if self._state is State.CLOSED:
            stats.count_drop(DropReason.CLOSED)
            return
        peer = self._peer
        if peer is not None and (addr[0] != peer[0] or addr[1] != peer[1]):
            stats.count_drop(DropReason.WRONG_ADDRESS)
            return
        size = len(data)
        if size < HEADER_SIZE:
            stats.count_drop(DropReason.TRUNCATED)
            return
        if size > HEADER_SIZE + self.config.max_payload:
            stats.count_drop(DropReason.OVERSIZED)
            return
        ptype, seq, ack, sack, hold = decode_header(data)
        if ptype == _DATA:
            self._on_data(data, seq, ack, sack, hold, now)
        elif ptype == _ACK:
            self._on_ack_packet(size, ack, sack, hold, now)
        elif ptype == _CONTROL:
            self._on_control(data, addr, seq, ack, sack, hold, now)
        else:
            stats.count_drop(DropReason.UNKNOWN_TYPE)

    def _accept(self, size: int, payload_size: int, now: float) -> None:
        received = self._stats.received
        received.datagrams += 1
        received.bytes += size
        received.header_bytes += HEADER_SIZE
        received.payload_bytes += payload_size
        self._last_receive = now

    def _on_data(self, data: bytes, seq: int, ack: int, sack: int, hold: int, now: float) -> None:
        stats = self._stats
        window = self._window
        if self._state is not State.ESTABLISHED or window is None:
            stats.count_drop(DropReason.NOT_ESTABLISHED)
            return
        if hold != HOLD_NO_ACK and not self._on_feedback(ack, sack, hold, now):
            stats.count_drop(DropReason.OPTIMISTIC_ACK)
            return
        arrival, full_seq, gap = window.on_data(seq, now)
        if arrival is Arrival.STALE:
            self._last_receive = now
            stats.count_drop(DropReason.STALE)
            return
        if arrival is not Arrival.DUPLICATE and self._ack_mode is AckMode.SEPARATE:
            # Trinomial acknowledges every arrival, whether or not the sample is delivered.
            self._separate_acks.append((full_seq, now))
        if arrival is Arrival.NEW:
            stats.peer_gaps += gap
        elif arrival is Arrival.LATE:
            stats.reordered += 1
            if not self.config.deliver_late:
                self._last_receive = now
                stats.count_drop(DropReason.LATE)
                return
        elif not self.config.deliver_duplicates:
            self._last_receive = now
            stats.count_drop(DropReason.DUPLICATE)
            return
        size = len(data)
        self._accept(size, size - HEADER_SIZE, now)
        stats.received.data_packets += 1
        stats.samples_delivered += 1
        rtt = self._rtt
        self._push_data_event(
            DataReceived(
                data[HEADER_SIZE:], full_seq, rtt.srtt / 2 if rtt.has_sample else None, now
            )
        )

    def _on_ack_packet(self, size: int, ack: int, sack: int, hold: int, now: float) -> None:
        stats = self._stats
        if self._state is not State.ESTABLISHED:
            stats.count_drop(DropReason.NOT_ESTABLISHED)
            return
        if hold != HOLD_NO_ACK and not self._on_feedback(ack, sack, hold, now):
            stats.count_drop(DropReason.OPTIMISTIC_ACK)
            return
        self._accept(size, 0, now)
        stats.received.ack_packets += 1

    def _on_feedback(self, ack: int, sack: int, hold_code: int, now: float) -> bool:
        """Process the acknowledgement in a header; False if it acknowledges a packet never sent."""
        sent = self._sent
        rtt = self._rtt
        hold = decode_hold(hold_code)
        full = sent.expand_ack(ack, hold, now, rtt.srtt)
        if full is None:
            return False
        outcome = sent.on_ack(full, sack, hold, now)
        stats = self._stats
        if outcome.spurious:
            stats.spurious_losses += outcome.spurious
        if outcome.rtt_sample is not None:
            rtt.on_sample(outcome.rtt_sample)
            stats.rtt_samples += 1
        lost = self._lost
        sent.detect_losses(now, self._loss_delay(), lost)
        if lost:
            self._on_losses(now)
        if outcome.newly_acked:
            stats.packets_acked += outcome.newly_acked
            self._controller.on_ack(
                now=now,
                acked=outcome.newly_acked,
                rtt_sample=outcome.rtt_sample,
                srtt=rtt.srtt,
                rttvar=rtt.rttvar,
                loss_event_rate=self._loss.update(sent.largest_acked),
            )
        return True

    def _on_losses(self, now: float) -> None:
        lost = self._lost
        estimator = self._loss
        srtt = self._rtt.srtt
        largest = self._sent.largest_acked
        stats = self._stats
        stats.packets_lost += len(lost)
        for packet in lost:
            if estimator.on_packet_lost(packet.seq, packet.send_time, srtt, largest):
                stats.loss_events += 1
                self._controller.on_loss_event(
                    now=now, srtt=srtt, loss_event_rate=estimator.loss_event_rate
                )
        lost.clear()

    def _loss_delay(self) -> float:
        """How long a packet reported absent may still turn up (RAP's timeout, mu 1.2 and phi 4).

        The peer's ACK delay is added because RTT samples exclude it: a late arrival is reported only
        with the peer's next reverse packet, up to ``ack_delay`` later.
        """
        rtt = self._rtt
        return (
            LOSS_DELAY_SRTT * rtt.srtt
            + max(LOSS_DELAY_RTTVAR * rtt.rttvar, TIMER_GRANULARITY)
            + self.config.ack_delay
        )

    def _on_control(
        self, data: bytes, addr: Address, seq: int, ack: int, sack: int, hold: int, now: float
    ) -> None:
        stats = self._stats
        try:
            body = decode_control(data[HEADER_SIZE:])
        except MalformedPacketError:
            stats.count_drop(DropReason.BAD_CONTROL)
            return
        code = body.code
        if isinstance(body, OpenBody):
            if code is ControlCode.OPEN:
                self._on_open(body, addr, seq, len(data), now)
            else:
                self._on_open_ack(body, seq, len(data), now)
            return
        if isinstance(body, CloseBody):
            if body.nonce != self._nonce or self._state not in (State.OPENING, State.ESTABLISHED):
                stats.count_drop(DropReason.NONCE_MISMATCH)
                return
            if code is ControlCode.REJECT and (
                self.role is not Role.MASTER or self._state is not State.OPENING
            ):
                stats.count_drop(DropReason.UNEXPECTED_CONTROL)
                return
            self._accept_control(len(data), now)
            if code is ControlCode.REJECT:
                self._terminate(CloseCause.REJECTED, _reason_text(body.reason))
            else:
                self._terminate(CloseCause.PEER_CLOSE, _reason_text(body.reason))
            return
        # KEEPALIVE
        if self._state is not State.ESTABLISHED:
            stats.count_drop(DropReason.NOT_ESTABLISHED)
            return
        if hold != HOLD_NO_ACK and not self._on_feedback(ack, sack, hold, now):
            stats.count_drop(DropReason.OPTIMISTIC_ACK)
            return
        self._accept_control(len(data), now)

    def _accept_control(self, size: int, now: float) -> None:
        self._accept(size, size - HEADER_SIZE, now)
        self._stats.received.control_packets += 1

    def _on_open(self, body: OpenBody, addr: Address, seq: int, size: int, now: float) -> None:
        stats = self._stats
        if self.role is not Role.SLAVE:
            stats.count_drop(DropReason.UNEXPECTED_CONTROL)
            return
        if self._state is State.ESTABLISHED:
            if body.nonce != self._nonce:
                stats.count_drop(DropReason.NONCE_MISMATCH)
                return
            # The master did not hear our OPEN_ACK: answer its retransmission again.
            self._accept_control(size, now)
            self._queue_open_ack()
            return
        if body.version != PROTOCOL_VERSION:
            stats.count_drop(DropReason.UNKNOWN_VERSION)
            self._control_out.append(
                (
                    encode_header(_CONTROL, 0, 0, 0, HOLD_NO_ACK)
                    + encode_close(ControlCode.REJECT, body.nonce, CloseReason.VERSION_UNSUPPORTED),
                    addr,
                )
            )
            return
        if body.max_payload == 0:
            stats.count_drop(DropReason.BAD_CONTROL)
            return
        self._peer = addr
        self._nonce = body.nonce
        self._ack_mode = (
            AckMode.SEPARATE if body.flags & OpenFlags.SEPARATE_ACKS else AckMode.BIDIRECTIONAL
        )
        self._send_limit = min(self.config.max_payload, body.max_payload)
        self._window = ReceiveWindow(seq)
        self._accept_control(size, now)
        self._queue_open_ack()
        self._establish(addr, now)

    def _on_open_ack(self, body: OpenBody, seq: int, size: int, now: float) -> None:
        stats = self._stats
        if self.role is not Role.MASTER:
            stats.count_drop(DropReason.UNEXPECTED_CONTROL)
            return
        if body.nonce != self._nonce or self._state not in (State.OPENING, State.ESTABLISHED):
            stats.count_drop(DropReason.NONCE_MISMATCH)
            return
        if self._state is State.ESTABLISHED:
            self._accept_control(size, now)
            return
        if body.version != PROTOCOL_VERSION:
            stats.count_drop(DropReason.UNKNOWN_VERSION)
            return
        if body.max_payload == 0:
            stats.count_drop(DropReason.BAD_CONTROL)
            return
        self._send_limit = min(self.config.max_payload, body.max_payload)
        self._window = ReceiveWindow(seq)
        self._accept_control(size, now)
        assert self._peer is not None  # set by connect(); OPENING implies it
        self._establish(self._peer, now)

    def _establish(self, peer: Address, now: float) -> None:
        self._state = State.ESTABLISHED
        self._last_receive = now
        self._last_send = now
        self._push_other_event(ConnectionEstablished(peer))

    # ------------------------------------------------------------------ timers

    def get_timer(self) -> float | None:
        """The next absolute time :meth:`handle_timer` (then :meth:`datagrams_to_send`) is due."""
        state = self._state
        if state is State.OPENING:
            return min(self._open_next, self._open_deadline)
        if state is not State.ESTABLISHED:
            return None
        config = self.config
        deadline = min(
            self._last_receive + config.idle_timeout,
            self._last_send + config.keepalive_interval,
        )
        if self._pending is not None:
            deadline = min(deadline, self._controller.next_send_time())
        window = self._window
        if self._ack_mode is AckMode.BIDIRECTIONAL:
            if window is not None and window.unreported_since is not None:
                deadline = min(deadline, window.unreported_since + config.ack_delay)
        elif self._separate_acks:
            deadline = min(deadline, self._separate_acks[0][1])
        loss_deadline = self._sent.loss_deadline(self._loss_delay())
        if loss_deadline is not None:
            deadline = min(deadline, loss_deadline)
        controller_deadline = self._controller.get_timer()
        if controller_deadline is not None:
            deadline = min(deadline, controller_deadline)
        return deadline

    def handle_timer(self, *, now: float) -> None:
        """Act on whatever is due at ``now``. Calling it early or late is harmless."""
        state = self._state
        if state is State.OPENING:
            if now >= self._open_deadline:
                self._terminate(
                    CloseCause.OPEN_TIMEOUT,
                    f"no answer to OPEN within {self.config.open_timeout} s",
                )
            return
        if state is not State.ESTABLISHED:
            return
        if now >= self._last_receive + self.config.idle_timeout:
            assert self._peer is not None
            self._queue_close(CloseReason.IDLE_TIMEOUT, self._peer)
            self._terminate(
                CloseCause.IDLE_TIMEOUT,
                f"nothing received from the peer for {self.config.idle_timeout} s",
            )
            return
        lost = self._lost
        self._sent.detect_losses(now, self._loss_delay(), lost)
        if lost:
            self._on_losses(now)
        controller_deadline = self._controller.get_timer()
        if controller_deadline is not None and now >= controller_deadline:
            self._controller.on_timer(now=now)

    # ------------------------------------------------------------------ output

    def datagrams_to_send(self, *, now: float) -> list[tuple[bytes, Address]]:
        """Everything that should leave at ``now``, with its destination."""
        out: list[tuple[bytes, Address]] = []
        state = self._state
        if state is State.OPENING and now >= self._open_next:
            assert self._peer is not None
            self._open_next = now + self.config.open_retry_interval
            flags = OpenFlags.SEPARATE_ACKS if self._ack_mode is AckMode.SEPARATE else 0
            self._emit_control(
                out,
                encode_header(_CONTROL, self._sent.next_seq, 0, 0, HOLD_NO_ACK)
                + encode_open(
                    ControlCode.OPEN,
                    PROTOCOL_VERSION,
                    int(flags),
                    self._nonce,
                    self.config.max_payload,
                ),
                self._peer,
                now,
            )
        if self._control_out:
            for datagram, addr in self._control_out:
                self._emit_control(out, datagram, addr, now)
            self._control_out.clear()
        if state is not State.ESTABLISHED:
            return out
        peer = self._peer
        assert peer is not None
        window = self._window
        assert window is not None
        bidirectional = self._ack_mode is AckMode.BIDIRECTIONAL
        payload = self._pending
        if payload is not None and now >= self._controller.next_send_time():
            self._pending = None
            ack, sack, hold = self._piggyback(window, now) if bidirectional else _NO_ACK
            datagram = encode_header(_DATA, self._sent.next_seq, ack, sack, hold) + payload
            size = len(datagram)
            self._sent.on_sent(now, size, self._lost)
            if self._lost:
                self._on_losses(now)
            self._controller.on_packet_sent(now=now, size=size, paced=self._pending_paced)
            sent = self._stats.sent
            sent.data_packets += 1
            sent.payload_bytes += len(payload)
            self._count_sent(size, now)
            out.append((datagram, peer))
        if bidirectional:
            if window.unreported_since is not None and (
                now >= window.unreported_since + self.config.ack_delay
                or window.coverage_exhausted()
            ):
                ack, sack, hold = self._piggyback(window, now)
                self._emit_ack(out, ack, sack, hold, peer, now)
        else:
            acks = self._separate_acks
            plain = self.config.plain_acks
            while acks:
                seq, arrival = acks.popleft()
                sack = 0 if plain else window.sack_below(seq)  # plain: this packet only
                self._emit_ack(out, seq, sack, encode_hold(now - arrival), peer, now)
        if now >= self._last_send + self.config.keepalive_interval:
            ack, sack, hold = self._piggyback(window, now) if bidirectional else _NO_ACK
            self._emit_control(
                out,
                encode_header(_CONTROL, self._sent.next_seq, ack, sack, hold) + encode_keepalive(),
                peer,
                now,
            )
        return out

    def _piggyback(self, window: ReceiveWindow, now: float) -> tuple[int, int, int]:
        """ACK fields reporting the newest peer data (or none before any arrived)."""
        if not window.has_data:
            return _NO_ACK
        window.mark_reported()
        return (
            window.highest,
            window.sack_below(window.highest),
            encode_hold(now - window.highest_arrival),
        )

    def _emit_ack(
        self,
        out: list[tuple[bytes, Address]],
        ack: int,
        sack: int,
        hold: int,
        peer: Address,
        now: float,
    ) -> None:
        datagram = encode_header(_ACK, self._sent.next_seq, ack, sack, hold)
        padding = self.config.ack_size - HEADER_SIZE
        if padding:
            datagram += bytes(padding)
        self._stats.sent.ack_packets += 1
        self._count_sent(len(datagram), now)
        out.append((datagram, peer))

    def _emit_control(
        self, out: list[tuple[bytes, Address]], datagram: bytes, addr: Address, now: float
    ) -> None:
        sent = self._stats.sent
        sent.control_packets += 1
        sent.payload_bytes += len(datagram) - HEADER_SIZE
        self._count_sent(len(datagram), now)
        out.append((datagram, addr))

    def _count_sent(self, size: int, now: float) -> None:
        sent = self._stats.sent
        sent.datagrams += 1
        sent.bytes += size
        sent.header_bytes += HEADER_SIZE
        self._last_send = now

    # ------------------------------------------------------------------ helpers

    def _queue_open_ack(self) -> None:
        assert self._peer is not None
        flags = OpenFlags.SEPARATE_ACKS if self._ack_mode is AckMode.SEPARATE else 0
        self._control_out.append(
            (
                encode_header(_CONTROL, self._sent.next_seq, 0, 0, HOLD_NO_ACK)
                + encode_open(
                    ControlCode.OPEN_ACK,
                    PROTOCOL_VERSION,
                    int(flags),
                    self._nonce,
                    self.config.max_payload,
                ),
                self._peer,
            )
        )

    def _queue_close(self, reason: CloseReason, addr: Address) -> None:
        self._control_out.append(
            (
                encode_header(_CONTROL, self._sent.next_seq, 0, 0, HOLD_NO_ACK)
                + encode_close(ControlCode.CLOSE, self._nonce, reason),
                addr,
            )
        )

    def _terminate(self, cause: CloseCause, detail: str) -> None:
        self._state = State.CLOSED
        self._pending = None
        self._separate_acks.clear()
        self._push_other_event(ConnectionClosed(cause, detail))

    def _push_data_event(self, event: DataReceived) -> None:
        events = self._data_events
        if len(events) + len(self._other_events) >= self.config.max_pending_events and events:
            events.popleft()
            self._stats.events_discarded += 1
        self._event_seq += 1
        events.append((self._event_seq, event))

    def _push_other_event(self, event: Event) -> None:
        self._event_seq += 1
        self._other_events.append((self._event_seq, event))


def _reason_text(reason: int) -> str:
    try:
        return CloseReason(reason).name.lower()
    except ValueError:
        return f"reason code {reason}"
