"""The sans-IO TDTP connection: a state machine that never touches a socket or reads a clock.

The caller owns I/O and time: datagrams in (:meth:`Connection.receive_datagram`), timer expiries
(:meth:`Connection.handle_timer`), samples (:meth:`Connection.send`), each with ``now``; after every
input it collects :meth:`Connection.datagrams_to_send`, re-arms one timer at
:meth:`Connection.get_timer` and takes :meth:`Connection.next_event`. The asyncio endpoints, the
emulator and the simulator all drive this one class. It checks input against the state, takes every
datagram in (address, size, protection, type), dispatches it, and carries out what the opening, the
watchdog (PROTOCOL.md 5.2) and path migration (5.8) decide; the pieces with state of their own (listed
in :mod:`tdtp.session`, a multipath session's paths in :mod:`tdtp.session.multipath`) live beside it.
Peer input never raises: anything malformed, unexpected or hostile is dropped and counted in
``stats.drops`` by reason. Misuse by the caller raises a :class:`~tdtp.errors.TdtpError` subclass.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable
from typing import Final

from tdtp.admission.admission import Admission, AdmittedOpen
from tdtp.admission.path_migration import NOT_OURS, OURS, ROAMED
from tdtp.config import AckMode, ConnectionConfig, Role
from tdtp.control.registry import create_controller
from tdtp.errors import ConnectionStateError
from tdtp.protection.keys import KeysInput, OneKeyInput
from tdtp.protection.packet_protection import PacketOpener
from tdtp.session import ending
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
from tdtp.session.handshake import Handshake, Reaction
from tdtp.session.liveness import Liveness
from tdtp.session.multipath.paths import Multipath
from tdtp.session.one_way import STAMP_CODES, STAMP_SIZE, TIMED
from tdtp.session.outbox import Outbox
from tdtp.session.path import PeerPath
from tdtp.session.receive_window import FAR_AHEAD, LATE, NEW, STALE
from tdtp.session.recovery import LossRecovery
from tdtp.session.reset_guard import ResetGuard
from tdtp.session.sender import SampleSender
from tdtp.session.state import CLOSED, ESTABLISHED, OPENING, State, dialing, refusal
from tdtp.session.stats import ConnectionStats, DropReason
from tdtp.session.timer_hint import TimerHint
from tdtp.session.view import ConnectionView
from tdtp.wire.control import (
    HANDSHAKE_CODES,
    MESSAGE_CODES,
    OPEN_BODY_SIZE,
    PATH_CODES,
    CloseBody,
    CloseReason,
    ControlCode,
    OpenFlags,
)
from tdtp.wire.header import HEADER_SIZE, PacketType, decode_header
from tdtp.wire.hold import HOLD_NO_ACK
from tdtp.wire.protected import PROTECTION_OVERHEAD, TAG_SIZE
from tdtp.wire.seqnum import SEQ_MODULUS

_DATA: Final = int(PacketType.DATA)
_ACK: Final = int(PacketType.ACK)
_CONTROL: Final = int(PacketType.CONTROL)
_RESET: Final = int(ControlCode.RESET)
_LARGEST_CONTROL: Final = OPEN_BODY_SIZE + TAG_SIZE
"""The largest control body (a keyed OPEN's): datagrams up to this size pass the size check whatever
``max_payload`` is."""


class Connection(ConnectionView):
    """One TDTP association. ``role``: the master commands, the slave obeys; ``dials``: this end
    sends the OPEN (by default the master; a slave dials a master behind a NAT, PROTOCOL.md 5.1).
    A dialer's ``key=`` opens a keyed session; a listener's ``keys=`` (one, several, a KeyRing)
    accepts keyed sessions only, after a cookie validated the dialer's address (``admission=``: a
    server's shared one). ``rng``: nonces and initial sequence number (seeded: reproducible runs;
    the default, the system's CSPRNG, is what a keyed session needs)."""

    def __init__(
        self,
        config: ConnectionConfig | None = None,
        *,
        role: Role,
        rng: random.Random | None = None,
        key: OneKeyInput | None = None,
        keys: KeysInput | None = None,
        admission: Admission | None = None,
        dials: bool | None = None,
    ) -> None:
        self.dials = dials = dialing(role, dials)  # whether this end sends the OPEN
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
            dials=dials,
            key=key,
            keys=keys,
            admission=admission,
            stats=stats,
            outbox=outbox,
            liveness=liveness,
        )
        self._state = State.IDLE if dials else State.LISTENING
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
        self._sender = sender = SampleSender(
            config,
            controller=controller,
            stats=stats,
            recovery=recovery,
            outbox=outbox,
            acks=acks,
            liveness=liveness,
            hint=hint,
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
            config, events=self._events, stats=stats, rtt=recovery.rtt, one_way=sender.one_way
        )
        self._ages = delivery.ages
        self.multipath: Multipath | None = None  # a multipath session's paths (PROTOCOL.md 5.11)

    # ------------------------------------------------------------------ caller API

    def connect(self, addr: Address, *, now: float) -> None:
        """The dialing side only: start opening towards the peer at ``addr``."""
        if not self.dials:
            raise ConnectionStateError(
                "connect() is for the side that dials (dials=True); a listening connection opens "
                "when its peer's OPEN arrives through receive_datagram()"
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

        When the sample may leave at once as the only datagram due (established, one path, the
        pacer and the socket allow it, no control packet, held ACK or separate ACK waiting), it is
        passed to ``transmit(datagram, addr)`` (``addr`` ``None`` when ``connected``, else the
        peer's: ``transport.sendto`` fits) *before* the bookkeeping. An :class:`OSError` from it
        counts in :attr:`transmit_errors` (the datagram is lost like any other). It raises what
        :meth:`send` raises; False: not sent, the sample offered as by :meth:`send` (then
        :meth:`datagrams_to_send` must run)."""
        peer = self._peer
        if self._state is not ESTABLISHED or peer is None or self._path.limited or self.multipath:
            self.send(payload, now=now)
            return False
        if not self._sender.send_direct(payload, transmit, peer, connected, now):
            return False
        sealer = self._outbox.sealer
        if sealer is not None and sealer.exhausted:
            self._terminate(CloseCause.KEY_EXHAUSTED, ending.KEY_EXHAUSTED_TEXT, now)
        return True

    def send_control(self, message: bytes | bytearray | memoryview, *, now: float) -> None:
        """Queue a message on the reliable control channel (:mod:`tdtp.session.control_channel`)."""
        if self._state is not State.ESTABLISHED:
            raise refusal(self._state, self._close_event)
        self._channel.send(message, now)

    def pause_sending(self) -> None:
        """The layer below cannot take datagrams now (the socket's send buffer is full). Data is
        held: the pending sample waits and newer samples supersede it (counted in
        ``samples_superseded`` and ``samples_blocked``) instead of queueing out of sight; ACKs and
        control packets still go out. Then :meth:`resume_sending` and :meth:`datagrams_to_send`."""
        self._sender.pause()

    def resume_sending(self) -> None:
        """The layer below takes datagrams again; the newest held sample leaves when the pacer allows."""
        self._sender.resume()

    def close(
        self, *, now: float, taken_over: bool = False, restarting: bool = False
    ) -> bytes | None:
        """End the connection: a CLOSE goes out with the next :meth:`datagrams_to_send` (and is
        returned, so that a server can repeat it: PROTOCOL.md 5.9; ``None``: nothing to send).
        ``taken_over``: an exclusive slave hands control to another master (PROTOCOL.md 5.9);
        ``restarting``: this side stops but expects to be back soon (CLOSE RESTARTING, 5.2)."""
        if self._state is State.CLOSED:
            return None
        reason, cause, detail = ending.local_ending(taken_over=taken_over, restarting=restarting)
        opened = self._state is State.OPENING or self._state is State.ESTABLISHED
        self._terminate(cause, detail, now, reason, send=opened)
        control = self._outbox.control
        return control[-1][0] if opened and control else None

    def accept_open(self, admitted: AdmittedOpen, addr: Address, *, now: float) -> None:
        """Slave only: take an OPEN that a shared :class:`~tdtp.admission.Admission` already
        admitted for ``addr`` (a server demultiplexing many masters on one socket does this; a
        stand-alone slave gets its OPENs through :meth:`receive_datagram`)."""
        if self.dials or self._state is not State.LISTENING:
            raise ConnectionStateError(
                f"accept_open() is for a listening connection (this is a {self.role.value} "
                f"that {'dials' if self.dials else 'listens'}, in state {self._state.value}); "
                "create a new Connection for each peer"
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
        """Take one datagram from the network. Never raises on its content. Optional inputs a
        driver may know (the core reads no clock for either): ``rx_time``, when the kernel received
        it (on ``now``'s clock; :attr:`last_rx_time`, what the peer's send times are read against),
        and ``ecn``, the IP header's ECN field (``3``, Congestion Experienced: ``stats.ecn_ce``)."""
        stats = self._stats
        stats.datagrams_in += 1
        if self._state is CLOSED:
            stats.count_drop(DropReason.CLOSED)
            return
        peer = self._peer
        if peer is not None and addr != peer and (addr[0] != peer[0] or addr[1] != peer[1]):
            paths = self.multipath  # another of a multipath session's paths, or a new one?
            if paths is None or not paths.admits(data, addr):
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
                established = self._state is State.ESTABLISHED and self.dials
                nonce = self._handshake.master_nonce
                answer = self._path.answer(data, now, established and not self.keyed, nonce)
                if answer is not None:
                    self._outbox.queue(answer, addr, 0, False)
                    self._hint.value = -math.inf
                return
        if ptype > _CONTROL:
            stats.count_drop(DropReason.UNKNOWN_TYPE)
            return
        paths = self.multipath
        if paths is not None and paths.intercept(data, addr, ptype, now):
            return  # multipath control, or a copy of a sample taken in already
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
        elif size > HEADER_SIZE and data[HEADER_SIZE] in STAMP_CODES:  # PROTOCOL.md 5.13
            kind = self._sender.one_way.take(data, self.last_rx_time, now)
            if kind == TIMED:
                self._on_data(data[:5] + data[5 + STAMP_SIZE :], seq, ack, sack, hold, now)
            elif kind:
                self._on_ack_packet(size, ack, sack, hold, now)
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
        refused = guard.judge(data, self._liveness.silent_for_watchdog(now))  # 5.7
        if refused is not None:
            self._stats.count_drop(refused)
            return
        self._stats.received.control_packets += 1
        self._terminate(CloseCause.PEER_RESTARTED, ending.restarted_text(self._peer_address()), now)

    def evict(self, detail: str, *, now: float) -> bytes | None:
        """Slave side: give this session's slot to a new master (:mod:`tdtp.admission.slots`
        chose it; ``detail`` says why). Queues a CLOSE ``EVICTED`` and returns it, so that the
        server can repeat it to the master's later datagrams (``None``: nothing to send)."""
        peer = self._peer
        if self._state is State.CLOSED or peer is None:
            return None
        self._terminate(CloseCause.EVICTED, detail, now, CloseReason.EVICTED, send=True)
        return self._outbox.control[-1][0]

    def roam(self, data: bytes, addr: Address, *, now: float) -> int:
        """Keyed slave: follow the master to ``addr`` if ``data`` from there authenticates above every
        packet number accepted so far (PROTOCOL.md 5.8), and take it in: ROAMED. OURS if it does at
        an older one (a copy of our master's), else NOT_OURS; the caller (PathMigration) counts."""
        opener = self._opener
        if opener is None or not self.migratable or len(data) > self._size_limit:
            return NOT_OURS
        opened = self._path.trial(opener, data, now)
        if opened is None:
            return OURS if opener.failure == "replayed" else NOT_OURS
        self._stats.datagrams_in += 1
        self._peer = addr
        self._hint.value = -math.inf
        self._path.move(len(data), self._recovery.sent.next_seq, self._sender.limit)
        self._dispatch(opened, data[0] >> 6, now)
        return ROAMED

    def migrate(self, addr: Address, *, now: float) -> None:
        """Unkeyed slave: move to ``addr`` (its PATH_RESPONSE carried our nonce), under the 3x limit
        until the old address has been silent for ``silence_timeout`` (:meth:`move_back`)."""
        if not self.migratable:
            raise ConnectionStateError(f"migrate() is for an established slave, not {self!r}")
        self._stats.datagrams_in += 1
        previous, self._peer = self._peer, addr
        self._hint.value = -math.inf
        self._path.move_unproven(previous, now + self.config.silence_timeout, self._sender.limit)
        self._heard(now)

    def move_back(self, data: bytes, addr: Address, *, now: float) -> bool:
        """Unkeyed slave moved by :meth:`migrate` whose old address ``addr`` speaks before the new
        one is proven: back there (validated before), taking ``data`` in. False otherwise."""
        if not self._path.returning(addr):
            return False
        self._peer = addr
        self._hint.value = -math.inf
        self.receive_datagram(data, addr, now=now)
        return True

    def use_path(self, addr: Address) -> None:
        """Send to ``addr``: a path to the peer proven outside the session (PROTOCOL.md 5.12)."""
        if self._state is not ESTABLISHED:
            raise ConnectionStateError(f"use_path() needs an established session, not {self!r}")
        self._peer = addr
        self._hint.value = -math.inf

    def _on_unopened(self, opener: PacketOpener, now: float) -> None:
        """A protected datagram that did not authenticate (or was replayed): dropped and counted; a
        key that has seen too many forgeries is retired with its connection (RFC 9001, 6.6)."""
        self._stats.count_drop(DropReason(opener.failure))
        if opener.exhausted:
            self._terminate(CloseCause.KEY_EXHAUSTED, ending.FORGERY_LIMIT_TEXT, now)

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
        arrival = self._acks.on_arrival(window, seq, now)
        if arrival is FAR_AHEAD:
            stats.count_drop(DropReason.FAR_AHEAD)  # no sign of life, its ACK unread (5.5)
            return
        echo: float | None = None
        if hold != HOLD_NO_ACK:
            if self._on_feedback(ack, sack, hold, now):
                echo = self._recovery.echo
            else:
                stats.optimistic_acks += 1  # the ACK is ignored, the sample taken (3.1)
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
                in_order = in_order and delivery.on_late(window.last_seq, window.highest, now)
                if not in_order and not self._deliver_late:
                    self._heard(now)
                    stats.count_drop(DropReason.LATE)
                    return
            else:
                delivery.on_duplicate(window.last_seq)  # a forgery's number, arriving for real?
                if not self._deliver_duplicates:
                    self._heard(now)
                    stats.count_drop(DropReason.DUPLICATE)
                    return
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
        sent_at = self._sender.one_way.sent_at(echo, hold, now)  # PROTOCOL.md 3.6
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
        self._sender.one_way.settle(None if hold == HOLD_NO_ACK else self._recovery.echo, hold, now)

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
        body = self._handshake.session_control(data)
        if body is None:
            return  # malformed, unexpected, or another nonce's (counted)
        if isinstance(body, CloseBody):
            self._accept(size, size - HEADER_SIZE, now)
            stats.received.control_packets += 1
            cause, detail = ending.peer_ending(body.reason)
            self._terminate(cause, detail, now, body.reason)
            return
        if self._state is not State.ESTABLISHED:
            stats.count_drop(DropReason.NOT_ESTABLISHED)
            return
        if hold != HOLD_NO_ACK and not self._on_feedback(ack, sack, hold, now):
            stats.optimistic_acks += 1  # the ACK is ignored, the KEEPALIVE taken (3.1)
        self._accept(size, size - HEADER_SIZE, now)
        stats.received.control_packets += 1

    # ------------------------------------------------------------------ opening

    def _on_handshake(self, data: bytes, addr: Address, now: float) -> None:
        """OPEN, OPEN_ACK, COOKIE or REJECT: the messages whose fields travel in the clear, read by
        the handshake; what they change in the session happens here."""
        self._hint.value = -math.inf  # the opening's timers may move
        handshake = self._handshake
        state = self._state
        if not self.dials:
            verdict = handshake.on_open(
                data, addr, now, listening=state is State.LISTENING, srtt=self._recovery.rtt.srtt
            )
            if isinstance(verdict, AdmittedOpen):
                self._open_session(verdict, addr, now)
            elif verdict is Reaction.ANSWER_AGAIN:
                self._queue_open_ack()
                self._delivery.opening_sent_at = now
            elif verdict is Reaction.REPLACED:
                self._terminate(CloseCause.REPLACED, ending.REPLACED_TEXT, now)
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
            self._terminate(CloseCause.REJECTED, handshake.detail, now, handshake.reject_reason)
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
        acks.open(admitted.initial_seq, handshake.keyed)
        self._channel.open(self._recovery.sent.next_seq, admitted.initial_seq, body.nonce)
        self._delivery.open(admitted.initial_seq, handshake.keyed)
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
            self._terminate(
                CloseCause.REJECTED,
                f"the slave accepts payloads of at most {peer_max_payload} bytes, smaller than "
                f"min_peer_payload ({self.config.min_peer_payload})",
                now,
                CloseReason.PAYLOAD_TOO_SMALL,
                send=True,
            )
            return
        self._sender.limit = min(self.config.max_payload, peer_max_payload)
        handshake = self._handshake
        self._acks.open(initial_seq, handshake.keyed)
        self._channel.open(self._recovery.sent.next_seq, initial_seq, handshake.master_nonce)
        self._delivery.open(initial_seq, handshake.keyed)
        self._establish(now)
        # Confirm at once (the slave waits for our first packet): a KEEPALIVE unless a sample goes
        # (twice the interval back: once can round to a deadline just after ``now``).
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

    def _establish(self, now: float) -> None:
        self._state = State.ESTABLISHED
        self._hint.value = -math.inf
        self._handshake.confirming = False
        self._sender.one_way.start(now, self._handshake.stamps, self._acks.mode is AckMode.SEPARATE)
        liveness = self._liveness
        liveness.last_receive = now
        liveness.last_send = now
        if self._handshake.multipath:
            self.multipath = Multipath.attach(self, now)
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
            if not self.dials:
                return handshake.open_deadline
            return min(handshake.open_next, handshake.open_deadline)
        if state is not ESTABLISHED:
            return None
        # Watchdog (or outage limit), keep-alive, pacer, ACK, loss, reorder wait, controller.
        if self._path.blocked(self._outbox.control, -math.inf):
            # Nothing may leave before more arrives from the new path (or, unkeyed, it is proven).
            deadline = min(self._liveness.watchdog_deadline(), self._path.proven_at)
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
                timeout = self.config.open_timeout
                detail = ending.open_timeout_text(dials=self.dials, timeout=timeout)
                self._terminate(CloseCause.OPEN_TIMEOUT, detail, now)
            return
        if state is not ESTABLISHED:
            return
        liveness = self._liveness
        if liveness.idle_expired(now):
            self._terminate(
                CloseCause.IDLE_TIMEOUT,
                f"nothing received from the peer for {self.config.idle_timeout:g} s",
                now,
                CloseReason.IDLE_TIMEOUT,
                send=True,
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
        if state is OPENING and self.dials and self._handshake.open_due(now):
            self._emit_open(out, now)
        path = self._path
        # The 3x limit of an unvalidated new path (PROTOCOL.md 5.8).
        if path.limited and path.blocked(outbox.control, now):
            if self._sender.pending is not None or self._liveness.keepalive_due(now):
                self._stats.path_limited += 1
            return out
        if outbox.control:
            outbox.flush(out, now)
        if state is ESTABLISHED and self._state is ESTABLISHED:
            self._emit_session(out, now)
        if path.limited:
            path.on_sent(out)
        if self.multipath is not None:
            return self.multipath.route(out, now)  # spread over the paths
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
            self._terminate(CloseCause.KEY_EXHAUSTED, ending.KEY_EXHAUSTED_TEXT, now)

    def _emit_open(self, out: list[tuple[bytes, Address]], now: float) -> None:
        handshake = self._handshake
        datagram = handshake.next_open(self._recovery.sent.next_seq, self._acks.mode)
        if datagram is None:
            self._terminate(CloseCause.OPEN_TIMEOUT, "no answer to 65536 OPENs", now)
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

    def _terminate(
        self,
        cause: CloseCause,
        detail: str,
        now: float,
        reason: int | None = None,
        *,
        send: bool = False,
    ) -> None:
        """End the session (``send``: with a CLOSE ``reason`` to the peer); control messages the
        peer never acknowledged are reported (``ControlExpired``) before the ``ConnectionClosed``."""
        peer = self._peer
        if send and reason is not None and peer is not None and self._state is not CLOSED:
            self._queue_close(CloseReason(reason), peer)
        self._state = State.CLOSED
        self._hint.value = -math.inf
        self._handshake.confirming = False
        self._sender.drop()
        self._acks.separate.clear()
        self._channel.abandon(ending.control_abandoned_text(cause, self._channel.unacked), now)
        self._close_event = event = ConnectionClosed(cause, detail, reason)
        self._push_other_event(event)

    def _push_other_event(self, event: Event) -> None:
        self._events.push(event)
        self._hint.value = -math.inf

    def _push_watchdog_event(self, event: PeerSilent | PeerResumed) -> None:
        """Watchdog events share the ``max_pending_events`` bound (EventQueue.push_watchdog)."""
        self._events.push_watchdog(event)
        self._hint.value = -math.inf
