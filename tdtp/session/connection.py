"""The sans-IO TDTP connection: a state machine that never touches a socket or reads a clock.

The caller owns I/O and time. It feeds datagrams in with :meth:`Connection.receive_datagram`, timer
expiries with :meth:`Connection.handle_timer` and samples with :meth:`Connection.send`, always passing
``now`` (seconds on one monotonic clock). After every input it collects
:meth:`Connection.datagrams_to_send` and re-arms a single timer at :meth:`Connection.get_timer`. What
happened comes out of :meth:`Connection.next_event`. The asyncio endpoints, the impairment emulator and
the virtual-time simulator all drive this one class. The watchdog's reactions (PeerSilent, PeerResumed,
the idle timeout: docs/PROTOCOL.md section 5.2) and path migration (5.8) live here too.

:class:`Connection` holds the session's state machine: it checks the caller's input against the state,
takes every datagram in (address, size, packet protection, type) and dispatches it, and carries out
what the opening and the watchdog decide. The pieces with state of their own (listed in
:mod:`tdtp.session`) live beside it, each owning that state and importing nothing of the connection.

Peer input never raises: anything malformed, unexpected or hostile is dropped and counted in
``stats.drops`` by reason. Misuse by the caller raises a :class:`~tdtp.errors.TdtpError` subclass.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable
from typing import Final

from tdtp.admission.admission import Admission, AdmittedOpen
from tdtp.config import AckMode, ConnectionConfig, Role
from tdtp.control.registry import create_controller
from tdtp.errors import ArgumentTypeError, ConnectionStateError
from tdtp.protection.keys import KeyInput, KeysInput
from tdtp.protection.packet_protection import PacketOpener
from tdtp.session.ack_scheduler import AckScheduler
from tdtp.session.control_channel import ALIVE, TAKEN, ControlChannel, largest_message_body
from tdtp.session.delivery import SampleDelivery
from tdtp.session.event_queue import EventQueue
from tdtp.session.events import (
    Address,
    CloseCause,
    ConnectionClosed,
    ConnectionEstablished,
    Event,
    PeerResumed,
    PeerSilent,
)
from tdtp.session.handshake import Handshake, Reaction, close_reason_text
from tdtp.session.liveness import Liveness
from tdtp.session.one_way import OneWayDelay
from tdtp.session.outbox import Outbox
from tdtp.session.path import PeerPath
from tdtp.session.receive_window import LATE, NEW, STALE
from tdtp.session.recovery import LossRecovery
from tdtp.session.reset_guard import ResetGuard
from tdtp.session.sender import SampleSender
from tdtp.session.state import CLOSED, ESTABLISHED, OPENING, State, refusal
from tdtp.session.stats import ConnectionStats, DropReason
from tdtp.session.timer_hint import TimerHint
from tdtp.session.view import ConnectionView
from tdtp.wire.control import (
    HANDSHAKE_CODES,
    MESSAGE_CODES,
    OPEN_BODY_SIZE,
    PATH_CODES,
    STAMP_CODES,
    STAMP_SIZE,
    CloseBody,
    CloseReason,
    ControlCode,
    KeepaliveBody,
    OpenFlags,
    decode_control,
)
from tdtp.wire.errors import MalformedPacketError
from tdtp.wire.header import HEADER_SIZE, PacketType, decode_header
from tdtp.wire.hold import HOLD_NO_ACK
from tdtp.wire.protected import PROTECTION_OVERHEAD, TAG_SIZE
from tdtp.wire.seqnum import SEQ_MODULUS

_DATA: Final = int(PacketType.DATA)
_ACK: Final = int(PacketType.ACK)
_CONTROL: Final = int(PacketType.CONTROL)
_RESET: Final = int(ControlCode.RESET)
_TIMED: Final = int(ControlCode.TIMED_DATA)
_LARGEST_CONTROL: Final = OPEN_BODY_SIZE + TAG_SIZE
"""The largest control body (a keyed OPEN's): datagrams up to this size pass the size check whatever
``max_payload`` is."""


class Connection(ConnectionView):
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
        self.config = config = config if config is not None else ConnectionConfig()
        self.role = role
        rng = rng if rng is not None else random.SystemRandom()
        self._stats = stats = ConnectionStats()
        self._liveness = liveness = Liveness(config)
        self._outbox = outbox = Outbox(config, stats, liveness)
        # Draws the nonces (and a slave's admission secret) from rng before the first sequence number.
        self._handshake = Handshake(
            config,
            role,
            rng,
            key=key,
            keys=keys,
            admission=admission,
            stats=stats,
            outbox=outbox,
            liveness=liveness,
        )
        self._state = State.IDLE if role is Role.MASTER else State.LISTENING
        self._peer: Address | None = None
        self.last_rx_time: float | None = None  # receive_datagram(rx_time=) of the last one
        self._path = PeerPath(config, stats)  # the peer's address: validated, or under the 3x limit
        # The peer's packet protection, once keyed (Handshake.keys; ours is the outbox's sealer).
        self._opener: PacketOpener | None = None
        self._overhead = 0  # bytes the peer's protection adds to each session datagram, once keyed
        # PROTOCOL.md 5.5: room for a keyed session's packet number and tag on a full payload.
        body = max(config.max_payload + STAMP_SIZE, _LARGEST_CONTROL, largest_message_body(config))
        self._size_limit = HEADER_SIZE + body + PROTECTION_OVERHEAD
        self._controller = controller = create_controller(
            config.controller, config.controller_config
        )
        # The peer holds ACKs up to its ack_delay; not negotiated, so ours stands for it.
        controller.feedback_delay = config.ack_delay
        controller.silence_timeout = config.silence_timeout
        controller.sample_waiting = False  # kept up to date by the sender
        self._hint = hint = TimerHint(controller)
        self._recovery = recovery = LossRecovery(
            rng.randrange(SEQ_MODULUS),
            config,
            controller=controller,
            stats=stats,
            liveness=liveness,
            hint=hint,
        )
        self._acks = acks = AckScheduler(config, stats=stats, hint=hint)
        self._one_way = outbox.one_way = one_way = OneWayDelay(config, controller, recovery)
        self._handshake.timestamps = role is Role.MASTER and one_way.wanted
        self._sender = SampleSender(
            config,
            controller=controller,
            stats=stats,
            recovery=recovery,
            outbox=outbox,
            acks=acks,
            liveness=liveness,
            hint=hint,
            one_way=one_way,
        )
        self._events = events = EventQueue(config.max_pending_events, stats)
        self._channel = ControlChannel(
            config, stats=stats, outbox=outbox, events=events, recovery=recovery, hint=hint
        )
        # The settings the per-packet paths read, copied out of the (plain Python) config once.
        self._max_payload = config.max_payload
        self._deliver_late = config.deliver_late
        self._deliver_duplicates = config.deliver_duplicates
        self._close_event: ConnectionClosed | None = None
        # In order through the reorder wait, timed (PROTOCOL.md 3.6, 5.5).
        self._delivery = delivery = SampleDelivery(
            config, events=self._events, stats=stats, rtt=recovery.rtt, one_way=one_way
        )
        self._ages = delivery.ages

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
        self._hint.value = -math.inf
        handshake = self._handshake
        key = handshake.key
        self._outbox.reset_guard = ResetGuard(key.reset_key if key is not None else None)
        handshake.start(now)
        self._liveness.last_receive = now

    def send(self, payload: bytes | bytearray | memoryview, *, now: float) -> None:
        """Offer the newest sample (bytes, bytearray or memoryview). It replaces any sample still
        waiting for the pacer or for the socket (which is counted as superseded): stale supermedia
        data is never queued or retransmitted."""
        if self._state is not ESTABLISHED:
            raise refusal(self._state, self._close_event)
        self._sender.offer(payload, now)

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
        peer = self._peer
        if self._state is not ESTABLISHED or peer is None or self._path.limited:
            self.send(payload, now=now)
            return False
        if not self._sender.send_direct(payload, transmit, peer, connected, now):
            return False
        sealer = self._outbox.sealer
        if sealer is not None and sealer.exhausted:
            self._exhausted()
        return True

    def _exhausted(self) -> None:
        self._terminate(
            CloseCause.KEY_EXHAUSTED,
            "the session protected as many packets as its keys may; open a new connection",
        )

    def send_control(self, message: bytes | bytearray | memoryview, *, now: float) -> None:
        """Queue a message on the reliable control channel (:mod:`tdtp.session.control_channel`)."""
        if self._state is not State.ESTABLISHED:
            raise refusal(self._state, self._close_event)
        self._channel.send(message, now)

    def pause_sending(self) -> None:
        """The layer below cannot take datagrams now (the socket's send buffer is full).

        Data is held: the pending sample waits and newer samples supersede it (counted in
        ``samples_superseded`` and ``samples_blocked``) instead of queueing in a buffer out of sight.
        Acknowledgements and control packets still go out. Call :meth:`resume_sending` when the
        buffer has drained, then :meth:`datagrams_to_send`.
        """
        self._sender.pause()

    def resume_sending(self) -> None:
        """The layer below takes datagrams again; the newest held sample leaves when the pacer allows."""
        self._sender.resume()

    def close(self, *, now: float, taken_over: bool = False) -> None:
        """End the connection: a CLOSE goes out with the next :meth:`datagrams_to_send`.
        ``taken_over``: an exclusive slave hands control to another master (PROTOCOL.md 5.9)."""
        if self._state is State.CLOSED:
            return
        reason = CloseReason.TAKEN_OVER if taken_over else CloseReason.NORMAL
        if self._state in (State.OPENING, State.ESTABLISHED) and self._peer is not None:
            self._queue_close(reason, self._peer)
        cause = CloseCause.TAKEN_OVER if taken_over else CloseCause.LOCAL_CLOSE
        detail = "another master took control" if taken_over else "closed by the application"
        self._terminate(cause, detail)

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
        self._hint.value = -math.inf
        self._open_session(admitted, addr, now)

    def next_event(self) -> Event | None:
        """The oldest event not yet taken, or ``None`` (pop's first test inline: most find none)."""
        events = self._events
        return events.pop() if events.solo is not None or events.items else None

    # ------------------------------------------------------------------ input

    def receive_datagram(
        self,
        data: bytes,
        addr: Address,
        *,
        now: float,
        rx_time: float | None = None,
        ecn: int | None = None,
    ) -> None:
        """Take one datagram from the network. Never raises on its content.

        Optional inputs a driver may know: ``rx_time``, when the kernel received it (on the same
        clock as ``now``; kept as :attr:`last_rx_time` for a controller that wants the exact
        one-way delay), and ``ecn``, the IP header's ECN field (0-3; ``3``, Congestion
        Experienced, is counted in ``stats.ecn_ce``). The core reads no clock for either."""
        stats = self._stats
        stats.datagrams_in += 1
        if self._state is CLOSED:
            stats.count_drop(DropReason.CLOSED)
            return
        peer = self._peer
        if peer is not None and addr != peer and (addr[0] != peer[0] or addr[1] != peer[1]):
            stats.count_drop(DropReason.WRONG_ADDRESS)
            return
        self.last_rx_time = rx_time
        if ecn == 3:
            stats.ecn_ce += 1
        size = len(data)
        if size < HEADER_SIZE:
            stats.count_drop(DropReason.TRUNCATED)
            return
        if size > self._size_limit:
            stats.count_drop(DropReason.OVERSIZED)
            return
        path = self._path
        if path.limited:
            path.on_received(size)
            self._hint.value = -math.inf  # held data may go now
        ptype = data[0] >> 6
        if ptype == _CONTROL and size > HEADER_SIZE:
            code = data[HEADER_SIZE]
            if code in HANDSHAKE_CODES:
                self._on_handshake(data, addr, now)
                return
            if code == _RESET:
                self._on_reset(data, now)
                return
            if code in PATH_CODES:  # an unkeyed master answers a PATH_CHALLENGE
                established = self._state is State.ESTABLISHED and self.role is Role.MASTER
                nonce = self._handshake.master_nonce
                answer = self._path.answer(data, now, established and not self.keyed, nonce)
                if answer is not None:
                    self._outbox.queue(answer, addr, 0, False)
                    self._hint.value = -math.inf
                return
        if ptype > _CONTROL:
            stats.count_drop(DropReason.UNKNOWN_TYPE)
            return
        if peer is None:
            # A listening slave answers with a RESET (its master's session died with a restart).
            self._handshake.on_stranger(data, addr, now)
            self._hint.value = -math.inf
            return
        handshake = self._handshake
        if handshake.keyed:
            opener = self._opener
            if opener is None:
                # A keyed master before the OPEN_ACK has no keys to read session packets with.
                stats.count_drop(DropReason.NOT_ESTABLISHED)
                return
            prefix = HEADER_SIZE + 1 if ptype == _CONTROL else HEADER_SIZE
            if size < prefix + PROTECTION_OVERHEAD:
                stats.count_drop(DropReason.TRUNCATED)
                return
            body = opener.open(data, prefix, now)
            if body is None:
                self._on_unopened(opener, now)
                return
            data = data[:prefix] + body
        self._dispatch(data, ptype, now)

    def _dispatch(self, data: bytes, ptype: int, now: float) -> None:
        """A datagram from the peer, its protection removed (sizes from here on are without it:
        :meth:`_accept` adds it)."""
        size = len(data)
        if self._handshake.confirming:
            # The master's first packet of the session: it has our OPEN_ACK and (keyed) the keys.
            self._delivery.on_opened(now)
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
        elif size > HEADER_SIZE and data[HEADER_SIZE] in STAMP_CODES:  # PROTOCOL.md 5.11
            if self._one_way.take(data, self.last_rx_time, now, self._stats):
                if data[HEADER_SIZE] == _TIMED:
                    self._on_data(data[:5] + data[5 + STAMP_SIZE :], seq, ack, sack, hold, now)
                else:
                    self._on_ack_packet(size, ack, sack, hold, now)
                self._one_way.pending = False  # (unread if the datagram was dropped)
        elif size > HEADER_SIZE and data[HEADER_SIZE] in MESSAGE_CODES:  # PROTOCOL.md 5.10
            verdict = self._channel.receive(data, self._state is ESTABLISHED, now)
            if verdict is TAKEN:
                self._accept(size, size - HEADER_SIZE, now)
            elif verdict is ALIVE:
                self._heard(now)  # dropped, but well formed and (keyed) authentic
        else:
            self._on_session_control(data, size, ack, sack, hold, now)

    def _on_reset(self, data: bytes, now: float) -> None:
        """A RESET: the slave holds no session for us (PROTOCOL.md 5.7). Taken only by an
        established master, if it echoes a recent datagram of ours (keyed: and proves the key)."""
        guard = self._outbox.reset_guard
        if self._state is not State.ESTABLISHED or guard is None:
            self._stats.count_drop(DropReason.UNEXPECTED_CONTROL)
            return
        refused = guard.judge(data)
        if refused is not None:
            self._stats.count_drop(refused)
            return
        self._stats.received.control_packets += 1
        peer = self._peer_address()
        self._terminate(
            CloseCause.PEER_RESTARTED,
            f"the slave at {peer[0]}:{peer[1]} holds no session for us (it restarted); open a "
            "new connection",
        )

    def evict(self, *, now: float) -> None:
        """Slave side: give this session's slot to a new master (the server is full and ours has
        been silent longest); the master, if it ever hears again, gets a CLOSE."""
        if self._state is State.CLOSED:
            return
        if self._peer is not None:
            self._queue_close(CloseReason.IDLE_TIMEOUT, self._peer)
        silent = now - self._liveness.last_receive
        self._terminate(
            CloseCause.EVICTED,
            f"the server was full and this master had been silent for {silent:.1f} s, longer "
            "than any other; its slot went to a new master",
        )

    def roam(self, data: bytes, addr: Address, *, now: float) -> bool:
        """Keyed slave: follow the master to ``addr`` if ``data`` from there authenticates with a
        packet number above every one accepted so far (PROTOCOL.md 5.8), and take it in. False,
        counting nothing, otherwise: the caller (:class:`~tdtp.admission.PathMigration`) counts."""
        opener = self._opener
        if opener is None or not self.migratable or len(data) > self._size_limit:
            return False
        opened = self._path.trial(opener, data, now)
        if opened is None:
            return False
        self._stats.datagrams_in += 1
        self._peer = addr
        self._hint.value = -math.inf
        self._path.move(False, len(data), self._recovery.sent.next_seq, self._sender.limit)
        self._dispatch(opened, data[0] >> 6, now)
        return True

    def migrate(self, addr: Address, *, now: float) -> None:
        """Unkeyed slave: move to ``addr``, validated (its PATH_RESPONSE carried our nonce)."""
        if not self.migratable:
            raise ConnectionStateError(f"migrate() is for an established slave, not {self!r}")
        self._stats.datagrams_in += 1
        self._peer = addr
        self._hint.value = -math.inf
        self._path.move(True, 0, 0, 0)
        self._heard(now)

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
        self._heard(now)

    def _heard(self, now: float) -> None:
        """A datagram from the peer, whether or not it is taken in (late, duplicate, stale): it
        shows the peer is alive."""
        liveness = self._liveness
        liveness.last_receive = now
        if liveness.silent_since is not None:
            self._on_peer_resumed(now)

    def _on_peer_resumed(self, now: float) -> None:
        silent_for = self._liveness.resume(now)
        stats = self._stats
        stats.longest_silence = max(stats.longest_silence, silent_for)
        self._push_watchdog_event(PeerResumed(silent_for, now))
        self._controller.on_peer_resumed(now=now, silent_for=silent_for)
        self._hint.value = -math.inf  # the watchdog's deadline is silence_timeout again, not idle

    def _on_data(self, data: bytes, seq: int, ack: int, sack: int, hold: int, now: float) -> None:
        stats = self._stats
        window = self._acks.window
        if self._state is not ESTABLISHED or window is None:
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
        echo: float | None = None
        if hold != HOLD_NO_ACK:
            if not self._on_feedback(ack, sack, hold, now):
                stats.count_drop(DropReason.OPTIMISTIC_ACK)
                return
            echo = self._recovery.echo
        arrival = self._acks.on_arrival(window, seq, now)
        delivery = self._delivery
        in_order = delivery.reorder is not None  # through the reorder wait, else as it came
        if arrival is not NEW:
            if arrival is STALE:
                self._heard(now)
                stats.count_drop(DropReason.STALE)
                return
            if arrival is LATE:
                stats.reordered += 1
                # False once its gap was given up: late after all.
                in_order = in_order and delivery.on_late(window.last_seq, now)
                if not in_order and not self._deliver_late:
                    self._heard(now)
                    stats.count_drop(DropReason.LATE)
                    return
            elif not self._deliver_duplicates:
                self._heard(now)
                stats.count_drop(DropReason.DUPLICATE)
                return
            else:
                in_order = False  # a duplicate the application asked for goes up as it came
        elif in_order and window.last_gap:
            delivery.on_gap(window.last_seq, window.last_gap, now)
        received = stats.received
        received.datagrams += 1
        received.bytes += size + self._overhead
        received.header_bytes += HEADER_SIZE
        received.payload_bytes += payload_size
        received.protection_bytes += self._overhead
        received.data_packets += 1
        liveness = self._liveness
        liveness.last_receive = now
        if liveness.silent_since is not None:
            self._on_peer_resumed(now)
        sent_at = self._one_way.sent_at(echo, hold, now)  # PROTOCOL.md 3.6
        if not in_order:
            delivery.deliver(data[HEADER_SIZE:], window.last_seq, now, now, sent_at)
        elif delivery.arrive(data[HEADER_SIZE:], window.last_seq, now, sent_at):
            self._hint.value = -math.inf  # held: the reorder wait has a deadline

    def _on_ack_packet(self, size: int, ack: int, sack: int, hold: int, now: float) -> None:
        stats = self._stats
        if self._state is not ESTABLISHED:
            stats.count_drop(DropReason.NOT_ESTABLISHED)
            return
        if hold != HOLD_NO_ACK and not self._on_feedback(ack, sack, hold, now):
            stats.count_drop(DropReason.OPTIMISTIC_ACK)
            return
        self._accept(size, 0, now)
        stats.received.ack_packets += 1
        self._one_way.settle(None if hold == HOLD_NO_ACK else self._recovery.echo, hold, now)

    def _on_feedback(self, ack: int, sack: int, hold: int, now: float) -> bool:
        """Hand the acknowledgement in a header to loss recovery (False if it acknowledges a packet
        never sent). It finishes later (``LossRecovery.settle``), after the application's answer."""
        recovery = self._recovery
        if not recovery.take_feedback(ack, sack, hold, now):
            return False
        if self._sender.pending is not None:
            self._hint.value = -math.inf  # a new rate may let the held sample go earlier
        if self._path.limited:
            recovery.settle()
            self._path.on_acked(recovery.sent.largest_acked)
        return True

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
        if not isinstance(body, CloseBody | KeepaliveBody):
            stats.count_drop(DropReason.UNEXPECTED_CONTROL)
            return
        # Another session's, or a blind forgery (the nonce is secret to off-path attackers): a
        # forged KEEPALIVE must not pass for a sign of life and hide a dead master.
        if body.nonce != self._handshake.master_nonce:
            stats.count_drop(DropReason.NONCE_MISMATCH)
            return
        if isinstance(body, CloseBody):
            self._accept(size, size - HEADER_SIZE, now)
            stats.received.control_packets += 1
            self._terminate(CloseCause.PEER_CLOSE, close_reason_text(body.reason))
            return
        if self._state is not State.ESTABLISHED:
            stats.count_drop(DropReason.NOT_ESTABLISHED)
            return
        if hold != HOLD_NO_ACK and not self._on_feedback(ack, sack, hold, now):
            stats.count_drop(DropReason.OPTIMISTIC_ACK)
            return
        self._accept(size, size - HEADER_SIZE, now)
        stats.received.control_packets += 1

    # ------------------------------------------------------------------ opening

    def _on_handshake(self, data: bytes, addr: Address, now: float) -> None:
        """OPEN, OPEN_ACK, COOKIE or REJECT: the messages whose fields travel in the clear, read by
        the handshake; what they change in the session happens here."""
        self._hint.value = -math.inf  # the opening's timers may move
        handshake = self._handshake
        state = self._state
        if self.role is Role.SLAVE:
            verdict = handshake.on_open(
                data, addr, now, listening=state is State.LISTENING, srtt=self._recovery.rtt.srtt
            )
            if isinstance(verdict, AdmittedOpen):
                self._open_session(verdict, addr, now)
            elif verdict is Reaction.ANSWER_AGAIN:
                self._queue_open_ack()
                self._delivery.opening_sent_at = now
            elif verdict is Reaction.REPLACED:
                self._terminate(
                    CloseCause.REPLACED, "the master opened a new connection from the same address"
                )
            return
        reaction = handshake.on_reply(
            data,
            now,
            opening=state is State.OPENING,
            established=state is State.ESTABLISHED,
            ack_mode=self._acks.mode,
            opener=self._opener,
        )
        if reaction is Reaction.IGNORED:
            return
        self._heard(now)
        if reaction is Reaction.REJECTED:
            self._terminate(CloseCause.REJECTED, handshake.detail)
        elif reaction is Reaction.OPENED:
            self._on_opened(decode_header(data).seq, now)

    def _open_session(self, admitted: AdmittedOpen, addr: Address, now: float) -> None:
        """A listening slave takes the admitted OPEN: adopt its settings, answer OPEN_ACK, and wait
        for the master's first packet of the session (it confirms the master has the OPEN_ACK)."""
        body = admitted.body
        handshake = self._handshake
        self._peer = addr
        handshake.adopt(admitted)
        acks = self._acks
        acks.mode = (
            AckMode.SEPARATE if body.flags & OpenFlags.SEPARATE_ACKS else AckMode.BIDIRECTIONAL
        )
        self._sender.limit = min(self.config.max_payload, body.max_payload)
        acks.open(admitted.initial_seq)
        self._channel.open(self._recovery.sent.next_seq, admitted.initial_seq)
        self._delivery.open(admitted.initial_seq)
        self._install_protection()
        self._stats.count_handshake(admitted.size, handshake.tag_size)
        self._heard(now)
        self._state = State.OPENING
        handshake.confirming = True
        handshake.open_deadline = now + self.config.open_timeout
        self._liveness.last_send = now
        self._queue_open_ack()
        self._delivery.opening_sent_at = now

    def _on_opened(self, initial_seq: int, now: float) -> None:
        """A master's OPEN_ACK (already counted): the session opens, unless the slave's payloads
        are too small for us."""
        self._delivery.on_opened(now)
        self._install_protection()
        peer_max_payload = self._handshake.peer_max_payload
        if peer_max_payload < self.config.min_peer_payload:
            self._queue_close(CloseReason.PAYLOAD_TOO_SMALL, self._peer_address())
            self._terminate(
                CloseCause.REJECTED,
                f"the slave accepts payloads of at most {peer_max_payload} bytes, smaller than "
                f"min_peer_payload ({self.config.min_peer_payload})",
            )
            return
        self._sender.limit = min(self.config.max_payload, peer_max_payload)
        self._acks.open(initial_seq)
        self._channel.open(self._recovery.sent.next_seq, initial_seq)
        self._delivery.open(initial_seq)
        self._establish(now)
        # Confirm at once (the slave waits for our first packet of the session): the next
        # datagrams_to_send sends a KEEPALIVE unless a sample goes out. (Twice the interval back:
        # exactly one back can round to a deadline just after ``now``, delaying the KEEPALIVE.)
        liveness = self._liveness
        liveness.last_send = now - 2.0 * liveness.keepalive

    def _install_protection(self) -> None:
        """A keyed session's keys, derived at the open, protect every datagram from now on."""
        keys = self._handshake.keys
        if keys is None:
            return
        outbox = self._outbox
        outbox.sealer, self._opener = keys
        outbox.overhead = self._overhead = PROTECTION_OVERHEAD

    def _peer_address(self) -> Address:
        peer = self._peer
        assert peer is not None  # set by connect() or at the OPEN
        return peer

    def _establish(self, now: float) -> None:
        self._state = State.ESTABLISHED
        self._hint.value = -math.inf
        self._handshake.confirming = False
        self._one_way.start(now, self._handshake.timestamps)
        liveness = self._liveness
        liveness.last_receive = now
        liveness.last_send = now
        self._push_other_event(ConnectionEstablished(self._peer_address()))

    # ------------------------------------------------------------------ timers

    def get_timer(self) -> float | None:
        """The next absolute time :meth:`handle_timer` (then :meth:`datagrams_to_send`) is due."""
        if self._recovery.pending:
            self._recovery.settle()
        hint = self._hint
        hint.value = math.inf
        state = self._state
        if state is OPENING:
            handshake = self._handshake
            if self.role is Role.SLAVE:
                return handshake.open_deadline
            return min(handshake.open_next, handshake.open_deadline)
        if state is not ESTABLISHED:
            return None
        # The watchdog until the peer is silent, then the outage limit; the keep-alive; the pacer's
        # for a waiting sample; the next ACK; the next loss; the controller's own.
        if self._path.blocked(self._outbox.control):
            # Nothing may leave before more arrives from the new path: only the watchdog's clock.
            deadline = self._liveness.watchdog_deadline()
        else:
            deadline = self._acks.deadline(self._sender.deadline(self._liveness.deadline()))
            deadline = self._channel.deadline(deadline)
        loss_deadline = self._recovery.loss_deadline()
        if loss_deadline is not None and loss_deadline < deadline:
            deadline = loss_deadline
        reorder_deadline = self._delivery.deadline()
        if reorder_deadline is not None and reorder_deadline < deadline:
            deadline = reorder_deadline
        controller_deadline = self._controller.get_timer()
        hint.controller_seen = controller_deadline
        if controller_deadline is not None and controller_deadline < deadline:
            deadline = controller_deadline
        return deadline

    def handle_timer(self, *, now: float) -> None:
        """Act on whatever is due at ``now``. Calling it early or late is harmless."""
        if self._recovery.pending:
            self._recovery.settle()
        self._hint.value = -math.inf
        state = self._state
        if state is OPENING:
            if now >= self._handshake.open_deadline:
                if self.role is Role.MASTER:
                    detail = f"no answer to OPEN within {self.config.open_timeout} s"
                else:
                    detail = (
                        "the master never confirmed the session within "
                        f"{self.config.open_timeout} s after our OPEN_ACK"
                    )
                self._terminate(CloseCause.OPEN_TIMEOUT, detail)
            return
        if state is not ESTABLISHED:
            return
        liveness = self._liveness
        if liveness.idle_expired(now):
            self._queue_close(CloseReason.IDLE_TIMEOUT, self._peer_address())
            self._terminate(
                CloseCause.IDLE_TIMEOUT,
                f"nothing received from the peer for {self.config.idle_timeout:g} s",
            )
            return
        if liveness.check_silence(now):
            self._stats.peer_silences += 1
            self._push_watchdog_event(PeerSilent(liveness.last_receive, now))
            self._controller.on_peer_silent(now=now)
        self._recovery.detect_losses(now)
        self._channel.expire(now)
        self._delivery.release(now)
        controller_deadline = self._controller.get_timer()
        if controller_deadline is not None and now >= controller_deadline:
            self._controller.on_timer(now=now)

    # ------------------------------------------------------------------ output

    def datagrams_to_send(self, *, now: float) -> list[tuple[bytes, Address]]:
        """Everything that should leave at ``now``, with its destination."""
        if self._recovery.pending:
            self._recovery.settle()
        out: list[tuple[bytes, Address]] = []
        outbox = self._outbox
        state = self._state
        if state is OPENING and self.role is Role.MASTER and self._handshake.open_due(now):
            self._emit_open(out, now)
        path = self._path
        # The 3x limit of an unvalidated new path (PROTOCOL.md 5.8).
        if path.limited and path.blocked(outbox.control):
            if self._sender.pending is not None or self._liveness.keepalive_due(now):
                self._stats.path_limited += 1
            return out
        if outbox.control:
            outbox.flush(out, now)
        if state is ESTABLISHED and self._state is ESTABLISHED:
            self._emit_session(out, now)
        if path.limited:
            path.on_sent(out)
        return out

    def _emit_session(self, out: list[tuple[bytes, Address]], now: float) -> None:
        """The established session's share of :meth:`datagrams_to_send`."""
        outbox = self._outbox
        peer = self._peer
        assert peer is not None  # ESTABLISHED implies it
        sent = self._recovery.sent
        acks = self._acks
        window = acks.window
        assert window is not None  # opened with the session
        # Each piece is asked only when it may have something (its method's first test, inline).
        if window.held:
            acks.emit_held(out, outbox, sent.next_seq, peer, now)  # before the sample: jump rule
        if self._sender.pending is not None:
            self._sender.take_due(out, peer, now)
        if acks.due <= now or acks.separate:
            acks.emit_due(out, outbox, sent.next_seq, peer, now)
        if self._channel.emit_at <= now:
            self._channel.emit(out, sent.next_seq, peer, now, self._path.limited)
        liveness = self._liveness
        if now >= liveness.last_send + liveness.keepalive:  # Liveness.keepalive_due, inline
            ack, sack, hold = acks.piggyback(window, now)
            nonce = self._handshake.master_nonce
            outbox.emit_keepalive(out, sent.next_seq, ack, sack, hold, nonce, peer, now)
        if outbox.sealer is not None and outbox.sealer.exhausted:
            self._exhausted()

    def _emit_open(self, out: list[tuple[bytes, Address]], now: float) -> None:
        handshake = self._handshake
        datagram = handshake.next_open(self._recovery.sent.next_seq, self._acks.mode)
        if datagram is None:
            self._terminate(CloseCause.OPEN_TIMEOUT, "no answer to 65536 OPENs")
            return
        self._outbox.emit_control(
            out, datagram, self._peer_address(), now, handshake.tag_size, True
        )
        self._delivery.opening_sent_at = now

    # ------------------------------------------------------------------ helpers

    def _queue_open_ack(self) -> None:
        handshake = self._handshake
        outbox = self._outbox
        seq = self._recovery.sent.next_seq
        datagram = handshake.open_ack(seq, self._acks.mode, outbox.sealer)
        outbox.queue(datagram, self._peer_address(), handshake.tag_size, True)

    def _queue_close(self, reason: CloseReason, addr: Address) -> None:
        self._outbox.queue_close(
            self._recovery.sent.next_seq, self._handshake.master_nonce, reason, addr
        )

    def _terminate(self, cause: CloseCause, detail: str) -> None:
        self._state = State.CLOSED
        self._hint.value = -math.inf
        self._handshake.confirming = False
        self._sender.drop()
        self._acks.separate.clear()
        self._close_event = event = ConnectionClosed(cause, detail)
        self._push_other_event(event)

    def _push_other_event(self, event: Event) -> None:
        self._events.push(event)
        self._hint.value = -math.inf

    def _push_watchdog_event(self, event: PeerSilent | PeerResumed) -> None:
        """Watchdog events share the ``max_pending_events`` bound (EventQueue.push_watchdog)."""
        self._events.push_watchdog(event)
        self._hint.value = -math.inf
