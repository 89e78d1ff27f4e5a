"""The sans-IO TDTP connection: a state machine that never touches a socket or reads a clock.

The caller owns I/O and time. It feeds datagrams in with :meth:`Connection.receive_datagram`, timer expiries
with :meth:`Connection.handle_timer` and samples with :meth:`Connection.send`, always passing ``now``
(seconds on one monotonic clock). After every input it collects :meth:`Connection.datagrams_to_send` and
re-arms a single timer at :meth:`Connection.get_timer`. What happened comes out of
:meth:`Connection.next_event`. The asyncio endpoints, the impairment emulator and the virtual-time simulator
all drive this one class.

The watchdog lives here too: nothing heard from the peer for ``silence_timeout`` gives a
:class:`~tdtp.events.PeerSilent` event, the next datagram a :class:`~tdtp.events.PeerResumed`, and the
connection survives the outage until ``idle_timeout`` (docs/PROTOCOL.md section 5.2).

Peer input never raises: anything malformed, unexpected or hostile is dropped and counted in
``stats.drops`` by reason. Misuse by the caller raises a :class:`~tdtp.errors.TdtpError` subclass.
"""

from __future__ import annotations

import enum
import math
import random
from collections import deque
from collections.abc import Callable
from typing import Final

from tdtp.admission.admission import Admission, AdmittedOpen, Reply
from tdtp.config import AckMode, ConnectionConfig, Role
from tdtp.control.base import RateController
from tdtp.control.registry import create_controller
from tdtp.errors import (
    ArgumentTypeError,
    ConnectionClosedError,
    ConnectionStateError,
    EmptyPayloadError,
    InvalidKeyError,
    PayloadTooLargeError,
    PayloadTypeError,
)
from tdtp.events import (
    Address,
    CloseCause,
    ConnectionClosed,
    ConnectionEstablished,
    DataReceived,
    Event,
    PeerResumed,
    PeerSilent,
    new_data_received,
)
from tdtp.loss_rate import LossIntervalEstimator
from tdtp.protection.derivation import derive_open_secret, derive_session_secrets
from tdtp.protection.keys import KeyInput, KeysInput, PresharedKey, as_key, as_key_ring
from tdtp.protection.packet_protection import (
    Direction,
    PacketOpener,
    PacketSealer,
)
from tdtp.receive_window import Arrival, ReceiveWindow
from tdtp.rtt import RttEstimator
from tdtp.sent_log import LostPacket, SentPacketLog
from tdtp.stats import ConnectionStats, DropReason
from tdtp.wire.control import (
    HANDSHAKE_CODES,
    NO_COOKIE,
    NO_KEY_ID,
    NONCE_SIZE,
    OPEN_BODY_SIZE,
    PROTOCOL_VERSION,
    CipherSuite,
    CloseBody,
    CloseReason,
    ControlCode,
    CookieBody,
    KeepaliveBody,
    OpenAckBody,
    OpenBody,
    OpenFlags,
    decode_control,
    encode_close,
    encode_keepalive,
    encode_open,
    encode_open_ack,
)
from tdtp.wire.errors import MalformedPacketError
from tdtp.wire.header import HEADER_SIZE, PacketType, decode_header, encode_header
from tdtp.wire.hold import HOLD_NO_ACK, decode_hold, encode_hold
from tdtp.wire.protected import PROTECTION_OVERHEAD, TAG_SIZE
from tdtp.wire.seqnum import SEQ_MODULUS

_DATA: Final = int(PacketType.DATA)
_ACK: Final = int(PacketType.ACK)
_CONTROL: Final = int(PacketType.CONTROL)
_NO_ACK: Final = (0, 0, HOLD_NO_ACK)
_OPEN: Final = int(ControlCode.OPEN)
_CLOSE_PREFIX: Final = bytes((ControlCode.CLOSE,))
_KEEPALIVE_PREFIX: Final = encode_keepalive()
_LARGEST_CONTROL: Final = OPEN_BODY_SIZE + TAG_SIZE
"""The largest control body (a keyed OPEN's): datagrams up to this size pass the size check whatever
``max_payload`` is."""
LOSS_DELAY_RTTVAR: Final = 4.0
REORDER_WINDOW_MIN_RTT: Final = 0.25
"""RACK's initial reorder window, a quarter of the minimum RTT (RFC 8985 section 6.2)."""
TIMER_GRANULARITY: Final = 0.001
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

    Unkeyed by default. A master given ``key=`` (a :class:`~tdtp.protection.PresharedKey` or its
    secret bytes) opens a keyed session; a slave given ``keys=`` (one key, several, or a
    :class:`~tdtp.protection.KeyRing`) accepts keyed sessions only, from masters holding one of them.
    A slave validates every master's address with a cookie before it keeps any state
    (:mod:`tdtp.admission`); a server sharing one socket among many slave connections passes them one
    shared ``admission``.

    ``rng`` supplies the nonces and the initial sequence number; pass a seeded
    :class:`random.Random` for reproducible runs (the default draws from the operating system's
    CSPRNG, which a keyed session needs: its nonces must be unpredictable).
    """

    def __init__(
        self,
        config: ConnectionConfig | None = None,
        *,
        role: Role,
        rng: random.Random | None = None,
        key: KeyInput | None = None,
        keys: KeysInput | None = None,
        admission: Admission | None = None,
    ) -> None:
        if not isinstance(role, Role):
            raise ArgumentTypeError(f"role must be Role.MASTER or Role.SLAVE, got {role!r}")
        self.config = config if config is not None else ConnectionConfig()
        self.role = role
        rng = rng if rng is not None else random.SystemRandom()
        self._key: PresharedKey | None = None
        self._admission: Admission | None = None
        if role is Role.MASTER:
            if keys is not None or admission is not None:
                raise InvalidKeyError(
                    "a master presents one key: pass key=, not keys= or admission="
                )
            self._key = as_key(key) if key is not None else None
        else:
            if key is not None:
                raise InvalidKeyError(
                    "a slave accepts keys=: one key, several, or a KeyRing (key= is the master's)"
                )
            if admission is not None and keys is not None:
                raise InvalidKeyError("pass keys= or a shared admission=, not both")
            self._admission = (
                admission
                if admission is not None
                else Admission(
                    self.config, as_key_ring(keys) if keys is not None else None, rng=rng
                )
            )
        self._state = State.IDLE if role is Role.MASTER else State.LISTENING
        self._peer: Address | None = None
        self._master_nonce = rng.randbytes(NONCE_SIZE)
        """The connection's identifier on control packets: the master's; a slave adopts it."""
        self._slave_nonce = rng.randbytes(NONCE_SIZE)
        self._keyed = self._key is not None
        """Whether this session is keyed: the master's choice, adopted by the slave at the open."""
        self._encrypt = self.config.encrypt
        self._suite = self.config.cipher_suite if self._keyed else CipherSuite.NONE
        self._sealer: PacketSealer | None = None
        self._opener: PacketOpener | None = None
        self._overhead = 0  # bytes packet protection adds to each session datagram, once keyed
        self._confirming = False  # a slave that answered OPEN_ACK and waits for the master's packet
        self._open_tagger: Direction | None = None  # a keyed master's OPEN key
        self._open_attempt = 0
        self._cookie = NO_COOKIE
        self._cookie_answered_at = -math.inf
        self._ack_mode = self.config.ack_mode
        self._send_limit = self.config.max_payload
        # PROTOCOL.md 5.5: room for a keyed session's packet number and tag on a full payload.
        self._size_limit = (
            HEADER_SIZE + max(self.config.max_payload, _LARGEST_CONTROL) + PROTECTION_OVERHEAD
        )
        self._controller: RateController = create_controller(
            self.config.controller, self.config.controller_config
        )
        # The peer holds ACKs up to its ack_delay; not negotiated, so ours stands for it.
        self._controller.feedback_delay = self.config.ack_delay
        self._controller.sample_waiting = False  # kept up to date below
        first_seq = rng.randrange(SEQ_MODULUS)
        self._sent = SentPacketLog(
            first_seq,
            reorder_threshold=self.config.reorder_threshold,
            max_tracked=self.config.max_tracked_packets,
        )
        self._rtt = RttEstimator(self.config.initial_rtt)
        # The settings the per-packet paths read, copied out of the (plain Python) config once.
        self._ack_delay = self.config.ack_delay
        self._max_payload = self.config.max_payload
        self._idle_timeout = self.config.idle_timeout
        self._max_events = self.config.max_pending_events
        self._deliver_late = self.config.deliver_late
        self._deliver_duplicates = self.config.deliver_duplicates
        self._plain_acks = self.config.plain_acks
        self._ack_padding = bytes(self.config.ack_size - HEADER_SIZE)
        self._loss_delay_value = self._loss_delay()
        self._hint = -math.inf  # see timer_hint
        self._controller_timer: float | None = None  # the controller's deadline at get_timer()
        self._transmit_errors = 0
        self._loss = LossIntervalEstimator(first_seq)
        self._window: ReceiveWindow | None = None
        self._pending: bytes | None = None
        self._pending_paced = False  # the pending sample had to wait for the pacer
        self._control_out: list[tuple[bytes, Address, int, bool]] = []
        """Control datagrams queued for the next flush: datagram, destination, protection bytes,
        and whether it is session traffic (not: admission's COOKIE or REJECT answering an OPEN)."""
        self._separate_acks: deque[tuple[int, float]] = deque()
        self._events: deque[Event] = deque()
        self._data_pending = 0  # DataReceived events among them
        self._last_send = 0.0
        self._last_receive = 0.0
        self._keepalive = self.config.effective_keepalive_interval
        self._silence = self.config.silence_timeout
        self._silent_since: float | None = None  # the watchdog: last arrival before a silence
        self._last_outage: tuple[float, float] | None = None  # (since, resumed at) of the last one
        self._send_paused = False
        self._close_event: ConnectionClosed | None = None
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
    def keyed(self) -> bool:
        """Whether the session is keyed (every datagram authenticated, and encrypted if
        :attr:`encrypted`). A listening slave with keys answers keyed OPENs only."""
        return self._keyed

    @property
    def encrypted(self) -> bool:
        """Whether a keyed session encrypts its payloads (the master's choice)."""
        return self._keyed and self._encrypt

    @property
    def key(self) -> PresharedKey | None:
        """The session's pre-shared key: the master's own, or the one a slave found in its ring for
        this master (its :attr:`~tdtp.protection.PresharedKey.name` says which master it is)."""
        return self._key

    @property
    def admission(self) -> Admission | None:
        """A slave's front door (cookie, rate limits, keys); ``None`` for a master."""
        return self._admission

    @property
    def peer_silent(self) -> bool:
        """True while the watchdog finds the peer silent (between :class:`~tdtp.events.PeerSilent`
        and :class:`~tdtp.events.PeerResumed`)."""
        return self._silent_since is not None

    @property
    def silent_since(self) -> float | None:
        """The ``now`` of the peer's last datagram while it is silent, else ``None``."""
        return self._silent_since

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
        return self._hint

    @property
    def pending_events(self) -> int:
        """Events waiting for :meth:`next_event`."""
        return len(self._events)

    @property
    def transmit_errors(self) -> int:
        """Datagrams whose ``transmit`` in :meth:`send_direct` raised :class:`OSError` (lost like
        any other)."""
        return self._transmit_errors

    @property
    def sending_paused(self) -> bool:
        """True between :meth:`pause_sending` and :meth:`resume_sending`."""
        return self._send_paused

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
        stats.packets_reordered = self._sent.reordered
        stats.rate = self._controller.rate
        stats.rate_limit = self._controller.rate_limit
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
        self._hint = -math.inf
        self._open_deadline = now + self.config.open_timeout
        self._open_next = now
        self._last_receive = now
        if self._key is not None:
            self._open_tagger = Direction(
                self._suite, derive_open_secret(self._key.secret, self._master_nonce, self._suite)
            )

    def send(self, payload: bytes | bytearray | memoryview, *, now: float) -> None:
        """Offer the newest sample (bytes, bytearray or memoryview). It replaces any sample still
        waiting for the pacer or for the socket (which is counted as superseded): stale supermedia
        data is never queued or retransmitted."""
        state = self._state
        if state is not State.ESTABLISHED:
            if state is State.CLOSED:
                event = self._close_event
                why = "" if event is None else f" ({event.cause.value}: {event.detail})"
                raise ConnectionClosedError(
                    f"the connection is closed{why}; open a new one to send again", event
                )
            raise ConnectionStateError(
                f"cannot send while {state.value}: wait for the ConnectionEstablished event"
            )
        if type(payload) is not bytes:
            payload = _as_payload(payload)
        if not payload:
            raise EmptyPayloadError(
                "a sample must have at least one byte (TDTP sends no empty DATA packet; the "
                "connection acknowledges and keeps itself alive on its own)"
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
            if self._send_paused:
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
            if paced and due < self._hint:
                self._hint = due  # the pacer's deadline for it
            controller.sample_waiting = True
            self._check_controller_timer()
        self._pending = payload

    def send_direct(
        self,
        payload: bytes | bytearray | memoryview,
        transmit: Callable[[bytes, Address | None], object],
        *,
        connected: bool,
        now: float,
    ) -> bool:
        """:meth:`send` for the common case, with the datagram handed straight to ``transmit``.

        When the sample may leave at once as the only datagram due (established, the pacer and the
        socket allow it, no control packet, held ACK or separate ACK waiting), it is encoded and
        passed to ``transmit(datagram, addr)`` (``addr`` ``None`` when ``connected``, else the
        peer's address: ``transport.sendto`` fits) *before* any bookkeeping, which follows. An
        :class:`OSError` from ``transmit`` counts in :attr:`transmit_errors` and the datagram is
        lost like any other. Returns False when it did not send: the sample is then offered as by
        :meth:`send`, and :meth:`datagrams_to_send` must run. Raises what :meth:`send` raises.
        """
        if (
            self._state is not State.ESTABLISHED
            or type(payload) is not bytes
            or self._send_paused
            or self._control_out
            or self._separate_acks
            or not 0 < len(payload) <= self._send_limit
            or now < self._controller.next_send_time()
        ):
            self.send(payload, now=now)
            return False
        window = self._window
        assert window is not None  # ESTABLISHED implies it
        if window.held:
            self.send(payload, now=now)
            return False
        stats = self._stats
        stats.samples_offered += 1
        paced = False
        if self._pending is not None:
            # A held sample the pacer would let go now: the newer one wins.
            stats.samples_superseded += 1
            paced = True
            self._pending = None
            self._controller.sample_waiting = False
        sent = self._sent
        if self._ack_mode is AckMode.BIDIRECTIONAL and window.has_data:
            window.mark_reported()
            header = encode_header(
                _DATA,
                sent.next_seq,
                window.highest,
                window.sack_below(window.highest),
                encode_hold(now - window.highest_arrival),
            )
        else:
            header = encode_header(_DATA, sent.next_seq, 0, 0, HOLD_NO_ACK)
        sealer = self._sealer
        datagram = header + payload if sealer is None else sealer.seal(header, payload)
        peer = self._peer
        try:
            transmit(datagram, None if connected else peer)
        except OSError:
            self._transmit_errors += 1
        # Bookkeeping, after the datagram has left.
        size = len(datagram)
        lost = self._lost
        sent.on_sent(now, size, lost)
        if lost:
            self._on_losses(now)
        controller = self._controller
        controller.on_packet_sent(now=now, size=size, paced=paced)
        counts = stats.sent
        counts.data_packets += 1
        counts.payload_bytes += len(payload)
        counts.datagrams += 1
        counts.bytes += size
        counts.header_bytes += HEADER_SIZE
        counts.protection_bytes += self._overhead
        self._last_send = now
        self._check_controller_timer()
        if sealer is not None and sealer.exhausted:
            self._exhausted()
        return True

    def _check_controller_timer(self) -> None:
        """After a controller hook: lower :attr:`timer_hint` if the controller's deadline moved
        earlier than get_timer() last saw it."""
        deadline = self._controller.get_timer()
        if deadline is not None and deadline < self._hint:
            seen = self._controller_timer
            if seen is None or deadline < seen:
                self._hint = deadline

    def _exhausted(self) -> None:
        self._terminate(
            CloseCause.KEY_EXHAUSTED,
            "the session protected as many packets as its keys may; open a new connection",
        )

    def pause_sending(self) -> None:
        """The layer below cannot take datagrams now (the socket's send buffer is full).

        Data is held: the pending sample waits and newer samples supersede it (counted in
        ``samples_superseded`` and ``samples_blocked``) instead of queueing in a buffer out of sight.
        Acknowledgements and control packets still go out. Call :meth:`resume_sending` when the
        buffer has drained, then :meth:`datagrams_to_send`.
        """
        if not self._send_paused:
            self._send_paused = True
            self._stats.send_pauses += 1

    def resume_sending(self) -> None:
        """The layer below takes datagrams again; the newest held sample leaves when the pacer allows."""
        self._send_paused = False
        self._hint = -math.inf

    def close(self, *, now: float) -> None:
        """End the connection: a CLOSE goes out with the next :meth:`datagrams_to_send`."""
        if self._state is State.CLOSED:
            return
        if self._state in (State.OPENING, State.ESTABLISHED) and self._peer is not None:
            self._queue_close(CloseReason.NORMAL, self._peer)
        self._terminate(CloseCause.LOCAL_CLOSE, "closed by the application")

    def accept_open(self, admitted: AdmittedOpen, addr: Address, *, now: float) -> None:
        """Slave only: take an OPEN that a shared :class:`~tdtp.admission.Admission` already
        admitted for ``addr`` (a server demultiplexing many masters on one socket does this; a
        stand-alone slave gets its OPENs through :meth:`receive_datagram`)."""
        if self.role is not Role.SLAVE or self._state is not State.LISTENING:
            raise ConnectionStateError(
                f"accept_open() is for a listening slave (this is a {self.role.value} in state "
                f"{self._state.value}); create a new Connection for each master"
            )
        self._stats.datagrams_in += 1
        self._hint = -math.inf
        self._open_session(admitted, addr, now)

    def next_event(self) -> Event | None:
        """The oldest event not yet taken, or ``None``."""
        events = self._events
        if not events:
            return None
        event = events.popleft()
        if type(event) is DataReceived:
            self._data_pending -= 1
        return event

    # ------------------------------------------------------------------ input

    def receive_datagram(self, data: bytes, addr: Address, *, now: float) -> None:
        """Take one datagram from the network. Never raises on its content."""
        stats = self._stats
        stats.datagrams_in += 1
        if self._state is State.CLOSED:
            stats.count_drop(DropReason.CLOSED)
            return
        peer = self._peer
        if peer is not None and addr != peer and (addr[0] != peer[0] or addr[1] != peer[1]):
            stats.count_drop(DropReason.WRONG_ADDRESS)
            return
        size = len(data)
        if size < HEADER_SIZE:
            stats.count_drop(DropReason.TRUNCATED)
            return
        if size > self._size_limit:
            stats.count_drop(DropReason.OVERSIZED)
            return
        ptype = data[0] >> 6
        if ptype == _CONTROL and size > HEADER_SIZE and data[HEADER_SIZE] in HANDSHAKE_CODES:
            self._on_handshake(data, addr, now)
            return
        if ptype > _CONTROL:
            stats.count_drop(DropReason.UNKNOWN_TYPE)
            return
        if self._keyed:
            opener = self._opener
            if opener is None:
                # A keyed master before the OPEN_ACK has no keys to read session packets with.
                stats.count_drop(DropReason.NOT_ESTABLISHED)
                return
            prefix = HEADER_SIZE + 1 if ptype == _CONTROL else HEADER_SIZE
            if size < prefix + PROTECTION_OVERHEAD:
                stats.count_drop(DropReason.TRUNCATED)
                return
            body = opener.open(data, prefix)
            if body is None:
                self._on_unopened(opener, now)
                return
            data = data[:prefix] + body
            size = len(data)  # from here on, sizes are without the protection (_accept adds it)
        if self._confirming:
            # The master's first packet of the session: it has our OPEN_ACK and (keyed) the keys.
            self._establish(now)
        # The header, decoded in place (wire/header.py's layout) rather than into a Header tuple.
        b1 = data[1]
        b3 = data[3]
        seq = ((data[0] & 0x3F) << 6) | (b1 >> 2)
        ack = ((b1 & 0x03) << 10) | (data[2] << 2) | (b3 >> 6)
        sack = b3 & 0x3F
        hold = data[4]
        if ptype == _DATA:
            self._on_data(data, seq, ack, sack, hold, now)
        elif ptype == _ACK:
            self._on_ack_packet(size, ack, sack, hold, now)
        else:
            self._on_session_control(data, size, ack, sack, hold, now)

    def _on_unopened(self, opener: PacketOpener, now: float) -> None:
        """A protected datagram that did not authenticate (or was replayed): dropped and counted; a
        key that has seen too many forgeries is retired with its connection (RFC 9001, 6.6)."""
        self._stats.count_drop(DropReason(opener.failure))
        if opener.exhausted:
            self._terminate(
                CloseCause.KEY_EXHAUSTED,
                "too many datagrams failed authentication under this session's key; open a new "
                "connection",
            )

    def _accept(self, size: int, payload_size: int, now: float) -> None:
        """Count a datagram taken in; ``size`` is its length without packet protection."""
        received = self._stats.received
        received.datagrams += 1
        received.bytes += size + self._overhead
        received.header_bytes += HEADER_SIZE
        received.payload_bytes += payload_size
        received.protection_bytes += self._overhead
        self._last_receive = now
        if self._silent_since is not None:
            self._on_peer_resumed(now)

    def _heard(self, now: float) -> None:
        """A datagram from the peer that is not taken in (late, duplicate, stale) still shows it is
        alive."""
        self._last_receive = now
        if self._silent_since is not None:
            self._on_peer_resumed(now)

    def _on_peer_resumed(self, now: float) -> None:
        since = self._silent_since
        assert since is not None
        self._silent_since = None
        self._last_outage = (since, now)
        silent_for = now - since
        stats = self._stats
        stats.longest_silence = max(stats.longest_silence, silent_for)
        self._push_watchdog_event(PeerResumed(silent_for, now))
        self._controller.on_peer_resumed(now=now, silent_for=silent_for)
        self._hint = -math.inf  # the watchdog's deadline is silence_timeout again, not idle

    def _on_data(self, data: bytes, seq: int, ack: int, sack: int, hold: int, now: float) -> None:
        stats = self._stats
        window = self._window
        if self._state is not State.ESTABLISHED or window is None:
            stats.count_drop(DropReason.NOT_ESTABLISHED)
            return
        size = len(data)
        payload_size = size - HEADER_SIZE
        if payload_size > self._max_payload:
            stats.count_drop(DropReason.OVERSIZED)
            return
        if not payload_size:
            stats.count_drop(DropReason.EMPTY_DATA)  # senders MUST NOT send one (section 4.1)
            return
        if hold != HOLD_NO_ACK and not self._on_feedback(ack, sack, hold, now):
            stats.count_drop(DropReason.OPTIMISTIC_ACK)
            return
        quiet = window.unreported_since is None
        arrival = window.classify(seq, now)
        if window.held:
            self._hint = -math.inf  # an ACK is due at once
        elif quiet and window.unreported_since is not None:
            due = now + self._ack_delay  # an ACK is due by then
            if due < self._hint:
                self._hint = due
        if arrival is Arrival.NEW:
            stats.peer_gaps += window.last_gap
            if self._ack_mode is AckMode.SEPARATE:
                self._separate_acks.append((window.last_seq, now))
                self._hint = -math.inf
        elif arrival is Arrival.STALE:
            self._heard(now)
            stats.count_drop(DropReason.STALE)
            return
        else:
            if self._ack_mode is AckMode.SEPARATE and arrival is not Arrival.DUPLICATE:
                # Trinomial acknowledges every arrival, whether or not the sample is delivered.
                self._separate_acks.append((window.last_seq, now))
                self._hint = -math.inf
            if arrival is Arrival.LATE:
                stats.reordered += 1
                if not self._deliver_late:
                    self._heard(now)
                    stats.count_drop(DropReason.LATE)
                    return
            elif not self._deliver_duplicates:
                self._heard(now)
                stats.count_drop(DropReason.DUPLICATE)
                return
        received = stats.received
        received.datagrams += 1
        received.bytes += size + self._overhead
        received.header_bytes += HEADER_SIZE
        received.payload_bytes += payload_size
        received.protection_bytes += self._overhead
        received.data_packets += 1
        self._last_receive = now
        if self._silent_since is not None:
            self._on_peer_resumed(now)
        stats.samples_delivered += 1
        rtt = self._rtt
        event = new_data_received(
            data[HEADER_SIZE:], window.last_seq, rtt.srtt / 2 if rtt.has_sample else None, now
        )
        events = self._events
        if len(events) >= self._max_events and self._data_pending:
            self._discard_oldest_data()
        events.append(event)
        self._data_pending += 1

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
        newly = sent.acknowledge(full, sack, hold, now)
        stats = self._stats
        if sent.spurious:
            stats.spurious_losses += sent.spurious
        sample = sent.rtt_sample
        if sample is not None:
            rtt.on_sample(sample)
            stats.rtt_samples += 1
            delay = self._loss_delay()
            if delay < self._loss_delay_value:
                # A shorter loss delay brings a pending loss deadline forward.
                due = sent.loss_deadline(delay)
                if due is not None and due < self._hint:
                    self._hint = due
            self._loss_delay_value = delay
        if sent.marked_missing:
            sent.marked_missing = False
            self._hint = -math.inf  # a loss deadline may be due earlier
        lost = self._lost
        sent.detect_losses(now, self._loss_delay_value, lost)
        if lost:
            self._on_losses(now)
        if newly:
            stats.packets_acked += newly
            self._controller.on_ack(
                now=now,
                acked=newly,
                rtt_sample=sample,
                srtt=rtt.srtt,
                rttvar=rtt.rttvar,
                loss_event_rate=self._loss.update(sent.largest_acked),
            )
            if self._pending is not None:
                self._hint = -math.inf  # a new rate may let the held sample go earlier
            self._check_controller_timer()
        return True

    def _on_losses(self, now: float) -> None:
        lost = self._lost
        estimator = self._loss
        srtt = self._rtt.srtt
        largest = self._sent.largest_acked
        stats = self._stats
        stats.packets_lost += len(lost)
        outage = self._last_outage if self._silent_since is None else (self._silent_since, now)
        for packet in lost:
            window = srtt
            during_outage = outage is not None and outage[0] <= packet.send_time <= outage[1]
            if during_outage:
                # Packets sent into a silent path are lost together: one loss event per outage,
                # however far apart the controller's back-off spaced them (docs/PROTOCOL.md 5.4).
                assert outage is not None
                window = srtt + outage[1] - outage[0]
            if estimator.on_packet_lost(packet.seq, packet.send_time, window, largest):
                stats.loss_events += 1
                if not during_outage:
                    # An outage's loss event counts in p; the controller answers the outage itself
                    # through on_peer_silent / on_peer_resumed, not a second time here.
                    self._controller.on_loss_event(
                        now=now, srtt=srtt, loss_event_rate=estimator.loss_event_rate
                    )
        lost.clear()
        self._hint = -math.inf

    def _loss_delay(self) -> float:
        """How long a packet reported absent may still turn up: srtt plus a reorder window (RFC 8985:
        ``min_rtt / 4`` at first, scaled up by each spurious loss, at most srtt; never less than
        RAP's ``4 rttvar`` nor the timer granularity), plus the peer's ACK delay, because RTT samples
        exclude it: a late arrival is reported only with the peer's next reverse packet.
        """
        rtt = self._rtt
        srtt = rtt.srtt
        reorder = 0.0
        if rtt.has_sample:
            reorder = min(
                REORDER_WINDOW_MIN_RTT * rtt.min_rtt * self._sent.reorder_window_scale, srtt
            )
        return (
            srtt + max(reorder, LOSS_DELAY_RTTVAR * rtt.rttvar, TIMER_GRANULARITY) + self._ack_delay
        )

    def _on_session_control(
        self, data: bytes, size: int, ack: int, sack: int, hold: int, now: float
    ) -> None:
        """KEEPALIVE and CLOSE (already opened in a keyed session)."""
        stats = self._stats
        try:
            body = decode_control(data[HEADER_SIZE:])
        except MalformedPacketError:
            stats.count_drop(DropReason.BAD_CONTROL)
            return
        if isinstance(body, CloseBody):
            if body.nonce != self._master_nonce or self._state not in (
                State.OPENING,
                State.ESTABLISHED,
            ):
                stats.count_drop(DropReason.NONCE_MISMATCH)
                return
            self._accept_control(size, now)
            self._terminate(CloseCause.PEER_CLOSE, _reason_text(body.reason))
            return
        # KEEPALIVE
        if self._state is not State.ESTABLISHED:
            stats.count_drop(DropReason.NOT_ESTABLISHED)
            return
        if hold != HOLD_NO_ACK and not self._on_feedback(ack, sack, hold, now):
            stats.count_drop(DropReason.OPTIMISTIC_ACK)
            return
        self._accept_control(size, now)

    def _accept_control(self, size: int, now: float) -> None:
        self._accept(size, size - HEADER_SIZE, now)
        self._stats.received.control_packets += 1

    def _accept_handshake(self, size: int, now: float, tag: int = 0, *, alive: bool = True) -> None:
        """Count a handshake message taken in; ``tag`` is the bytes of its tag (keyed OPEN and
        OPEN_ACK), counted as protection. ``alive``: it shows the peer is there (refreshes the idle
        timer)."""
        received = self._stats.received
        received.datagrams += 1
        received.bytes += size
        received.header_bytes += HEADER_SIZE
        received.payload_bytes += size - HEADER_SIZE - tag
        received.protection_bytes += tag
        received.control_packets += 1
        if alive:
            self._heard(now)

    # ------------------------------------------------------------------ opening

    def _on_handshake(self, data: bytes, addr: Address, now: float) -> None:
        """OPEN, OPEN_ACK, COOKIE or REJECT: the messages whose fields travel in the clear."""
        self._hint = -math.inf  # the opening's timers may move
        stats = self._stats
        if self.role is Role.SLAVE:
            if data[HEADER_SIZE] != _OPEN:
                stats.count_drop(DropReason.UNEXPECTED_CONTROL)
                return
            self._on_open(data, addr, now)
            return
        try:
            body = decode_control(data[HEADER_SIZE:])
        except MalformedPacketError:
            stats.count_drop(DropReason.BAD_CONTROL)
            return
        if isinstance(body, OpenBody | KeepaliveBody):
            stats.count_drop(DropReason.UNEXPECTED_CONTROL)  # an OPEN sent to a master
        elif body.nonce != self._master_nonce:
            stats.count_drop(DropReason.NONCE_MISMATCH)
        elif self._state is not State.OPENING:
            if isinstance(body, OpenAckBody) and self._state is State.ESTABLISHED:
                self._on_duplicate_open_ack(body, data, now)
            else:
                stats.count_drop(DropReason.UNEXPECTED_CONTROL)
        elif isinstance(body, CookieBody):
            self._on_cookie(body, len(data), now)
        elif isinstance(body, OpenAckBody):
            self._on_open_ack(body, data, now)
        elif isinstance(body, CloseBody):  # REJECT
            self._accept_handshake(len(data), now)
            self._terminate(CloseCause.REJECTED, _reject_text(body.reason, self))
        else:  # pragma: no cover - decode_control returns one of the above for these codes
            stats.count_drop(DropReason.BAD_CONTROL)

    def _on_open(self, data: bytes, addr: Address, now: float) -> None:
        """A slave's OPEN: through admission first (cookie, rate, key), then by state."""
        stats = self._stats
        admission = self._admission
        assert admission is not None  # every slave has one
        verdict = admission.admit(data, addr, now)
        if isinstance(verdict, DropReason):
            stats.count_drop(verdict)
            return
        if isinstance(verdict, Reply):
            stats.count_drop(verdict.reason)
            self._control_out.append((verdict.datagram, addr, 0, False))
            return
        if self._state is State.LISTENING:
            self._open_session(verdict, addr, now)
        elif verdict.body.nonce == self._master_nonce:
            # The master did not hear our OPEN_ACK: answer its retransmission again. Not a sign
            # of life: a master sends OPENs only until it is established, so once the session is
            # established this is a delayed duplicate or a replay (PROTOCOL.md 5.2).
            self._accept_handshake(verdict.size, now, self._tag_size(), alive=False)
            self._queue_open_ack()
        elif now - self._last_receive > self._keepalive + 2.0 * self._rtt.srtt:
            # The same address opens anew and this session has been silent longer than a live
            # master ever is (it sends at least a KEEPALIVE per interval): the master restarted.
            # A live session is never replaced, so a replayed OPEN cannot end it.
            stats.count_drop(DropReason.NONCE_MISMATCH)
            self._terminate(
                CloseCause.REPLACED, "the master opened a new connection from the same address"
            )
        else:
            stats.count_drop(DropReason.NONCE_MISMATCH)

    def _open_session(self, admitted: AdmittedOpen, addr: Address, now: float) -> None:
        """A listening slave takes the admitted OPEN: adopt its settings, answer OPEN_ACK, and wait
        for the master's first packet of the session (it confirms the master has the OPEN_ACK)."""
        body = admitted.body
        self._peer = addr
        self._master_nonce = body.nonce
        self._ack_mode = (
            AckMode.SEPARATE if body.flags & OpenFlags.SEPARATE_ACKS else AckMode.BIDIRECTIONAL
        )
        self._send_limit = min(self.config.max_payload, body.max_payload)
        self._window = self._new_window(admitted.initial_seq)
        if admitted.key is not None:
            self._key = admitted.key
            self._keyed = True
            self._encrypt = bool(body.flags & OpenFlags.ENCRYPTED)
            self._suite = CipherSuite(body.suite)
            self._start_protection()
        self._accept_handshake(admitted.size, now, self._tag_size())
        self._state = State.OPENING
        self._confirming = True
        self._open_deadline = now + self.config.open_timeout
        self._last_send = now
        self._queue_open_ack()

    def _start_protection(self) -> None:
        """Derive the session's keys from the pre-shared key and both nonces."""
        key = self._key
        assert key is not None
        secrets = derive_session_secrets(
            key.secret, self._master_nonce, self._slave_nonce, self._suite
        )
        master = self.role is Role.MASTER
        ours, theirs = (
            (secrets.master_to_slave, secrets.slave_to_master)
            if master
            else (secrets.slave_to_master, secrets.master_to_slave)
        )
        self._sealer = PacketSealer(self._suite, ours, encrypt=self._encrypt)
        self._opener = PacketOpener(self._suite, theirs, encrypt=self._encrypt)
        self._overhead = PROTECTION_OVERHEAD

    def _on_cookie(self, body: CookieBody, size: int, now: float) -> None:
        """The slave wants proof that we receive at our address: echo its cookie in the OPEN."""
        if body.version != PROTOCOL_VERSION:
            self._stats.count_drop(DropReason.UNKNOWN_VERSION)
            return
        self._accept_handshake(size, now)
        self._cookie = body.cookie
        # Answer at once, but at most once per retry interval: COOKIEs cannot make us flood.
        if now >= self._cookie_answered_at + self.config.open_retry_interval:
            self._cookie_answered_at = now
            self._open_next = now

    def _on_open_ack(self, body: OpenAckBody, data: bytes, now: float) -> None:
        stats = self._stats
        if body.version != PROTOCOL_VERSION:
            stats.count_drop(DropReason.UNKNOWN_VERSION)
            return
        if body.max_payload == 0 or body.flags != self._open_flags() or body.suite != self._suite:
            stats.count_drop(DropReason.BAD_CONTROL)
            return
        self._slave_nonce = body.slave_nonce
        if self._keyed:
            self._start_protection()
            opener = self._opener
            assert opener is not None
            if not opener.verify_numbered(body.packet_number, data[:-TAG_SIZE], data[-TAG_SIZE:]):
                stats.count_drop(DropReason(opener.failure))
                self._sealer = self._opener = None  # not the slave we opened towards
                self._overhead = 0
                return
        self._accept_handshake(len(data), now, self._tag_size())
        if body.max_payload < self.config.min_peer_payload:
            self._queue_close(CloseReason.PAYLOAD_TOO_SMALL, self._peer_address())
            self._terminate(
                CloseCause.REJECTED,
                f"the slave accepts payloads of at most {body.max_payload} bytes, smaller than "
                f"min_peer_payload ({self.config.min_peer_payload})",
            )
            return
        self._send_limit = min(self.config.max_payload, body.max_payload)
        self._window = self._new_window(decode_header(data).seq)
        self._establish(now)
        # Confirm at once (the slave waits for our first packet of the session): the next
        # datagrams_to_send sends a KEEPALIVE unless a sample goes out. (Twice the interval back:
        # exactly one back can round to a deadline just after ``now``, delaying the KEEPALIVE.)
        self._last_send = now - 2.0 * self._keepalive

    def _on_duplicate_open_ack(self, body: OpenAckBody, data: bytes, now: float) -> None:
        """The slave answered a retransmitted OPEN again; our open is already done. In a keyed
        session it must still authenticate (through the replay window) to count as a sign of life."""
        opener = self._opener
        if opener is not None and not opener.verify_numbered(
            body.packet_number, data[:-TAG_SIZE], data[-TAG_SIZE:]
        ):
            self._stats.count_drop(DropReason(opener.failure))
            return
        self._accept_handshake(len(data), now, self._tag_size())

    def _tag_size(self) -> int:
        """Bytes of the tag a keyed OPEN or OPEN_ACK ends in."""
        return TAG_SIZE if self._keyed else 0

    def _open_flags(self) -> int:
        flags = OpenFlags.SEPARATE_ACKS if self._ack_mode is AckMode.SEPARATE else OpenFlags.NONE
        if self._keyed:
            flags |= OpenFlags.KEYED
            if self._encrypt:
                flags |= OpenFlags.ENCRYPTED
        return int(flags)

    def _peer_address(self) -> Address:
        peer = self._peer
        assert peer is not None  # set by connect() or at the OPEN
        return peer

    def _new_window(self, initial_seq: int) -> ReceiveWindow:
        """The receive window for the peer's data from ``initial_seq``, in this session's ACK mode."""
        return ReceiveWindow(
            initial_seq,
            coverage=self._ack_mode is AckMode.BIDIRECTIONAL,
            silence_guard=self._silence,
        )

    def _establish(self, now: float) -> None:
        self._state = State.ESTABLISHED
        self._hint = -math.inf
        self._confirming = False
        self._last_receive = now
        self._last_send = now
        self._push_other_event(ConnectionEstablished(self._peer_address()))

    # ------------------------------------------------------------------ timers

    def get_timer(self) -> float | None:
        """The next absolute time :meth:`handle_timer` (then :meth:`datagrams_to_send`) is due."""
        self._hint = math.inf
        state = self._state
        if state is State.OPENING:
            if self.role is Role.SLAVE:
                return self._open_deadline
            return min(self._open_next, self._open_deadline)
        if state is not State.ESTABLISHED:
            return None
        # The watchdog until the peer is silent, then the outage limit; the keep-alive.
        deadline = self._last_receive + (
            self._silence if self._silent_since is None else self._idle_timeout
        )
        candidate = self._last_send + self._keepalive
        if candidate < deadline:
            deadline = candidate
        controller = self._controller
        if self._pending is not None and not self._send_paused:
            candidate = controller.next_send_time()
            if candidate < deadline:
                deadline = candidate
        window = self._window
        if window is not None:
            if self._ack_mode is AckMode.BIDIRECTIONAL:
                since = window.unreported_since
                if since is not None and since + self._ack_delay < deadline:
                    deadline = since + self._ack_delay
                if window.held and window.highest_arrival < deadline:
                    deadline = window.highest_arrival  # due since the jump
            elif self._separate_acks:
                candidate = self._separate_acks[0][1]
                if candidate < deadline:
                    deadline = candidate
        loss_deadline = self._sent.loss_deadline(self._loss_delay_value)
        if loss_deadline is not None and loss_deadline < deadline:
            deadline = loss_deadline
        controller_deadline = controller.get_timer()
        self._controller_timer = controller_deadline
        if controller_deadline is not None and controller_deadline < deadline:
            deadline = controller_deadline
        return deadline

    def handle_timer(self, *, now: float) -> None:
        """Act on whatever is due at ``now``. Calling it early or late is harmless."""
        self._hint = -math.inf
        state = self._state
        if state is State.OPENING:
            if now >= self._open_deadline:
                if self.role is Role.MASTER:
                    detail = f"no answer to OPEN within {self.config.open_timeout} s"
                else:
                    detail = (
                        "the master never confirmed the session within "
                        f"{self.config.open_timeout} s after our OPEN_ACK"
                    )
                self._terminate(CloseCause.OPEN_TIMEOUT, detail)
            return
        if state is not State.ESTABLISHED:
            return
        if now >= self._last_receive + self._idle_timeout:
            self._queue_close(CloseReason.IDLE_TIMEOUT, self._peer_address())
            self._terminate(
                CloseCause.IDLE_TIMEOUT,
                f"nothing received from the peer for {self.config.idle_timeout:g} s",
            )
            return
        if self._silent_since is None and now >= self._last_receive + self._silence:
            self._silent_since = self._last_receive
            self._stats.peer_silences += 1
            self._push_watchdog_event(PeerSilent(self._last_receive, now))
            self._controller.on_peer_silent(now=now)
        lost = self._lost
        self._sent.detect_losses(now, self._loss_delay_value, lost)
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
        if state is State.OPENING and self.role is Role.MASTER and now >= self._open_next:
            self._open_next = now + self.config.open_retry_interval
            self._emit_open(out, now)
        if self._control_out:
            for datagram, addr, protection, session in self._control_out:
                self._emit_control(out, datagram, addr, now, protection, session)
            self._control_out.clear()
        if state is not State.ESTABLISHED or self._state is not State.ESTABLISHED:
            return out
        peer = self._peer
        assert peer is not None  # ESTABLISHED implies it
        window = self._window
        assert window is not None
        bidirectional = self._ack_mode is AckMode.BIDIRECTIONAL
        if bidirectional and window.held:
            # The jump rule (section 3.2): report what a newer packet put out of reach, first.
            for held in window.take_held():
                self._emit_ack(out, held.ack, held.sack, encode_hold(now - held.arrival), peer, now)
        payload = self._pending
        if (
            payload is not None
            and not self._send_paused
            and now >= self._controller.next_send_time()
        ):
            self._pending = None
            self._controller.sample_waiting = False
            ack, sack, hold = self._piggyback(window, now) if bidirectional else _NO_ACK
            header = encode_header(_DATA, self._sent.next_seq, ack, sack, hold)
            sealer = self._sealer
            datagram = header + payload if sealer is None else sealer.seal(header, payload)
            size = len(datagram)
            self._sent.on_sent(now, size, self._lost)
            if self._lost:
                self._on_losses(now)
            self._controller.on_packet_sent(now=now, size=size, paced=self._pending_paced)
            sent = self._stats.sent
            sent.data_packets += 1
            sent.payload_bytes += len(payload)
            self._count_sent(size, now, self._overhead)
            out.append((datagram, peer))
            self._check_controller_timer()
        if bidirectional:
            if window.unreported_since is not None and (
                now >= window.unreported_since + self._ack_delay or window.coverage_exhausted()
            ):
                ack, sack, hold = self._piggyback(window, now)
                self._emit_ack(out, ack, sack, hold, peer, now)
        else:
            acks = self._separate_acks
            plain = self._plain_acks
            while acks:
                seq, arrival = acks.popleft()
                sack = 0 if plain else window.sack_below(seq)  # plain: this packet only
                self._emit_ack(out, seq, sack, encode_hold(now - arrival), peer, now)
        if now >= self._last_send + self._keepalive:
            ack, sack, hold = self._piggyback(window, now) if bidirectional else _NO_ACK
            self._emit_control(
                out,
                self._protect(
                    encode_header(_CONTROL, self._sent.next_seq, ack, sack, hold)
                    + _KEEPALIVE_PREFIX,
                    b"",
                ),
                peer,
                now,
                self._overhead,
            )
        sealer = self._sealer
        if sealer is not None and sealer.exhausted:
            self._exhausted()
        return out

    def _protect(self, prefix: bytes, body: bytes) -> bytes:
        """Seal a session datagram in a keyed session; plain ``prefix + body`` otherwise."""
        sealer = self._sealer
        return prefix + body if sealer is None else sealer.seal(prefix, body)

    def _emit_open(self, out: list[tuple[bytes, Address]], now: float) -> None:
        attempt = self._open_attempt
        if attempt > 0xFFFF:  # the OPEN tag's nonce counter must never repeat
            self._terminate(CloseCause.OPEN_TIMEOUT, "no answer to 65536 OPENs")
            return
        self._open_attempt = attempt + 1
        key = self._key
        datagram = encode_header(_CONTROL, self._sent.next_seq, 0, 0, HOLD_NO_ACK) + encode_open(
            OpenBody(
                PROTOCOL_VERSION,
                self._open_flags(),
                int(self._suite),
                self.config.max_payload,
                attempt,
                self._master_nonce,
                key.key_id if key is not None else NO_KEY_ID,
                self._cookie,
            )
        )
        tagger = self._open_tagger
        if tagger is not None:
            datagram += tagger.tag(attempt, datagram)
        self._emit_control(out, datagram, self._peer_address(), now, self._tag_size())

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
        datagram = self._protect(
            encode_header(_ACK, self._sent.next_seq, ack, sack, hold),
            self._ack_padding,
        )
        self._stats.sent.ack_packets += 1
        self._count_sent(len(datagram), now, self._overhead)
        out.append((datagram, peer))

    def _emit_control(
        self,
        out: list[tuple[bytes, Address]],
        datagram: bytes,
        addr: Address,
        now: float,
        protection: int,
        session: bool = True,
    ) -> None:
        sent = self._stats.sent
        sent.control_packets += 1
        sent.payload_bytes += len(datagram) - HEADER_SIZE - protection
        self._count_sent(len(datagram), now, protection, session)
        out.append((datagram, addr))

    def _count_sent(self, size: int, now: float, protection: int, session: bool = True) -> None:
        sent = self._stats.sent
        sent.datagrams += 1
        sent.bytes += size
        sent.header_bytes += HEADER_SIZE
        sent.protection_bytes += protection
        if session:
            # The peer hears from us: no KEEPALIVE needed for a while. A COOKIE or REJECT to
            # whoever sent an OPEN says nothing to the peer (it may be a forgery or a replay),
            # so it must not hold back our KEEPALIVEs (PROTOCOL.md 5.2).
            self._last_send = now

    # ------------------------------------------------------------------ helpers

    def _queue_open_ack(self) -> None:
        sealer = self._sealer
        number = sealer.take_number() if sealer is not None else 0
        datagram = encode_header(
            _CONTROL, self._sent.next_seq, 0, 0, HOLD_NO_ACK
        ) + encode_open_ack(
            OpenAckBody(
                PROTOCOL_VERSION,
                self._open_flags(),
                int(self._suite),
                self.config.max_payload,
                number & 0xFFFF,
                self._master_nonce,
                self._slave_nonce,
            )
        )
        if sealer is not None:
            datagram += sealer.tag(number, datagram)
        self._control_out.append((datagram, self._peer_address(), self._tag_size(), True))

    def _queue_close(self, reason: CloseReason, addr: Address) -> None:
        datagram = self._protect(
            encode_header(_CONTROL, self._sent.next_seq, 0, 0, HOLD_NO_ACK) + _CLOSE_PREFIX,
            encode_close(ControlCode.CLOSE, self._master_nonce, reason)[1:],
        )
        self._control_out.append((datagram, addr, self._overhead, True))

    def _terminate(self, cause: CloseCause, detail: str) -> None:
        self._state = State.CLOSED
        self._hint = -math.inf
        self._confirming = False
        self._pending = None
        self._controller.sample_waiting = False
        self._separate_acks.clear()
        self._close_event = event = ConnectionClosed(cause, detail)
        self._push_other_event(event)

    def _discard_oldest_data(self) -> None:
        """The event queue is full: the oldest data event goes (the application is not reading)."""
        events = self._events
        for index, pending in enumerate(events):
            if type(pending) is DataReceived:
                del events[index]
                self._data_pending -= 1
                self._stats.events_discarded += 1
                return

    def _push_other_event(self, event: Event) -> None:
        self._events.append(event)
        self._hint = -math.inf

    def _push_watchdog_event(self, event: PeerSilent | PeerResumed) -> None:
        """Watchdog events share the ``max_pending_events`` bound: an application that never takes
        events loses the oldest data event, or failing that the oldest watchdog event."""
        events = self._events
        if len(events) >= self._max_events:
            if self._data_pending:
                self._discard_oldest_data()
            else:
                for index, pending in enumerate(events):
                    if isinstance(pending, PeerSilent | PeerResumed):
                        del events[index]
                        self._stats.events_discarded += 1
                        break
        self._push_other_event(event)


def _as_payload(payload: object) -> bytes:
    if isinstance(payload, bytes | bytearray | memoryview):
        return bytes(payload)
    hint = "; encode text first, e.g. text.encode()" if isinstance(payload, str) else ""
    raise PayloadTypeError(
        "a sample must be bytes-like (bytes, bytearray or memoryview), got "
        f"{type(payload).__name__}{hint}"
    )


def _reason_text(reason: int) -> str:
    try:
        return CloseReason(reason).name.lower()
    except ValueError:
        return f"reason code {reason}"


_REJECT_TEXT = {
    CloseReason.BUSY: "the slave serves as many masters as it may (max_peers) or its accept "
    "backlog is full; try again later",
    CloseReason.KEY_REQUIRED: "the slave accepts keyed sessions only; connect with key= "
    "(--key-file) holding a key the slave knows",
    CloseReason.KEY_UNKNOWN: "the slave does not hold this key (key id {key_id}), or accepts "
    "unkeyed sessions only",
    CloseReason.VERSION_UNSUPPORTED: f"the slave does not speak TDTP version {PROTOCOL_VERSION}",
    CloseReason.PAYLOAD_TOO_SMALL: "the slave sends payloads larger than this master's "
    "max_payload ({max_payload}); raise max_payload",
    CloseReason.SUITE_UNSUPPORTED: "the slave does not implement the cipher suite {suite}",
}


def _reject_text(reason: int, conn: Connection) -> str:
    """Why the slave refused us, in words a user can act on."""
    try:
        known = CloseReason(reason)
    except ValueError:
        return f"refused (reason code {reason})"
    template = _REJECT_TEXT.get(known)
    if template is None:
        return known.name.lower()
    key = conn.key
    return template.format(
        key_id=key.key_id.hex() if key is not None else "-",
        max_payload=conn.config.max_payload,
        suite=conn.config.cipher_suite.name,
    )
